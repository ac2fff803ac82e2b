"""Exceptions of the analysis (``rig.analysis.analyse`` and its modules). Messages name the file, segment or
column
and say what to run or change."""

from __future__ import annotations


class AnalysisError(ValueError):
    """Base class: observations, calibration or timing cannot become 3-D tracks as asked."""


class MissingInputError(AnalysisError, FileNotFoundError):
    """A file the analysis needs (``calibration.json``, ``timing.json``, ``record.jsonl``) is absent."""


class MissingObservationsError(AnalysisError):
    """A camera of the calibration has no observations (in the run, or in one segment)."""


class NoPairableTracksError(AnalysisError):
    """No 2-D track of one camera could be paired with a track of the other."""


class ClockMappingError(AnalysisError):
    """The record holds no ``camera`` event relating a camera clock to the controller clock."""

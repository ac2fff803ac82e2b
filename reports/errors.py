"""Exceptions of the reports layer; each message names the field or value at fault and what is allowed."""

from __future__ import annotations


class ReportError(ValueError):
    """Base class of every error raised while building a report."""


class RunFolderError(ReportError):
    """The run folder (or ``rig measure`` folder) is missing, unreadable or lacks a required document."""


class CriteriaError(ReportError):
    """An acceptance criterion in the configuration is unknown or has an invalid value."""


class AnalysisFailedError(ReportError):
    """The analysis of the primary sync method failed (the cause is chained and named in the message)."""


class FitError(ReportError):
    """A fit cannot be made (too few points, non-positive uncertainties, degenerate design)."""

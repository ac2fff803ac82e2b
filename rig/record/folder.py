"""A run folder read once: the record, ``calibration.json`` and ``timing.json`` decoded into their types.

``load_folder(run_dir) -> RunFolder`` is the one reader of the side files: the analysis and the reports
take the :class:`RunFolder` instead of reading the folder again. A side file that is absent is ``None``
(a run may not have calibrated or synchronized yet); one that is present but malformed raises
:class:`SideFileError` naming the file and what is wrong with it.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.record.reader import RECORD_NAME, Run, load_run
from rig.stereo.errors import StereoError
from rig.stereo.timing import TimingResult

CALIBRATION_FILE = "calibration.json"
TIMING_FILE = "timing.json"


class SideFileError(ValueError):
    """``calibration.json`` or ``timing.json`` is not what its schema says (the message names the file)."""


@dataclass(frozen=True)
class Calibration:
    """``calibration.json``: per camera its DLT entry (``P`` 3×4, ``image_size``, ``rms_px``,
    ``residuals_px``, … as :meth:`rig.stereo.dlt.DLTCamera.to_dict` writes it), the projection convention
    and the whole document (units, plate grid) for display."""

    cameras: dict[str, dict[str, Any]]
    convention: str | None = None
    document: dict[str, Any] = field(default_factory=dict, repr=False)

    @classmethod
    def from_dict(cls, d: dict[str, Any], path: Path | str = CALIBRATION_FILE) -> Calibration:
        """Decode the ``calibration.json`` content; raises :class:`SideFileError` on a malformed one."""
        entries = d.get("cameras")
        if not isinstance(entries, dict) or not all(isinstance(e, dict) for e in entries.values()):
            raise SideFileError(f"{path}: 'cameras' must map camera names to DLT entries (objects), got "
                                f"{str(entries)[:80]}; run `rig run calibrate`")
        convention = d.get("convention")
        return cls({str(k): dict(v) for k, v in entries.items()},
                   None if convention is None else str(convention), dict(d))

    def to_dict(self) -> dict[str, Any]:
        return {**self.document, "cameras": self.cameras, "convention": self.convention}


def read_json_object(path: Path) -> dict[str, Any] | None:
    """The JSON object in ``path``; None when the file is absent; :class:`SideFileError` when it is not an
    object."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SideFileError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise SideFileError(f"{path}: the top level must be a JSON object")
    return data


def read_calibration(run_dir: Path) -> Calibration | None:
    """``run_dir/calibration.json`` decoded, or None when absent."""
    data = read_json_object(run_dir / CALIBRATION_FILE)
    return None if data is None else Calibration.from_dict(data, run_dir / CALIBRATION_FILE)


def read_timing(run_dir: Path) -> TimingResult | None:
    """``run_dir/timing.json`` decoded into a :class:`TimingResult`, or None when absent."""
    data = read_json_object(run_dir / TIMING_FILE)
    if data is None:
        return None
    try:
        return TimingResult.from_dict(data)
    except StereoError as exc:
        raise SideFileError(f"{run_dir / TIMING_FILE}: {exc}; run `rig run sync`") from exc


@dataclass(frozen=True)
class RunFolder:
    """A run folder read once: the record (:class:`rig.record.reader.Run`) and its decoded side files."""

    run: Run
    calibration: Calibration | None
    timing: TimingResult | None

    @property
    def run_dir(self) -> Path:
        return self.run.run_dir


def load_folder(run_dir: str | os.PathLike[str], *, quiet: bool = False) -> RunFolder:
    """Read ``run_dir``'s record, ``calibration.json`` and ``timing.json`` (see the module docstring).

    ``quiet``: do not warn about a truncated last line (it is still flagged in ``run.truncated_last_line``).
    Raises :class:`rig.record.reader.RecordError` (no or a corrupt ``record.jsonl``) and
    :class:`SideFileError`.
    """
    run_dir = Path(run_dir)
    with warnings.catch_warnings():
        if quiet:
            warnings.simplefilter("ignore")
        run = load_run(run_dir)
    return RunFolder(run, read_calibration(run_dir), read_timing(run_dir))


__all__ = ["CALIBRATION_FILE", "RECORD_NAME", "TIMING_FILE", "Calibration", "RunFolder", "SideFileError",
           "load_folder", "read_calibration", "read_json_object", "read_timing"]

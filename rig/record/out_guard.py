"""Where ``rig measure --out DIR`` and ``rig calibrate --out FILE`` may write: never into a run folder, and
over earlier results only with ``--force``.

A run folder (a folder holding ``record.jsonl``, or any folder inside one) is evidence: nothing but its
own run writes there, ``--force`` included. An ``--out`` that already holds results (the files the
command writes) is refused unless ``force`` is set; other files in the folder (the videos, say) do not
count. Checked before any video is decoded, so a refusal costs nothing.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from rig.record.reader import RECORD_NAME

__all__ = ["OutputRefusedError", "check_out_file", "check_out_folder", "run_folder_of"]


class OutputRefusedError(ValueError):
    """``--out`` names a run folder, or holds results and ``--force`` was not given (exit 4)."""

    def __init__(self, path: Path, why: str) -> None:
        super().__init__(f"--out {path}: {why}")
        self.path, self.why = path, why


def run_folder_of(path: str | Path) -> Path | None:
    """The run folder ``path`` is or lies in (the nearest folder holding ``record.jsonl``), else None."""
    here = Path(path).resolve()
    for folder in (here, *here.parents):
        if (folder / RECORD_NAME).is_file():
            return folder
    return None


def _refuse_run_folder(path: Path, folder: Path) -> None:
    run = run_folder_of(folder)
    if run is not None:
        where = "is a run folder" if run == path.resolve() else f"lies in the run folder {run}"
        raise OutputRefusedError(path, f"{where} (it has {RECORD_NAME}); a run's evidence is never "
                                       "written over, --force included; give another folder")


def check_out_folder(path: str | Path, results: Iterable[str], *, force: bool) -> None:
    """Refuse ``path`` as an output folder: a run folder (always), a file, or a folder holding any of
    ``results`` (names of files or folders the command writes) unless ``force``."""
    path = Path(path)
    _refuse_run_folder(path, path)
    if path.exists() and not path.is_dir():
        raise OutputRefusedError(path, "is a file; give a folder")
    held = sorted(name for name in results if (path / name).exists())
    if held and not force:
        raise OutputRefusedError(path, f"already holds results ({', '.join(held)}); give a new or empty "
                                       "folder, or --force to replace them")


def check_out_file(path: str | Path, *, force: bool) -> None:
    """Refuse ``path`` as an output file: one in a run folder (always), a folder, or an existing file
    unless ``force``."""
    path = Path(path)
    _refuse_run_folder(path, path.parent)
    if path.is_dir():
        raise OutputRefusedError(path, "is a folder; give a file name (e.g. calibration.json)")
    if path.exists() and not force:
        raise OutputRefusedError(path, "already exists; give another file name, or --force to replace it")

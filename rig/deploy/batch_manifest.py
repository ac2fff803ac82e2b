"""The manifest of ``rig batch``: sites, camera pairs, their calibrations, options and video segments.

A manifest is a TOML file; paths in it are relative to the manifest's folder::

    [batch]
    name = "bridge-2026"          # names the batch in its record
    max_retries = 2               # a failed task is tried again this many times, then reported
    match_tolerance_s = 5.0       # left/right segments pair up when their start times differ by less

    [[sites]]
    name = "bridge-a"

    [[sites.pairs]]
    name = "pier-3"
    calibration = "pier-3/calibration.json"
    left = ["pier-3/left/*.mp4"]  # globs or files: the segments the camera wrote
    right = ["pier-3/right/*.mp4"]
    sync = "trajectory"           # as rig measure --sync
    timing = "pier-3/timing.json" # optional, as rig measure --timing: one timing for every segment
    reference_markers = "auto"    # "auto", "none", or a list of [x, y, z] (mm)
    static_mm = 0.1
    window_s = 600.0              # long recordings: a task per window of this length (0: a task per file)
    overlap_s = 5.0               # each window measured this much longer at both ends, then trimmed

A segment's start time is read from its file name (``YYYYmmdd-HHMMSS``, ``YYYYmmdd_HHMMSS`` or
``YYYYmmddTHHMMSS``, UTC), the form segmenting cameras and recorders write. Without ``timing`` each
segment's timing is estimated from its videos' motion (as ``rig measure`` does by default); with it, that
``timing.json`` serves every segment of the pair (cameras triggered together, or a timing measured once
with ``rig run sync``), and the pair's timing continuity is not checked (there is nothing estimated).
Segments of the two cameras of a pair are matched by start time; a segment without a partner is reported,
never silently dropped. With ``window_s``, a recording longer than two windows is split into windows, each
a task (:mod:`rig.deploy.batch`).
"""

from __future__ import annotations

import datetime as dt
import glob
import hashlib
import json
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SYNC_CHOICES = ("trajectory", "bandlimited", "cubic", "linear")
_STAMP = re.compile(r"(?<!\d)(\d{4})(\d{2})(\d{2})[-_T](\d{2})(\d{2})(\d{2})(?!\d)")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")  # a name that is also a safe partition value


class ManifestError(ValueError):
    """The manifest is malformed; ``field`` names where (e.g. ``sites[0].pairs[1].calibration``)."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name


@dataclass(frozen=True)
class Segment:
    """One video file a camera wrote, with its start time (UTC) from the file name."""

    path: Path
    start_utc: dt.datetime


@dataclass(frozen=True)
class PairSpec:
    """A camera pair of a site: its calibration, measurement options and both cameras' segments."""

    site: str
    name: str
    calibration: Path
    left: tuple[Segment, ...]
    right: tuple[Segment, ...]
    sync: str = "trajectory"
    reference_markers: str | tuple[tuple[float, float, float], ...] = "auto"
    static_mm: float = 0.1
    window_s: float = 0.0  # 0: one task per segment pair; else one per window of the recording (s)
    overlap_s: float = 5.0  # a window is measured this much longer at both ends (s), then trimmed
    timing: Path | None = None  # a timing.json for every segment (rig measure --timing); None: estimated


@dataclass(frozen=True)
class BatchManifest:
    """A parsed manifest; ``sha256`` is the hash of its text (the batch record states it)."""

    name: str
    source: Path
    sha256: str
    max_retries: int
    match_tolerance_s: float
    pairs: tuple[PairSpec, ...] = field(default=())


def segment_start_utc(path: Path) -> dt.datetime:
    """The start time in ``path``'s file name (UTC); ManifestError when the name holds none."""
    found = _STAMP.findall(path.stem)
    if not found:
        raise ManifestError(str(path), "no start time in the file name (expected YYYYmmdd-HHMMSS, "
                                       "YYYYmmdd_HHMMSS or YYYYmmddTHHMMSS, UTC)")
    y, mo, d, h, mi, s = (int(x) for x in found[-1])
    try:
        return dt.datetime(y, mo, d, h, mi, s, tzinfo=dt.UTC)
    except ValueError as exc:
        raise ManifestError(str(path), f"the start time in the file name is not a date: {exc}") from exc


def _table(doc: dict[str, Any], key: str, where: str) -> dict[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise ManifestError(f"{where}{key}", "must be a table")
    return value


def _unknown(table: dict[str, Any], allowed: set[str], where: str) -> None:
    extra = sorted(set(table) - allowed)
    if extra:
        raise ManifestError(f"{where}{extra[0]}", f"unknown field; allowed: {', '.join(sorted(allowed))}")


def _name(value: Any, where: str) -> str:
    if not isinstance(value, str) or not _NAME.match(value):
        raise ManifestError(where, f"{value!r}: a name of letters, digits, '.', '_' or '-' is required")
    return value


def _number(table: dict[str, Any], key: str, default: float | None, limits: tuple[float, float],
            where: str) -> Any:
    lo, hi = limits
    value = table.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not lo <= value <= hi:
        raise ManifestError(f"{where}{key}", f"{value!r} is outside the allowed range [{lo:g}, {hi:g}]")
    return value


def _segments(patterns: Any, folder: Path, where: str) -> tuple[Segment, ...]:
    if isinstance(patterns, str):
        patterns = [patterns]
    if not isinstance(patterns, list) or not patterns or not all(isinstance(p, str) for p in patterns):
        raise ManifestError(where, "a list of files or glob patterns is required")
    paths: set[Path] = set()
    for pattern in patterns:
        matched = sorted(Path(p) for p in glob.glob(str(folder / pattern)))
        if not matched:
            raise ManifestError(where, f"{pattern!r} matches no file (relative to {folder})")
        paths.update(p.resolve() for p in matched if p.is_file())
    segments = (Segment(p, segment_start_utc(p)) for p in paths)
    return tuple(sorted(segments, key=lambda s: (s.start_utc, s.path)))


def _reference_markers(value: Any, where: str) -> str | tuple[tuple[float, float, float], ...]:
    if value in ("auto", "none"):
        return str(value)
    def is_point(p: Any) -> bool:
        return isinstance(p, list) and len(p) == 3 and all(isinstance(c, int | float) for c in p)

    if isinstance(value, list) and value and all(is_point(p) for p in value):
        return tuple((float(p[0]), float(p[1]), float(p[2])) for p in value)
    raise ManifestError(where, f"{value!r}; allowed: \"auto\", \"none\" or a list of [x, y, z] in mm")


PAIR_FIELDS = {"name", "calibration", "left", "right", "sync", "reference_markers", "static_mm", "window_s",
               "overlap_s", "timing"}


def _pair(table: Any, site: str, folder: Path, where: str) -> PairSpec:
    if not isinstance(table, dict):
        raise ManifestError(where, "must be a table")
    _unknown(table, PAIR_FIELDS, f"{where}.")
    for required in ("name", "calibration", "left", "right"):
        if required not in table:
            raise ManifestError(f"{where}.{required}", "missing")
    calibration = (folder / str(table["calibration"])).resolve()
    if not calibration.is_file():
        raise ManifestError(f"{where}.calibration", f"{calibration}: no such file")
    sync = table.get("sync", "trajectory")
    if sync not in SYNC_CHOICES:
        raise ManifestError(f"{where}.sync", f"{sync!r}; allowed: {', '.join(SYNC_CHOICES)}")
    return PairSpec(
        site=site, name=_name(table["name"], f"{where}.name"), calibration=calibration,
        left=_segments(table["left"], folder, f"{where}.left"),
        right=_segments(table["right"], folder, f"{where}.right"), sync=sync,
        reference_markers=_reference_markers(table.get("reference_markers", "auto"),
                                             f"{where}.reference_markers"),
        static_mm=_number(table, "static_mm", 0.1, (1e-6, 1e3), f"{where}."),
        window_s=float(_number(table, "window_s", 0.0, (0.0, 1e6), f"{where}.")),
        overlap_s=_overlap(table, where), timing=_timing(table.get("timing"), folder, f"{where}.timing"),
    )


def _timing(value: Any, folder: Path, where: str) -> Path | None:
    """``timing``: a readable ``timing.json`` for the cameras ``left`` and ``right`` (checked now, not when a
    task runs), or None when absent."""
    from rig.analysis.errors import AnalysisError
    from rig.analysis.sync_tracks import timing_result

    if value is None:
        return None
    if not isinstance(value, str):
        raise ManifestError(where, f"{value!r}: the path of a timing.json is required")
    path = (folder / value).resolve()
    try:
        cameras = set(timing_result(json.loads(path.read_text(encoding="utf-8"))).offset_s)
    except OSError as exc:
        raise ManifestError(where, f"{path}: cannot read it ({exc.strerror or exc})") from exc
    except (ValueError, AnalysisError) as exc:  # JSON errors are ValueErrors
        raise ManifestError(where, f"{path}: not a timing.json ({exc})") from exc
    if cameras != {"left", "right"}:
        raise ManifestError(where, f"{path}: timing of cameras {sorted(cameras)}; a pair's timing names "
                                   "'left' and 'right'")
    return path


def _overlap(table: dict[str, Any], where: str) -> float:
    """``overlap_s``, checked against ``window_s`` (a window is longer than its two overlaps)."""
    overlap_s = float(_number(table, "overlap_s", 5.0, (0.0, 3600.0), f"{where}."))
    window_s = float(table.get("window_s", 0.0))
    if window_s and window_s < 1.0:
        raise ManifestError(f"{where}.window_s", f"{window_s!r}; allowed: 0 (a task per file) or ≥ 1 s")
    if window_s and 2 * overlap_s >= window_s:
        raise ManifestError(f"{where}.overlap_s", f"{overlap_s!r} s; allowed: less than half of window_s "
                                                  f"({window_s:g} s)")
    return overlap_s


def load_manifest(path: str | Path) -> BatchManifest:
    """Parse and check a manifest (every file it names must exist); ManifestError names the field."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ManifestError(str(path), f"cannot read the manifest ({exc.strerror or exc})") from exc
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ManifestError(str(path), f"not valid TOML ({exc})") from exc
    _unknown(doc, {"batch", "sites"}, "")
    batch = _table(doc, "batch", "")
    _unknown(batch, {"name", "max_retries", "match_tolerance_s"}, "batch.")
    name = _name(batch.get("name", path.stem), "batch.name")
    max_retries = int(_number(batch, "max_retries", 2, (0, 20), "batch."))
    match_tolerance_s = float(_number(batch, "match_tolerance_s", 5.0, (0.0, 3600.0), "batch."))
    sites = doc.get("sites")
    if not isinstance(sites, list) or not sites:
        raise ManifestError("sites", "at least one [[sites]] table is required")
    folder = path.resolve().parent
    pairs: list[PairSpec] = []
    for i, site in enumerate(sites):
        if not isinstance(site, dict):
            raise ManifestError(f"sites[{i}]", "must be a table")
        _unknown(site, {"name", "pairs"}, f"sites[{i}].")
        site_name = _name(site.get("name"), f"sites[{i}].name")
        site_pairs = site.get("pairs")
        if not isinstance(site_pairs, list) or not site_pairs:
            raise ManifestError(f"sites[{i}].pairs", "at least one [[sites.pairs]] table is required")
        pairs += [_pair(p, site_name, folder, f"sites[{i}].pairs[{j}]") for j, p in enumerate(site_pairs)]
    seen: set[tuple[str, str]] = set()
    for p in pairs:
        if (p.site, p.name) in seen:
            raise ManifestError(f"sites.{p.site}.pairs", f"pair name {p.name!r} appears twice")
        seen.add((p.site, p.name))
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    return BatchManifest(name=name, source=path.resolve(), sha256=digest, max_retries=max_retries,
                         match_tolerance_s=match_tolerance_s, pairs=tuple(pairs))


def match_segments(left: tuple[Segment, ...], right: tuple[Segment, ...], tolerance_s: float,
                   ) -> tuple[list[tuple[Segment, Segment]], list[Segment]]:
    """Pair each left segment with the right one starting nearest to it, within ``tolerance_s``.

    Returns the matched pairs in time order and the segments of either camera left without a partner.
    """
    matched: list[tuple[Segment, Segment]] = []
    free = list(right)
    alone: list[Segment] = []
    for seg in left:
        if not free:
            alone.append(seg)
            continue
        best = min(free, key=lambda r: abs((r.start_utc - seg.start_utc).total_seconds()))
        if abs((best.start_utc - seg.start_utc).total_seconds()) <= tolerance_s:
            matched.append((seg, best))
            free.remove(best)
        else:
            alone.append(seg)
    return matched, sorted(alone + free, key=lambda s: (s.start_utc, s.path))

"""A camera's clock against the controller's from the timing fiducial's recorded rows (``[fiducial]``).

Inputs, as a recording provides them: the ``fiducial`` start event (the controller's clock just before it
sent ``PHASe:SYNChronize`` and just after ``*OPC?`` confirmed it, and the sync frequency), the LED's
rows of one camera (frame index, the frame's time stamp, row, mean brightness of the configured region in
that row), the camera's rolling-shutter line time and exposure, and the start-event relation of the same
recording (controller − camera clock, ±½ frame) as the prior that picks which edge is which.

The sync edges in the controller's clock are those of a square wave from phase 0 at the midpoint of the
command's bracket, each with the bracket's rectangular standard uncertainty (width/√12): the part of the
offset's uncertainty the camera cannot reduce. :func:`rig.stereo.fiducial.fit_fiducial_clock` does the
rest. Without a fiducial the start-event method of :mod:`rig.analysis.analyse` remains.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rig.analysis.errors import AnalysisError
from rig.record.fiducial_rows import ROW_COLUMNS, ROWS_DIR
from rig.stereo.errors import StereoError
from rig.stereo.fiducial import DriveEdges, FiducialClock, RowSamples, fit_fiducial_clock, square_wave_edges
from rig.stereo.timing import TimingResult

__all__ = ["OWN_FIDUCIAL_PRIOR_S", "ROWS_DIR", "ROW_COLUMNS", "CameraDating", "FiducialStart", "camera_clock",
           "clock_row", "own_camera_dating", "segment_clock"]

METHOD = "fiducial"
OWN_FIDUCIAL_PRIOR_S = 2e-3  # another camera's fiducial edges told apart within ± this of the model's date


@dataclass(frozen=True)
class FiducialStart:
    """The fiducial's start as the controller recorded it: ``t_sent_s`` ≤ ``t_confirmed_s`` (controller
    clock, s) bracket the phase restart; ``frequency_hz`` of the sync square wave."""

    t_sent_s: float
    t_confirmed_s: float
    frequency_hz: float

    @classmethod
    def from_event(cls, event: dict[str, Any]) -> FiducialStart:
        """From a ``fiducial`` event of the record (fields as named here); AnalysisError naming a bad one."""
        values = {}
        for name in ("t_sent_s", "t_confirmed_s", "frequency_hz"):
            v = event.get(name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise AnalysisError(f"fiducial event: {name}={v!r} must be a finite number")
            values[name] = float(v)
        start = cls(**values)
        if start.t_confirmed_s < start.t_sent_s or start.frequency_hz <= 0:
            raise AnalysisError(f"fiducial event: need t_sent_s ≤ t_confirmed_s and frequency_hz > 0, got "
                                f"{start}")
        return start

    @property
    def origin_s(self) -> float:
        return 0.5 * (self.t_sent_s + self.t_confirmed_s)

    @property
    def u_origin_s(self) -> float:
        return (self.t_confirmed_s - self.t_sent_s) / math.sqrt(12.0)


def _check_rows(rows: pd.DataFrame) -> None:
    missing = [c for c in ROW_COLUMNS if c not in rows.columns]
    if missing:
        raise AnalysisError(f"fiducial rows: missing column(s) {', '.join(missing)}")
    if rows.empty:
        raise AnalysisError("fiducial rows: none recorded (is the LED region inside the image?)")


def _edges(recordings: list[tuple[FiducialStart, np.ndarray]], prior_offset_s: float,
           margin_s: float) -> DriveEdges:
    """The sync edges (controller clock) over every recording's rows, each from its own start and only
    until the next start restarts the wave."""
    times, rising, u = [], [], 0.0
    recordings = sorted(recordings, key=lambda r: r[0].origin_s)
    for k, (start, row_start_s) in enumerate(recordings):
        t0 = max(float(row_start_s.min()) + prior_offset_s - margin_s, start.origin_s)
        t1 = float(row_start_s.max()) + prior_offset_s + margin_s
        if k + 1 < len(recordings):
            t1 = min(t1, recordings[k + 1][0].origin_s - 1e-9)
        if t1 <= t0:
            continue
        e = square_wave_edges(start.origin_s, start.frequency_hz, t0, t1, u_origin_s=start.u_origin_s)
        times.append(e.times_s)
        rising.append(e.rising)
        u = max(u, start.u_origin_s)
    t, r = np.concatenate(times), np.concatenate(rising)
    keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)
    order = np.argsort(t[keep], kind="stable")
    return DriveEdges(t[keep][order], r[keep][order], u)


def camera_clock(recordings: list[tuple[FiducialStart, pd.DataFrame]], *, row_start_s: Any,
                 exposure_s: float, prior_offset_s: float, prior_half_width_s: float,
                 rise_time_s: float, late_s: float = 0.0) -> FiducialClock:
    """Fit controller − camera clock from one camera's LED rows (``ROW_COLUMNS``) of one or more
    recordings, each with the fiducial start it was recorded under.

    The edges are searched within ``prior_offset_s`` ± ``prior_half_width_s``, extended earlier by
    ``late_s`` (≥ 0: how late the prior may be) and on both sides by the restarts' brackets, as far as the
    pattern stays unambiguous.

    ``row_start_s(timestamp_s, row_px)`` → the rows' exposure starts on the camera's (or the timing
    model's) clock, e.g. ``timestamp + row · line time``. Raises AnalysisError naming what is missing,
    or the stereo core's reason (ambiguous prior, no edge seen).
    """
    starts, bright, spans, rows_px = [], [], [], []
    for start, rows in recordings:
        _check_rows(rows)
        s = np.asarray(row_start_s(rows["timestamp_s"].to_numpy(float), rows["row_px"].to_numpy(float)),
                       dtype=float)
        starts.append(s)
        bright.append(rows["brightness_dn"].to_numpy(float))
        rows_px.append(rows["row_px"].to_numpy(float))
        spans.append((start, s))
    if not starts:
        raise AnalysisError("fiducial rows: no recording")
    s, b = np.concatenate(starts), np.concatenate(bright)
    order = np.argsort(s, kind="stable")
    samples = RowSamples(s[order], b[order], exposure_s, np.concatenate(rows_px)[order])
    try:
        edges = _edges(spans, prior_offset_s, prior_half_width_s + late_s + exposure_s + 0.05)
        # the edges are known within their restart's bracket (±√3 u), and the prior may be late by late_s
        half_width_s = prior_half_width_s + 0.5 * late_s + math.sqrt(3.0) * edges.u_s
        if late_s or edges.u_s:  # widened only while the pattern stays unambiguous (±0.45 of its repeat)
            half_width_s = max(prior_half_width_s, min(half_width_s, 0.45 * edges.repeat_s()))
        return fit_fiducial_clock(samples, edges, prior_offset_s=prior_offset_s - 0.5 * late_s,
                                  prior_half_width_s=half_width_s, rise_time_s=rise_time_s)
    except StereoError as exc:
        raise AnalysisError(f"fiducial: {exc}") from exc


def segment_clock(run_dir: Path, events: pd.DataFrame | None, segment: str, session: int, camera: str, *,
                  row_start_s: Any, exposure_s: float, prior_offset_s: float,
                  prior_half_width_s: float, late_s: float = 0.0) -> tuple[FiducialClock | None, str]:
    """The fiducial's clock of ``camera`` over one segment's recordings, from the record's ``fiducial``
    events (``start`` then ``rows`` per recording; ``unavailable``/``invalid`` ones are skipped) and the
    row files; (None, why) when the segment has none usable — the caller keeps the start events."""
    if events is None or events.empty or "action" not in events.columns:
        return None, ""
    sessions = events["session"].fillna(0).astype(int) if "session" in events.columns else 0
    here = events[(events["segment"].astype(str) == segment) & (sessions == session)]
    recordings: list[tuple[FiducialStart, pd.DataFrame]] = []
    start: FiducialStart | None = None
    rise = None
    for event in here.to_dict("records"):
        action = event.get("action")
        if action == "start":
            start, rise = FiducialStart.from_event(event), event.get("rise_time_s")
        elif action in ("unavailable", "invalid"):
            start = None
        elif action == "rows" and event.get("camera") == camera and start is not None:
            recordings.append((start, pd.read_parquet(run_dir / str(event.get("file")))))
    if not recordings:
        why = "; ".join(str(r) for r in here.get("reason", pd.Series(dtype=object)).dropna())
        return None, f"timing fiducial not used ({why})" if why else ""
    try:
        fit = camera_clock(recordings, row_start_s=row_start_s, exposure_s=exposure_s,
                           prior_offset_s=prior_offset_s, prior_half_width_s=prior_half_width_s,
                           rise_time_s=float(rise) if isinstance(rise, int | float) else 1e-5, late_s=late_s)
    except AnalysisError as exc:
        return None, f"timing fiducial not used: {exc}"
    if not fit.line_time_fitted:  # the offset holds at the LED's rows only; the markers' are elsewhere
        return None, (f"timing fiducial not used: {fit.n_edges_seen} edge(s) in {fit.n_transition_rows} rows "
                      "cannot fit the line time that carries its offset from the LED's rows to the markers'")
    return fit, ""


def clock_row(camera: str, fit: FiducialClock) -> dict[str, Any]:
    """The fit as a row of the analysis's clock table: offset at ``t_ref_s`` and how it was found."""
    line = (f"; the timing model's line time corrected by {fit.line_time_error_s * 1e9:+.3f} ± "
            f"{fit.u_line_time_error_s * 1e9:.3f} ns/row" if fit.line_time_fitted else "")
    drift = f"rate {fit.rate * 1e6:+.3f} ± {fit.u_rate * 1e6:.3f} ppm" if fit.rate_fitted else \
        "rate not resolved (edges seen over too short a span), 0"
    return {"camera": camera, "offset_s": fit.offset_s, "u_offset_s": fit.u_offset_s, "t_ref_s": fit.t_ref_s,
            "rate": fit.rate, "method": METHOD,
            "source": f"timing fiducial: {fit.n_edges_seen} edges in {fit.n_transition_rows} rows lit "
                      f"part-way (fit ±{1e6 * fit.u_fit_s:.2f} µs; LED rise and edge knowledge included; "
                      f"{drift}{line})"}


@dataclass(frozen=True)
class CameraDating:
    """One camera's own fiducial dating over a segment: the controller time of its instants t (the timing
    model's, with the line time plus ``line_time_error_s``) is t + offset_s + rate·(t − t_ref_s);
    ``u_offset_s`` at the markers' rows."""

    camera: str
    offset_s: float
    u_offset_s: float
    rate: float
    t_ref_s: float
    line_time_error_s: float

    def controller_times_s(self, timing: TimingResult, timestamp_s: np.ndarray,
                           row_px: np.ndarray) -> np.ndarray:
        """The camera's observations (frame time stamps, rows) on the controller clock."""
        dated = timing if not self.line_time_error_s else dataclasses.replace(
            timing, line_time_s={c: v + self.line_time_error_s for c, v in timing.line_time_s.items()})
        t = dated.times(self.camera, timestamp_s, row_px)
        return np.asarray(t + self.offset_s + self.rate * (t - self.t_ref_s), dtype=float)


def own_camera_dating(run_dir: Path, events: pd.DataFrame | None, segment: str, session: int, camera: str, *,
                      timing: TimingResult, exposure_s: float, prior_offset_s: float,
                      row_px: float) -> tuple[CameraDating | None, str]:
    """``camera``'s own fiducial fit over a segment (its LED rows, dated by the timing model on the reference
    clock), its edges told apart within ±``OWN_FIDUCIAL_PRIOR_S`` of ``prior_offset_s`` (the reference
    camera's controller offset at row 0, with half its exposure); (None, why) when not usable. ``row_px``:
    the markers' median row, where the stated uncertainty holds."""
    fid, why = segment_clock(run_dir, events, segment, session, camera,
                             row_start_s=lambda ts, rows: timing.times(camera, ts, rows),
                             exposure_s=exposure_s,
                             prior_offset_s=prior_offset_s - 0.5 * exposure_s,
                             prior_half_width_s=OWN_FIDUCIAL_PRIOR_S)
    if fid is None:
        return None, why or "no fiducial rows of this camera in the segment"
    return CameraDating(camera, fid.offset_s - fid.line_time_error_s * fid.row_ref_px + 0.5 * exposure_s,
                        fid.offset_at_row_s(row_px)[1], fid.rate, fid.t_ref_s, fid.line_time_error_s), ""

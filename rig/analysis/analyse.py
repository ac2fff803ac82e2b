"""Observations of a run folder → matched, time-aligned, triangulated 3-D tracks (``analyse``).

The pure steps live in their own modules and work on DataFrames without a run folder (``rig measure``
reuses them): :func:`rig.analysis.tracks2d.tracks_2d` (per camera, frame to frame),
:func:`rig.analysis.pairing.pair_tracks`
(cross-camera, median epipolar distance, optimal assignment, ambiguity flagged),
:func:`rig.analysis.sync_tracks.row_corrected_times` (timing model) and
:func:`rig.analysis.sync_tracks.triangulate_tracks`
(sync methods ``trajectory`` (default), ``bandlimited``, ``cubic``, ``linear`` = the paper's).

:func:`analyse` takes a run folder read once (:func:`rig.record.folder.load_folder`: ``record.jsonl``,
``observations/``, ``calibration.json`` and ``timing.json``, decoded) or its path, analyses every
recording segment (the step that recorded the
observations, per session) and puts the tracks on the **controller clock** (contracts.md,
"Analysis → reports"):

- the timing model puts every observation on the reference camera's clock;
- each ``camera`` event with ``action = "start"`` (contracts.md) relates a camera clock to the controller
  clock: the controller time of the event and the camera time stamp of the first frame recorded after it.
  That frame's exposure started within one frame period after the event, so its row-0 exposure start is
  taken as event time + ½ frame period (uniform error ±T/2, standard uncertainty T/√12 ≈ 4.8 ms at 60 fps
  per event; it shifts whole tracks in time, never their shape), and the instant the timing model gives
  that row (the middle of its exposure) as that + ½ exposure (``rig["cameras"][name]["exposure_s"]``,
  0 when the snapshot has none). When all start events of a session (every camera,
  through the timing model) admit one constant or straight line — clocks continuous, drifting
  linearly — within the ±T/2 band, each segment's offset is the midpoint of the interval those
  relations allow there, with uncertainty width/√12 (a bound: averaging would assume the events'
  phases against the frame grid random, which start events on a controller grid commensurate with the
  frame period are not — a bias of ≈ 3 ms on the simulated certify run); otherwise each segment uses
  its own events' interval, and a segment without any the median of the run's; without any event,
  :class:`ClockMappingError`. ``Analysis.clock`` says which, with the standard
  uncertainty;
- with a timing fiducial recorded (``[fiducial]``; ``fiducial`` events and ``fiducial/`` row files of
  :mod:`rig.run.fiducial`), the reference camera's clock is dated from the LED's edges instead
  (:mod:`rig.analysis.fiducial`: offset and rate, to microseconds plus how well the controller knows its
  edges), the start events' interval only telling its edges apart; a segment whose fiducial is missing
  or unusable keeps the start events, with a note saying why;
- pairing is restricted to a **volume**: the robot envelope box of the configuration snapshot
  (``rig["limits"]["robot"]["envelope_*_mm"]``) joined with the reference markers' positions
  (``rig["targets"]["references"]["positions_mm"]``), grown by ``volume_margin_mm``; pairs that would
  triangulate outside it are wrong pairs (ghosts of markers on a common epipolar plane).

Nothing is cached: a call with a path reads the files again, so a changed file can never give stale tracks.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import linprog

from rig.analysis.errors import (
    AnalysisError,
    ClockMappingError,
    MissingInputError,
    MissingObservationsError,
    NoPairableTracksError,
)
from rig.analysis.fiducial import CameraDating, clock_row, own_camera_dating, segment_clock
from rig.analysis.sync_tracks import (
    SYNC_METHODS,
    TRACK_COLUMNS,
    pair_all,
    prepare_observations,
    triangulate_tracks,
)
from rig.analysis.tracks2d import tracks_2d
from rig.record.folder import (
    CALIBRATION_FILE,
    RECORD_NAME,
    TIMING_FILE,
    Calibration,
    RunFolder,
    SideFileError,
    load_folder,
)
from rig.record.reader import RecordError
from rig.stereo.dlt import DLTCamera
from rig.stereo.errors import StereoError
from rig.stereo.fiducial import FiducialClock
from rig.stereo.timing import TimingResult

# bound (ppm, rectangular) of a camera clock's rate error against the controller when the start events
# cannot resolve it (consumer camera crystals: ±50 ppm); enters the offset's uncertainty away from t_mid
UNRESOLVED_DRIFT_PPM = 50.0
# how late (frames) a camera's start events may be: a stream-stamped camera's clock is mapped onto the host's
# by its frames' lowest arrival latency, ≥ its readout (≤ 1 frame) plus encoding and transport
START_EVENT_LATE_FRAMES = 2.0

__all__ = ["SYNC_METHODS", "TRACK_COLUMNS", "Analysis", "PreparedRun", "analyse", "analyse_prepared",
           "controller_offsets", "pairing_volume", "prepare_run"]


@dataclass
class Analysis:
    """The analysis of one run folder.

    ``tracks``: ``TRACK_COLUMNS`` — segment (str), time_s (controller clock), track_id (int, unique within a
    segment), x_mm, y_mm, z_mm, reprojection_px, n_cameras. ``timing`` / ``calibration``: the decoded files
    used. ``pairs``: every cross-camera pair (segment, session, camera, track_a, track_b, distance_px,
    n_common, ambiguous, resolved). ``clock``: per (segment, session) the offset controller − reference
    clock (s), its standard uncertainty ``u_offset_s`` and where it came from. ``notes``: what was skipped
    and why.
    """

    tracks: pd.DataFrame
    timing: TimingResult
    calibration: Calibration
    sync: str
    pairs: pd.DataFrame = field(default_factory=pd.DataFrame)
    clock: pd.DataFrame = field(default_factory=pd.DataFrame)
    notes: list[str] = field(default_factory=list)


def _load(run_dir: Path) -> RunFolder:
    """The run folder read (:func:`rig.record.folder.load_folder`), its errors as the analysis' own."""
    if not (run_dir / RECORD_NAME).is_file():
        raise MissingInputError(f"{run_dir}: not a run folder (no {RECORD_NAME})")
    try:
        return load_folder(run_dir, quiet=True)
    except RecordError as exc:
        raise MissingInputError(f"{run_dir}: {exc}") from exc
    except SideFileError as exc:
        raise AnalysisError(str(exc)) from exc


def load_cameras(calibration: dict[str, Any], path: Path | str = CALIBRATION_FILE) -> dict[str, DLTCamera]:
    """camera name → :class:`DLTCamera` from the ``calibration.json`` content."""
    entries = calibration.get("cameras")
    if not isinstance(entries, dict) or len(entries) < 2:
        raise AnalysisError(f"{path}: 'cameras' must map ≥ 2 camera names to DLT entries, got "
                            f"{str(entries)[:80]}; run `rig run calibrate`")
    out = {}
    for name, entry in entries.items():
        try:
            out[str(name)] = DLTCamera.from_dict(entry)
        except StereoError as exc:
            raise AnalysisError(f"{path}: camera {name!r}: {exc}") from exc
    return out


def pairing_volume(rig: dict[str, Any], margin_mm: float = 150.0) -> tuple[tuple[float, float], ...] | None:
    """Box (mm) where markers can be: robot envelope ∪ reference markers, grown by ``margin_mm``; None if
    the snapshot has no envelope."""
    try:
        robot = rig["limits"]["robot"]
        box = np.array([robot[f"envelope_{a}_mm"] for a in "xyz"], dtype=float)
    except (KeyError, TypeError, ValueError):
        return None
    if box.shape != (3, 2) or not np.isfinite(box).all():
        return None
    refs = ((rig.get("targets") or {}).get("references") or {}).get("positions_mm") or []
    pts = np.asarray(refs, dtype=float).reshape(-1, 3) if len(refs) else np.zeros((0, 3))
    lo = np.min(np.vstack([box[:, 0], pts]), axis=0) - margin_mm
    hi = np.max(np.vstack([box[:, 1], pts]), axis=0) + margin_mm
    return tuple((float(a), float(b)) for a, b in zip(lo, hi, strict=True))


def _frame_period_s(rig: dict[str, Any], camera: str, obs: pd.DataFrame) -> float:
    fps = ((rig.get("cameras") or {}).get(camera) or {}).get("fps")
    if isinstance(fps, int | float) and fps > 0:
        return 1.0 / float(fps)
    stamps = np.unique(obs["timestamp_s"].to_numpy(float)) if len(obs) else np.zeros(0)
    steps = np.diff(stamps)
    return float(np.median(steps)) if steps.size else 1.0 / 60.0


def _exposure_s(rig: dict[str, Any], camera: str) -> float:
    """The camera's exposure time (s) from the configuration snapshot; 0 when absent or not a number."""
    e = ((rig.get("cameras") or {}).get(camera) or {}).get("exposure_s")
    return float(e) if isinstance(e, int | float) and not isinstance(e, bool) and 0 <= e < 1 else 0.0


def controller_offsets(camera_events: pd.DataFrame | None, timing: TimingResult,
                       frame_period_s: dict[str, float],
                       exposure_s: dict[str, float] | None = None) -> pd.DataFrame:
    """One row per usable ``camera`` start event: segment, session, camera, offset_s (controller − reference).

    ``camera_events``: the ``camera`` stream of :func:`rig.record.writer.load_run` (columns time_s, step,
    session,
    camera, action, first_timestamp_s; optional ``t_s`` = controller time of the start when the event is
    written later, and ``segment`` when a step records several segments). ``exposure_s``: camera →
    exposure time (s, default 0): the timing model's instants are mid-exposure. See the module docstring
    for the ½-frame convention.
    """
    cols = ["segment", "session", "camera", "offset_s", "t_s", "period_s"]
    if camera_events is None or camera_events.empty or "action" not in camera_events.columns:
        return pd.DataFrame(columns=cols)
    rows = []
    for r in camera_events.to_dict("records"):
        cam, first = r.get("camera"), _number(r.get("first_timestamp_s"))
        t_start = _number(r.get("t_s"))
        t_start = _number(r.get("time_s")) if t_start is None else t_start
        if r.get("action") != "start" or cam not in timing.offset_s or first is None or t_start is None:
            continue
        t_ref = float(timing.times(cam, np.array([first]), np.array([0.0]))[0])
        period = frame_period_s.get(cam, 1.0 / 60.0)
        segment = r.get("segment") if isinstance(r.get("segment"), str) else r.get("step")
        session = _number(r.get("session"))
        mid_exposure = 0.5 * (exposure_s or {}).get(cam, 0.0)
        rows.append((segment, 0 if session is None else int(session), cam,
                     t_start + 0.5 * period + mid_exposure - t_ref, t_start, period))
    return pd.DataFrame(rows, columns=cols)


def _number(value: Any) -> float | None:
    """A finite float, or None for None/NaN/non-numbers."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _feasible_interval_s(t_s: np.ndarray, offset_s: np.ndarray, half_s: float, t_eval_s: float, *,
                         t_mid_s: float, with_drift: bool) -> tuple[float, float] | None:
    """[lo, hi] (s) of the offset at ``t_eval_s`` over every relation c (+ d·(t − t_mid)) that keeps all
    events' offsets within ±``half_s`` of it; None when no relation does (the events disagree)."""
    if not with_drift:
        lo, hi = float(offset_s.max()) - half_s, float(offset_s.min()) + half_s
        return (lo, hi) if lo <= hi else None
    A = np.column_stack([np.ones_like(t_s), t_s - t_mid_s])
    a_ub, b_ub = np.r_[-A, A], np.r_[half_s - offset_s, half_s + offset_s]
    objective = np.array([1.0, t_eval_s - t_mid_s])
    ends = []
    for sign in (1.0, -1.0):
        res = linprog(sign * objective, A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * 2, method="highs")
        if res.status != 0:
            return None
        ends.append(sign * float(res.fun))
    return ends[0], ends[1]


def _prepared_observations(observations: dict[str, pd.DataFrame], cameras: dict[str, DLTCamera],
                           timing: TimingResult, track_gate_px: float,
                           notes: list[str]) -> dict[str, pd.DataFrame]:
    """Per camera: its observations with a position (the others counted in ``notes``), on the reference
    camera's clock (:func:`prepare_observations`), each with its 2-D track id (:func:`tracks_2d`)."""
    obs = {}
    for cam in cameras:
        o = observations[cam].copy()
        finite = np.isfinite(o[["timestamp_s", "u_px", "v_px"]].to_numpy(float)).all(axis=1)
        if not finite.all():
            notes.append(f"camera {cam!r}: {int((~finite).sum())} observation(s) without a position left out")
            o = o[finite]
        if "session" not in o.columns:
            o["session"] = 0
        o["segment"] = o["segment"].astype(str)
        obs[cam] = prepare_observations(o.drop(columns=["time_s", "track_id"], errors="ignore"), timing, cam)
        obs[cam]["track_id"] = tracks_2d(obs[cam], gate_px=track_gate_px).to_numpy()
    return obs


CLOCK_COLUMNS = ["segment", "session", "offset_s", "u_offset_s", "source", "rate", "t_ref_s",
                 "line_time_error_s"]
"""``Analysis.clock``: per segment and session, :class:`SegmentClock`'s fields (controller time of the
reference camera's time t, its instants dated with the line time plus ``line_time_error_s``)."""


@dataclass(frozen=True)
class SegmentClock:
    """Controller time of a segment's reference-camera time: t_controller = t + offset_s + rate·(t − t_ref_s);
    ``u_offset_s`` its standard uncertainty (s), ``source`` how it was found. ``line_time_error_s``: what
    the timing fiducial measured the joint timing model's (common) line time to lack, s/row; the segment's
    instants are recomputed with it added (:func:`redated`), so every marker's row is dated right, not only
    the median row's."""

    offset_s: float
    u_offset_s: float
    source: str
    rate: float = 0.0
    t_ref_s: float = 0.0
    line_time_error_s: float = 0.0
    others: tuple[CameraDating, ...] = ()  # the other cameras dated by their own fiducial fits


def own_dated(sel: dict[str, pd.DataFrame], timing: TimingResult,
              clock: SegmentClock) -> dict[str, pd.DataFrame]:
    """``sel`` with every camera of ``clock.others`` re-dated by its own fiducial fit, its ``time_s`` put on
    the reference camera's clock of the segment (the inverse of ``clock``'s relation)."""
    out = dict(sel)
    for d in clock.others:
        o = sel[d.camera]
        t_ctrl = d.controller_times_s(timing, o["timestamp_s"].to_numpy(float), o["v_px"].to_numpy(float))
        t_ref_clock = (t_ctrl - clock.offset_s + clock.rate * clock.t_ref_s) / (1 + clock.rate)
        out[d.camera] = o.assign(time_s=t_ref_clock)
    return out


def redated(sel: dict[str, pd.DataFrame], timing: TimingResult,
            line_time_error_s: float) -> dict[str, pd.DataFrame]:
    """Each camera's observations with ``time_s`` recomputed from a line time ``line_time_error_s`` longer
    (every camera's: the joint model fits one line time for the pair); ``sel`` itself when nothing to add."""
    if not line_time_error_s:
        return sel
    fixed = dataclasses.replace(timing, line_time_s={c: v + line_time_error_s
                                                     for c, v in timing.line_time_s.items()})
    return {c: o.assign(time_s=fixed.times(c, o["timestamp_s"].to_numpy(float), o["v_px"].to_numpy(float)))
            for c, o in sel.items()}


SegmentDating = Callable[[str, int, dict[str, pd.DataFrame]], SegmentClock]


@dataclass(frozen=True)
class _SegmentInputs:
    """One recording (``segment`` of ``session``) up to its triangulation, which no sync method changes: its
    pairs (with the ``session`` column), its notes (the pairing's, then the dating's or why it has no pairable
    track), its controller clock and its observations dated on it (both None without a pairable track)."""

    segment: str
    session: int
    pairs: pd.DataFrame
    notes: tuple[str, ...]
    clock: SegmentClock | None
    dated: dict[str, pd.DataFrame] | None


def _segment_inputs(obs: dict[str, pd.DataFrame], cameras: dict[str, DLTCamera], timing: TimingResult,
                    date: SegmentDating, date_notes: list[str], *, segment: str, session: int,
                    gate_px: float, volume_mm: tuple[tuple[float, float], ...] | None) -> _SegmentInputs:
    """Pair the cameras' tracks of one recording and date it on the controller clock (``date`` appends to
    ``date_notes``); MissingObservationsError when a camera recorded nothing in it while another did."""
    ref = timing.reference_camera
    sel = {c: o[(o["segment"] == segment) & (o["session"] == session)] for c, o in obs.items()}
    empty = sorted(c for c, o in sel.items() if o.empty)
    if empty:
        raise MissingObservationsError(
            f"segment {segment!r} (session {session}): camera(s) {empty} recorded no observations while "
            f"{sorted(set(sel) - set(empty))} did; check the camera view and re-run that step")
    p, notes = pair_all(sel, cameras, ref, gate_px=gate_px, volume_mm=volume_mm)
    p.insert(1, "session", session)
    if p.empty or not (~p["ambiguous"].astype(bool)).any():
        notes.append(f"segment {segment!r} (session {session}): no pairable tracks")
        return _SegmentInputs(segment, session, p, tuple(notes), None, None)
    first = len(date_notes)
    clock = date(segment, session, sel)
    notes += date_notes[first:]
    dated = own_dated(redated(sel, timing, clock.line_time_error_s), timing, clock)
    return _SegmentInputs(segment, session, p, tuple(notes), clock, dated)


@dataclass(frozen=True)
class PreparedRun:
    """What a run's analysis computes before the sync method matters (:func:`prepare_run`): the checked
    inputs, the observations with their 2-D tracks, every recording's pairs and controller clock, and the
    notes so far. :func:`analyse_prepared` triangulates it with one sync method; a report analysing a run
    with several methods prepares it once (the 2-D tracking, pairing and fiducial dating are most of an
    analysis that is not the triangulation)."""

    folder: RunFolder
    calibration: Calibration
    timing: TimingResult
    cameras: dict[str, DLTCamera]
    notes: tuple[str, ...]
    segments: tuple[_SegmentInputs, ...]


def prepare_run(source: str | Path | RunFolder, *, gate_px: float = 8.0, track_gate_px: float = 25.0,
                volume_margin_mm: float = 150.0) -> PreparedRun:
    """The sync-independent stages of :func:`analyse` (its arguments of the same names; its errors, but
    for the sync method's)."""
    folder = source if isinstance(source, RunFolder) else _load(Path(source))
    run = folder.run
    calibration, timing, cameras = _checked_inputs(folder)
    rig = run.start.get("rig") or {}
    periods = {c: _frame_period_s(rig, c, run.observations[c]) for c in cameras}
    offsets = controller_offsets(run.events.get("camera"), timing, periods,
                                 {c: _exposure_s(rig, c) for c in cameras})
    volume = pairing_volume(rig, volume_margin_mm) if isinstance(rig, dict) else None
    notes: list[str] = []
    obs = _prepared_observations(run.observations, cameras, timing, track_gate_px, notes)
    groups = sorted({(s, int(n)) for cam in cameras for s, n in zip(obs[cam]["segment"], obs[cam]["session"],
                                                                     strict=True)})
    date_notes: list[str] = []
    date = _segment_dating(folder, timing, offsets, periods, date_notes)
    segments = tuple(_segment_inputs(obs, cameras, timing, date, date_notes, segment=segment, session=session,
                                     gate_px=gate_px, volume_mm=volume) for segment, session in groups)
    return PreparedRun(folder, calibration, timing, cameras, tuple(notes), segments)


def _offset_for(offsets: pd.DataFrame, segment: str, session: int) -> tuple[float, float, str]:
    """(offset_s, standard uncertainty s, source) of controller − reference clock for one segment.

    Each start event's offset errs by at most ±T/2 (the first frame's exposure began within one period
    after the event). When all start events of the session admit one relation (a constant, or a straight
    line in controller time when they span long enough to resolve a drift of 20 ppm) within that band,
    the offset at the segment is known to lie in the interval of every such relation's value there (a
    set-membership bound, exact for bounded errors whatever the events' phases against the frame grid:
    start events on a controller grid commensurate with the frame period, as on the simulated rig, do
    not average their errors out); its midpoint is the estimate and (hi − lo)/√12 the standard
    uncertainty (an unresolved drift adds ±``UNRESOLVED_DRIFT_PPM``·|t − t_mid|). Otherwise (a camera
    clock restarted) the midpoint of the segment's own events' interval, else the median of the run's.
    """
    here = offsets[(offsets["segment"] == segment) & (offsets["session"] == session)]
    same = offsets[offsets["session"] == session]
    if len(same) >= 3:
        t = same["t_s"].to_numpy(float)
        period = float(same["period_s"].max())
        t_mid = float(t.mean())
        spread = float(np.sum((t - t_mid) ** 2))
        # the drift is fitted only when the events span enough time to pin it to ≤ 20 ppm (1 σ)
        with_drift = spread > 0 and period / math.sqrt(12.0 * spread) <= 20e-6
        t_seg = float(here["t_s"].mean()) if len(here) else t_mid
        half = 0.5 * period * 1.02 + 1e-7  # ±T/2, 2 % for the nominal period against the camera's own
        ends = _feasible_interval_s(t, same["offset_s"].to_numpy(float), half, t_seg,
                                    t_mid_s=t_mid, with_drift=with_drift)
        if ends is not None:
            lo, hi = ends
            u = (hi - lo) / math.sqrt(12.0)
            if not with_drift:  # an unresolved rate error of up to ±UNRESOLVED_DRIFT_PPM away from t_mid
                u = math.hypot(u, UNRESOLVED_DRIFT_PPM * 1e-6 / math.sqrt(3.0) * abs(t_seg - t_mid))
            return (0.5 * (lo + hi), u,
                    f"fit of all {len(same)} camera start events of session {session} (interval bound, "
                    f"{'drift fitted' if with_drift else 'drift not resolved, 0'}; offset within "
                    f"{1e3 * (lo - 0.5 * (lo + hi)):+.2f}/{1e3 * (hi - 0.5 * (lo + hi)):+.2f} ms)")
    if len(here):
        half = 0.5 * float(here["period_s"].max())
        off = here["offset_s"].to_numpy(float)
        lo, hi = float(off.max()) - half, float(off.min()) + half
        source = f"{len(here)} camera start event(s) of the segment"
        if lo > hi:  # the segment's own events disagree too: their mean, ±T/√12
            return float(off.mean()), half / math.sqrt(3.0), source
        return 0.5 * (lo + hi), (hi - lo) / math.sqrt(12.0), source
    if len(offsets):
        u = float(offsets["period_s"].max()) / math.sqrt(12.0)
        return (float(offsets["offset_s"].median()), u,
                f"median of all {len(offsets)} camera start events of the run")
    raise ClockMappingError(
        f"segment {segment!r}: the record has no `camera` start events relating the camera clocks to the "
        "controller clock (contracts.md); re-record the segment with a procedure that logs them"
    )


def _fiducial_clock(run_dir: Path, events: pd.DataFrame | None, segment: str, session: int, *,
                    timing: TimingResult, exposure_s: float, offset_s: float, u_offset_s: float,
                    period_s: float) -> tuple[FiducialClock | None, str]:
    """The reference camera's clock from the timing fiducial (:mod:`rig.analysis.fiducial`), its edges told
    apart by the start events' interval (the offset ± √3 u, at least ±½ frame), extended earlier by
    :data:`START_EVENT_LATE_FRAMES` frames: a camera stamping its own frames is mapped onto the host's clock
    by their lowest arrival latency (readout, encoding, transport), so its start events may be late by that
    much (20.5 ms, 1.2 frames, on `rig mock lab`); (None, why) without one."""
    ref = timing.reference_camera
    return segment_clock(run_dir, events, segment, session, ref,
                         row_start_s=lambda ts, row: timing.times(ref, ts, row), exposure_s=exposure_s,
                         prior_offset_s=offset_s - 0.5 * exposure_s,
                         prior_half_width_s=max(math.sqrt(3.0) * u_offset_s, 0.51 * period_s),
                         late_s=START_EVENT_LATE_FRAMES * period_s)


def _checked_inputs(folder: RunFolder) -> tuple[Calibration, TimingResult, dict[str, DLTCamera]]:
    """The folder's calibration, timing and cameras, after checking that they belong together and that
    every calibrated camera has observations (the errors name the file and what to run)."""
    run, run_dir = folder.run, folder.run_dir
    if folder.calibration is None:
        raise MissingInputError(f"{run_dir / CALIBRATION_FILE}: no calibration; run `rig run calibrate` (or "
                                "copy the bench's calibration.json) first")
    if folder.timing is None:
        raise MissingInputError(f"{run_dir / TIMING_FILE}: no timing; run `rig run sync` first")
    calibration, timing = folder.calibration, folder.timing
    cameras = load_cameras(calibration.to_dict(), run_dir / CALIBRATION_FILE)
    for cam in cameras:
        if cam not in timing.offset_s:
            raise AnalysisError(f"{run_dir / TIMING_FILE}: camera {cam!r} of calibration.json has no offset "
                                f"(timing.json has {sorted(timing.offset_s)}); run `rig run sync`")
        if cam not in run.observations or run.observations[cam].empty:
            raise MissingObservationsError(
                f"{run_dir / 'observations' / cam}: camera {cam!r} of calibration.json has no observations; "
                "check the camera and re-run the measuring procedure (`rig run <procedure>`)")
    if timing.reference_camera not in cameras:
        raise AnalysisError(f"{run_dir / TIMING_FILE}: reference camera {timing.reference_camera!r} is not "
                            f"calibrated (calibration.json has {sorted(cameras)})")
    return calibration, timing, cameras


def _segment_dating(folder: RunFolder, timing: TimingResult, offsets: pd.DataFrame,
                    periods: dict[str, float], notes: list[str]) -> SegmentDating:
    """How a segment's reference-camera time becomes controller time: the start events' offset, or the
    timing fiducial's clock when one was recorded (stated at the reference camera's median marker row,
    where the line time's correction applies). Appends to ``notes`` why a fiducial was not used."""
    run, run_dir, ref = folder.run, folder.run_dir, timing.reference_camera
    rig = run.start.get("rig") or {}

    def date(segment: str, session: int, sel: dict[str, pd.DataFrame]) -> SegmentClock:
        offset, u_offset, source = _offset_for(offsets, segment, session)
        exposure_s = _exposure_s(rig, ref)
        fid, why = _fiducial_clock(run_dir, run.events.get("fiducial"), segment, session, timing=timing,
                                   exposure_s=exposure_s, offset_s=offset, u_offset_s=u_offset,
                                   period_s=periods[ref])
        if why:
            notes.append(f"segment {segment!r} (session {session}): {why}")
        if fid is None:
            return SegmentClock(offset, u_offset, source)
        # the instants get the fitted line time (SegmentClock.line_time_error_s): the offset is then the one
        # at row 0; its uncertainty is the one at the markers' median row
        u_offset = fid.offset_at_row_s(float(sel[ref]["v_px"].median()))[1]
        offset = fid.offset_s - fid.line_time_error_s * fid.row_ref_px + 0.5 * exposure_s
        others, how = _other_cameras(segment, session, sel, offset)
        return SegmentClock(offset, u_offset, clock_row(ref, fid)["source"] + how, fid.rate, fid.t_ref_s,
                            fid.line_time_error_s, others)

    def _other_cameras(segment: str, session: int, sel: dict[str, pd.DataFrame],
                       offset_s: float) -> tuple[tuple[CameraDating, ...], str]:
        """The other cameras' own fiducial datings and how each camera was dated (for the clock's source)."""
        others, how = [], []
        for cam in sorted(c for c in sel if c != ref):
            d, why = own_camera_dating(run_dir, run.events.get("fiducial"), segment, session, cam,
                                       timing=timing, exposure_s=_exposure_s(rig, cam),
                                       prior_offset_s=offset_s, row_px=float(sel[cam]["v_px"].median()))
            if d is not None:
                others.append(d)
                how.append(f"camera {cam!r} by its own fiducial fit (u {1e6 * d.u_offset_s:.2f} µs)")
            else:
                how.append(f"camera {cam!r} through the timing model's offset and drift from the sync step "
                           f"({why})")
        return tuple(others), "; " + "; ".join(how) if how else ""

    return date


def analyse(
    source: str | Path | RunFolder,
    *,
    sync: str = "trajectory",
    gate_px: float = 8.0,
    track_gate_px: float = 25.0,
    volume_margin_mm: float = 150.0,
    knot_spacing_frames: float = 0.75,
) -> Analysis:
    """Analyse a run folder (see the module docstring); deterministic, nothing cached: :func:`prepare_run`,
    then :func:`analyse_prepared` with ``sync``.

    ``source``: the folder's path, or the folder already read (:func:`rig.record.folder.load_folder`; the
    reports read it once and analyse it with several sync methods).
    ``sync``: one of ``SYNC_METHODS``. ``gate_px``: epipolar gate of the cross-camera pairing (px).
    ``track_gate_px``: frame-to-frame gate of the 2-D tracking (px).
    Raises :class:`MissingInputError` (no calibration.json / timing.json / record),
    :class:`MissingObservationsError` (a calibrated camera without observations, in the run or in a
    segment), :class:`NoPairableTracksError`, :class:`ClockMappingError`, :class:`AnalysisError` for
    malformed files.
    """
    _check_sync_method(sync)
    prepared = prepare_run(source, gate_px=gate_px, track_gate_px=track_gate_px,
                           volume_margin_mm=volume_margin_mm)
    return analyse_prepared(prepared, sync=sync, knot_spacing_frames=knot_spacing_frames)


def _check_sync_method(sync: str) -> None:
    if sync not in SYNC_METHODS:
        raise AnalysisError(f"sync={sync!r}: allowed are {SYNC_METHODS}")


def analyse_prepared(prepared: PreparedRun, *, sync: str = "trajectory",
                     knot_spacing_frames: float = 0.75) -> Analysis:
    """:func:`analyse` of a run prepared by :func:`prepare_run`: every recording triangulated with ``sync``
    and put on the controller clock (``prepared`` is not changed: analyse it with another method after)."""
    _check_sync_method(sync)
    timing, ref = prepared.timing, prepared.timing.reference_camera
    notes = list(prepared.notes)
    tracks: list[pd.DataFrame] = []
    pairs: list[pd.DataFrame] = []
    clock: list[tuple[str, int, float, float, str, float, float, float]] = []
    next_id: dict[str, int] = {}  # sessions of a segment continue the track numbering
    for seg in prepared.segments:
        pairs.append(seg.pairs)
        notes += seg.notes
        if seg.clock is None or seg.dated is None:
            continue
        t = triangulate_tracks(seg.dated, prepared.cameras, timing, sync=sync, reference=ref, pairs=seg.pairs,
                               knot_spacing_frames=knot_spacing_frames)
        notes += t.attrs.get("notes", [])
        if t.empty:
            continue
        c = seg.clock
        clock.append((seg.segment, seg.session, c.offset_s, c.u_offset_s, c.source, c.rate, c.t_ref_s,
                      c.line_time_error_s))
        t = t.copy()
        t["time_s"] = t["time_s"] + c.offset_s + c.rate * (t["time_s"] - c.t_ref_s)
        t["segment"] = seg.segment
        t["track_id"] = t["track_id"].astype(np.int64) + next_id.get(seg.segment, 0)
        next_id[seg.segment] = int(t["track_id"].max()) + 1
        tracks.append(t)
    if not tracks:
        raise NoPairableTracksError(
            f"{prepared.folder.run_dir}: no track of {ref!r} could be paired with another camera in any "
            f"segment ({', '.join(repr(s.segment) for s in prepared.segments)}); check that calibration.json "
            "and timing.json belong to these cameras (`rig run calibrate`, `rig run sync`)")
    out = pd.concat(tracks, ignore_index=True)
    out = out.sort_values(["segment", "time_s", "track_id"], kind="stable", ignore_index=True)
    return Analysis(
        tracks=out[TRACK_COLUMNS],
        timing=timing,
        calibration=prepared.calibration,
        sync=sync,
        pairs=pd.concat(pairs, ignore_index=True) if pairs else pd.DataFrame(),
        clock=pd.DataFrame(clock, columns=CLOCK_COLUMNS),
        notes=notes,
    )

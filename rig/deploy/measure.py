"""``rig measure``: two videos of a vibrating structure + a calibration → displacement and spectra.

Pipeline (every step reuses the shared modules):

1. both videos → marker observations, in parallel (:mod:`rig.deploy.video_markers`; duplicated and dropped
frames
   reported per file, duplicates left out of the analysis);
2. timing: ``timing.json`` given (``--timing``), or estimated from the videos' motion
   (:mod:`rig.deploy.video_timing`; the default);
3. 2-D tracks, cross-camera pairs and time-aligned 3-D tracks on the reference (first) camera's clock:
   :func:`rig.analysis.sync_tracks.prepare_observations`, :func:`~rig.analysis.sync_tracks.pair_all`,
   :func:`~rig.analysis.sync_tracks.triangulate_tracks` (sync method ``trajectory`` by default);
4. reference markers (``auto``: tracks that stay within ``static_mm``; or positions ``X,Y,Z`` in mm, the
   nearest track within ``reference_gate_mm``): each target is stabilised by the rigid transform mapping
   the references back home (:func:`rig.stereo.stabilize`), references interpolated to the target's
   instants; displacement = stabilised position − its median;
5. per target: principal direction of motion, spectrum (uniform grid of one frame period) and dominant
   frequency, four-parameter sine fit at it (amplitude and frequency with standard uncertainties); the
   Welch spectrum, every significant tone (amplitude, frequency, active interval) and the STFT table
   (:mod:`rig.deploy.spectra`: several modes, successive tones, sweeps);
6. ``DIR``: ``tables/*.csv`` (units in column names), ``timing.json``, ``frames.json``, ``measure.json``
   (inputs, frame reports, notes); with a run record (``--record``), the controller's clock too
   (:mod:`rig.deploy.video_clock`, ``clock.json``, ``controller_time_s`` columns). The report
   (``figures/*.svg``, ``report.html``) is rendered from this folder by :mod:`reports.measurement`, which
   the command (:mod:`rig.cli_measure`) calls after the measurement.

Times in the outputs are seconds on the reference video's clock (its presentation time stamps).
A truncated or corrupt video does not stop the measurement: the frames read are used, the problem is in
``MeasureResult.problems`` and the report, and ``rig measure`` exits with code 4.
"""

from __future__ import annotations

import json
import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from drivers.camera.container_times import ContainerError, ContainerTimes, read_container_times
from drivers.camera.video_file import VideoFile, decoder_threads_per_file
from rig.analysis.analyse import load_cameras
from rig.analysis.errors import AnalysisError
from rig.analysis.sync_tracks import (
    pair_all,
    prepare_observations,
    timing_result,
    triangulate_tracks,
)
from rig.deploy.choices import DEFAULT_CLOCK_AGREEMENT_S, MEASURE_SYNC
from rig.deploy.container_prior import OffsetWindow, offset_window
from rig.deploy.csv_table import write_csv
from rig.deploy.series import SeriesError, reference_tracks, stabilised_displacement, summarise
from rig.deploy.video_markers import ExtractOptions, VideoObservations, extract_video, window_note
from rig.deploy.video_timing import VideoTimingError, estimate_video_timing, rotor_timing, tracked
from rig.record.atomic import atomic_path, write_json
from rig.record.out_guard import check_out_folder
from rig.stereo.blas import one_blas_thread
from rig.stereo.dlt import DLTCamera
from rig.stereo.errors import StereoError

log = logging.getLogger(__name__)

__all__ = ["MEASURE_RESULTS", "MEASURE_SYNC", "MeasureError", "MeasureOptions", "MeasureResult",
           "measure_videos"]


FPS_TOLERANCE = 0.01  # relative: two cameras at one nominal rate differ by ppm, never by 1 %
MEASURE_RESULTS = ("measure.json", "report.html", "timing.json", "frames.json", "clock.json", "tables",
                   "figures", "observations")  # what measure_videos writes into its folder


class MeasureError(ValueError):
    """The inputs cannot give a measurement (the message names the file or option and what to do)."""


@dataclass(frozen=True)
class MeasureOptions:
    """Options of :func:`measure_videos` (units in the names)."""

    sync: str = "trajectory"
    reference_markers: str | tuple[tuple[float, float, float], ...] = "auto"  # "auto" | "none" | positions
    static_mm: float = 0.1
    reference_gate_mm: float = 20.0
    window_s: tuple[float, float] | None = None
    gate_px: float = 5.0
    line_time_s: float | None = None
    # the cameras started within prior_offset_s ± max_offset_s (s); None: from the containers' creation
    # times, else 0 ± 10 s (rig.deploy.container_prior)
    max_offset_s: float | None = None
    prior_offset_s: float | None = None
    clock_agreement_s: float = DEFAULT_CLOCK_AGREEMENT_S  # the cameras' own clocks agree within this (s)
    extract: ExtractOptions = field(default_factory=ExtractOptions)


@dataclass
class MeasureResult:
    """What :func:`measure_videos` produced: tables (DataFrames), files written, notes and input problems."""

    out_dir: Path
    tracks: pd.DataFrame
    displacement: pd.DataFrame
    summary: pd.DataFrame
    spectra: pd.DataFrame
    timing: dict[str, Any]
    frame_reports: dict[str, dict[str, Any]]
    files: dict[str, Path]
    notes: list[str]
    problems: list[str]
    timings_s: dict[str, float]  # per camera (decode, extract, total), per step: wall ("step_*") and
    # process CPU ("cpu_step_*"; read_videos: both reading threads), s
    peaks: pd.DataFrame = field(default_factory=pd.DataFrame)  # significant tones per target track
    time_frequency: pd.DataFrame = field(default_factory=pd.DataFrame)  # STFT amplitude per target track


def _write_csv(frame: pd.DataFrame, path: Path) -> None:
    with atomic_path(path) as tmp:
        write_csv(frame, tmp)  # the text of frame.to_csv(tmp, index=False)


def _load_json(path: Path | None, what: str, how: str) -> dict[str, Any]:
    if path is None or not Path(path).is_file():
        raise MeasureError(f"{path}: no {what} file; {how}")
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise MeasureError(f"{path}: not a valid JSON {what} file ({exc}); {how}") from exc
    if not isinstance(data, dict):
        raise MeasureError(f"{path}: the {what} file must hold a JSON object; {how}")
    return data


def check_inputs(videos: dict[str, Path], calibration_path: Path,
                 fps: float | None = None) -> dict[str, DLTCamera]:
    """Calibration present and matching the videos (names, image sizes) — before any decoding."""
    how = "make one with `rig calibrate LEFT RIGHT --target target.toml --out calibration.json`"
    calibration = _load_json(calibration_path, "calibration", how)
    try:
        cameras = load_cameras(calibration, calibration_path)
    except AnalysisError as exc:
        raise MeasureError(str(exc)) from exc
    missing = [n for n in videos if n not in cameras]
    if missing:
        raise MeasureError(f"{calibration_path}: no calibration for camera(s) {missing} (it has "
                           f"{sorted(cameras)}); name the videos' cameras with --names")
    opened = {name: VideoFile(path, name=name, fps=fps) for name, path in videos.items()}
    described = {n: f"{n} {v.fps:.6g} fps {v.width_px}×{v.height_px} px ({videos[n]})"
                 for n, v in opened.items()}
    rates = [v.fps for v in opened.values()]
    if max(rates) > min(rates) * (1 + FPS_TOLERANCE):
        raise MeasureError(f"the videos' frame rates differ: {' vs '.join(described.values())}; rig measure "
                           "needs both cameras at the same frame rate (--fps if a container states a wrong "
                           "one)")
    for name, video in opened.items():
        want = tuple(cameras[name].image_size)
        if (video.width_px, video.height_px) != want:
            raise MeasureError(f"camera {name!r}: the video is {video.width_px}×{video.height_px} px but "
                               f"{calibration_path} calibrated it at {want[0]}×{want[1]} px "
                               f"({' vs '.join(described.values())}); calibrate at the resolution you "
                               "measure with")
    return cameras


def _observations(vo: VideoObservations) -> pd.DataFrame:
    obs = vo.observations
    obs = obs[~obs["duplicate"].to_numpy(bool)].drop(columns=["duplicate"]).reset_index(drop=True)
    obs["segment"] = "measure"
    return obs


def _timing(args: dict[str, Any], obs: dict[str, pd.DataFrame], cameras: dict[str, DLTCamera], *,
            fps: dict[str, float], reference: str, notes: list[str]) -> dict[str, Any]:
    if args.get("timing") is not None:
        d = _load_json(Path(args["timing"]), "timing",
                       "write one with `rig run sync` or use --estimate-timing")
        tr = timing_result(d)
        if set(tr.offset_s) != set(obs):
            raise MeasureError(f"{args['timing']}: cameras {sorted(tr.offset_s)} do not match the videos' "
                               f"{sorted(obs)}")
        notes.append(f"timing from {args['timing']} (method {tr.method})"
                     + ("; --sync rotor estimates nothing with a timing file: 3-D by trajectory"
                        if args.get("sync") == "rotor" else ""))
        return tr.to_dict()
    try:
        window: OffsetWindow = args["offset_window"]
        tr = estimate_video_timing(obs, cameras, fps, reference=reference,
                                   line_time_s=args.get("line_time_s"),
                                   max_offset_s=window.max_offset_s, prior_offset_s=window.prior_offset_s)
        if args.get("sync") == "rotor":
            joint = tr
            tr = rotor_timing(obs, cameras, joint, reference=reference)
            other = next(c for c in obs if c != reference)
            notes.append(f"timing by the rotating-marker phase method (row-corrected, --sync rotor): offset "
                         f"{tr.offset_s[other]:+.6f} s ± {tr.uncertainty['offset_s'][other] * 1e3:.4f} ms, "
                         f"line time {tr.line_time_s[other] * 1e6:.3f} ± "
                         f"{tr.uncertainty['line_time_s'][other] * 1e6:.3f} µs at "
                         f"{tr.details['rotation_hz']:.4f} rev/s; the joint estimate (offset "
                         f"{joint.offset_s[other]:+.6f} s) in timing.json details.comparison")
    except (VideoTimingError, AnalysisError) as exc:
        raise MeasureError(f"estimating the timing from the videos: {exc}") from exc
    tr.details = {**tr.details, "offset_window": window.to_dict()}  # joint or rotor: the window searched
    other = next(c for c in obs if c != reference)
    coarse = tr.details["coarse"]
    notes.append(f"timing: {window.statement}")
    notes.append(f"timing estimated from the videos' motion: offset {tr.offset_s[other]:+.6f} s ± "
                 f"{tr.uncertainty['offset_s'][other] * 1e3:.4f} ms (coarse "
                 f"{coarse['chosen_offset_s']:+.4f} s "
                 f"of {len(coarse['candidates'])} candidate(s) within {coarse['window_s'][0]:+.1f} … "
                 f"{coarse['window_s'][1]:+.1f} s), line time {tr.line_time_s[other] * 1e6:.3f} ± "
                 f"{tr.uncertainty['line_time_s'][other] * 1e6:.3f} µs")
    for key in ("ambiguity_note", "line_time_note"):
        if tr.details.get(key):
            notes.append("timing: " + tr.details[key])
    return tr.to_dict()


def _check_window_options(opts: MeasureOptions) -> None:
    """The offset-window options, before any video is decoded (NaN fails every comparison)."""
    if opts.max_offset_s is not None and not 0 < opts.max_offset_s < math.inf:
        raise MeasureError(f"max_offset_s={opts.max_offset_s!r}; allowed: > 0 s, finite")
    if opts.prior_offset_s is not None and not math.isfinite(opts.prior_offset_s):
        raise MeasureError(f"prior_offset_s={opts.prior_offset_s!r}; allowed: a finite number of s")
    if not 0 <= opts.clock_agreement_s < math.inf:
        raise MeasureError(f"clock_agreement_s={opts.clock_agreement_s!r}; allowed: ≥ 0 s, finite")


def _offset_window(paths: dict[str, Path], vos: dict[str, VideoObservations], reference: str,
                   opts: MeasureOptions) -> OffsetWindow:
    """The offset window from the options and the containers' creation times (rig.deploy.container_prior)."""
    times: dict[str, ContainerTimes | ContainerError] = {}
    for name, path in paths.items():
        try:
            times[name] = read_container_times(path)
        except ContainerError as exc:
            times[name] = exc
    first = {n: vo.report.first_pts_s or 0.0 for n, vo in vos.items()}
    try:
        return offset_window(times, first, reference=reference, prior_offset_s=opts.prior_offset_s,
                             max_offset_s=opts.max_offset_s, clock_agreement_s=opts.clock_agreement_s)
    except ValueError as exc:
        raise MeasureError(str(exc)) from exc


def _controller_clock(record: str | Path, obs: pd.DataFrame, period_s: float,
                      notes: list[str]) -> dict[str, Any]:
    from rig.deploy.video_clock import VideoClockError, relate_to_record
    from rig.record.reader import RecordError, load_run

    try:
        run = load_run(record)
        rel = relate_to_record(obs, run.events, period_s)
    except (RecordError, VideoClockError, OSError) as exc:
        raise MeasureError(f"relating the video to the record {record}: {exc}") from exc
    notes.append(f"controller clock: controller − video = {rel['offset_s']:+.4f} s ± "
                 f"{rel['uncertainty_s']:.4f} s ({rel['method']}, {'/'.join(rel['streams'])} events, "
                 f"correlation {rel['correlation']:.2f})")
    return {**rel, "record": str(record)}


def measure_videos(videos: dict[str, str | Path], calibration: str | Path, out_dir: str | Path, *,
                   timing: str | Path | None = None, options: MeasureOptions | None = None,
                   record: str | Path | None = None, force: bool = False) -> MeasureResult:
    """Measure (see the module docstring). ``videos``: camera name → file, the first is the reference.
    ``record``: a run folder whose motion events the videos show; adds ``controller_time_s`` (the
    controller's clock, related by :mod:`rig.deploy.video_clock`) to the tables and writes ``clock.json``.
    ``out_dir`` must not be (or lie in) a run folder, nor hold results unless ``force``
    (:class:`rig.record.out_guard.OutputRefusedError`); every file is written atomically
    (:mod:`rig.record.atomic`); an
    ``OSError`` while writing propagates."""
    opts = options or MeasureOptions()
    if opts.sync not in MEASURE_SYNC:
        raise MeasureError(f"sync={opts.sync!r}; allowed: {MEASURE_SYNC}")
    _check_window_options(opts)
    if len(videos) != 2:
        raise MeasureError(f"{len(videos)} video(s) given; rig measure takes exactly 2 (LEFT RIGHT)")
    paths = {n: Path(p) for n, p in videos.items()}
    out = Path(out_dir)
    check_out_folder(out, MEASURE_RESULTS, force=force)
    job = _Job(out, paths, check_inputs(paths, Path(calibration), opts.extract.fps), Path(calibration),
               timing, record, opts)
    out.mkdir(parents=True, exist_ok=True)
    for stale in ("measure.json", "clock.json"):  # --force: never leave an earlier run's index or clock
        (out / stale).unlink(missing_ok=True)
    notes: list[str] = []
    problems: list[str] = []
    stamps = [_stamp("start")]
    extract = opts.extract  # the two videos decoded at once: the cores shared between their decoders
    if extract.decoder_threads is None:
        extract = replace(extract, decoder_threads=decoder_threads_per_file(len(paths)))
    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="measure-video") as pool:
        futures = {n: pool.submit(extract_video, p, n, extract) for n, p in paths.items()}
        vos = {n: f.result() for n, f in futures.items()}
    for n, vo in vos.items():
        notes.append(f"camera {n}: {vo.report.summary()}")
        if vo.error:
            problems.append(f"camera {n}: {vo.error}")
    try:
        return _measure(job, vos, notes, problems, stamps)
    except MeasureError as exc:
        if not problems:
            raise
        # the cause is the damaged video, not what then failed for lack of its frames
        raise MeasureError(f"{'; '.join(problems)}; with the frames that could be read: {exc}") from exc


def _stamp(step: str) -> tuple[str, float, float]:
    """A step's end: its name, wall clock and process CPU time (all threads), s."""
    return step, time.perf_counter(), time.process_time()


@dataclass(frozen=True)
class _Job:
    """The checked inputs of one :func:`measure_videos` call."""

    out: Path
    paths: dict[str, Path]
    cameras: dict[str, DLTCamera]
    calibration: Path
    timing: str | Path | None
    record: str | Path | None
    opts: MeasureOptions


@one_blas_thread()  # the analysis' many small solves: BLAS's other threads would only spin
def _measure(job: _Job, vos: dict[str, VideoObservations], notes: list[str], problems: list[str],
             stamps: list[tuple[str, float, float]]) -> MeasureResult:
    """Observations → timing → 3-D tracks → displacement → tables, report and measure.json."""
    out, paths, cameras, opts, record = job.out, job.paths, job.cameras, job.opts, job.record
    timing, calibration = job.timing, job.calibration
    reports = {n: vo.report.to_dict() for n, vo in vos.items()}
    obs = {n: _observations(vo) for n, vo in vos.items()}
    if opts.extract.mode == "track":
        for n, o in obs.items():
            if (note := window_note(o, opts.extract.window_px, n)) is not None:
                notes.append(note)
                log.warning(note)
    files: dict[str, Path] = {}
    (out / "observations").mkdir(exist_ok=True)
    for n, o in obs.items():
        files[f"observations_{n}"] = out / "observations" / f"{n}.csv"
        _write_csv(o, files[f"observations_{n}"])
    files["frames"] = write_json(out / "frames.json", reports)
    for n, o in obs.items():
        if o.empty:
            raise MeasureError(f"camera {n} ({paths[n]}): no marker found in any frame; check the "
                               "detection options (polarity, min_contrast) and the video")
    reference = next(iter(paths))
    fps = {n: vo.fps for n, vo in vos.items()}
    stamps.append(_stamp("read_videos"))
    timing_dict = _timing({"timing": timing, "line_time_s": opts.line_time_s, "sync": opts.sync,
                           "offset_window": _offset_window(paths, vos, reference, opts)},
                          obs, cameras, fps=fps,
                          reference=reference, notes=notes)
    files["timing"] = write_json(out / "timing.json", timing_dict)
    stamps.append(_stamp("timing"))
    tracks = _tracks_3d(obs, cameras, timing_dict, reference=reference, opts=opts, notes=notes)
    stamps.append(_stamp("tracks_3d"))
    clock = None
    if record is not None:
        clock = _controller_clock(record, obs[reference], 1.0 / fps[reference], notes)
        files["clock"] = write_json(out / "clock.json", clock)
    try:
        refs, ref_note = reference_tracks(tracks, opts.reference_markers, static_mm=opts.static_mm,
                                          gate_mm=opts.reference_gate_mm)
        notes.append(ref_note)
        displacement = stabilised_displacement(tracks, refs)
        series = summarise(displacement, refs, window_s=opts.window_s, notes=notes)
    except (SeriesError, StereoError) as exc:
        raise MeasureError(f"displacement: {exc}") from exc
    if clock is not None:
        for frame in (tracks, displacement):
            frame.insert(frame.columns.get_loc("time_s") + 1, "controller_time_s",
                         frame["time_s"] + clock["offset_s"])
    tables = out / "tables"
    tables.mkdir(exist_ok=True)
    for name, frame in (("tracks_3d", tracks), ("displacement", displacement), ("summary", series.summary),
                        ("spectra", series.spectra), ("peaks", series.peaks),
                        ("time_frequency", series.time_frequency)):
        files[name] = tables / f"{name}.csv"
        _write_csv(frame, files[name])
    stamps.append(_stamp("series_tables"))
    timings = {f"{n}_{k}": v for n, vo in vos.items() for k, v in vo.timings_s.items()}
    timings.update({f"step_{name}": t - stamps[i][1] for i, (name, t, _) in enumerate(stamps[1:])})
    timings.update({f"cpu_step_{name}": c - stamps[i][2] for i, (name, _, c) in enumerate(stamps[1:])})
    result = MeasureResult(out, tracks, displacement, series.summary, series.spectra, timing_dict, reports,
                           files, notes, problems, timings, series.peaks, series.time_frequency)
    meta = {"videos": {n: str(p) for n, p in paths.items()}, "calibration": str(calibration),
            "timing": str(timing) if timing else "estimated", "sync": opts.sync,
            "reference_camera": reference,
            "reference_markers": refs, "window_s": opts.window_s, "notes": notes,
            "problems": problems,
            "files": {k: str(v.relative_to(out)) for k, v in files.items()},
            "clock": "reference video PTS, s", "controller_clock": clock}
    files["measure"] = write_json(out / "measure.json", meta, default=str)
    return result


def _tracks_3d(obs: dict[str, pd.DataFrame], cameras: dict[str, DLTCamera], timing: dict[str, Any], *,
               reference: str, opts: MeasureOptions, notes: list[str]) -> pd.DataFrame:
    """The cameras' observations tracked in 2-D, paired and triangulated with ``timing`` (the 3-D tracks;
    the steps' notes appended to ``notes``); :class:`MeasureError` when that fails or pairs no track."""
    try:
        # a lone fast marker the 2-D tracking splits (a rotor) is one track (rig.deploy.video_timing.tracked)
        prepared = {n: prepare_observations(tracked(o), timing, n) for n, o in obs.items()}
        pairs, more = pair_all(prepared, cameras, reference, gate_px=opts.gate_px)
        notes += more
        tracks = triangulate_tracks(prepared, cameras, timing, reference=reference,
                                    sync="trajectory" if opts.sync == "rotor" else opts.sync,
                                    pairs=pairs)
    except (AnalysisError, StereoError) as exc:
        raise MeasureError(f"3-D tracks: {exc}") from exc
    notes += tracks.attrs.get("notes", [])
    if tracks.empty:
        raise MeasureError("no marker track could be paired between the two videos; check that the "
                           "calibration belongs to these cameras and the timing (--timing/--estimate-timing)")
    return tracks

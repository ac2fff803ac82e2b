"""The deployment sub-commands of ``rig``: ``calibrate`` (on site, from a video pair) and ``measure``.

``rig/cli.py`` calls :func:`add_parsers` and dispatches to :data:`COMMANDS`. Exit codes as ``rig``: 0 done,
4 bad input (message on stderr; a measurement from a truncated video is written, then exits 4; an --out
that is a run folder, or holds results without --force), 3 an I/O fault (an ``OSError`` such as a full
disk or a read-only folder propagates to ``rig.cli.main``; no result is left half-written).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from rig.deploy.choices import DEFAULT_CLOCK_AGREEMENT_S, DISTORTION_MODELS, MEASURE_SYNC
from rig.run.exit_codes import EXIT_BAD_INPUT

__all__ = ["COMMANDS", "add_parsers", "cmd_calibrate", "cmd_measure"]

TARGET_HELP = """target.toml: [plate] rows = 5, cols = 7 (row 0 on top, column 0 on the left as the cameras
see the plate); one [[positions]] table per still position, in filming order, with
markers_mm = [[x, y, z], ...] (rows × cols points in mm, node r·cols + c)."""


def _names(args: argparse.Namespace) -> list[str]:
    names = list(args.names or ("left", "right"))
    if len(names) != 2 or names[0] == names[1]:
        from rig.run.procedure import ParameterError

        raise ParameterError("--names", f"{' '.join(names)}: give two different camera names")
    return names


def cmd_calibrate(args: argparse.Namespace) -> int:
    from drivers.camera.video_file import VideoFileError
    from rig.deploy.onsite_calibration import (
        OnsiteCalibrationError,
        calibrate_from_videos,
        residual_summary,
        write_calibration,
    )
    from rig.record.out_guard import OutputRefusedError, check_out_file

    names = _names(args)
    try:
        check_out_file(args.out, force=args.force)  # before the videos are decoded
        cal = calibrate_from_videos({names[0]: args.left, names[1]: args.right}, args.target,
                                    distortion=args.distortion, still_px=args.still_px,
                                    min_still_frames=args.min_still_frames, max_rms_px=args.max_rms_px)
    except (OnsiteCalibrationError, VideoFileError, OutputRefusedError) as exc:
        print(f"rig calibrate: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    path = write_calibration(cal, args.out, force=args.force)
    print(f"rig calibrate: {path}\n{residual_summary(cal)}")
    return 0


def _position(text: str) -> tuple[float, float, float]:
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: a reference marker is X,Y,Z in mm") from exc
    return x, y, z


def cmd_measure(args: argparse.Namespace) -> int:
    from drivers.camera.video_file import VideoFileError
    from reports.measurement import write_measurement_report
    from rig.deploy.measure import MeasureError, MeasureOptions, measure_videos
    from rig.deploy.video_markers import ExtractOptions
    from rig.record.out_guard import OutputRefusedError

    names = _names(args)
    refs: str | tuple[tuple[float, float, float], ...]
    if not args.reference_markers or args.reference_markers == ["auto"]:
        refs = "auto"
    elif args.reference_markers == ["none"]:
        refs = "none"
    else:
        try:
            refs = tuple(_position(t) for t in args.reference_markers)
        except argparse.ArgumentTypeError as exc:
            print(f"rig measure: --reference-markers {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
    detect = {"polarity": args.polarity} if args.polarity else {}
    window = tuple(args.window) if args.window else None
    options = MeasureOptions(sync=args.sync, reference_markers=refs, window_s=window,
                             line_time_s=args.line_time_s, static_mm=args.static_mm,
                             max_offset_s=args.max_offset_s, prior_offset_s=args.prior_offset_s,
                             clock_agreement_s=args.clock_agreement_s,
                             extract=ExtractOptions(window_px=args.window_px, detect=detect, fps=args.fps,
                                                    duplicate_policy=args.duplicate_policy))
    try:
        result = measure_videos({names[0]: args.left, names[1]: args.right}, args.calibration, args.out,
                                timing=None if args.estimate_timing else args.timing, options=options,
                                record=args.record, force=args.force)
    except (MeasureError, VideoFileError, OutputRefusedError) as exc:
        print(f"rig measure: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    write_measurement_report(args.out)  # rig.deploy may not import reports: the command layer renders
    targets = result.summary[result.summary["role"] == "target"]
    for row in targets.to_dict("records"):  # no sine fit: NaN, or no column when no track has one
        a, f = row.get("amplitude_mm", float("nan")), row.get("frequency_hz", float("nan"))
        print(f"  track {row['track_id']}: {a:.4f} mm at {f:.4f} Hz")
    print(f"rig measure: {Path(args.out) / 'report.html'}")
    if result.problems:
        for p in result.problems:
            print(f"rig measure: INPUT PROBLEM: {p} (partial result written)", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add ``calibrate`` and ``measure`` to the ``rig`` sub-command parser."""
    p = sub.add_parser("calibrate", help="calibrate on site from a video pair of the slid plate",
                       description="DLT calibration of two cameras from their videos of the calibration "
                                   "plate held still at the positions listed in target.toml.",
                       epilog=TARGET_HELP)
    p.add_argument("left", metavar="LEFT", help="video of the first camera")
    p.add_argument("right", metavar="RIGHT", help="video of the second camera")
    p.add_argument("--target", required=True, metavar="TARGET.TOML", help="plate grid and positions (mm)")
    p.add_argument("--out", default="calibration.json", metavar="CALIBRATION.JSON",
                   help="the calibration file to write; never inside a run folder (default calibration.json)")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.add_argument("--names", nargs=2, metavar=("LEFT_NAME", "RIGHT_NAME"), help="camera names (left right)")
    p.add_argument("--distortion", choices=sorted(DISTORTION_MODELS), default="k1",
                   help="lens distortion terms fitted (default k1)")
    p.add_argument("--still-px", type=float, default=0.3, help="largest marker motion of a still frame, px")
    p.add_argument("--min-still-frames", type=int, default=20, help="frames a still segment lasts at least")
    p.add_argument("--max-rms-px", type=float, default=2.0,
                   help="largest reprojection RMS accepted (px); above it the grid or coordinates are wrong")
    p = sub.add_parser("measure", help="displacement and spectra from a video pair",
                       description="Markers → matches → timing → 3-D tracks → displacement relative to the "
                                   "reference markers → spectra → tables, figures and report.html in OUT.")
    p.add_argument("left", metavar="LEFT", help="video of the reference camera")
    p.add_argument("right", metavar="RIGHT", help="video of the second camera")
    p.add_argument("--calibration", required=True, metavar="CALIBRATION.JSON")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--timing", metavar="TIMING.JSON", help="camera timing (offset, line time, drift)")
    group.add_argument("--estimate-timing", action="store_true",
                       help="estimate the timing from the videos' motion (the default without --timing)")
    p.add_argument("--reference-markers", nargs="+", metavar="X,Y,Z",
                   help="'auto' (static tracks, default), 'none', or ≥ 3 positions in mm")
    p.add_argument("--static-mm", type=float, default=0.1,
                   help="'auto' reference markers move less than this RMS, mm (default 0.1)")
    p.add_argument("--out", required=True, metavar="DIR", help="a new or empty folder for the results; never "
                   "a run folder")
    p.add_argument("--force", action="store_true",
                   help="replace the results of an earlier measurement in --out (never in a run folder)")
    p.add_argument("--names", nargs=2, metavar=("LEFT_NAME", "RIGHT_NAME"), help="camera names (left right)")
    p.add_argument("--sync", choices=MEASURE_SYNC, default="trajectory",
                   help="3-D timing of the tracks: trajectory (default), bandlimited, cubic, linear (the "
                        "paper's interpolation), or rotor (timing by the paper's rotating-marker phase "
                        "method, row-corrected, on a marker turning at constant speed; 3-D by trajectory)")
    p.add_argument("--window", nargs=2, type=float, metavar=("START_S", "STOP_S"),
                   help="analyse spectra and amplitudes in this time window only (reference clock, s)")
    p.add_argument("--line-time-s", type=float,
                   help="known rolling-shutter line time (s) for --estimate-timing")
    p.add_argument("--max-offset-s", type=float,
                   help="the cameras started within --prior-offset-s ± this, s: offsets outside are not "
                        "considered; whole periods of a steady motion inside it are listed as candidates "
                        "(default: from the containers' creation times, their resolution and "
                        "--clock-agreement-s; without them 10)")
    p.add_argument("--prior-offset-s", type=float,
                   help="expected start of the second video relative to the first, s (default: from the "
                        "containers' creation times, else 0)")
    p.add_argument("--clock-agreement-s", type=float, default=DEFAULT_CLOCK_AGREEMENT_S,
                   help="how closely the two cameras' own clocks agree, s, for the window from the "
                        f"containers' creation times (default {DEFAULT_CLOCK_AGREEMENT_S:g})")
    p.add_argument("--record", metavar="RUN", help="run folder of the procedure the videos show: relate the "
                   "video clock to the controller's (controller_time_s columns, clock.json)")
    p.add_argument("--window-px", type=int, default=41, help="marker tracking window, px")
    p.add_argument("--fps", type=float, help="the cameras' nominal frame rate, Hz, when the container's is "
                   "wrong (drops are gaps longer than 1.5 nominal periods)")
    p.add_argument("--polarity", choices=("bright", "dark"), help="markers brighter or darker than around")
    p.add_argument("--duplicate-policy", choices=("replace", "insert"), default="replace",
                   help="a duplicated frame with an advancing time stamp replaced a missed frame (default) "
                        "or was inserted (later time stamps one period late)")


COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {"calibrate": cmd_calibrate,
                                                           "measure": cmd_measure}

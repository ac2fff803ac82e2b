"""Test support: a small monitoring archive written by the twin, as segmenting cameras write one.

Two camera pairs film a vibrating marker column (half-size sensors, the simulated rig's geometry): each
camera writes consecutive segment files named by their start time (``left_20261201-120000.mp4``, …); the
right camera runs ``RIGHT_DELAY_S`` behind the left. One calibration serves both pairs: they share the
simulated rig's camera geometry (the demo plate videos through ``rig calibrate``, or one given, e.g. the
session's ``calibrated_site``). Each pair also gets ``timing.json``, the twin's true timing of its first
segment, for manifests whose tests are not about the timing estimate (a task then costs ≈ 1 CPU-s, not 11).
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import measure_twin as mt

from drivers.sim.clock import VirtualClock
from drivers.sim.world import World, WorldLayout
from rig.cli import main
from rig.demo import camera_pair, write_demo

SEGMENT_S = 2.0
RIGHT_DELAY_S = 0.15
SPINUP_S = 2.0  # the exciter runs this long before the first segment: steady motion from frame 0
ARCHIVE_START = dt.datetime(2026, 12, 1, 12, 0, 0, tzinfo=dt.UTC)
PAIRS = {"p1": (5.0, 3, 11), "p2": (7.0, 2, 12)}  # name: (frequency Hz, segments, seed)


@dataclass(frozen=True)
class Archive:
    folder: Path
    manifest: Path  # both pairs, each segment's timing estimated from its videos
    manifest_mixed: Path  # both pairs: p1 with its timing.json, p2 estimated
    manifest_of: dict[str, Path]  # one pair alone, with its timing.json (smaller, cheaper batches)
    timing_of: dict[str, Path]  # each pair's timing.json (the twin's truth for its first segment)
    calibration: Path
    frequency_hz: dict[str, float]
    amplitude_mm: float


def _stamp(t: dt.datetime) -> str:
    return t.strftime("%Y%m%d-%H%M%S")


def _pair_segments(folder: Path, frequency_hz: float, segments: int, seed: int,
                   segment_s: float = SEGMENT_S) -> float:
    """The pair's segments in ``folder/left``, ``folder/right`` and ``folder/timing.json`` (the true timing of
    the first segment; later ones drift from it by the cameras' clock-rate difference, 47 ppm); the crank
    radius (mm)."""
    world = World(VirtualClock(), seed=seed, layout=WorldLayout(initial_scene="sweep_column"))
    world.exciter.set_frequency(0.0, frequency_hz)
    left, right = camera_pair(world)
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir(parents=True)
    truth = mt.truth_timing(left, right, SPINUP_S, SPINUP_S + RIGHT_DELAY_S)
    (folder / "timing.json").write_text(json.dumps(truth), encoding="utf-8")
    for k in range(segments):
        t0 = SPINUP_S + k * segment_s
        name = _stamp(ARCHIVE_START + dt.timedelta(seconds=k * segment_s))
        left.write_video(folder / "left" / f"left_{name}.mp4", t0, t0 + segment_s)
        right.write_video(folder / "right" / f"right_{name}.mp4", t0 + RIGHT_DELAY_S,
                          t0 + segment_s + RIGHT_DELAY_S)
    return world.layout.crank_radius_mm


def write_calibration(folder: Path) -> Path:
    """``folder/calibration.json``, by ``rig calibrate`` from the demo plate videos."""
    demo = write_demo(folder / "demo")
    calibration = folder / "calibration.json"
    assert main(["calibrate", str(demo.plate[0]), str(demo.plate[1]), "--target", str(demo.target_toml),
                 "--out", str(calibration)]) == 0
    return calibration


def _calibration(folder: Path, calibration: Path | None) -> Path:
    """``folder/calibration.json``: a copy of ``calibration``, or made from the demo plate videos."""
    if calibration is None:
        return write_calibration(folder)
    return Path(shutil.copyfile(calibration, folder / "calibration.json"))


def write_long_pair(folder: Path, seconds: float, frequency_hz: float = 5.0, seed: int = 13,
                    calibration: Path | None = None) -> Path:
    """One long recording per camera (``pair/left/left_….mp4``, ``pair/right/…``) of the vibrating column
    and its calibration (``calibration`` copied, or made) in ``folder``; returns the calibration's path."""
    calibration = _calibration(folder, calibration)
    _pair_segments(folder / "pair", frequency_hz, 1, seed, segment_s=seconds)
    return calibration


def write_archive(folder: Path, calibration: Path | None = None) -> Archive:
    """The archive, its calibration (``calibration`` copied, or made) and its manifests in ``folder``."""
    calibration = _calibration(folder, calibration)
    amplitude_mm = 0.0
    for name, (frequency_hz, segments, seed) in PAIRS.items():
        amplitude_mm = _pair_segments(folder / name, frequency_hz, segments, seed)

    def pair(name: str, given_timing: bool) -> str:
        return (f'[[sites.pairs]]\nname = "{name}"\ncalibration = "calibration.json"\n'
                f'left = ["{name}/left/*.mp4"]\nright = ["{name}/right/*.mp4"]\n'
                + (f'timing = "{name}/timing.json"\n' if given_timing else ""))

    def manifest(path: Path, pairs: dict[str, bool]) -> Path:
        path.write_text('[batch]\nname = "test-archive"\nmax_retries = 1\n\n[[sites]]\nname = "bridge"\n\n'
                        + "\n".join(pair(n, given) for n, given in pairs.items()), encoding="utf-8")
        return path

    return Archive(folder, manifest(folder / "manifest.toml", dict.fromkeys(PAIRS, False)),
                   manifest(folder / "manifest_mixed.toml", {"p1": True, "p2": False}),
                   {n: manifest(folder / f"manifest_{n}.toml", {n: True}) for n in PAIRS},
                   {n: folder / n / "timing.json" for n in PAIRS}, calibration,
                   {n: f for n, (f, _, _) in PAIRS.items()}, amplitude_mm)

"""Synthetic run folders and analysis tracks with known injected errors, for the reports tests.

Everything is exact (no noise unless asked): the static poses are measured at commanded + a known
offset, the sweep markers move with a known amplitude gain 1 + e(f)/100 and delay, the rotor at a known
radius. Frequencies are held constant inside each 1 Hz bin (steps placed between camera samples), so a
bin's fitted amplitude equals the injected one to rounding.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from reports.build import ReportResult

FS_HZ = 60.0
SWEEP_T0_S = 100.0
SWEEP_AMPLITUDE_MM = 5.0
SWEEP_AXIS = (1.0, 0.0, 0.0)
SWEEP_BIN_S = 3.0
SWEEP_FREQS_HZ = tuple(k + 0.5 for k in range(1, 24))  # 1.5 … 23.5 Hz, one per 1 Hz bin
ROTATION = {
    "segment": "rotation",
    "t_start_s": 300.0,
    "t_stop_s": 310.0,
    "frequency_hz": 2.0,
    "radius_mm": 50.0,
    "centre_mm": [0.0, 0.0, 400.0],
    "axis": [0.0, 1.0, 0.0],
}
ROTOR_RADIUS_MEAS_MM = 50.3
PLATE = {
    "segment": "plate",
    "t_start_s": 400.0,
    "t_stop_s": 406.0,
    "frequency_hz": 3.5,
    "amplitude_mm": 10.0,
    "axis": [0.0, 0.0, 1.0],
    "marker_ids": ["plate_r0c0"],
}
PLATE_AMPLITUDE_MEAS_MM = 9.9
FRAME_MARKERS_MM = {"frame0": (0.0, 0.0, 0.0), "frame1": (200.0, 0.0, 0.0), "frame2": (0.0, 0.0, 150.0)}
TARGETS_MM = {"P1": (0.0, 0.0, 300.0), "P2": (-150.0, 50.0, 200.0), "P3": (150.0, -50.0, 420.0)}
N_CYCLES = 3


def pose_offset_mm(target_index: int, cycle: int, marker_index: int) -> np.ndarray:
    """The injected measurement error of one marker in one pose (exact, mm)."""
    return np.array([0.1 * (target_index + 1), -0.05 * cycle, 0.02 * marker_index])


def sweep_error_pct(f_hz: np.ndarray, method: str) -> np.ndarray:
    """Injected relative amplitude error e(f) in % per sync method (quadratic, known c0 and c2)."""
    c0, c2 = SWEEP_COEFFS[method]
    return c0 + c2 * np.asarray(f_hz) ** 2


SWEEP_COEFFS = {"trajectory": (0.1, -0.002), "linear": (0.0, -0.08)}
SWEEP_DELAY_S = {"trajectory": 0.0, "linear": 0.002}


def sweep_profile() -> list[list[float]]:
    """Stepped profile: each frequency held for SWEEP_BIN_S; each step lies between two camera samples."""
    prof = [[SWEEP_T0_S, SWEEP_FREQS_HZ[0]]]
    for k in range(1, len(SWEEP_FREQS_HZ)):
        t_step = SWEEP_T0_S + k * SWEEP_BIN_S  # a sample instant: it still belongs to bin k − 1
        prof.append([t_step + 0.25 / FS_HZ, SWEEP_FREQS_HZ[k - 1]])
        prof.append([t_step + 0.75 / FS_HZ, SWEEP_FREQS_HZ[k]])
    prof.append([SWEEP_T0_S + len(SWEEP_FREQS_HZ) * SWEEP_BIN_S, SWEEP_FREQS_HZ[-1]])
    return prof


def sweep_event() -> dict[str, Any]:
    prof = sweep_profile()
    return {
        "t_start_s": prof[0][0],
        "t_stop_s": prof[-1][0],
        "amplitude_mm": SWEEP_AMPLITUDE_MM,
        "axis": list(SWEEP_AXIS),
        "marker_ids": ["col0", "col1"],
        "profile": prof,
        "segment": "sweep",
    }


def accuracy_events() -> list[dict[str, Any]]:
    events, index = [], 0
    for cycle in range(N_CYCLES):
        for target, base in TARGETS_MM.items():
            t0 = 10.0 + 2.0 * index
            markers = {m: list(np.add(base, off)) for m, off in FRAME_MARKERS_MM.items()}
            events.append(
                {
                    "index": index,
                    "cycle": cycle,
                    "target": target,
                    "t_start_s": t0,
                    "t_stop_s": t0 + 0.5,
                    "markers": markers,
                    "segment": "accuracy",
                }
            )
            index += 1
    return events


def _times(t0: float, t1: float) -> np.ndarray:
    n0, n1 = int(np.ceil(t0 * FS_HZ)), int(np.floor(t1 * FS_HZ))
    return np.arange(n0, n1 + 1) / FS_HZ


def make_tracks(method: str, *, position_noise_mm: float = 0.0, seed: int = 0) -> pd.DataFrame:
    """Analysis tracks of the synthetic run for one sync method (the method changes only the sweep)."""
    return _make_tracks(method, position_noise_mm, seed).copy()


@functools.lru_cache(maxsize=8)
def _make_tracks(method: str, position_noise_mm: float, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows: list[pd.DataFrame] = []

    def add(segment: str, track_id: int, t: np.ndarray, xyz: np.ndarray) -> None:
        rows.append(
            pd.DataFrame(
                {
                    "segment": segment,
                    "time_s": t,
                    "track_id": track_id,
                    "x_mm": xyz[:, 0],
                    "y_mm": xyz[:, 1],
                    "z_mm": xyz[:, 2],
                    "reprojection_px": 0.1,
                    "n_cameras": 2,
                }
            )
        )

    for ev in accuracy_events():
        t = _times(ev["t_start_s"], ev["t_stop_s"])
        ti = list(TARGETS_MM).index(ev["target"])
        for mi, (m, xyz) in enumerate(sorted(ev["markers"].items())):
            p = np.asarray(xyz) + pose_offset_mm(ti, ev["cycle"], list(FRAME_MARKERS_MM).index(m))
            noise = rng.normal(0, position_noise_mm, (len(t), 3)) if position_noise_mm else 0.0
            add("accuracy", 100 * ev["index"] + mi, t, np.tile(p, (len(t), 1)) + noise)
        add(
            "accuracy", 100 * ev["index"] + 99, t, np.tile([900.0, 0.0, 0.0], (len(t), 1))
        )  # a reference marker

    from reports.frequency import profile_frequency_hz, sweep_phase_rad

    sw = sweep_event()
    t = _times(sw["t_start_s"], sw["t_stop_s"])
    tau = SWEEP_DELAY_S[method]
    gain = 1 + sweep_error_pct(profile_frequency_hz(sw, t), method) / 100
    disp = SWEEP_AMPLITUDE_MM * gain * np.sin(sweep_phase_rad(sw, t - tau))
    for i, base in enumerate(([0.0, 0.0, 300.0], [0.0, 0.0, 360.0])):
        add("sweep", i, t, np.asarray(base) + np.outer(disp, SWEEP_AXIS))
    add("sweep", 7, t, np.tile([900.0, 0.0, 0.0], (len(t), 1)))

    rt = _times(ROTATION["t_start_s"], ROTATION["t_stop_s"])
    ang = 2 * np.pi * ROTATION["frequency_hz"] * rt
    c = np.asarray(ROTATION["centre_mm"])
    xyz = c + ROTOR_RADIUS_MEAS_MM * np.column_stack([np.cos(ang), np.zeros_like(ang), np.sin(ang)])
    add("rotation", 0, rt, xyz)
    add("rotation", 1, rt, np.tile([900.0, 0.0, 0.0], (len(rt), 1)))

    pt = _times(PLATE["t_start_s"], PLATE["t_stop_s"])
    z = PLATE_AMPLITUDE_MEAS_MM * np.sin(2 * np.pi * PLATE["frequency_hz"] * pt)
    add("plate", 0, pt, np.column_stack([np.full_like(pt, 100.0), np.zeros_like(pt), 300 + z]))
    return pd.concat(rows, ignore_index=True)


def _projection(centre_mm: tuple[float, float, float]) -> list[list[float]]:
    """A camera at ``centre_mm`` looking along +y (image x = world x, image y = −world z)."""
    K = np.array([[1400.0, 0, 960], [0, 1400.0, 540], [0, 0, 1]])
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    C = np.asarray(centre_mm)
    return (K @ np.column_stack([R, -R @ C])).tolist()


CAMERA_CENTRES_MM = {"left": (-300.0, -2500.0, 300.0), "right": (300.0, -2500.0, 300.0)}
CALIBRATION = {
    "convention": "homogeneous-svd",
    "cameras": {
        name: {
            "P": _projection(c),
            "image_size": [1920, 1080],
            "rms_px": 0.21 + 0.1 * i,
            "residuals_px": [[0.1, 0.0], [0.0, -0.2]],
        }
        for i, (name, c) in enumerate(CAMERA_CENTRES_MM.items())
    },
}
TIMING = {
    "reference_camera": "left",
    "offset_s": {"left": 0.0, "right": 0.0041},
    "line_time_s": {"left": 1.4e-5, "right": 1.4e-5},
    "drift_ppm": {"left": 0.0, "right": 3.0},
    "method": "trajectory",
    "uncertainty": {"offset_s": {"right": 2.0e-5}},
}
RIG = {
    "cameras": {"left": {"fps": FS_HZ}, "right": {"fps": FS_HZ}},
    "criteria": {"position_max_mm": 1.0, "min_usable_frequency_hz": 15.0, "amplitude_error_up_to_hz": 15.0},
}


def write_run(run_dir: Path, *, rig: dict | None = None, exit_status: str = "success") -> Path:
    """Write record.jsonl (contracts.md documents), calibration.json and timing.json into ``run_dir``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    docs: list[dict[str, Any]] = [
        {
            "type": "start",
            "time_s": 0.0,
            "wall_utc": "2026-11-21T23:15:00.000000+00:00",
            "session": 0,
            "run_id": run_dir.name,
            "procedure": "certify",
            "parameters": {"seed": 1},
            "rig": rig or RIG,
            "versions": {"rig-controller": "0.1.0", "python": "3.11"},
            "clock": "virtual",
            "resume": False,
        }
    ]
    seq: dict[str, int] = {}

    def event(stream: str, data: dict, step: str) -> None:
        docs.append(
            {
                "type": "event",
                "time_s": float(data.get("t_stop_s", 0.0)),
                "wall_utc": "2026-11-21T23:15:01.000000+00:00",
                "session": 0,
                "stream": stream,
                "seq": seq.get(stream, 0),
                "step": step,
                "data": data,
            }
        )
        seq[stream] = seq.get(stream, 0) + 1

    for ev in accuracy_events():
        event("accuracy_pose", ev, "accuracy")
    event("sweep", sweep_event(), "sweep")
    event("rotation", ROTATION, "rotation")
    event("plate", PLATE, "plate")
    docs.append(
        {
            "type": "stop",
            "time_s": 500.0,
            "wall_utc": "2026-11-21T23:25:00.000000+00:00",
            "session": 0,
            "exit_status": exit_status,
            "reason": "",
            "num_events": sum(seq.values()),
        }
    )
    (run_dir / "record.jsonl").write_text("".join(json.dumps(d) + "\n" for d in docs))
    (run_dir / "calibration.json").write_text(json.dumps(CALIBRATION))
    (run_dir / "timing.json").write_text(json.dumps(TIMING))
    return run_dir


@dataclass
class FakeAnalysis:
    """Stands in for ``rig.analysis.analyse.Analysis`` (same attributes)."""

    tracks: pd.DataFrame
    clock: pd.DataFrame = field(default_factory=lambda: pd.DataFrame(CLOCK))
    notes: list[str] = field(default_factory=list)


# the controller-clock offset of the synthetic tracks (they are on the controller clock already), dated as
# a timing fiducial would date them (the phase criteria need it)
CLOCK = {"segment": ["sweep"], "session": [0], "offset_s": [0.0], "u_offset_s": [1.0e-5],
         "source": ["timing fiducial (synthetic)"]}


def fake_analyse(run_dir: object, *, sync: str) -> FakeAnalysis:
    """An injected analysis step: the synthetic tracks of ``sync``."""
    if sync not in SWEEP_COEFFS:
        raise ValueError(f"sync must be one of {sorted(SWEEP_COEFFS)}, got {sync!r}")
    return FakeAnalysis(make_tracks(sync))


RUN_NAME = "20261121-231500_certify_ab12cd34"


def built_report(folder: Path) -> ReportResult:
    """The synthetic run ``folder/RUN_NAME`` and its first report, issued (the tables, the figures, the page
    and the certificate of the fake analysis): :func:`reports.build.build_report`'s result."""
    from reports.build import build_report

    return build_report(write_run(folder / RUN_NAME), analysis=fake_analyse)


def moved(result: ReportResult, run_dir: Path) -> ReportResult:
    """``result`` (what a report wrote) for a copy of its run folder at ``run_dir``."""
    import dataclasses

    def move(path: Path) -> Path:
        return run_dir / path.relative_to(result.run_dir)

    return dataclasses.replace(result, run_dir=run_dir, report_html=move(result.report_html),
                               certificate_json=move(result.certificate_json),
                               tables={k: move(v) for k, v in result.tables.items()},
                               figures={k: move(v) for k, v in result.figures.items()})

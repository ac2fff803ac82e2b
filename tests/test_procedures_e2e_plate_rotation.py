"""``rig run plate`` and ``rig run rotation`` end to end on the simulated rig (calibrate → sync → the
procedure's own recording → report, all through the real command), checked against the twin's truth.

Truth comes from the twin's own target objects (``rig.run.station.world_layout`` of the configuration:
the plate's marker shape weights × the crank radius, the rotor's centre, axis and radius) and the
commanded frequencies — never from the numbers the procedure itself recorded.

Tolerances are derived from the run's measured noise, as in ``tests/test_certify_e2e.py``: σ is the
single-frame centroid noise (px) of the still calibration plate; it becomes mm laterally (× Z/f) and in
depth (× Z/B). The plate moves along its normal (towards the cameras: depth), so one sample's noise is
σ_z = σ·(Z/f)·(Z/B); a sine fit over N samples has amplitude uncertainty σ_z·√(2/N) and frequency
uncertainty √12·σ_z / (2π·A·T·√N) (Cramér–Rao, T the record length). Amplitudes must be within 5 such
u plus the floor of the certify test's sweep check (3 σ·Z/f: calibration and rolling-shutter residuals);
frequencies within 5 u plus the cameras' clock tolerance (50 ppm). The rotor's radius uses the certify
test's static floor (20 units of σ·(Z/f)·(Z/B): noise plus the k1-only lens model's extrapolation).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rig.cli import main
from rig.config.rig_config import load_config
from rig.record.catalogue import run_folders
from rig.record.writer import load_run, read_observations
from rig.run.station import world_layout
from tests.certify_support import (
    ROTATION_HZ,
    ROTATION_RECORD_S,
    depth_scale,
    read_json,
    still_pixel_noise_px,
    write_config,
)

CLOCK_PPM = 50e-6  # the twin's cameras' clocks are within ±50 ppm of the controller's
PLATE_HZ = 3.5
ROTOR_HZ = ROTATION_HZ  # the session's rotation run (certify_support.rotation_run)


def _run(tmp_path: Path, procedure: str, *settings: str) -> tuple[Path, Path]:
    config = write_config(tmp_path)
    args = ["run", procedure, "--config", str(config)]
    for s in settings:
        args += ["--set", s]
    code = main(args)
    (run_dir,) = run_folders(tmp_path / "runs")
    _check_run(code, run_dir, procedure)
    return config, run_dir


def _check_run(code: int, run_dir: Path, procedure: str) -> None:
    run = load_run(run_dir)
    # a single procedure evaluates only its own criteria: its certificate is INCOMPLETE, not a pass
    assert code == 1 and run.stop["outcome"] == "incomplete", run.stop
    assert run.stop["exit_status"] == "success"
    criteria = pd.read_csv(run_dir / "tables" / "criteria.csv")
    evaluated = criteria[criteria["status"] != "NOT EVALUATED"]
    assert {"frequency_error_pct", "calibration_rms_px"} <= set(evaluated["id"])
    assert (evaluated["status"] == "PASS").all(), evaluated[["id", "value", "status"]]
    assert set(run.steps_completed) >= {"calibrate", "sync", procedure, "report"}
    assert (run_dir / "report.html").is_file() and (run_dir / "certificate.json").is_file()


def _noise(run_dir: Path, centre_mm: tuple[float, float, float]) -> tuple[float, float, float]:
    """(σ px, mm per px, depth / baseline) at ``centre_mm`` from the still calibration plate."""
    sigma_px = float(np.median([still_pixel_noise_px(o[o["segment"] == "calibrate"])
                                for o in (read_observations(run_dir, c) for c in ("left", "right"))]))
    assert 0 < sigma_px < 0.5, sigma_px
    mm_per_px, z_over_b = depth_scale(read_json(run_dir / "calibration.json"), centre_mm)
    return sigma_px, mm_per_px, z_over_b


@pytest.mark.slow
def test_run_plate_measures_every_markers_frequency_and_amplitude(tmp_path: Path) -> None:
    record_s = 1.5
    config, run_dir = _run(tmp_path, "plate", f"record_s={record_s}", f"frequency_hz={PLATE_HZ}")
    cfg = load_config(config)
    plate = world_layout(cfg).targets.plate
    crank_mm = cfg.devices.exciter.crank_radius_mm
    rest = plate.rest_positions_mm()
    truth_mm = {marker: weight * crank_mm for marker, (_, weight) in rest.items()}
    centre = tuple(np.mean([p for p, _ in rest.values()], axis=0))
    sigma_px, mm_per_px, z_over_b = _noise(run_dir, centre)
    sigma_z_mm = sigma_px * mm_per_px * z_over_b  # one sample, along the plate normal (depth)

    # the drive ran at the commanded frequency all through the recording (its polls)
    run = load_run(run_dir)
    (event,) = [d["data"] for d in run.event_documents("plate")]
    polled = run.events["exciter"]
    during = polled[(polled["time_s"] >= event["t_start_s"]) & (polled["time_s"] <= event["t_stop_s"])]
    assert len(during) >= 3 and np.allclose(during["frequency_hz"], PLATE_HZ, atol=0.01), during

    table = pd.read_csv(run_dir / "tables" / "plate.csv")
    assert sorted(table["marker_id"]) == sorted(truth_mm)  # every marker of the plate found once
    n = table["n_samples"].to_numpy(float)
    assert (n >= 0.9 * record_s * 60).all(), table[["marker_id", "n_samples"]]
    duration_s = n / 60.0
    truth = table["marker_id"].map(truth_mm).to_numpy(float)
    u_amp = sigma_z_mm * np.sqrt(2 / n)
    amp_err = table["amplitude_meas_mm"].to_numpy(float) - truth
    assert (np.abs(amp_err) <= 5 * u_amp + 3 * sigma_px * mm_per_px).all(), \
        pd.DataFrame({"marker": table["marker_id"], "err_mm": amp_err, "u_mm": u_amp})
    u_f = np.sqrt(12) * sigma_z_mm / (2 * np.pi * truth * duration_s * np.sqrt(n))
    f_err = table["frequency_meas_hz"].to_numpy(float) - PLATE_HZ
    assert (np.abs(f_err) <= 5 * u_f + PLATE_HZ * CLOCK_PPM).all(), \
        pd.DataFrame({"marker": table["marker_id"], "err_hz": f_err, "u_hz": u_f})


def test_run_rotation_measures_the_rotor_radius_and_frequency(rotation_run: dict) -> None:
    from reports.motion import rotation_samples, rotation_summary
    from rig.analysis.analyse import analyse

    # the session's run (built once: test_evidence_io_faults reports on copies of it), checked here
    config, run_dir = rotation_run["config"], rotation_run["run_dir"]
    _check_run(rotation_run["code"], run_dir, "rotation")
    rotor = world_layout(load_config(config)).targets.rotor
    sigma_px, mm_per_px, z_over_b = _noise(run_dir, rotor.centre_mm)
    unit_mm = sigma_px * mm_per_px * z_over_b

    # the rotation step's own recording, analysed about the twin's rotor (not the procedure's event)
    run = load_run(run_dir)
    (event,) = [d["data"] for d in run.event_documents("rotation") if d["step"] == "rotation"]
    truth = {"t_start_s": event["t_start_s"], "t_stop_s": event["t_stop_s"], "frequency_hz": ROTOR_HZ,
             "radius_mm": rotor.radius_mm, "centre_mm": list(rotor.centre_mm), "axis": list(rotor.axis)}
    tracks = analyse(run_dir).tracks
    samples = rotation_samples(tracks[tracks["segment"] == "rotation"], truth)
    summary = rotation_summary(samples, truth)
    assert summary["n_samples"] >= 0.9 * ROTATION_RECORD_S * 60, summary
    assert abs(summary["radius_error_mm"]) <= 20 * unit_mm, (summary, unit_mm)
    assert abs(samples["axial_mm"].mean()) <= 20 * unit_mm  # in the rotor's plane
    clock_hz = ROTOR_HZ * CLOCK_PPM
    assert abs(summary["frequency_meas_hz"] - ROTOR_HZ) <= 5 * summary["u_frequency_hz"] + clock_hz

    # the report's rotor table exists and agrees with the truth too
    reported = pd.read_csv(run_dir / "tables" / "rotation_summary.csv").iloc[0]
    assert reported["n_samples"] == summary["n_samples"]  # the rotation step's recording, not the sync step's
    assert abs(reported["radius_mean_mm"] - rotor.radius_mm) <= 20 * unit_mm
    assert abs(reported["frequency_meas_hz"] - ROTOR_HZ) <= 5 * reported["u_frequency_hz"] + clock_hz

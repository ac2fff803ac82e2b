"""``rig certify`` end to end on the simulated rig: report and certificate exist and their numbers match the
twin's hidden truth within tolerances derived from the measured pixel noise.

The fast preset runs in the default suite; the full certification is marked slow. Tolerance floor: the
single-frame centroid noise σ (px, measured on the still markers of the run) turned into millimetres at
the volume (Z/f mm per px) and into depth (× Z/B); the static checks allow 20 such units — 3 σ of noise
plus the k1-only lens model's extrapolation error over the volume (docs/stereo_core.md: 0.14 mm at twice
the plate's extent, ≈ 12 units on this rig).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rig.cli import main
from rig.record.catalogue import run_folders
from rig.record.writer import load_run, read_observations
from tests.certify_support import (
    depth_scale,
    read_json,
    still_pixel_noise_px,
    true_offset_s,
    twin_cameras,
    write_config,
)

VOLUME_CENTRE_MM = (420.0, 0.0, 300.0)


def _certify(tmp_path: Path, *extra: str, full_report: bool = False) -> tuple[int, Path]:
    """``rig certify`` on the simulated rig; ``full_report``: the built-in rig's ``[report]`` (the linear
    comparison and the figures), else the certificate only."""
    config = write_config(tmp_path, comparison=("linear",), figures=True) if full_report else \
        write_config(tmp_path)
    code = main(["certify", "--config", str(config), *extra])
    runs = run_folders(tmp_path / "runs")
    assert len(runs) == 1
    return code, runs[0]


def _check_against_truth(run_dir: Path, config: Path) -> None:
    cert = read_json(run_dir / "certificate.json")
    assert (run_dir / "report.html").is_file()
    rows = {r["id"]: r for r in cert["criteria"]}
    calibration = read_json(run_dir / "calibration.json")
    timing = read_json(run_dir / "timing.json")
    sigma_px = float(np.median([still_pixel_noise_px(o[o["segment"].str.startswith("accuracy")])
                                for o in (read_observations(run_dir, c) for c in ("left", "right"))]))
    mm_per_px, z_over_b = depth_scale(calibration, VOLUME_CENTRE_MM)
    unit_mm = sigma_px * mm_per_px * z_over_b
    assert 0 < sigma_px < 0.5, sigma_px  # the twin's noise gives hundredths of a pixel

    # static positions: every commanded marker found, errors within the floor
    pos = pd.read_csv(run_dir / "tables" / "position_errors.csv")
    assert len(pos) and pos["error_mm"].notna().all()
    assert pos["error_mm"].max() <= 20 * unit_mm, (pos["error_mm"].max(), unit_mm)
    assert (pos["n_unsettled"] == 0).all(), pos  # the twin's arm is at rest in every frame of a pose's window
    assert rows["repeatability_mm"]["value"] <= 20 * unit_mm
    assert rows["length_error_mm"]["value"] <= 2 * 20 * unit_mm
    assert rows["calibration_rms_px"]["value"] <= 10 * sigma_px

    # timing against the cameras' hidden clocks (k·u of the joint fit; the known row-distortion bias of the
    # estimator, ≈ 5 u on this rig, is inside)
    cams = twin_cameras(config)
    ref, other = timing["reference_camera"], "right" if timing["reference_camera"] == "left" else "left"
    truth = true_offset_s(cams[ref], cams[other], timing["epoch_s"][other])
    u_off = timing["uncertainty"]["offset_s"][other]
    assert abs(timing["offset_s"][other] - truth) <= 10 * u_off + 1e-6, \
        (timing["offset_s"][other], truth, u_off)
    true_drift = ((1 + cams[ref].clock_ppm * 1e-6) / (1 + cams[other].clock_ppm * 1e-6) - 1) * 1e6
    assert abs(timing["drift_ppm"][other] - true_drift) <= 6 * timing["uncertainty"]["drift_ppm"][other] + 0.5
    line_truth = cams[ref].line_time_s
    assert abs(timing["line_time_s"][other] - line_truth) <= 10 * timing["uncertainty"]["line_time_s"][other]

    # sweep: amplitude of the crank (4 mm) up to the usable frequency, within the bins' own uncertainty
    bins = pd.read_csv(run_dir / "tables" / "sweep_bins.csv")
    main_bins = bins[(bins["sync_method"] == "trajectory") & (bins["frequency_hz"] <= 10.0)]
    assert len(main_bins) >= 3
    floor_pct = 100 * 3 * sigma_px * mm_per_px / 4.0
    bound = 5 * main_bins["u_amplitude_error_pct"] + floor_pct
    assert (main_bins["amplitude_error_pct"].abs() <= bound).all()

    # phase (the built-in rig's timing fiducial dates the sweep): the twin's markers move with the crank and
    # its controller clock is the world's, so the true delay is 0 — within 3 u of the stated budget
    ph = cert["phase"]
    assert "timing fiducial" in ph["clock_source"], ph["clock_source"]
    assert abs(ph["delay_ms"]) <= 3 * ph["u_delay_ms"], ph
    assert rows["phase_delay_ms"]["status"] != "NOT EVALUATED", rows["phase_delay_ms"]
    clock = rows["controller_clock_u_ms"]
    assert clock["status"] == "PASS" and clock["value"] <= 0.05, clock

    # rotor: radius 60 mm and 10 Hz
    rot = pd.read_csv(run_dir / "tables" / "rotation_summary.csv").iloc[0]
    assert abs(rot["radius_error_mm"]) <= 20 * unit_mm
    assert abs(rot["frequency_meas_hz"] - 10.0) <= 5 * rot["u_frequency_hz"] + 10.0 * 50e-6  # + clock ppm


def test_certify_fast_preset_end_to_end(tmp_path: Path) -> None:
    code, run_dir = _certify(tmp_path, "--set", 'preset="fast"', "--set", "figures=false")
    run = load_run(run_dir)
    assert run.stop["exit_status"] == "success"
    assert code in (0, 1)
    cert = read_json(run_dir / "certificate.json")
    assert (run_dir / "report.html").is_file()
    statuses = {r["id"]: r["status"] for r in cert["criteria"]}
    # the verdict follows the criteria: exit 0 exactly when every criterion passed
    assert (code == 0) == all(s == "PASS" for s in statuses.values()), statuses
    # ... and agrees with the certificate; the certificate knows the run was finishing normally
    assert (code == 0) == (cert["result"] == "PASS")
    assert run.stop["verdict"] == {"PASS": "pass", "FAIL": "fail", "INCOMPLETE": "incomplete"}[cert["result"]]
    assert cert["conditions"]["exit_status"] == "success"
    assert not any("killed" in note for note in cert["conditions"]["notes"]), cert["conditions"]["notes"]
    # sim.toml sets the band's criteria and the fast preset has no band step: said in the log before the
    # first move, and the certificate cannot pass through them
    assert {s for c, s in statuses.items() if c.startswith("band_")} == {"NOT EVALUATED"}, statuses
    assert cert["result"] == "INCOMPLETE" and code == 1
    log = (run_dir / "rig.log").read_text()
    assert log.index("stay NOT EVALUATED without the band step") < log.index("mounted target"), log[:2000]
    for stream in ("arm", "calibration_position", "accuracy_pose", "sweep", "rotation", "camera", "exciter"):
        assert stream in run.events, stream
    _check_against_truth(run_dir, tmp_path / "rig.toml")


@pytest.mark.slow
@pytest.mark.timeout(1800)  # the whole certification: 301 s wall at load ≈ 16 (the suite's default: 300 s)
def test_certify_full_preset_passes(tmp_path: Path) -> None:
    code, run_dir = _certify(tmp_path, full_report=True)  # everything the certification computes
    assert code == 0, read_json(run_dir / "certificate.json")["criteria"]
    assert (run_dir / "figures").is_dir() and any((run_dir / "figures").iterdir())
    cert = read_json(run_dir / "certificate.json")
    assert cert["conditions"]["compared_sync_methods"] == ["linear"] and "linear" in cert["usable_frequency"]
    _check_against_truth(run_dir, tmp_path / "rig.toml")
    sweep = load_run(run_dir).events["sweep"]
    assert np.isclose(max(f for _, f in sweep["profile"].iloc[0]), 30.0)
    _check_extended_band(read_json(run_dir / "certificate.json"))


def _check_extended_band(cert: dict) -> None:
    """Issue 18's "done when": amplitude and phase criteria over the band beyond the crank sweep (the shaker
    27 → 50 Hz, phase against the generator's own waveform, cameras dated by the fiducial on channel 2).
    Per bin the error is within 4 standard uncertainties of 0 (no bias beyond the noise) and the issue's
    targets hold with the expanded uncertainty (≤ 1 % at 40 Hz, ≤ 5 % at 50 Hz)."""
    rows = {r["id"]: r for r in cert["criteria"]}
    for criterion in ("band_amplitude_error_pct", "band_phase_deg", "band_min_hz", "phase_delay_ms",
                      "controller_clock_u_ms"):
        assert rows[criterion]["status"] == "PASS", rows[criterion]
    ext = cert["extended_band"]
    assert ext["sweep_hz"] == [27.0, 50.0] and ext["certified_to_hz"] == pytest.approx(50.0)
    assert ext["usable_from_hz"] <= 31.0 and ext["clock_source"].startswith("timing fiducial")
    assert "timing fiducial" in ext["phase_origin"]
    bins = pd.DataFrame(ext["bins"])
    assert (bins["refused"] == "").all() and bins["frequency_hz"].max() > 49.0
    assert (bins["amplitude_error_pct"].abs() <= 4 * bins["u_amplitude_error_pct"]).all(), bins
    assert (bins["phase_deg"].abs() <= 4 * bins["u_phase_deg"]).all(), bins
    for f_hz, target_pct in ((40.0, 1.0), (49.5, 5.0)):
        row = bins.iloc[(bins["frequency_hz"] - f_hz).abs().argmin()]
        assert abs(row["amplitude_error_pct"]) + 2 * row["u_amplitude_error_pct"] <= target_pct

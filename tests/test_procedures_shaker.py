"""``rig run sweep`` and ``rig run plate`` with the electrodynamic shaker (``body = "shaker"``) on the
simulated rig, through the real command, checked against the twin's truth.

The twin's shaker moves by s(f)·V_peak (the mock generator's physics, given the configuration's
sensitivity table); with the flat tables used here that is exactly the commanded ``shaker_amplitude_mm``.
Tolerances come from the run's measured noise as in ``tests/test_procedures_e2e_plate_rotation.py``:
σ (px) is the single-frame centroid noise of the still calibration plate. The sweep column moves along
base z, across the cameras' view (lateral: one sample's noise σ·Z/f); the plate along its normal, towards
the cameras (depth: σ·(Z/f)·(Z/B)). A sine fit over n samples has amplitude uncertainty σ_x·√(2/n); the
floor for calibration and rolling-shutter residuals is 3·σ·Z/f (the certify test's). Frequencies: the
Cramér–Rao bound √12·σ_x / (2π·A·T·√n) plus the cameras' clock tolerance (50 ppm).

Limits: a plan above the generator's (volts at the amplifier, displacement, (2πf)²·x) exits 3 with
nothing recorded after the device snapshot; what the generator's built-in sweep cannot do (a
sensitivity table that is not flat over the sweep) exits 4, also before anything is sent. The Fig. 17
points profile runs as phase-continuous CW frequency steps (``procedures/_shaker.py``): each step at the
profile's mean frequency over it, so the staircase's phase equals the profile's at every step's end.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from procedures._shaker import staircase_plan
from procedures.sweep import Parameters, profile_of
from reports.frequency import sweep_phase_rad
from rig.cli import main
from rig.config.rig_config import load_config
from rig.record.catalogue import run_folders
from rig.record.writer import load_run, read_observations
from rig.run.station import world_layout
from tests.certify_support import depth_scale, read_json, still_pixel_noise_px, write_config

CLOCK_PPM = 50e-6


def _config(tmp_path: Path, target: str, *, sensitivity: str | None = None) -> Path:
    """The simulated rig with ``targets.<target>.body = "shaker"`` (and another sensitivity table)."""
    path = write_config(tmp_path)
    text = path.read_text()
    text, n = re.subn(rf'(\[targets\.{target}\]\nbody = )"exciter"', r'\1"shaker"', text)
    assert n == 1
    if sensitivity is not None:
        text, n = re.subn(r"^sensitivity_mm_per_v = .*$", f"sensitivity_mm_per_v = {sensitivity}", text,
                          flags=re.M)
        assert n == 1
    path.write_text(text)
    return path


def _run(tmp_path: Path, config: Path, procedure: str, *settings: str) -> tuple[int, Path]:
    args = ["run", procedure, "--config", str(config)]
    for s in settings:
        args += ["--set", s]
    code = main(args)
    (run_dir,) = run_folders(tmp_path / "runs")
    return code, run_dir


def _assert_passed(code: int, run_dir: Path, procedure: str) -> None:
    run = load_run(run_dir)
    # a single procedure evaluates only its own criteria: its certificate is INCOMPLETE, not a pass
    assert code == 1 and run.stop["outcome"] == "incomplete", run.stop
    assert run.stop["exit_status"] == "success"
    assert set(run.steps_completed) >= {"calibrate", "sync", procedure, "report"}
    criteria = pd.read_csv(run_dir / "tables" / "criteria.csv")
    evaluated = criteria[criteria["status"] != "NOT EVALUATED"]
    assert (evaluated["status"] == "PASS").all(), evaluated[["id", "value", "status"]]


def _noise(run_dir: Path, centre_mm: tuple[float, ...]) -> tuple[float, float, float]:
    sigma_px = float(np.median([still_pixel_noise_px(o[o["segment"] == "calibrate"])
                                for o in (read_observations(run_dir, c) for c in ("left", "right"))]))
    assert 0 < sigma_px < 0.5, sigma_px
    mm_per_px, z_over_b = depth_scale(read_json(run_dir / "calibration.json"), centre_mm)
    return sigma_px, mm_per_px, z_over_b


@pytest.mark.slow
def test_shaker_sweep_runs_the_generator_sweep_at_constant_amplitude(tmp_path: Path) -> None:
    # log: every 1 Hz bin from 2 to 12 Hz lasts ≥ 3 cycles (the report's minimum) in 6 s
    amp_mm, f0, f1, sweep_s = 2.0, 2.0, 12.0, 6.0
    config = _config(tmp_path, "sweep_column")
    code, run_dir = _run(tmp_path, config, "sweep", "shape=log", f"start_hz={f0}", f"max_hz={f1}",
                         f"duration_s={sweep_s}", "hold_s=0.5", f"shaker_amplitude_mm={amp_mm}")
    _assert_passed(code, run_dir, "sweep")
    run = load_run(run_dir)
    (event,) = [d["data"] for d in run.event_documents("sweep")]
    assert event["body"] == "shaker" and event["amplitude_mm"] == amp_mm
    assert event["amplitude_vpp"] == pytest.approx(2 * amp_mm / 0.5)
    prof = np.asarray(event["profile"], float)
    assert prof[0, 1] == f0 and prof[-1, 1] == f1 and np.all(np.diff(prof[:, 1]) >= 0)
    law = f0 * (f1 / f0) ** ((prof[:, 0] - prof[0, 0]) / sweep_s)  # the generator's log law, then the hold
    assert np.allclose(prof[:, 1], np.minimum(law, f1), rtol=1e-9)
    assert prof[-1, 0] - prof[0, 0] == pytest.approx(sweep_s + 0.5)

    # what the generator reported while sweeping: its sweep settings, output on, the commanded volts
    gen = [d["data"] for d in run.event_documents("generator")]
    sweeping = [g for g in gen if event["t_start_s"] <= g["t_s"] < event["t_start_s"] + sweep_s]
    assert len(sweeping) >= sweep_s / 0.5 - 1
    for g in sweeping:
        assert g["output_on"] and g["sweep_on"] and g["amplitude_vpp"] == pytest.approx(8.0)
        assert g["sweep"] == {"start_hz": f0, "stop_hz": f1, "time_s": sweep_s, "spacing": "log"}
    assert not gen[-1]["output_on"]  # ramped down and switched off after the sweep

    # the cameras' amplitude in every 1 Hz bin agrees with the twin's (flat table: the commanded mm)
    cfg = load_config(config)
    centre = tuple(world_layout(cfg).targets.sweep_column.centre_mm)
    sigma_px, mm_per_px, _ = _noise(run_dir, centre)
    sigma_x_mm = sigma_px * mm_per_px  # motion along z: across the view
    bins = pd.read_csv(run_dir / "tables" / "sweep_bins.csv")
    # the primary sync (the "linear" comparison shows the interpolation error that grows with f, by design)
    bins = bins[bins["sync_method"] == "trajectory"]
    assert bins["frequency_hz"].min() < f0 + 1 and bins["frequency_hz"].max() > f1 - 1
    assert bins["track"].nunique() >= 5  # the column's five markers
    n = bins["n_samples"].to_numpy(float)
    err = bins["amplitude_meas_mm"].to_numpy(float) - amp_mm
    bound = 5 * sigma_x_mm * np.sqrt(2 / n) + 3 * sigma_px * mm_per_px
    assert (np.abs(err) <= bound).all(), bins.assign(err_mm=err, bound_mm=bound)[
        ["track", "frequency_hz", "err_mm", "bound_mm"]]

    # the hold at f1 is a steady step; the generator's own sweep has no recorded phase origin, so its phase
    # is stated against the sweep line's constant (reports.phase), within 3 × its u of the truth (0) plus the
    # cameras' relative offset's share (10 u, as in test_phase_e2e)
    cert = read_json(run_dir / "certificate.json")
    (step,) = cert["steady_steps"]["steps"]
    # the sweep's delay against the generator's log law, sampled densely enough (a 0.05-s chord had put the
    # reference 0.25° ahead by the end: τ = +0.06 ms, 9 u)
    assert abs(cert["phase"]["delay_ms"]) <= 3 * cert["phase"]["u_delay_ms"], cert["phase"]["delay_ms"]
    u_cameras_s = max(read_json(run_dir / "timing.json")["uncertainty"]["offset_s"].values())
    assert step["frequency_ref_hz"] == pytest.approx(f1)
    assert abs(step["phase_deg"]) <= 3 * step["u_phase_deg"] + 360.0 * f1 * 10 * u_cameras_s, step


@pytest.mark.slow
def test_shaker_plate_matches_the_twin(tmp_path: Path) -> None:
    plate_hz, tip_mm, record_s = 3.5, 4.0, 1.5
    # 1 mm per volt: the crank's 4 mm at 8 Vpp (the sim table's 0.5 mm/V allows at most 2.5 mm at 10 Vpp)
    config = _config(tmp_path, "plate", sensitivity="[[1.0, 1.0], [100.0, 1.0]]")
    code, run_dir = _run(tmp_path, config, "plate", f"record_s={record_s}", f"frequency_hz={plate_hz}",
                         f"shaker_amplitude_mm={tip_mm}")
    _assert_passed(code, run_dir, "plate")
    run = load_run(run_dir)
    (event,) = [d["data"] for d in run.event_documents("plate")]
    assert event["body"] == "shaker" and event["amplitude_mm"] == pytest.approx(tip_mm)
    gen = [d["data"] for d in run.event_documents("generator")]
    during = [g for g in gen if event["t_start_s"] <= g["t_s"] <= event["t_stop_s"]]
    assert len(during) >= 3
    assert all(g["output_on"] and not g["sweep_on"] and g["frequency_hz"] == plate_hz for g in during)
    assert not gen[-1]["output_on"]

    plate = world_layout(load_config(config)).targets.plate
    rest = plate.rest_positions_mm()
    truth_mm = {marker: weight * tip_mm for marker, (_, weight) in rest.items()}
    centre = tuple(np.mean([p for p, _ in rest.values()], axis=0))
    sigma_px, mm_per_px, z_over_b = _noise(run_dir, centre)
    sigma_z_mm = sigma_px * mm_per_px * z_over_b

    table = pd.read_csv(run_dir / "tables" / "plate.csv")
    assert sorted(table["marker_id"]) == sorted(truth_mm)
    n = table["n_samples"].to_numpy(float)
    assert (n >= 0.9 * record_s * 60).all()
    truth = table["marker_id"].map(truth_mm).to_numpy(float)
    amp_err = table["amplitude_meas_mm"].to_numpy(float) - truth
    assert (np.abs(amp_err) <= 5 * sigma_z_mm * np.sqrt(2 / n) + 3 * sigma_px * mm_per_px).all(), \
        pd.DataFrame({"marker": table["marker_id"], "err_mm": amp_err})
    u_f = np.sqrt(12) * sigma_z_mm / (2 * np.pi * truth * (n / 60.0) * np.sqrt(n))
    f_err = table["frequency_meas_hz"].to_numpy(float) - plate_hz
    assert (np.abs(f_err) <= 5 * u_f + plate_hz * CLOCK_PPM).all(), \
        pd.DataFrame({"marker": table["marker_id"], "err_hz": f_err, "u_hz": u_f})


@pytest.mark.parametrize(("settings", "expected"), [
    # 3 mm at 0.5 mm/V needs 12 Vpp: above the amplifier's 10 Vpp
    (("shaker_amplitude_mm=3.0", "max_hz=12"), ("generator amplitude 12 Vpp",
                                                 "sweep.shaker_amplitude_mm = 3 mm",
                                                 "(devices.generator.max_amplitude_vpp)")),
    # 2 mm at 80 Hz: (2π·80)²·2 mm = 505 m/s² > 500 m/s²
    (("shaker_amplitude_mm=2.0", "max_hz=80"), ("acceleration (2π·80 Hz)²·2 mm", "sweep.max_hz = 80 Hz",
                                                 "(limits.generator.max_acceleration_m_s2)")),
    # above the shaker's 5 mm stroke
    (("shaker_amplitude_mm=6.0", "max_hz=12"), ("displacement 6 mm", "sweep.shaker_amplitude_mm = 6 mm",
                                                 "(limits.generator.max_displacement_mm)")),
])
def test_shaker_sweep_above_the_limits_exits_4_before_connecting(tmp_path: Path, settings: tuple[str, ...],
                                                                  expected: tuple[str, ...],
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "sweep", "--config", str(_config(tmp_path, "sweep_column")), "--set", "shape=linear",
                 *(a for s in settings for a in ("--set", s))])
    err = capsys.readouterr().err
    assert code == 4 and not (tmp_path / "runs").exists(), err  # refused before the run folder and station
    assert all(e in err for e in expected), err


def test_shaker_plate_above_the_amplifier_limit_exits_4_before_connecting(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = _config(tmp_path, "plate")
    code = main(["run", "plate", "--config", str(config), "--set", "shaker_amplitude_mm=3.0"])
    err = capsys.readouterr().err
    assert code == 4 and not (tmp_path / "runs").exists(), err
    assert "generator amplitude 12 Vpp" in err and "limit 10 Vpp" in err, err


def test_shaker_sweep_needs_a_flat_sensitivity_table(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    # 0.5 → 0.6 mm/V over 1..100 Hz: 2 % over 2..12 Hz, more than the 0.5 % the constant-volts sweep allows
    config = _config(tmp_path, "sweep_column", sensitivity="[[1.0, 0.5], [100.0, 0.6]]")
    code = main(["run", "sweep", "--config", str(config), "--set", "shape=linear", "--set", "start_hz=2",
                 "--set", "max_hz=12"])
    err = capsys.readouterr().err
    assert code == 4 and not (tmp_path / "runs").exists(), err
    assert "devices.generator.sensitivity_mm_per_v" in err and "0.5 %" in err, err


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.05, 5.0), st.floats(0.0, 3.0)), min_size=1, max_size=6),
       st.floats(0.5, 5.0), st.floats(0.02, 2.0))
def test_staircase_has_the_profiles_phase_at_every_step_end(segments: list[tuple[float, float]],
                                                            f0_hz: float, step_s: float) -> None:
    t, f, points = 0.0, f0_hz, [(0.0, f0_hz)]
    for dt, df in segments:  # a monotone piecewise-linear profile
        t, f = t + dt, f + df
        points.append((t, f))
    plan = staircase_plan(points, step_s)
    ends = [p[0] for p in plan[1:]] + [t]
    assert plan[0][0] == 0 and all(b > a for a, b in itertools.pairwise(ends))
    freqs = np.array([p[1] for p in plan])
    assert np.all(np.diff(freqs) >= -1e-9) and freqs.min() >= f0_hz - 1e-9 and freqs.max() <= f + 1e-9
    stair = [(0.0, freqs[0])]
    for (t_k, f_k), (_, f_prev) in zip(plan[1:], plan[:-1], strict=True):
        stair += [(t_k, f_prev), (t_k, f_k)]
    stair.append((t, freqs[-1]))
    prof_phase = sweep_phase_rad({"profile": points}, np.array(ends))
    stair_phase = sweep_phase_rad({"profile": stair}, np.array(ends))
    assert np.allclose(stair_phase, prof_phase, rtol=1e-9, atol=1e-9)


@pytest.mark.slow
def test_shaker_fig17_sweep_runs_as_phase_continuous_steps(tmp_path: Path) -> None:
    amp_mm, f0, f1, rise_s, step_s = 2.0, 2.0, 12.0, 8.0, 0.5
    config = _config(tmp_path, "sweep_column")
    code, run_dir = _run(tmp_path, config, "sweep", f"start_hz={f0}", f"max_hz={f1}", f"duration_s={rise_s}",
                         "hold_s=0.5", f"update_interval_s={step_s}", f"shaker_amplitude_mm={amp_mm}")
    _assert_passed(code, run_dir, "sweep")
    run = load_run(run_dir)
    (event,) = [d["data"] for d in run.event_documents("sweep")]
    assert event["spacing"] == "steps" and event["amplitude_mm"] == amp_mm
    stair = np.asarray(event["profile"], float)
    assert np.all(np.diff(stair[:, 0]) >= 0) and np.all(np.diff(stair[:, 1]) >= 0)
    t0 = event["t_start_s"]  # the output on at the first step's frequency; the steps are timed from it
    assert stair[-1, 0] - t0 == pytest.approx(rise_s + 0.5)
    # the profile starts at channel 1's phase restart (armed with the output OFF), its law exact from there
    assert stair[0, 0] == pytest.approx(np.mean(event["phase_origin_s"])) and stair[0, 0] <= t0
    assert len(event["step_brackets_s"]) == len(np.unique(stair[1:-1, 0]))
    # the phase at every step's end is the Fig. 17 profile's (points from the procedure's own law)
    law = profile_of(Parameters(start_hz=f0, max_hz=f1, duration_s=rise_s, hold_s=0.5)).points(step_s)
    law = [(t0 + t, f) for t, f in law]
    ends = np.unique(stair[1:, 0])
    measured = sweep_phase_rad(event, ends) - sweep_phase_rad(event, np.array([t0]))
    assert np.allclose(measured, sweep_phase_rad({"profile": law}, ends), atol=1e-6)

    # the generator reported, after every step, the CW frequency of the staircase at that instant
    gen = [d["data"] for d in run.event_documents("generator")]
    polled = [g for g in gen if event["t_start_s"] <= g["t_s"] < event["t_stop_s"]]
    assert len(polled) >= rise_s / step_s
    for g in polled:
        current = stair[stair[:, 0] <= g["t_s"]][-1, 1]
        assert g["output_on"] and not g["sweep_on"] and g["frequency_hz"] == pytest.approx(current, abs=1e-9)
    assert not gen[-1]["output_on"]

    cfg = load_config(config)
    sigma_px, mm_per_px, _ = _noise(run_dir, tuple(world_layout(cfg).targets.sweep_column.centre_mm))
    bins = pd.read_csv(run_dir / "tables" / "sweep_bins.csv")
    bins = bins[bins["sync_method"] == "trajectory"]
    assert bins["frequency_hz"].min() < f0 + 1 and bins["frequency_hz"].max() > f1 - 1
    n = bins["n_samples"].to_numpy(float)
    err = bins["amplitude_meas_mm"].to_numpy(float) - amp_mm
    bound = 5 * sigma_px * mm_per_px * np.sqrt(2 / n) + 3 * sigma_px * mm_per_px
    assert (np.abs(err) <= bound).all(), bins.assign(err_mm=err, bound_mm=bound)[
        ["track", "frequency_hz", "err_mm", "bound_mm"]]

    # phase per steady step against the staircase's law (the twin shaker follows it: truth 0), within 3 ×
    # its stated u plus the cameras' relative offset's share (10 u, as in test_phase_e2e)
    cert = read_json(run_dir / "certificate.json")
    steps = cert["steady_steps"]
    assert "timing fiducial" in steps["clock_source"] and steps["settle_s"] == pytest.approx(0.1)
    table = pd.DataFrame(steps["steps"])
    assert len(table) >= 3 and table["frequency_ref_hz"].max() == pytest.approx(f1)  # the hold is a step
    u_cameras_s = max(read_json(run_dir / "timing.json")["uncertainty"]["offset_s"].values())
    f = table["frequency_ref_hz"].to_numpy(float)
    tolerance = 3 * table["u_phase_deg"].to_numpy(float) + 360.0 * f * 10 * u_cameras_s
    assert (np.abs(table["phase_deg"].to_numpy(float)) <= tolerance).all(), table
    assert (np.abs(table["amplitude_error_pct"]) <= 100 * bound.max() / amp_mm).all(), table
    assert (run_dir / "tables" / "steady_steps.csv").is_file()
    assert "id='steps'" in (run_dir / "report.html").read_text()


def test_retune_keeps_the_displacement_and_the_phase_and_checks_limits_first() -> None:
    from drivers.exciter.generator import GeneratorError, ScpiGenerator
    from drivers.exciter.limits import LimitError, MotionLimits
    from drivers.exciter.shaker import SensitivityTable, Shaker
    from drivers.mock.generator_instrument import GeneratorInstrument
    from drivers.mock.generator_server import GeneratorServer
    from drivers.sim.clock import VirtualClock
    from drivers.sim.world import World
    from drivers.transport import open_transport

    table = [(1.0, 0.80), (20.0, 0.50), (100.0, 0.20)]  # not flat: the volts must follow it
    limits = MotionLimits(max_frequency_hz=100.0, max_displacement_mm=5.0, max_acceleration_m_s2=200.0,
                          max_ramp_rate_hz_per_s=10.0)
    world = World(VirtualClock(), seed=5)
    instrument = GeneratorInstrument(world.shaker, world.clock, sensitivity_mm_per_v=table)
    with GeneratorServer(instrument, mode="tcp") as server:
        transport = open_transport(server.url, timeout_s=0.5)
        try:
            shaker = Shaker(ScpiGenerator(transport, timeout_s=0.5), clock=world.clock, limits=limits,
                            sensitivity=SensitivityTable(table))
            with pytest.raises(GeneratorError, match="output is OFF"):
                shaker.retune(5.0, 1.0)
            shaker.start(4.0, 1.0)
            t_step = world.clock.now_s()
            phase_before = world.shaker.phase_rad(t_step)
            shaker.retune(6.0, 1.0)
            t = world.clock.now_s()
            assert world.shaker.frequency_hz(t) == 6.0
            assert world.shaker.amplitude_at_mm(t) == pytest.approx(1.0, rel=1e-9)
            assert world.shaker.phase_rad(t_step) == pytest.approx(phase_before, abs=1e-12)  # no jump
            state = shaker.read_state()
            assert state.output_on and not state.sweep_on and state.frequency_hz == 6.0
            assert state.displacement_mm == pytest.approx(1.0, rel=1e-9)
            seen = server.instrument.lines_received
            with pytest.raises(LimitError, match="acceleration"):
                shaker.retune(80.0, 1.0)  # (2π·80)²·1 mm = 253 m/s² > 200 m/s²
            assert server.instrument.lines_received == seen  # nothing was sent
            shaker.stop()
            assert not shaker.read_state().output_on
        finally:
            transport.close()

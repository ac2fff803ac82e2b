"""Phase error of the measured sweep motion at 10 and 25 Hz against the twin's truth, with the timing
fiducial and with the start-event method on the same run (issue 18).

    .venv/bin/python benchmarks/phase.py [--seeds N] [--duration S]

Per seed: ``rig run sweep`` on the built-in simulated rig (its ``[fiducial]`` LED bar on the generator's sync
output; ``[sim] seed`` varied) through the real drivers and mocks — calibrate, sync, the crank's Fig. 17
sweep 1 → 30 Hz — keeping the twin's world to read the crank's true phase φ(t) afterwards. The run folder
is analysed twice (``trajectory`` sync): the sweep's reference-camera clock dated by the fiducial (as the
run does), and by the start events alone (the fiducial's rows ignored: the baseline, ±½ frame). In each
frequency bin the measured axial displacement is fitted with the true phase (three-parameter sine fit):
its phase against φ is the measured motion's phase error (°), interpolated at 10 and 25 Hz and averaged
over the column's markers. Besides, the delay τ the report states against the polled reference, with its
standard uncertainty (the drive's 0.01 Hz read-back dominates it). Targets: ≤ 0.5° at 10 Hz, ≤ 2° at 25 Hz.

    .venv/bin/python benchmarks/phase.py --band [--seeds N]

The band step beyond the crank sweep (issue 18, certify's ``band``): per seed ``rig certify`` with the fast
preset plus the band step (the shaker 27 → 50 Hz, the LED on the generator's channel 2), keeping the twin's
shaker. Per 1 Hz bin the report's interleaved fit (:mod:`reports.band_phase`) states the amplitude error and
the phase against the generator's waveform (reference: its sweep law from the fiducial's PHASe:SYNChronize);
the truth is the twin shaker's own phase, so the printed "vs truth" adds the reference's error (the law at
the bracket's midpoint against the shaker) to the stated phase. Baseline in the same run: the cameras dated
by the start events alone (±½ frame).

    .venv/bin/python benchmarks/phase.py --steps [--seeds N] [--duration S]

Phase per steady step (issue 18): per seed ``rig run sweep`` with the sweep column on the shaker
(``targets.sweep_column.body = "shaker"``), the Fig. 17 profile 1 → 30 Hz as the generator's staircase of
0.5-s phase-continuous CW steps, armed at its first step so the recording's fiducial restart
(``PHASe:SYNChronize``) fixes its phase origin; the twin's shaker kept. Per steady step
(:mod:`reports.step_phase`) the stated phase against the staircase's law and, as the truth, the phase of
the same tracks fitted against the twin shaker's own phase; baseline: the cameras dated by the start
events in the same runs.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import rig.analysis.analyse as analyse_module  # noqa: E402
import rig.run.station as station_module  # noqa: E402
from reports import band, band_phase, frequency, phase, step_phase  # noqa: E402
from reports.load import load_record, stream_events, typed_events  # noqa: E402
from rig.cli import main as rig_main  # noqa: E402
from rig.record.catalogue import run_folders  # noqa: E402
from rig.record.events import BandSweepEvent, SweepEvent  # noqa: E402

SIM_TOML = (ROOT / "rig" / "data" / "sim.toml").read_text()


def _run_keeping_world(tmp: Path, seed: int, command: list[str], options: list[str],
                       rig_toml: str = SIM_TOML) -> tuple[Path, Any]:
    """``rig COMMAND --config RIG OPTIONS`` on ``rig_toml`` (the built-in rig) with ``seed`` and its runs
    under ``tmp``; (run folder, the station's twin world, kept by wrapping ``open_station`` for the run)."""
    text = rig_toml.replace('runs_dir = "runs"', f'runs_dir = "{(tmp / "runs").as_posix()}"')
    config = tmp / "rig.toml"
    config.write_text(text.replace("seed = 20261121", f"seed = {seed}"))
    kept: dict[str, Any] = {}
    original = station_module.open_station

    @contextlib.contextmanager
    def keep_world(cfg: Any, clock: Any, **kw: Any) -> Iterator[Any]:
        with original(cfg, clock, **kw) as station:
            kept["world"] = station.world
            yield station

    station_module.open_station = keep_world
    try:
        rig_main([*command, "--config", str(config), *options])
    finally:
        station_module.open_station = original
    return run_folders(tmp / "runs")[-1], kept["world"]


def sweep_run(tmp: Path, seed: int, duration_s: float) -> tuple[Path, Any]:
    """One ``rig run sweep`` on the built-in rig with ``seed``; (run folder, the twin's exciter body)."""
    run_dir, world = _run_keeping_world(tmp, seed, ["run", "sweep"],
                                        ["--no-dashboard", "--set", f"duration_s={duration_s}"])
    return run_dir, world.exciter


@contextlib.contextmanager
def start_events_only() -> Iterator[None]:
    """The analysis without the fiducial's rows: every segment dated by its start events (±½ frame)."""
    original = analyse_module.segment_clock
    analyse_module.segment_clock = lambda *a, **k: (None, "")
    try:
        yield
    finally:
        analyse_module.segment_clock = original


CLOCKS = ("fiducial", "start events")


def analyses_by_clock(seeds: int, run: Callable[[Path, int], tuple[Path, Any]],
                      ) -> Iterator[tuple[int, str, Path, Any, Any]]:
    """Per seed one run (``run(tmp, seed)`` → (run folder, the twin's body)), analysed (``trajectory``
    sync) once per clock of :data:`CLOCKS`: (seed, clock, run folder, body, analysis). The run folder
    lives until the next seed's run."""
    for seed in range(seeds):
        with tempfile.TemporaryDirectory() as tmp:
            run_dir, body = run(Path(tmp), 1000 + seed)
            for label in CLOCKS:
                with start_events_only() if label == "start events" else contextlib.nullcontext():
                    a = analyse_module.analyse(run_dir, sync="trajectory")
                yield seed, label, run_dir, body, a


def true_phase_errors_deg(run_dir: Path, exciter: Any, tracks: pd.DataFrame) -> dict[float, float]:
    """Phase (°) of the measured motion against the crank's true phase, at 10 and 25 Hz."""
    run = load_record(run_dir)
    sweep = typed_events(run.events, SweepEvent)[-1].to_dict()
    samples = frequency.sweep_samples(tracks, sweep)
    rows = []
    for _, g in samples.groupby("track"):
        t, x = g["time_s"].to_numpy(float), g["displacement_mm"].to_numpy(float)
        phi = np.asarray(exciter.phase_rad(t))
        f = np.asarray(exciter.frequency_hz(t))
        for lo in np.arange(1.0, 30.0):
            m = (f >= lo) & (f < lo + 1.0)
            if m.sum() >= 12:
                rows.append((float(f[m].mean()), np.rad2deg(frequency._fit_bin(t[m], x[m], phi[m])[2])))
    b = pd.DataFrame(rows, columns=["f", "p"]).groupby(pd.Series([round(r[0]) for r in rows])).mean()
    return {f0: float(np.interp(f0, b["f"], b["p"])) for f0 in (10.0, 25.0)}


def stated_delay(run_dir: Path, tracks: pd.DataFrame, clock: pd.DataFrame) -> phase.PhaseResult | None:
    """The delay the report states for these tracks (against the polled reference)."""
    run = load_record(run_dir)
    sweep = typed_events(run.events, SweepEvent)[-1].to_dict()
    polled = stream_events(run.events, "exciter")
    ref, source = frequency.reference_sweep(sweep, polled)
    bins = frequency.amplitude_by_bin(frequency.sweep_samples(tracks, ref), ref, sync_method="trajectory")
    row = clock[clock["segment"] == sweep["segment"]].iloc[0]
    return phase.phase_of_sweep(bins, "trajectory", u_clock_s=float(row["u_offset_s"]),
                                clock_source=str(row["source"]),
                                reference=phase.reference_resolution(polled, source))


def band_run(tmp: Path, seed: int) -> tuple[Path, Any]:
    """``rig certify`` (fast preset plus the band step) with ``seed``; (run folder, the twin's shaker)."""
    options = ["--no-dashboard", "--set", 'preset="fast"', "--set", "band=true", "--set", "figures=false"]
    run_dir, world = _run_keeping_world(tmp, seed, ["certify"], options)
    return run_dir, world.shaker


def band_table(run_dir: Path, shaker: Any, tracks: pd.DataFrame, clock: pd.DataFrame) -> pd.DataFrame:
    """The band step's per-bin table as the report states it, plus the phase against the twin's truth."""
    run = load_record(run_dir)
    sweep = typed_events(run.events, BandSweepEvent)[-1].to_dict()
    bins, _ = band.interleaved_bins(run, tracks, clock, sweep, fs_hz=60.0, bin_hz=1.0)
    row = clock[clock["segment"] == sweep["segment"]].iloc[0]
    table = band_phase.per_bin(bins, float(row["u_offset_s"]))
    # the reference's own error at each bin's middle instant: law (from the bracket's midpoint) − truth
    t0, f0 = sweep["profile"][0]
    t1, f1 = sweep["profile"][-1]
    t_mid = t0 + (table["frequency_hz"].to_numpy(float) - f0) / ((f1 - f0) / (t1 - t0))
    ref = np.asarray(frequency.sweep_phase_rad(sweep, t_mid))
    ref_error = np.rad2deg(np.angle(np.exp(1j * (ref - np.asarray(shaker.phase_rad(t_mid))))))
    return table.assign(vs_truth_deg=table["phase_deg"] + ref_error, reference_error_deg=ref_error)


def band_main(seeds: int) -> None:
    """The band step's figures (module docstring, ``--band``)."""
    print(f"{'seed':>4} {'clock':>12} {'f Hz':>6} {'e %':>8} {'u(e) %':>7} {'phase °':>8} {'u °':>6} "
          f"{'vs truth °':>10} {'ref err °':>9}")
    worst: dict[str, list[float]] = {label: [] for label in CLOCKS}
    for seed, label, run_dir, shaker, a in analyses_by_clock(seeds, band_run):
        table = band_table(run_dir, shaker, a.tracks, a.clock)
        worst[label].append(float(table["vs_truth_deg"].abs().max()))
        for f_hz in (32.0, 40.0, 49.5):
            r = table.iloc[(table["frequency_hz"] - f_hz).abs().argmin()]
            print(f"{seed:>4} {label:>12} {r['frequency_hz']:>6.1f} "
                  f"{r['amplitude_error_pct']:>+8.3f} {r['u_amplitude_error_pct']:>7.3f} "
                  f"{r['phase_deg']:>+8.3f} {r['u_phase_deg']:>6.3f} "
                  f"{r['vs_truth_deg']:>+10.3f} {r['reference_error_deg']:>+9.4f}")
    for label, values in worst.items():
        print(f"{label}: max |phase vs truth| over the band {max(values):.3f}° (over {seeds} seeds)")
    print(f"ratio start events / fiducial: {max(worst['start events']) / max(worst['fiducial']):.0f}×")


def steps_run(tmp: Path, seed: int, duration_s: float) -> tuple[Path, Any]:
    """``rig run sweep`` of the column on the shaker (the Fig. 17 staircase); (run folder, twin shaker)."""
    column = "[targets.sweep_column]\nbody = "
    rig_toml = SIM_TOML.replace(f'{column}"exciter"', f'{column}"shaker"')
    assert rig_toml != SIM_TOML, "sim.toml: targets.sweep_column.body not found"
    run_dir, world = _run_keeping_world(tmp, seed, ["run", "sweep"],
                                        ["--no-dashboard", "--set", f"duration_s={duration_s}"], rig_toml)
    return run_dir, world.shaker


def step_table(run_dir: Path, shaker: Any, tracks: pd.DataFrame, clock: pd.DataFrame) -> pd.DataFrame:
    """The steps as the report states them, plus each step's phase against the twin shaker's true phase
    (the same tracks and four-parameter fit, the truth's φ in place of the staircase's law)."""
    run = load_record(run_dir)
    sweep = typed_events(run.events, SweepEvent)[-1].to_dict()
    row = clock[clock["segment"] == sweep["segment"]].iloc[0]
    sp = step_phase.step_phase(tracks, sweep, sweep, fs_hz=60.0, u_clock_s=float(row["u_offset_s"]),
                               clock_source=str(row["source"]), sync_method="trajectory")
    assert sp is not None and len(sp.bins), "no steady step"
    samples = frequency.sweep_samples(tracks, sweep)
    truth = []
    for r in sp.bins.itertuples():
        z = []
        for _, g in samples.groupby("track"):
            t, x = g["time_s"].to_numpy(float), g["displacement_mm"].to_numpy(float)
            m = (t >= r.t_start_s) & (t <= r.t_stop_s)
            if m.sum() >= step_phase.MIN_SAMPLES:
                fit = step_phase.fit_step(t[m], x[m], np.asarray(shaker.phase_rad(t[m])), r.frequency_ref_hz)
                z.append(np.exp(1j * fit.phase_rad))
        truth.append(float(np.rad2deg(np.angle(np.mean(z)))))
    return sp.bins.assign(vs_truth_deg=truth)


def steps_main(seeds: int, duration_s: float) -> None:
    """The per-step figures (module docstring, ``--steps``)."""
    print(f"{'seed':>4} {'clock':>12} {'f Hz':>6} {'e %':>8} {'phase °':>8} {'u °':>6} {'vs truth °':>10} "
          f"{'delay ms':>9} {'u ms':>7}")
    worst: dict[str, list[float]] = {label: [] for label in CLOCKS}
    runs = analyses_by_clock(seeds, lambda tmp, seed: steps_run(tmp, seed, duration_s))
    for seed, label, run_dir, shaker, a in runs:
        table = step_table(run_dir, shaker, a.tracks, a.clock)
        worst[label].append(float(table["vs_truth_deg"].abs().max()))
        for f_hz in (10.0, 20.0, 28.0):
            r = table.iloc[(table["frequency_ref_hz"] - f_hz).abs().argmin()]
            print(f"{seed:>4} {label:>12} {r['frequency_ref_hz']:>6.2f} "
                  f"{r['amplitude_error_pct']:>+8.3f} {r['phase_deg']:>+8.3f} "
                  f"{r['u_phase_deg']:>6.3f} {r['vs_truth_deg']:>+10.3f} {r['delay_ms']:>+9.4f} "
                  f"{r['u_delay_ms']:>7.4f}")
        print(f"{seed:>4} {label:>12} {len(table)} steps "
              f"{table['frequency_ref_hz'].min():.2f}–{table['frequency_ref_hz'].max():.2f} Hz: "
              f"max |stated phase| {table['phase_deg'].abs().max():.3f}°, max |vs truth| "
              f"{table['vs_truth_deg'].abs().max():.3f}°, max |stated − truth| "
              f"{(table['phase_deg'] - table['vs_truth_deg']).abs().max():.4f}°, max u "
              f"{table['u_phase_deg'].max():.3f}°")
    for label, values in worst.items():
        print(f"{label}: max |phase vs truth| over the steps {max(values):.3f}° (over {seeds} seeds)")
    print(f"ratio start events / fiducial: {max(worst['start events']) / max(worst['fiducial']):.0f}×")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="independent runs (twin seeds)")
    parser.add_argument("--duration", type=float, default=24.0, help="sweep rise time (s), 1 → 30 Hz")
    parser.add_argument("--band", action="store_true", help="the certify band step (27 → 50 Hz, shaker)")
    parser.add_argument("--steps", action="store_true", help="phase per steady step (the shaker staircase)")
    args = parser.parse_args()
    if args.band:
        band_main(args.seeds)
        return
    if args.steps:
        steps_main(args.seeds, args.duration)
        return
    sweep_main(args.seeds, args.duration)


def sweep_main(seeds: int, duration_s: float) -> None:
    """The crank sweep's figures at 10 and 25 Hz (module docstring, the default)."""
    print(f"{'seed':>4} {'clock':>12} {'10 Hz °':>8} {'25 Hz °':>8} {'stated τ ms':>12} {'u(τ) ms':>8}")
    found: dict[str, list[tuple[float, float]]] = {label: [] for label in CLOCKS}
    runs = analyses_by_clock(seeds, lambda tmp, seed: sweep_run(tmp, seed, duration_s))
    for seed, label, run_dir, exciter, a in runs:
        err = true_phase_errors_deg(run_dir, exciter, a.tracks)
        stated = stated_delay(run_dir, a.tracks, a.clock)
        found[label].append((err[10.0], err[25.0]))
        tau = (stated.delay_ms, stated.u_delay_ms) if stated else (float("nan"),) * 2
        print(f"{seed:>4} {label:>12} {err[10.0]:>+8.3f} {err[25.0]:>+8.3f} {tau[0]:>+12.4f} {tau[1]:>8.4f}")
    for label, values in found.items():
        e = np.abs(np.array(values))
        print(f"{label}: max |phase error| {e[:, 0].max():.3f}° at 10 Hz (target ≤ 0.5°), "
              f"{e[:, 1].max():.3f}° at 25 Hz (target ≤ 2°)")
    fid, base = np.abs(np.array(found["fiducial"])), np.abs(np.array(found["start events"]))
    print(f"ratio start events / fiducial (RMS over seeds): "
          f"{np.sqrt(np.mean(base[:, 0] ** 2)) / np.sqrt(np.mean(fid[:, 0] ** 2)):.0f}× at 10 Hz, "
          f"{np.sqrt(np.mean(base[:, 1] ** 2)) / np.sqrt(np.mean(fid[:, 1] ** 2)):.0f}× at 25 Hz")


if __name__ == "__main__":
    main()

"""Controller↔camera clock error with the timing fiducial, against the start-event method (issue 18).

    .venv/bin/python benchmarks/fiducial.py [--seconds S] [--seeds N]

The whole chain of the twin: the SCPI driver over TCP commands the generator mock (sync on, 10.27 Hz, output
off, ``PHAS:SYNC`` bracketed by the controller's clock before the command and after ``*OPC?``), whose
sync output lights a 10 × 150 mm LED bar (first-order rise, τ = 5 µs); both default cameras (60 fps, rolling
shutter, clock errors −12/+35 ppm, noise on) render it; the LED's rows are read from the rendered images
(a fixed image region per camera) and :func:`rig.stereo.fiducial.fit_fiducial_clock` dates each camera's
clock against the controller's. Truth: the world clock is the controller's.

Baseline measured in the same run: the start-event method (``rig.analysis``): a ``camera`` start event
at a controller instant, the first frame exposed after it taken as exposed ½ frame later. Its error over
N start events at random instants (uniform ±½ frame; the simulated rig's events on a grid commensurate
with the frame period make it a bias of the same size). Target: fiducial error ≤ 0.05 ms.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from fiducial_support import led_rows  # noqa: E402

from drivers.exciter.generator import ScpiGenerator  # noqa: E402
from drivers.mock.generator_instrument import GeneratorInstrument  # noqa: E402
from drivers.mock.generator_server import GeneratorServer  # noqa: E402
from drivers.sim.camera import SimCamera  # noqa: E402
from drivers.sim.clock import VirtualClock  # noqa: E402
from drivers.sim.fiducial import SyncLed  # noqa: E402
from drivers.sim.stereo_rig import default_stereo_pair  # noqa: E402
from drivers.sim.world import World, WorldLayout  # noqa: E402
from drivers.transport import open_transport  # noqa: E402
from rig.stereo.fiducial import fit_fiducial_clock, square_wave_edges  # noqa: E402

FIDUCIAL_HZ = 10.27


def true_offset_s(cam: SimCamera, camera_time_s: float) -> float:
    """controller − camera clock at a camera time (row-0 exposure starts)."""
    rate = cam.fps * cam.frame_period_true_s
    return cam.start_offset_s + (camera_time_s - cam.timestamp_origin_s) * rate - camera_time_s


def start_event_errors_s(cam: SimCamera, rng: np.random.Generator, n: int) -> np.ndarray:
    """The start-event method's error at n random controller instants (its ½-frame convention)."""
    errors = []
    for t_event in rng.uniform(1.0, 30.0, n):
        first = cam.first_frame_index_at_or_after(t_event)
        stamp = cam.frame_timestamp_s(first)
        estimate = t_event + 0.5 / cam.fps - stamp
        errors.append(estimate - true_offset_s(cam, stamp))
    return np.array(errors)


def run(seed: int, seconds: float) -> list[tuple[str, float, float, float, int]]:
    world = World(VirtualClock(), seed=seed, layout=WorldLayout(initial_scene="none"))
    led = world.add_led(SyncLed("fiducial", (400.0, -200.0, 300.0), (0.0, 5.0, 0.0), (0.0, 0.0, 75.0)))
    instrument = GeneratorInstrument(world.shaker, world.clock, sync_led=led)
    with GeneratorServer(instrument, mode="tcp") as server:
        transport = open_transport(server.url, timeout_s=2.0)
        try:
            gen = ScpiGenerator(transport, timeout_s=2.0)
            gen.write("*RST")
            gen.set_output(False)
            gen.set_frequency_hz(FIDUCIAL_HZ)
            gen.set_sync(True)
            world.clock.advance_to(0.3 + 0.1 * seed)
            t_sent = world.clock.now_s()
            gen.synchronize_phase()
            gen.wait_complete()
            t_done = world.clock.now_s()
        finally:
            transport.close()
    origin, u_origin = 0.5 * (t_sent + t_done), (t_done - t_sent) / math.sqrt(12.0)
    edges = square_wave_edges(origin, FIDUCIAL_HZ, origin, origin + seconds + 2.0, u_origin_s=u_origin)
    out = []
    rng = np.random.default_rng(seed)
    for cam in default_stereo_pair(world):
        rows = led_rows(cam, led, origin + 0.5, origin + 0.5 + seconds)
        t_ref = float(np.median(rows.start_s))
        truth = true_offset_s(cam, t_ref)
        prior = truth + rng.uniform(-0.45, 0.45) / cam.fps  # the start events' ±½ frame
        fit = fit_fiducial_clock(rows, edges, prior_offset_s=prior, prior_half_width_s=0.51 / cam.fps,
                                 rise_time_s=2.2 * led.time_constant_s, t_ref_s=t_ref)
        baseline = start_event_errors_s(cam, rng, 200)
        out.append((cam.name, fit.offset_s - truth, fit.u_offset_s, float(np.sqrt(np.mean(baseline**2))),
                    fit.n_edges_seen))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0, help="recording per run (s)")
    parser.add_argument("--seeds", type=int, default=3, help="independent runs (twin seeds)")
    args = parser.parse_args()
    errors, uncertainties, baselines = [], [], []
    print(f"{'seed':>4} {'camera':>6} {'error µs':>9} {'u µs':>6} {'edges':>5} {'start-event rms µs':>19}")
    for seed in range(args.seeds):
        for name, err, u, base, n_edges in run(seed, args.seconds):
            errors.append(err)
            uncertainties.append(u)
            baselines.append(base)
            print(f"{seed:>4} {name:>6} {1e6 * err:>+9.2f} {1e6 * u:>6.2f} {n_edges:>5} {1e6 * base:>19.0f}")
    rms = float(np.sqrt(np.mean(np.square(errors))))
    base = float(np.sqrt(np.mean(np.square(baselines))))
    print(f"fiducial: rms error {1e3 * rms:.4f} ms, max |error| {1e3 * max(map(abs, errors)):.4f} ms, "
          f"mean stated u {1e3 * float(np.mean(uncertainties)):.4f} ms (target ≤ 0.05 ms)")
    print(f"start events (baseline): rms error {1e3 * base:.2f} ms; "
          f"ratio baseline/fiducial {base / rms:,.0f}×")


if __name__ == "__main__":
    main()

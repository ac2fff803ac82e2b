"""The timing fiducial in the twin: the generator's sync output (driver ↔ mock over TCP) lights an LED that
the rolling-shutter cameras render row by row; the fit dates each camera's clock against the controller's.

Truth: the world clock is the controller's; a camera stamps frame k ``timestamp_origin_s + k/fps`` while
its row 0 starts exposing at ``start_offset_s + k·T_true`` world time.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
import pytest
from fiducial_support import led_rows
from hypothesis import given
from hypothesis import strategies as st

from drivers.exciter.generator import ScpiGenerator
from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.generator_server import GeneratorServer
from drivers.sim.clock import VirtualClock
from drivers.sim.errors import SimCommandError
from drivers.sim.fiducial import SyncLed
from drivers.sim.stereo_rig import default_stereo_pair
from drivers.sim.world import World
from drivers.transport import open_transport
from rig.stereo.fiducial import fit_fiducial_clock, square_wave_edges

FIDUCIAL_HZ = 10.27  # incommensurate with 60 fps: the edges walk through the frame


def bar() -> SyncLed:
    """A 10 × 150 mm LED bar facing the default cameras, in both views."""
    return SyncLed("fiducial", (400.0, -200.0, 300.0), (0.0, 5.0, 0.0), (0.0, 0.0, 75.0))


@contextlib.contextmanager
def fiducial_rig() -> Iterator[tuple[ScpiGenerator, World, SyncLed]]:
    world = World(VirtualClock(), seed=11)
    led = world.add_led(bar())
    instrument = GeneratorInstrument(world.shaker, world.clock, sync_led=led)
    with GeneratorServer(instrument, mode="tcp") as server:
        transport = open_transport(server.url, timeout_s=2.0)
        try:
            yield ScpiGenerator(transport, timeout_s=2.0), world, led
        finally:
            transport.close()


def test_sync_edges_follow_the_generator_from_its_phase_restart_over_tcp() -> None:
    with fiducial_rig() as (gen, world, led):
        gen.write("*RST")
        gen.write("SOUR1:FUNC", "SQU")
        gen.set_frequency_hz(FIDUCIAL_HZ)
        gen.set_sync(True)
        world.clock.advance_to(2.0)
        gen.synchronize_phase()
        assert gen.sync_enabled() and not gen.output()  # the LED blinks with the main output off
        edges, rising, _ = led.drive_edges(2.0 + 1e-6, 3.0)
        expected = square_wave_edges(2.0, FIDUCIAL_HZ, 2.0 + 1e-6, 3.0)  # phase 0 at the restart
        assert edges.size == expected.times_s.size == 20
        assert np.allclose(edges, expected.times_s, atol=1e-9)
        assert rising.tolist() == expected.rising.tolist()
        assert led.mean_levels(np.array([2.0 + 1e-3]), 1e-4)[0] == pytest.approx(1.0)  # high after phase 0
        world.clock.advance_to(3.5)
        gen.set_sync(False)
        assert led.drive_edges(3.6, 5.0)[0].size == 0
        assert np.all(led.mean_levels(np.array([3.7, 4.2]), 1e-4) == 0.0)


def test_the_sync_led_light_is_the_first_order_response_averaged_over_the_exposure() -> None:
    led = bar()
    led.waveform.set_frequency(0.0, 40.0)
    led.set_enabled(0.0, True)
    exposure = 1 / 6000
    starts = np.linspace(0.0101, 0.0265, 157)  # across the falling edge at 12.5 ms and the rise at 25 ms
    t = starts[:, None] + (np.arange(2000) + 0.5)[None, :] / 2000 * exposure
    tau = led.time_constant_s
    edges, rising, high = led.drive_edges(0.005, 0.03)
    assert high and edges.tolist() == pytest.approx([0.0125, 0.025]) and rising.tolist() == [False, True]
    light = np.full(t.shape, 1.0)  # the ODE's solution by superposition of settled steps
    for e, up in zip(edges, rising, strict=True):
        light += (1.0 if up else -1.0) * -np.expm1(-np.maximum(t - e, 0.0) / tau)
    assert np.allclose(led.mean_levels(starts, exposure), light.mean(axis=1), atol=1e-3)
    assert 0.0 < led.mean_levels(np.array([0.0125 - 0.5 * exposure]), exposure)[0] < 1.0


def test_an_led_needs_a_rectangle_and_a_time_constant() -> None:
    with pytest.raises(SimCommandError, match="span a rectangle"):
        SyncLed("x", (0, 0, 0), (0, 1, 0), (0, 2, 0))
    with pytest.raises(SimCommandError, match="time_constant_s"):
        SyncLed("x", (0, 0, 0), (0, 1, 0), (0, 0, 1), time_constant_s=0.0)
    world = World()
    world.add_led(bar())
    with pytest.raises(ValueError, match="already in the world"):
        world.add_led(bar())


def test_a_frame_shows_the_edge_part_way_down_the_bar() -> None:
    world = World(seed=2)
    led = world.add_led(bar())
    led.waveform.set_frequency(0.0, FIDUCIAL_HZ)
    led.set_enabled(0.0, True)
    cam = default_stereo_pair(world)[0]
    rows = led_rows(cam, led, 0.0, 1.0)
    per_frame = rows.brightness_dn.reshape(len(cam.frame_indices_between(0.0, 1.0)), -1)
    lit = (per_frame - per_frame.min()) / np.ptp(per_frame)
    split = [f for f in lit if f.min() < 0.1 and f.max() > 0.9]  # dark rows and lit rows in one frame
    assert split, "no frame caught an edge within the bar's rows"
    assert any(np.any((f > 0.15) & (f < 0.85)) for f in split)  # rows lit part-way through the exposure


def retried_restarts(led: SyncLed, gaps_s: list[float], switch_every: int = 0) -> float:
    """The generator blinking at FIDUCIAL_HZ, its phase restarted after each gap (a retried ``PHAS:SYNC``
    is a gap of a few ms) and, every ``switch_every`` restarts, its sync output switched; the last time."""
    led.waveform.set_frequency(0.0, FIDUCIAL_HZ)
    led.set_enabled(0.0, True)
    t = 0.05
    for i, gap in enumerate(gaps_s):
        t += gap
        led.restart_phase(t)
        if switch_every and i % switch_every == switch_every - 1:
            led.set_enabled(t + 0.5 * gap, bool(i % 2))
    return t


@given(gaps=st.lists(st.floats(1e-4, 0.2), min_size=1, max_size=60), max_changes=st.integers(2, 8),
       seed=st.integers(0, 2**16))
def test_bounded_restarts_render_what_all_of_them_render_from_the_history_start(
        gaps: list[float], max_changes: int, seed: int) -> None:
    every = SyncLed("f", (0, 0, 0), (0, 1, 0), (0, 0, 1), max_changes=10_000)
    kept = SyncLed("f", (0, 0, 0), (0, 1, 0), (0, 0, 1), max_changes=max_changes)
    t_end_s = retried_restarts(every, gaps, switch_every=3)
    assert retried_restarts(kept, gaps, switch_every=3) == t_end_s
    assert len(kept._phases.starts_s) <= max_changes and len(kept._enabled.starts_s) <= max_changes
    start_s = max(kept._phases.history_start_s, kept._enabled.history_start_s)
    if start_s > -np.inf:  # rows exposed before the kept history are refused, not rendered from a guess
        with pytest.raises(SimCommandError, match="before the kept history"):
            kept.mean_levels(np.array([start_s - 1e-3]), 1e-4)
    settled_s = 40 * kept.time_constant_s  # a render looks back that far for edges still settling
    lo_s = max(start_s + settled_s, 0.0)
    windows = np.random.default_rng(seed).uniform(lo_s, t_end_s + 0.3, 200)  # in no particular order
    assert np.array_equal(kept.mean_levels(windows, 1e-3), every.mean_levels(windows, 1e-3))


def test_twenty_retried_phase_restarts_render_the_same_frames_and_keep_the_history_bounded() -> None:
    frames = []
    for max_changes in (10_000, 25):  # 25: the last burst and the end of the one before
        world = World(seed=3)
        led = world.add_led(SyncLed("fiducial", (400.0, -200.0, 300.0), (0.0, 5.0, 0.0), (0.0, 0.0, 75.0),
                                    max_changes=max_changes))
        gaps = [0.3 if i % 20 == 0 else 0.004 for i in range(100)]  # 5 syncs, each retried 20×
        t_end_s = retried_restarts(led, gaps)
        assert len(led._phases.starts_s) == min(101, max_changes)
        cam = default_stereo_pair(world)[0]
        indices = list(cam.frame_indices_between(t_end_s - 0.1, t_end_s + 0.2))
        frames.append([cam.render(i) for i in reversed(indices)])  # rendered last to first
    assert len(frames[0]) > 10
    assert all(np.array_equal(a, b) for a, b in zip(*frames, strict=True))


@pytest.mark.slow
def test_each_camera_clock_against_the_controller_within_its_uncertainty_and_the_target() -> None:
    """The issue's target: controller↔camera offset error ≤ 0.05 ms with the fiducial."""
    world = World(seed=4)
    led = world.add_led(bar())
    led.waveform.set_frequency(0.0, FIDUCIAL_HZ)
    led.set_enabled(0.0, True)
    for cam in default_stereo_pair(world):
        rows = led_rows(cam, led, 0.5, 6.5)
        t_ref = float(np.median(rows.start_s))
        true_rate = cam.fps * cam.frame_period_true_s
        true_offset = cam.start_offset_s + (t_ref - cam.timestamp_origin_s) * true_rate - t_ref
        prior = true_offset + 0.4 * cam.frame_period_true_s  # the start events' ±½ frame, off by 0.4 frame
        fit = fit_fiducial_clock(rows, square_wave_edges(0.0, FIDUCIAL_HZ, 0.0, 8.0), prior_offset_s=prior,
                                 prior_half_width_s=0.51 / cam.fps, rise_time_s=2.2 * led.time_constant_s,
                                 t_ref_s=t_ref)
        assert fit.u_offset_s <= 5e-5
        assert abs(fit.offset_s - true_offset) <= 3.0 * fit.u_offset_s
        assert fit.rate_fitted and abs(fit.rate - (true_rate - 1.0)) <= 5.0 * fit.u_rate + 1e-9

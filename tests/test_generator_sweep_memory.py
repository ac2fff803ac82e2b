"""A free-running generator sweep costs nothing per update: the twin's oscillator holds it as one periodic
segment (phase exact across restarts), the history of any body is bounded, and the mock keeps bounded
records of what it received. Asserted on segment counts and traced allocations in virtual time, never
on wall-clock time."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mock.generator_instrument import LINES_KEPT, GeneratorInstrument
from drivers.sim.clock import VirtualClock
from drivers.sim.errors import SimCommandError
from drivers.sim.oscillator import OscillatorBody
from drivers.sim.world import World


def test_one_ms_repeating_sweep_keeps_memory_and_segments_flat() -> None:
    world = World(VirtualClock(), seed=3)
    instrument = GeneratorInstrument(world.shaker, world.clock)
    setup = "OUTP1:LOAD INF;:FUNC SIN;VOLT 1;FREQ:STAR 5;STOP 30;:SWE:TIME 0.001"
    assert instrument.handle_line(setup) is None
    instrument.handle_line("SWE:STAT ON;:OUTP1 ON")
    assert not instrument.errors
    segments = world.shaker.segment_count

    def updates(n: int) -> None:  # 7.3 ms of virtual time between requests: ~7 sweeps each
        for _ in range(n):
            world.clock.sleep_s(0.0073)
            assert instrument.handle_line("SYST:ERR?") == '+0,"No error"'
            world.shaker.phase_rad(world.clock.now_s())

    updates(500)  # warm-up: caches, interned strings
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        updates(5000)  # 36.5 virtual seconds, ~36,500 sweep restarts
        growth = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert world.shaker.segment_count == segments  # no segment per restart
    assert len(instrument.commands_seen) == LINES_KEPT and instrument.lines_received == 5502
    assert growth < 100_000, f"{growth} bytes retained over 5000 updates"
    t = world.clock.now_s()
    f = world.shaker.frequency_hz(np.array([t, t + 0.0005]))
    assert f.min() >= 5.0 and f.max() <= 30.0


def test_repeating_sweep_equals_explicit_restarts() -> None:
    """The periodic segment gives the phase that restarting the sweep at every end gives."""
    for spacing in ("linear", "log"):
        periodic, restarted = OscillatorBody(), OscillatorBody()
        periodic.set_frequency(0.0, 3.0)
        restarted.set_frequency(0.0, 3.0)
        assert periodic.sweep(0.5, 5.0, 30.0, 0.25, spacing, repeat=True) == pytest.approx(0.75)
        t_end = 0.5
        while t_end < 30.0:
            t_end = restarted.sweep(t_end, 5.0, 30.0, 0.25, spacing)
        t = np.linspace(0.0, 29.9, 30_001)
        np.testing.assert_allclose(periodic.phase_rad(t), restarted.phase_rad(t), rtol=1e-11, atol=1e-8)
        np.testing.assert_allclose(periodic.frequency_hz(t), restarted.frequency_hz(t), rtol=1e-9, atol=1e-9)
        assert periodic.segment_count == 4 and restarted.segment_count > 100
        # scalar evaluation agrees with the vectorised one
        assert periodic.phase_rad(17.3) == pytest.approx(float(periodic.phase_rad(np.array([17.3]))[0]),
                                                         rel=1e-13)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.1, 40.0), st.floats(0.1, 40.0), st.floats(1e-3, 2.0), st.floats(0.0, 50.0))
def test_repeating_sweep_phase_is_the_integral_of_frequency(f0: float, f1: float, period: float,
                                                            t: float) -> None:
    body = OscillatorBody()
    body.sweep(0.0, f0, f1, period, "linear", repeat=True)
    cycles = math.floor(t / period)
    tau = t - cycles * period
    full = f0 * period + 0.5 * (f1 - f0) * period
    expected = 2 * math.pi * (cycles * full + f0 * tau + 0.5 * (f1 - f0) / period * tau * tau)
    assert body.phase_rad(t) == pytest.approx(expected, rel=1e-9, abs=1e-9)


def test_history_is_bounded_and_a_dropped_time_is_refused() -> None:
    body = OscillatorBody("shaker", max_segments=8)
    for i in range(100):
        body.set_frequency(float(i), 1.0 + i % 5)
        body.set_amplitude(float(i) + 0.5, 0.1 * (i % 3))
    assert body.segment_count <= 16
    assert body.frequency_hz(99.5) == 1.0 + 99 % 5
    t = np.linspace(93.0, 100.0, 701)  # inside the kept history: still continuous
    assert np.max(np.abs(np.diff(body.phase_rad(t)))) <= 2 * math.pi * 5.0 * 0.01 * (1 + 1e-9)
    with pytest.raises(SimCommandError, match="before the kept history"):
        body.phase_rad(10.0)
    with pytest.raises(SimCommandError, match="before the kept history"):
        body.amplitude_at_mm(np.array([10.0, 99.0]))


def test_a_new_sweep_command_replaces_the_repeating_one() -> None:
    body = OscillatorBody()
    body.sweep(0.0, 5.0, 10.0, 1.0, repeat=True)
    phase_before = body.phase_rad(2.5)
    body.set_frequency(2.5, 7.0)
    assert body.phase_rad(2.5) == pytest.approx(phase_before)
    assert body.frequency_hz(100.0) == 7.0
    assert body.frequency_hz(1.5) == pytest.approx(7.5)  # the past is kept

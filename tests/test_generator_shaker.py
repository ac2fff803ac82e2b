"""Shaker (generator driver + sensitivity table + limits) ↔ mock generator over TCP and a pty.

Truth: the twin's shaker. With a sensitivity table s(f) shared by the rig configuration and the mock's
physics, a commanded displacement x at f must appear as amplitude x on the twin (exact up to the
decimal formatting of the volts, < 1e-9 relative), at the commanded frequency.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Iterator

import pytest
from vfd_support import ScriptedPeer

from drivers.exciter.generator import GeneratorError, ScpiError, ScpiGenerator
from drivers.exciter.limits import LimitError, MotionLimits
from drivers.exciter.shaker import SensitivityTable, Shaker
from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.generator_server import GeneratorServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport

TABLE = [(1.0, 0.80), (20.0, 0.50), (100.0, 0.20)]  # mm per V peak, falling with frequency
LIMITS = MotionLimits(max_frequency_hz=100.0, max_displacement_mm=5.0, max_acceleration_m_s2=200.0,
                      max_ramp_rate_hz_per_s=10.0)


@contextlib.contextmanager
def shaker_rig(mode: str = "tcp", timeout_s: float = 0.5) -> Iterator[tuple[Shaker, World, GeneratorServer]]:
    world = World(VirtualClock(), seed=5)
    instrument = GeneratorInstrument(world.shaker, world.clock, sensitivity_mm_per_v=TABLE)
    with GeneratorServer(instrument, mode="tcp" if mode == "socket" else mode) as server:
        url = f"socket://127.0.0.1:{server.port}" if mode == "socket" else server.url  # pyserial's URL
        transport = open_transport(url, timeout_s=timeout_s)
        generator = ScpiGenerator(transport, timeout_s=timeout_s,
                                  reopen=lambda: open_transport(url, timeout_s=timeout_s))
        try:
            yield (Shaker(generator, clock=world.clock, limits=LIMITS, sensitivity=SensitivityTable(TABLE),
                          amplitude_step_vpp=0.5, step_interval_s=0.1, safe_deadline_s=1.0), world, server)
        finally:
            transport.close()
            generator.transport.close()


def test_sensitivity_table_interpolates_and_never_extrapolates() -> None:
    table = SensitivityTable(TABLE)
    assert table.mm_per_v(10.5) == pytest.approx(0.65)
    assert table.mm_per_v(60.0) == pytest.approx(0.35)
    with pytest.raises(ValueError, match=r"outside the sensitivity table 1..100 Hz"):
        table.mm_per_v(120.0)
    with pytest.raises(ValueError, match="frequencies must increase strictly"):
        SensitivityTable([(1.0, 0.5), (1.0, 0.6)])
    with pytest.raises(ValueError, match="mm_per_v=0: must be > 0"):
        SensitivityTable([(1.0, 0)])


@pytest.mark.parametrize("mode", ["tcp", "pty", "socket"])
def test_start_vibrates_the_twin_at_the_commanded_displacement(mode: str) -> None:
    with shaker_rig(mode) as (shaker, world, server):
        vpp = shaker.start(10.0, 1.3)
        assert vpp == pytest.approx(2 * 1.3 / (0.8 - 0.3 * 9 / 19))  # s(10 Hz) on the 1–20 Hz piece
        t = world.clock.now_s()
        assert world.shaker.frequency_hz(t) == 10.0
        assert world.shaker.amplitude_at_mm(t) == pytest.approx(1.3, rel=1e-9)
        # the amplitude was raised in steps of at most 0.5 Vpp, 0.1 s apart
        volts = [float(c.split()[1]) for c in server.instrument.commands_seen if c.startswith("SOUR1:VOLT ")]
        assert all(b - a <= 0.5 + 1e-9 for a, b in itertools.pairwise(volts))
        assert server.instrument.load_ohm == math.inf  # the driver set the amplifier's high-Z input
        shaker.stop()
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0
        assert server.instrument.output is False


@pytest.mark.parametrize(("mode", "spacing"), [("tcp", "linear"), ("pty", "log")])
def test_sweep_moves_the_twin_along_the_profile(mode: str, spacing: str) -> None:
    with shaker_rig(mode) as (shaker, world, _):
        result = shaker.sweep(5.0, 30.0, 20.0, spacing=spacing, amplitude_mm=1.0)
        assert result.t_stop_s - result.t_start_s == pytest.approx(20.0)
        for t_s, f_hz in result.profile:
            if t_s < result.t_stop_s:
                assert world.shaker.frequency_hz(t_s) == pytest.approx(f_hz, rel=1e-9)
        mid = result.t_start_s + 10.0
        expected_mid = 17.5 if spacing == "linear" else 5.0 * 6**0.5
        assert world.shaker.frequency_hz(mid) == pytest.approx(expected_mid, rel=1e-9)
        assert world.shaker.amplitude_at_mm(mid) == pytest.approx(1.0, rel=1e-9)  # start frequency's
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0  # ramped down and off after


@contextlib.contextmanager
def silent_shaker() -> Iterator[tuple[Shaker, ScriptedPeer]]:
    peer = ScriptedPeer([])
    transport = open_transport(peer.client_port, timeout_s=0.3)
    try:
        yield (Shaker(ScpiGenerator(transport, timeout_s=0.3), clock=VirtualClock(), limits=LIMITS,
                      sensitivity=SensitivityTable(TABLE)), peer)
    finally:
        transport.close()
        peer.close()


@pytest.mark.parametrize(("action", "quantity"), [
    (lambda s: s.start(10.0, 6.0), "displacement"),  # > 5 mm
    (lambda s: s.start(60.0, 4.0), "acceleration"),  # (2π·60)²·4 mm = 568 m/s² > 200
    (lambda s: s.start(3.0, 4.0), "generator amplitude"),  # 2·4/s(3 Hz) = 10.4 Vpp > 10
    # 2 mm at 5 Hz needs 5.43 Vpp; at 100 Hz that gives 0.54 mm and (2π·100)²·0.54 mm = 214 m/s² > 200
    (lambda s: s.sweep(5.0, 100.0, 30.0, amplitude_mm=2.0), "acceleration"),
    (lambda s: s.sweep(5.0, 30.0, 2.0, amplitude_mm=0.5), "ramp rate"),  # 12.5 Hz/s
    (lambda s: s.sweep(2.0, 50.0, 10.0, spacing="log", amplitude_mm=0.1), "ramp rate"),  # 50·ln 25/10
])
def test_limits_raise_before_anything_is_sent(action, quantity: str) -> None:
    with silent_shaker() as (shaker, peer):
        with pytest.raises(LimitError) as info:
            action(shaker)
        assert info.value.quantity == quantity
    assert bytes(peer.received) == b""


def test_sweep_check_finds_the_acceleration_peak_inside_a_table_piece() -> None:
    # s(f) = 0.8 − 0.6·(f − 1)/19 on 1..20 Hz: at constant volts the acceleration f²·s(f) peaks inside
    limits = MotionLimits(max_frequency_hz=100.0, max_displacement_mm=5.0, max_acceleration_m_s2=1e9,
                          max_ramp_rate_hz_per_s=100.0)
    table = SensitivityTable([(1.0, 0.8), (20.0, 0.01)])
    a, b = 0.8 + 0.79 / 19, -0.79 / 19
    f_peak = -2 * a / (3 * b)  # stationary point of f²(a + b f)
    vpp = 2.0
    acc_peak = (2 * math.pi * f_peak) ** 2 * (a + b * f_peak) * vpp / 2 / 1000
    ends = max((2 * math.pi * f) ** 2 * table.mm_per_v(f) * vpp / 2 / 1000 for f in (1.0, 20.0))
    assert acc_peak > ends * 1.05
    strict = MotionLimits(max_frequency_hz=100.0, max_displacement_mm=5.0,
                          max_acceleration_m_s2=(acc_peak + ends) / 2, max_ramp_rate_hz_per_s=100.0)
    with silent_shaker() as (shaker, peer):
        shaker.limits, shaker.sensitivity = strict, table
        with pytest.raises(LimitError, match="acceleration"):
            shaker.check_sweep(1.0, 20.0, 10.0, "linear", vpp)
        shaker.limits = limits
        shaker.check_sweep(1.0, 20.0, 10.0, "linear", vpp)
    assert bytes(peer.received) == b""


@pytest.mark.parametrize("mode", ["tcp", "pty"])
def test_silent_generator_ends_in_a_clear_error_and_an_abort_is_attempted(mode: str) -> None:
    with shaker_rig(mode, timeout_s=0.2) as (shaker, world, server):
        shaker.start(10.0, 1.0)
        server.inject("no_reply")
        with pytest.raises(GeneratorError, match=r"no reply within 0.2 s.*abort .*attempted but failed"
                                                 r".*output OFF NOT confirmed"):
            shaker.start(12.0, 1.0)
        # the abort went on, on fresh links, until its deadline: OFF was sent but never read back
        outcome = shaker.last_safe_outcome
        assert outcome is not None and not outcome.output_off and outcome.attempts >= 2
        assert outcome.reconnects >= 1  # fresh links, silent as well
        # the abort's commands reached the instrument even though its replies were swallowed
        assert server.instrument.output is False
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0


def test_disconnected_generator_ends_in_a_clear_error() -> None:
    with shaker_rig("tcp", timeout_s=0.2) as (shaker, _, server):
        shaker.start(10.0, 1.0)
        server.inject("disconnect")
        with pytest.raises(GeneratorError, match="abort"):
            shaker.stop()


def test_instrument_error_raises_and_aborts() -> None:
    with shaker_rig("tcp") as (shaker, world, server):
        shaker.min_amplitude_vpp = 0.001  # misconfigured: below the generator's 2 mVpp into high-Z
        expected = r"-222,\"Data out of range\".*abort: minimum amplitude, output OFF confirmed"
        with pytest.raises(ScpiError, match=expected) as info:
            shaker.start(10.0, 1.0)
        assert info.value.command == "SOUR1:VOLT 0.001"
        # the abort still switched the output off (the refused amplitude does not stop it)
        assert server.instrument.output is False
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0


def test_safe_state_and_heartbeat() -> None:
    with shaker_rig("pty") as (shaker, world, server):
        shaker.start(10.0, 1.0)
        assert shaker.heartbeat() is True
        shaker.safe_state()
        assert server.instrument.output is False
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0


def test_make_safe_goes_through_a_late_reply_and_a_dropped_connection() -> None:
    with shaker_rig("tcp", timeout_s=0.3) as (shaker, world, server):
        shaker.start(10.0, 1.0)
        server.inject("late", 0.6, count=1)  # the ramp-down's first error check answers late
        shaker.safe_state()
        assert server.instrument.output is False and shaker.generator.resyncs >= 1
        shaker.start(10.0, 1.0)
        server.inject("disconnect")  # the connection drops; the instrument stays reachable
        server.clear_faults()
        shaker.safe_state()  # the link is replaced, then the ramp-down goes on
        assert server.instrument.output is False
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0

"""Limits: (2πf)²·x and friends; violations raise before a single byte reaches the line."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from vfd_support import EXCITER_LIMITS, ScriptedPeer, rtu_client_for

from drivers.exciter.exciter import Exciter
from drivers.exciter.limits import LimitError, MotionLimits, peak_acceleration_m_s2
from drivers.exciter.rotor import Rotor
from drivers.exciter.sweep import LinearSweep, PointsSweep
from drivers.exciter.vfd import VfdDriver
from drivers.sim.clock import VirtualClock


@pytest.mark.parametrize(("f_hz", "printed", "last_digit"),
                         [(1, 0.16, 0.01), (5, 3.95, 0.01), (10, 15.8, 0.1), (20, 63.2, 0.1), (30, 142, 1)])
def test_acceleration_ceiling_table_of_the_notes(f_hz: float, printed: float, last_digit: float) -> None:
    # exciter notes §5: x = 4 mm peak (B&K 4809 stroke); printed values are rounded to their last digit
    assert abs(peak_acceleration_m_s2(f_hz, 4.0) - printed) <= last_digit / 2


@given(st.floats(0.1, 100), st.floats(0.01, 20))
def test_max_frequency_for_amplitude_is_on_the_boundary(f_hz: float, x_mm: float) -> None:
    limits = MotionLimits(max_frequency_hz=200, max_displacement_mm=20, max_acceleration_m_s2=100,
                          max_ramp_rate_hz_per_s=1, max_velocity_mm_s=400)
    f_max = limits.max_frequency_for_amplitude_hz(x_mm)
    limits.check_point(f_max * (1 - 1e-9), x_mm)
    with pytest.raises(LimitError):
        limits.check_point(f_max * (1 + 1e-6), x_mm)


def test_limit_error_names_quantity_value_and_limit() -> None:
    with pytest.raises(LimitError) as info:
        EXCITER_LIMITS.check_point(30.0, 10.0)
    err = info.value
    assert err.quantity == "acceleration" and err.limit == 250.0 and err.unit == "m/s²"
    assert err.value == pytest.approx((2 * math.pi * 30) ** 2 * 0.010)
    assert "acceleration 355.3" in str(err) and "limit 250 m/s²" in str(err)


@pytest.mark.parametrize("table", [
    {"max_frequency_hz": 0, "max_displacement_mm": 1, "max_acceleration_m_s2": 1,
     "max_ramp_rate_hz_per_s": 1},
    {"max_frequency_hz": 1, "max_displacement_mm": 1, "max_acceleration_m_s2": float("nan"),
     "max_ramp_rate_hz_per_s": 1},
])
def test_invalid_limits_are_rejected(table: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="must be a positive finite number"):
        MotionLimits.from_dict(table)


def test_from_dict_rejects_unknown_and_missing_keys() -> None:
    with pytest.raises(ValueError, match=r"unknown limit keys \['max_freq'\]"):
        MotionLimits.from_dict({"max_freq": 1})
    with pytest.raises(ValueError, match="missing limit keys"):
        MotionLimits.from_dict({"max_frequency_hz": 1})


@contextmanager
def silent_line() -> Iterator[tuple[VfdDriver, ScriptedPeer]]:
    """A driver whose RTU line ends in a peer that expects nothing: every byte sent is recorded."""
    peer = ScriptedPeer([])
    try:
        with rtu_client_for(peer, timeout_s=0.2) as client:
            yield VfdDriver(client, max_output_hz=60.0), peer
    finally:
        peer.close()


def _exciter(vfd: VfdDriver, **kwargs: Any) -> Exciter:
    return Exciter(vfd, clock=VirtualClock(), limits=EXCITER_LIMITS, crank_radius_mm=4.0, gear_ratio=1.5,
                   ramp_rate_hz_per_s=1.0, **kwargs)


@pytest.mark.parametrize(("action", "quantity"), [
    (lambda ex: ex.set_frequency(33.0), "frequency"),
    (lambda ex: ex.set_frequency(10.0, ramp_rate_hz_per_s=2.5), "ramp rate"),
    (lambda ex: ex.sweep(LinearSweep(5.0, 35.0, 60.0)), "frequency"),
    (lambda ex: ex.sweep(LinearSweep(5.0, 30.0, 10.0)), "ramp rate"),
    (lambda ex: ex.sweep(PointsSweep([(0, 1.0), (10, 10.0), (11, 12.5)])), "ramp rate"),
])
def test_exciter_violations_raise_before_anything_is_sent(action: Callable[[Exciter], Any],
                                                         quantity: str) -> None:
    with silent_line() as (vfd, peer):
        with pytest.raises(LimitError) as info:
            action(_exciter(vfd))
        assert info.value.quantity == quantity
    assert bytes(peer.received) == b""


def test_acceleration_limit_binds_a_large_crank() -> None:
    with silent_line() as (vfd, peer):
        exciter = Exciter(vfd, clock=VirtualClock(), limits=EXCITER_LIMITS, crank_radius_mm=10.0)
        with pytest.raises(LimitError, match="acceleration") as info:
            exciter.set_frequency(30.0)  # (2π·30)²·0.010 m = 355 m/s² > 250
        assert info.value.limit == 250.0
        exciter.check_frequency(25.0)  # 247 m/s²: allowed
    assert bytes(peer.received) == b""


def test_construction_rejects_a_crank_beyond_the_displacement_limit() -> None:
    with silent_line() as (vfd, peer), pytest.raises(LimitError, match="displacement 12 mm"):
        Exciter(vfd, clock=VirtualClock(), limits=EXCITER_LIMITS, crank_radius_mm=12.0)
    assert bytes(peer.received) == b""


def test_rotor_centripetal_acceleration_limit() -> None:
    limits = MotionLimits(max_frequency_hz=12.0, max_displacement_mm=100.0, max_acceleration_m_s2=150.0,
                          max_ramp_rate_hz_per_s=5.0)
    with silent_line() as (vfd, peer):
        rotor = Rotor(vfd, clock=VirtualClock(), limits=limits, marker_radius_mm=50.0)
        with pytest.raises(LimitError, match="acceleration"):  # (2π·10)²·0.05 = 197 m/s²
            rotor.set_rotation_hz(10.0)
    assert bytes(peer.received) == b""


def test_drive_range_is_checked_too() -> None:
    wide = MotionLimits(max_frequency_hz=100.0, max_displacement_mm=10.0, max_acceleration_m_s2=1e5,
                        max_ramp_rate_hz_per_s=5.0)
    with silent_line() as (vfd, peer):
        exciter = Exciter(vfd, clock=VirtualClock(), limits=wide, crank_radius_mm=1.0, gear_ratio=2.0)
        with pytest.raises(ValueError, match="max_output_hz"):
            exciter.set_frequency(31.0)  # 62 Hz at the drive > 60 Hz
    assert bytes(peer.received) == b""

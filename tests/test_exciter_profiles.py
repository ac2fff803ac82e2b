"""Register map as data (built-in, dict, TOML) and the monotone sweep profiles."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.exciter.register_map import (
    DELTA_MAP,
    RegisterMap,
    get_register_map,
    load_register_map,
)
from drivers.exciter.sweep import LinearSweep, LogSweep, PointsSweep

# ---------------------------------------------------------------------------- register map


def test_delta_map_matches_the_documented_table() -> None:
    assert DELTA_MAP.addresses() == {
        "command": 0x2000, "freq_set": 0x2001, "aux_command": 0x2002, "fault": 0x2100, "status": 0x2101,
        "freq_cmd": 0x2102, "freq_out": 0x2103, "current": 0x2104, "accel_time": 0x0109, "decel_time": 0x010A,
        "comm_fault_treatment": 0x0902, "comm_timeout": 0x0903}
    assert (DELTA_MAP.cmd_stop, DELTA_MAP.cmd_run_forward, DELTA_MAP.cmd_run_reverse) == (0x01, 0x12, 0x22)
    assert DELTA_MAP.freq_to_register(10.0) == 1000
    assert get_register_map("delta") is DELTA_MAP


def test_map_from_a_toml_table_overrides_the_base(tmp_path: Path) -> None:
    path = tmp_path / "rig.toml"
    path.write_text('[devices.rotor.registers]\nmodel = "other"\nunit_id = 2\ncommand = 0x0063\n'
                    'freq_set = 0x0064\naccel_time = "none"\ndecel_time = "none"\nfreq_unit_hz = 0.1\n')
    m = load_register_map(path, table="devices.rotor.registers")
    assert (m.model, m.unit_id, m.command, m.freq_set, m.fault) == ("other", 2, 0x63, 0x64, 0x2100)
    assert not m.has_ramp_registers
    assert m.freq_to_register(12.34) == 123


def test_map_from_a_dict_with_a_named_base() -> None:
    m = get_register_map({"base": "delta", "unit_id": 7})
    assert m.unit_id == 7 and m.command == DELTA_MAP.command


@pytest.mark.parametrize(("table", "message"), [
    ({"comand": 0x2000}, r"unknown register map keys \['comand'\]"),
    ({"command": 0x10000}, "command=65536: must be a wire address 0..65535"),
    ({"freq_set": 0x2000}, "must be distinct"),
    ({"unit_id": 0}, "unit_id=0"),
    ({"accel_time": "none"}, "both be given or both be None"),
    ({"cmd_run_forward": 0x0001}, "distinct codes"),
    ({"freq_unit_hz": 0}, "freq_unit_hz=0: must be a positive number"),
])
def test_bad_maps_name_the_field(table: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        get_register_map(table)


def test_unknown_map_name() -> None:
    with pytest.raises(ValueError, match=r"register_map='abb': unknown; built-in maps are \['delta'\]"):
        get_register_map("abb")


def test_frequency_outside_register_range_raises_instead_of_wrapping() -> None:
    with pytest.raises(ValueError, match="outside the register range"):
        RegisterMap().freq_to_register(655.36)


# ---------------------------------------------------------------------------- profiles

freqs = st.floats(0.5, 60.0)
durations = st.floats(0.5, 120.0)
steps = st.floats(0.05, 5.0)


@given(freqs, freqs, durations, steps, st.booleans())
def test_segments_are_contiguous_exact_at_ends_and_monotone(f0: float, f1: float, dur: float, step: float,
                                                            log: bool) -> None:
    profile = LogSweep(f0, f1, dur) if log else LinearSweep(f0, f1, dur)
    segs = profile.segments(step)
    assert segs[0][0] == 0.0 and segs[0][1] == pytest.approx(f0)
    assert segs[-1][2] == pytest.approx(dur) and segs[-1][3] == pytest.approx(f1)
    for a, b in itertools.pairwise(segs):
        assert a[2] == b[0] and a[3] == b[1]
    for t0, fa, t1, fb in segs:
        assert 0 < t1 - t0 <= step * (1 + 1e-9)
        assert (fb - fa) * (f1 - f0) >= -1e-12  # never turns back
        # relative slack for the rounding of f(t) at the segment ends, absolute for near-flat sweeps
        assert abs(fb - fa) / (t1 - t0) <= profile.max_slope_hz_per_s() * (1 + 1e-9) + 1e-9


@given(st.floats(0.5, 30.0), st.floats(0.5, 30.0), durations, st.floats(0, 1))
def test_log_sweep_has_constant_time_per_octave(f0: float, f1: float, dur: float, u: float) -> None:
    profile = LogSweep(f0, f1, dur)
    expected = f0 * math.exp(u * math.log(f1 / f0))
    assert profile.frequency_hz(u * dur) == pytest.approx(expected, rel=1e-12)


def test_points_profile_interpolates_and_reports_its_slopes() -> None:
    profile = PointsSweep([(0, 2.0), (5, 5.0), (10, 15.0), (20, 30.0)])
    assert profile.frequency_hz(2.5) == pytest.approx(3.5)
    assert profile.frequency_hz(7.5) == pytest.approx(10.0)
    assert profile.max_slope_hz_per_s() == pytest.approx(2.0)
    assert [s[0] for s in profile.segments(10.0)] == [0, 5, 10]  # knots are segment boundaries


@pytest.mark.parametrize(("points", "message"), [
    ([(0, 1.0), (5, 3.0), (8, 2.0)], r"points\[2\].f_hz=2.0: the profile must be monotone"),
    ([(0, 1.0), (5, 3.0), (5, 4.0)], r"points\[2\].t_s=5.0: times must increase strictly"),
    ([(1, 1.0), (5, 3.0)], r"points\[0\].t_s=1.0: the profile must start at t_s = 0"),
    ([(0, 1.0)], "need at least 2"),
    ([(0, -1.0), (1, 2.0)], r"points\[0\].f_hz=-1.0: must be >= 0"),
    ([(0, 1.0, 2.0), (1, 2.0)], r"points\[0\]=\(0, 1.0, 2.0\): must be a \(t_s, f_hz\) pair"),
])
def test_points_profile_validation(points: list, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        PointsSweep(points)


def test_log_sweep_needs_positive_frequencies() -> None:
    with pytest.raises(ValueError, match=r"start_hz=0.0: must be > 0"):
        LogSweep(0.0, 30.0, 10.0)


def test_falling_profiles_are_monotone_too() -> None:
    profile = PointsSweep([(0, 30.0), (10, 20.0), (12, 20.0), (20, 5.0)])
    assert not profile.rising
    assert profile.frequency_hz(11.0) == 20.0

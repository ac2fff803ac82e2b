"""The plan checker (rig/run/plan.py): any plan within the limits passes, and any plan beyond limits is
refused
naming exactly the limits it breaks, their rig.toml fields and the parameters behind each value.

The expectations are computed here, independently of the drivers' rules the checker uses: the limits of
the built-in rig (``[limits.exciter]``: 32 Hz, 10 mm, 250 m/s², 2 Hz/s; the drive's 50 Hz output, gear ratio
1; ``[limits.robot]``: x 150..650,
y −350..350, z 50..650 mm, 500 mm/s).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from rig.config.rig_config import default_config
from rig.run.plan import ArmMoves, Plan, PlanRefused, PlanStep, Vibration, check_plan, validate_procedure

CONFIG = default_config()
EXCITER = {"max_frequency_hz": 32.0, "max_displacement_mm": 10.0, "max_acceleration_m_s2": 250.0,
           "max_ramp_rate_hz_per_s": 2.0, "max_output_hz": 50.0}  # the last: devices.exciter (its drive)
ENVELOPE = {"x": (150.0, 650.0), "y": (-350.0, 350.0), "z": (50.0, 650.0)}


def _away_from(value: float, limit: float) -> bool:
    return abs(value - limit) > 1e-6 * max(1.0, abs(limit))  # no verdict hinges on rounding at the bound


def test_the_limits_assumed_here_are_the_built_in_rigs() -> None:
    lim, drive = CONFIG.limits.exciter, CONFIG.devices.exciter
    assert {k: getattr(lim, k) for k in EXCITER if k != "max_output_hz"} == {
        k: v for k, v in EXCITER.items() if k != "max_output_hz"}
    assert (drive.max_output_hz, drive.gear_ratio) == (50.0, 1.0)
    r = CONFIG.limits.robot
    assert (r.envelope_x_mm, r.envelope_y_mm, r.envelope_z_mm) == tuple(ENVELOPE.values())
    assert r.max_speed_mm_s == 500.0


@settings(max_examples=200, deadline=None)
@given(f0=st.floats(0.0, 40.0), rise_hz=st.floats(0.0, 40.0), duration_s=st.floats(0.5, 60.0),
       amplitude_mm=st.floats(0.05, 15.0))
def test_a_frequency_profile_is_refused_exactly_for_the_limits_it_breaks(f0: float, rise_hz: float,
                                                                          duration_s: float,
                                                                          amplitude_mm: float) -> None:
    f1 = f0 + rise_hz
    slope = rise_hz / duration_s
    acceleration = (2 * math.pi * f1) ** 2 * amplitude_mm / 1000.0
    values = {"max_frequency_hz": f1, "max_displacement_mm": amplitude_mm,
              "max_acceleration_m_s2": acceleration, "max_output_hz": f1}  # gear ratio 1
    if slope > 0:
        values["max_ramp_rate_hz_per_s"] = slope
    assume(all(_away_from(v, EXCITER[k]) for k, v in values.items()))
    broken = {k for k, v in values.items() if v > EXCITER[k]}
    vibration = Vibration("exciter", ((0.0, f0), (duration_s, f1)), amplitude_mm, "p.max_hz",
                          "p.amplitude_mm", max_slope_hz_per_s=slope if slope > 0 else None,
                          slope_from="p.duration_s")
    plan = Plan("p", (PlanStep("sweep", duration_s, vibration=vibration),))
    checks = check_plan(plan, CONFIG)
    def field(name: str) -> str:
        return f"devices.exciter.{name}" if name == "max_output_hz" else f"limits.exciter.{name}"

    assert {c.field for c in checks if not c.passed} == {field(k) for k in broken}
    origins = {"max_frequency_hz": "p.max_hz", "max_displacement_mm": "p.amplitude_mm",
               "max_acceleration_m_s2": "p.max_hz with p.amplitude_mm",
               "max_ramp_rate_hz_per_s": "p.duration_s",
               "max_output_hz": "p.max_hz with devices.exciter.gear_ratio = 1"}
    for c in checks:
        name = c.field.rsplit(".", 1)[1]
        assert c.origin == origins[name]
        assert c.value == pytest.approx(values[name], rel=1e-12)  # the most demanding value of the profile
        assert c.limit == EXCITER[name] and (c.margin < 0) == (not c.passed)
    if broken:
        with pytest.raises(PlanRefused) as info:
            raise PlanRefused(plan, checks)
        first = info.value.failed[0]
        assert f"({first.field})" in str(info.value) and first.origin in str(info.value)


coordinate = {"x": st.floats(0.0, 800.0), "y": st.floats(-500.0, 500.0), "z": st.floats(0.0, 800.0)}


@settings(max_examples=200, deadline=None)
@given(poses=st.lists(st.tuples(coordinate["x"], coordinate["y"], coordinate["z"]), min_size=1, max_size=8),
       speed_mm_s=st.one_of(st.none(), st.floats(1.0, 1000.0)))
def test_arm_moves_are_refused_exactly_on_the_axes_and_speed_they_break(
        poses: list[tuple[float, float, float]], speed_mm_s: float | None) -> None:
    for pose in poses:
        assume(all(_away_from(v, b) for v, axis in zip(pose, "xyz", strict=True) for b in ENVELOPE[axis]))
    assume(speed_mm_s is None or _away_from(speed_mm_s, 500.0))
    full = tuple((*p, 90.0, 0.0, 90.0) for p in poses)
    broken = {f"limits.robot.envelope_{axis}_mm" for axis, k in zip("xyz", range(3), strict=True)
              if any(not ENVELOPE[axis][0] <= p[k] <= ENVELOPE[axis][1] for p in poses)}
    if speed_mm_s is not None and speed_mm_s > 500.0:
        broken.add("limits.robot.max_speed_mm_s")
    moves = ArmMoves(full, "p.poses", speed_mm_s, "p.speed_mm_s")
    checks = check_plan(Plan("p", (PlanStep("move", 1.0, arm=moves),)), CONFIG)
    assert {c.field for c in checks if not c.passed} == broken
    speed = next(c for c in checks if c.quantity == "speed")
    assert speed.value == (500.0 if speed_mm_s is None else speed_mm_s)


def test_a_procedure_without_a_plan_is_left_to_its_drivers() -> None:
    import types

    module = types.ModuleType("user_procedure")
    assert validate_procedure(module, None, CONFIG) == []

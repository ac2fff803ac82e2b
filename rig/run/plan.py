"""Plans and limits: what a procedure will do to the rig, checked as a whole before any device is connected.

A procedure module may define ``plan(params, config) -> Plan``: its complete plan computed from its
parameters and the rig configuration alone (no device) — per step the arm's poses and speed, the frequency
profile and amplitude of a vibration source, and a duration estimate. The runner calls
:func:`validate_procedure` before the station is opened; a violation raises :class:`PlanRefused` (a
:class:`~rig.run.procedure.ParameterError`: exit 4, no run folder) naming the parameter and its value, the
limit, and the ``rig.toml`` field the limit comes from. The procedure then carries out the plan of the
same pure function of the same frozen inputs, so what was checked is what runs. ``rig run --dry-run``
prints the plan and its checks (:func:`format_plan`).

The rules are the drivers' own, never written twice: :meth:`MotionLimits.evaluate` and
:meth:`MotionLimits.evaluate_ramp_rate` (frequency, displacement, (2πf)²·x, 2πf·x, ramp rate),
:class:`ShakerLimits` (the amplifier's volts; the exact maxima over a generator sweep),
:class:`BoxEnvelope` and :func:`check_speed` of the arm driver.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, TypeVar

from drivers.denso.arm import BoxEnvelope, check_speed
from drivers.denso.arm import LimitError as ArmLimitError
from drivers.denso.pose import check_pose
from drivers.exciter.limits import LimitCheck, LimitError, MotionLimits
from drivers.exciter.shaker import SensitivityTable, ShakerLimits
from drivers.exciter.vfd import check_output_hz
from rig.config.devices import VfdConfig
from rig.config.limits import VibrationLimits
from rig.config.rig_config import RigConfig
from rig.run.procedure import ParameterError

__all__ = ["ArmMoves", "GeneratorSweep", "Plan", "PlanCheck", "PlanRefused", "PlanStep", "Vibration",
           "check_plan", "format_plan", "plan_of", "robot_envelope", "shaker_limits",
           "validate_procedure"]

VIBRATION_DEVICES = ("exciter", "rotor", "generator")


@dataclass(frozen=True)
class ArmMoves:
    """Arm moves of a step: flange ``poses`` (x, y, z mm; rx, ry, rz deg) in order, at ``speed_mm_s``
    (None: ``limits.robot.max_speed_mm_s``), holding ``hold_s`` s at each (settle + recording).
    ``poses_from`` / ``speed_from`` name what they follow from (parameters and values)."""

    poses: tuple[tuple[float, ...], ...]
    poses_from: str
    speed_mm_s: float | None
    speed_from: str
    hold_s: float = 0.0


@dataclass(frozen=True)
class GeneratorSweep:
    """The generator's own sweep at constant volts (``spacing`` linear | log), checked at its exact maxima."""

    start_hz: float
    stop_hz: float
    duration_s: float
    spacing: str
    amplitude_vpp: float


@dataclass(frozen=True)
class Vibration:
    """A vibration source's motion: ``device`` (exciter | rotor | generator) follows ``profile`` [(t_s from
    its start, f_hz)] at peak displacement ``amplitude_mm`` (crank radius, rotor marker radius, shaker
    displacement). ``max_slope_hz_per_s``: the steepest commanded frequency change (None: a constant
    frequency reached at the drive's configured ramp). Generator only: the volts of every profile point
    (``amplitude_vpp``) and the built-in sweep (``generator_sweep``). The ``*_from`` strings name the
    parameters (and values) each quantity follows from."""

    device: str
    profile: tuple[tuple[float, float], ...]
    amplitude_mm: float
    frequency_from: str
    amplitude_from: str
    max_slope_hz_per_s: float | None = None
    slope_from: str = ""
    amplitude_vpp: tuple[float, ...] = ()
    generator_sweep: GeneratorSweep | None = None

    @property
    def frequency_range_hz(self) -> tuple[float, float]:
        fs = [f for _, f in self.profile]
        return min(fs), max(fs)

    @property
    def duration_s(self) -> float:
        return self.profile[-1][0] - self.profile[0][0]


_Part = TypeVar("_Part", ArmMoves, Vibration)


@dataclass(frozen=True)
class PlanStep:
    """One recorded step: its name (the run's step and segment), what it moves, how long it lasts (s,
    an estimate: motion, settling and recording; analysis not included), and what may lengthen it
    (``may_repeat``: e.g. the recordings tried again, with the longest the step may then take)."""

    name: str
    duration_s: float
    arm: ArmMoves | None = None
    vibration: Vibration | None = None
    what: str = ""  # what a step that moves nothing does (the report: analysis on the host, not timed here)
    may_repeat: str = ""


@dataclass(frozen=True)
class Plan:
    """A procedure's complete plan, in execution order."""

    procedure: str
    steps: tuple[PlanStep, ...]

    @property
    def duration_s(self) -> float:
        return sum(s.duration_s for s in self.steps)

    def step(self, name: str) -> PlanStep:
        for s in self.steps:
            if s.name == name:
                return s
        raise KeyError(f"the plan of {self.procedure!r} has no step {name!r}")

    def moves(self, name: str) -> ArmMoves:
        """The arm moves of step ``name`` (KeyError when it has none)."""
        arm = self.step(name).arm
        if arm is None:
            raise KeyError(f"step {name!r} of {self.procedure!r} moves no arm")
        return arm

    def vibration(self, name: str) -> Vibration:
        """The vibration of step ``name`` (KeyError when it has none)."""
        vib = self.step(name).vibration
        if vib is None:
            raise KeyError(f"step {name!r} of {self.procedure!r} has no vibration")
        return vib

    def __add__(self, other: Plan) -> Plan:
        return Plan(self.procedure, self.steps + other.steps)

    def renamed(self, names: dict[str, str]) -> Plan:
        """The same plan with parameter names replaced in every ``*_from`` text (``{"sweep.max_hz":
        "certify.sweep_max_hz"}``: a procedure naming the parameters it sets for the steps it runs)."""
        pattern = re.compile("|".join(rf"\b{re.escape(k)}\b" for k in names)) if names else None

        def text(value: str) -> str:
            return pattern.sub(lambda m: names[m.group(0)], value) if pattern else value

        def fix(part: _Part) -> _Part:
            origins = [f.name for f in dataclasses.fields(part) if f.name.endswith("_from")]
            # every ``*_from`` field, read by the name dataclasses.fields gives
            changes: dict[str, Any] = {name: text(getattr(part, name)) for name in origins}
            return dataclasses.replace(part, **changes)

        return Plan(self.procedure, tuple(dataclasses.replace(
            s, arm=None if s.arm is None else fix(s.arm),
            vibration=None if s.vibration is None else fix(s.vibration)) for s in self.steps))


@dataclass(frozen=True)
class PlanCheck:
    """One limit against the plan's most demanding value of its quantity. ``limit`` is the upper bound
    (``lower`` the lower one of a range); ``field`` the ``rig.toml`` field of the limit; ``origin`` the
    parameters the value follows from; ``where`` which point of the plan; ``passed`` the drivers' verdict."""

    step: str
    device: str
    quantity: str
    value: float
    limit: float
    unit: str
    field: str
    origin: str
    passed: bool
    where: str = ""
    formula: str = ""
    lower: float | None = None

    @property
    def margin(self) -> float:
        """Distance to the nearest bound, in ``unit`` (negative when violated)."""
        upper = self.limit - self.value
        return upper if self.lower is None else min(upper, self.value - self.lower)

    def message(self) -> str:
        at = f" at {self.where}" if self.where else ""
        if self.lower is not None:
            return (f"{self.origin}: {self.quantity} = {self.value:.6g} {self.unit}{at} is outside the "
                    f"{self.device}'s range [{self.lower:.6g}, {self.limit:.6g}] {self.unit} ({self.field})")
        value = f"{self.formula} = {self.value:.6g}" if self.formula else f"{self.value:.6g}"
        return (f"{self.origin}: {self.quantity} {value} {self.unit}{at} exceeds the {self.device}'s limit "
                f"{self.limit:.6g} {self.unit} ({self.field})")


class PlanRefused(ParameterError):  # noqa: N818 — a refusal, as ParameterError
    """The plan breaks a limit: nothing was connected. ``checks``: every check, ``failed`` the violations."""

    def __init__(self, plan: Plan, checks: list[PlanCheck]) -> None:
        self.plan = plan
        self.checks = checks
        self.failed = [c for c in checks if not c.passed]
        first = self.failed[0]
        others = [f"{c.step} {c.device} {c.quantity}" for c in self.failed[1:]]
        more = f" (also beyond a limit: {', '.join(others)})" if others else ""
        super().__init__("", f"step {first.step}: {first.message()}{more}; refused before connecting any "
                             "device")
        self.field = first.origin.split(" ")[0]  # the first parameter named


# ------------------------------------------------------------------------------------------------ limits
def robot_envelope(config: RigConfig) -> BoxEnvelope:
    """The arm driver's envelope of ``[limits.robot]`` (ParameterError when absent)."""
    lim = config.limits.robot
    if lim is None:
        raise ParameterError("limits.robot", "the plan moves the arm, but the configuration has no "
                                             "[limits.robot]")
    envelope: BoxEnvelope = lim.envelope()
    return envelope


def _vfd_config(config: RigConfig, device: str) -> VfdConfig | None:
    """``[devices.exciter]`` or ``[devices.rotor]`` (``device`` names a VFD-driven source)."""
    return {"exciter": config.devices.exciter, "rotor": config.devices.rotor}[device]


def _motion_limits(config: RigConfig, device: str) -> MotionLimits:
    """``[limits.<device>]`` of a vibration source (exciter, rotor, generator) as the drivers' limits;
    ParameterError when the configuration lacks ``[devices.<device>]``."""
    configured = config.devices.generator if device == "generator" else _vfd_config(config, device)
    if configured is None:
        raise ParameterError(f"devices.{device}", f"the plan needs [devices.{device}], which this rig "
                                                  "configuration lacks")
    limits: VibrationLimits | None = {"exciter": config.limits.exciter, "rotor": config.limits.rotor,
                                      "generator": config.limits.generator}[device]
    assert limits is not None, "the configuration check pairs every device with its limits"
    return limits.motion_limits()


def shaker_limits(config: RigConfig) -> ShakerLimits:
    """The shaker's :class:`ShakerLimits` of the configuration (ParameterError without a generator)."""
    motion = _motion_limits(config, "generator")
    gen = config.devices.generator
    assert gen is not None  # _motion_limits raised otherwise
    return ShakerLimits(motion, SensitivityTable(gen.sensitivity_mm_per_v),
                        gen.max_amplitude_vpp)


# ------------------------------------------------------------------------------------------------ checks
def _worst(rows: Iterable[PlanCheck]) -> PlanCheck:
    """The most demanding row: a failing one first, then the smallest margin relative to the limit."""
    return min(rows, key=lambda r: (r.passed, r.margin / abs(r.limit) if r.limit else r.margin))


def _passes(check: Callable[..., Any], *args: Any) -> bool:
    """Whether a driver's check accepts ``args`` (its LimitError, a ValueError, means no)."""
    try:
        check(*args)
    except ValueError:
        return False
    return True


def _pose_text(pose: tuple[float, ...]) -> str:
    return "[" + ", ".join(f"{round(v, 9) + 0.0:.6g}" for v in pose) + "]"  # + 0.0: no "-0"


def _arm_checks(step: str, arm: ArmMoves, config: RigConfig) -> list[PlanCheck]:
    envelope = robot_envelope(config)
    rows: list[PlanCheck] = []
    n = len(arm.poses)
    bounds = {"x_mm": envelope.x_mm, "y_mm": envelope.y_mm, "z_mm": envelope.z_mm}
    centre = [0.5 * sum(b) for b in bounds.values()]
    for k, (axis, (lo, hi)) in enumerate(bounds.items()):
        per_pose = []
        for i, pose in enumerate(arm.poses):
            probe = [*centre, 0.0, 0.0, 0.0]  # this axis alone, by the driver's own check
            probe[k] = float(check_pose(pose)[k])
            passed = _passes(envelope.check, check_pose(probe))
            value = round(float(pose[k]), 9) + 0.0
            per_pose.append(PlanCheck(step, "arm", f"pose {axis[0]}", value, hi, "mm",
                                      f"limits.robot.envelope_{axis}", arm.poses_from, passed,
                                      where=f"pose {i + 1} of {n} {_pose_text(pose)}", lower=lo))
        if per_pose:
            rows.append(_worst(per_pose))
    for i, pose in enumerate(arm.poses):  # the orientation range of the driver (not configurable)
        try:
            envelope.orientation.check(check_pose(pose))
        except ArmLimitError as exc:
            rows.append(PlanCheck(step, "arm", exc.axis, exc.value, exc.allowed[1], "deg",
                                  "the arm driver's orientation range", arm.poses_from, False,
                                  where=f"pose {i + 1} of {n} {_pose_text(pose)}", lower=exc.allowed[0]))
    assert config.limits.robot is not None  # robot_envelope refused the plan otherwise
    limit = config.limits.robot.max_speed_mm_s
    speed = limit if arm.speed_mm_s is None else arm.speed_mm_s
    rows.append(PlanCheck(step, "arm", "speed", speed, limit, "mm/s", "limits.robot.max_speed_mm_s",
                          arm.speed_from, _passes(check_speed, speed, limit)))
    return rows


def _field(device: str, exc_or_check: LimitError | LimitCheck) -> str:
    if exc_or_check.quantity == "generator amplitude":
        return "devices.generator.max_amplitude_vpp"
    return f"limits.{device}.{exc_or_check.field}"


def _origin(vib: Vibration, quantity: str) -> str:
    if quantity == "frequency":
        return vib.frequency_from
    if quantity == "displacement":
        return vib.amplitude_from
    if quantity == "ramp rate":
        return vib.slope_from
    return f"{vib.frequency_from} with {vib.amplitude_from}"


def _vibration_checks(step: str, vib: Vibration, config: RigConfig) -> list[PlanCheck]:
    limits = _motion_limits(config, vib.device)
    shaker = shaker_limits(config) if vib.amplitude_vpp else None
    by_quantity: dict[str, list[PlanCheck]] = {}
    for i, (t_s, f_hz) in enumerate(vib.profile):
        for c in limits.evaluate(f_hz, vib.amplitude_mm):
            by_quantity.setdefault(c.quantity, []).append(PlanCheck(
                step, vib.device, c.quantity, c.value, c.limit, c.unit, _field(vib.device, c),
                _origin(vib, c.quantity), c.passed, where=f"t = {t_s:.4g} s", formula=c.formula))
        if shaker is not None:
            vpp = vib.amplitude_vpp[i]
            by_quantity.setdefault("generator amplitude", []).append(PlanCheck(
                step, vib.device, "generator amplitude", vpp, shaker.max_amplitude_vpp, "Vpp",
                "devices.generator.max_amplitude_vpp", f"{vib.amplitude_from} at {f_hz:g} Hz",
                _passes(shaker.check_volts, vpp),
                where=f"t = {t_s:.4g} s"))
    rows = [_worst(v) for v in by_quantity.values()]
    if vib.max_slope_hz_per_s is not None and vib.max_slope_hz_per_s > 0:
        c = limits.evaluate_ramp_rate(vib.max_slope_hz_per_s)
        rows.append(PlanCheck(step, vib.device, c.quantity, c.value, c.limit, c.unit, _field(vib.device, c),
                              vib.slope_from, c.passed))
    if vib.device != "generator":
        rows.append(_drive_output_check(step, vib, config))
    if vib.generator_sweep is not None and all(r.passed for r in rows):
        g = vib.generator_sweep  # the exact maxima between the planned points (the table's pieces)
        try:
            shaker_limits(config).check_sweep(g.start_hz, g.stop_hz, g.duration_s, g.spacing, g.amplitude_vpp)
        except LimitError as exc:
            rows.append(PlanCheck(step, vib.device, exc.quantity, exc.value, exc.limit, exc.unit,
                                  _field(vib.device, exc), _origin(vib, exc.quantity), False,
                                  where=f"within the {g.spacing} sweep {g.start_hz:g}..{g.stop_hz:g} Hz"))
    return rows


def _drive_output_check(step: str, vib: Vibration, config: RigConfig) -> PlanCheck:
    """The VFD's output at the highest planned frequency (× gear ratio) against its ``max_output_hz``."""
    dev = _vfd_config(config, vib.device)
    assert dev is not None  # _motion_limits refused the plan otherwise
    output_hz = vib.frequency_range_hz[1] * dev.gear_ratio
    passed = _passes(check_output_hz, output_hz, dev.max_output_hz)
    return PlanCheck(step, vib.device, "drive output", output_hz, dev.max_output_hz, "Hz",
                     f"devices.{vib.device}.max_output_hz",
                     f"{vib.frequency_from} with devices.{vib.device}.gear_ratio = {dev.gear_ratio:g}",
                     passed)


def check_plan(plan: Plan, config: RigConfig) -> list[PlanCheck]:
    """Every limit against the plan (nothing is connected); one row per quantity, device and step."""
    rows: list[PlanCheck] = []
    for step in plan.steps:
        if step.arm is not None and step.arm.poses:
            rows += _arm_checks(step.name, step.arm, config)
        if step.vibration is not None:
            rows += _vibration_checks(step.name, step.vibration, config)
    return rows


def plan_of(module: types.ModuleType, params: object, config: RigConfig) -> Plan | None:
    """The procedure's plan (its ``plan(params, config)``), or None for a module without one (a user's
    procedure file: then only the drivers' checks at each command guard it)."""
    make = getattr(module, "plan", None)
    if not callable(make):
        return None
    try:
        plan: Plan = make(params, config)
    except ParameterError:
        raise
    except ValueError as exc:  # e.g. a profile the parameters make impossible: bad input, not a crash
        raise ParameterError(module.NAME, f"its plan cannot be made from these parameters: {exc}") from exc
    return plan


def validate_procedure(module: types.ModuleType, params: object, config: RigConfig) -> list[PlanCheck]:
    """Compute and check the procedure's whole plan; :class:`PlanRefused` (exit 4) on any violation."""
    plan = plan_of(module, params, config)
    if plan is None:
        return []
    checks = check_plan(plan, config)
    if any(not c.passed for c in checks):
        raise PlanRefused(plan, checks)
    return checks


# ------------------------------------------------------------------------------------------------ text
def _duration_text(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes, s = divmod(round(seconds), 60)
    return f"{minutes} min {s:02d} s" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


def _step_text(step: PlanStep) -> str:
    parts = []
    if step.arm is not None and step.arm.poses:
        speed = "the speed limit" if step.arm.speed_mm_s is None else f"{step.arm.speed_mm_s:g} mm/s"
        parts.append(f"arm {len(step.arm.poses)} poses at {speed}")
    if step.vibration is not None:
        v = step.vibration
        lo, hi = v.frequency_range_hz
        freq = f"{lo:g} Hz" if math.isclose(lo, hi) else f"{lo:g} → {hi:g} Hz"
        slope = f", max slope {v.max_slope_hz_per_s:.3g} Hz/s" if v.max_slope_hz_per_s else ""
        accel = max((2 * math.pi * f) ** 2 * v.amplitude_mm / 1000.0 for _, f in v.profile)
        parts.append(f"{v.device} {freq} at {v.amplitude_mm:g} mm over {v.duration_s:.3g} s{slope}, "
                     f"max acceleration {accel:.4g} m/s²")
    what = "; ".join(parts) or step.what or "no motion"
    timed = "not timed" if step.what and not step.duration_s else f"≈ {_duration_text(step.duration_s)}"
    repeat = f"; {step.may_repeat}" if step.may_repeat else ""
    return f"  {step.name:<18s} {timed:>12s}  {what}{repeat}"


def format_plan(plan: Plan, checks: list[PlanCheck]) -> str:
    """The plan and its checks as text (``rig run --dry-run``)."""
    lines = [f"plan of {plan.procedure}: {len(plan.steps)} steps, ≈ {_duration_text(plan.duration_s)} "
             "(motion, settling and recording; the report's analysis not included)"]
    lines += [_step_text(s) for s in plan.steps]
    passed = sum(c.passed for c in checks)
    lines.append(f"checks ({passed}/{len(checks)} pass; margin = distance to the limit):")
    for c in checks:
        bound = f"[{c.lower:.6g}, {c.limit:.6g}]" if c.lower is not None else f"≤ {c.limit:.6g}"
        at = f" at {c.where}" if c.where else ""
        lines.append(f"  {'PASS' if c.passed else 'FAIL'}  {c.step:<16s} {c.device:<9s} {c.quantity:<19s} "
                     f"{c.value:10.4g} {c.unit:<5s} {bound:>18s} {c.unit:<5s} margin {c.margin:+.4g}  "
                     f"({c.field}; from {c.origin}{at})")
    return "\n".join(lines)

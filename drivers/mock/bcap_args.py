"""Argument coercion and mock-chosen error codes of the mock RC8 (``bcap_state.py`` uses them).

Numbers are accepted as any integer or real VARIANT scalar, and number lists as I4/R4/R8 (or nested
VARIANT) arrays (bcap.md §15 item 5). Poses: ``"@P P(x,y,z,rx,ry,rz[,fig])"`` or ``[[x..fig], "P", "@E"]``.
"""

from __future__ import annotations

import math
import re

from drivers.mock import bcap_wire as w
from drivers.mock.bcap_wire import ARRAY as VT_ARRAY
from drivers.mock.bcap_wire import BSTR as VT_BSTR
from drivers.mock.bcap_wire import VARIANT as VT_VARIANT
from drivers.mock.bcap_wire import Value as Variant

# mock-chosen controller errors (0x83xxxxxx): code -> (name, description)
OUT_OF_REACH = 0x8350A001
JOINT_LIMIT = 0x8350A002
MOTOR_OFF = 0x8350A003
ROBOT_BUSY = 0x8350A004
INJECTED_MOVE_ERROR = 0x8350A005
MOCK_ERRORS: dict[int, tuple[str, str]] = {
    OUT_OF_REACH: ("MOCK_OUT_OF_REACH", "Target pose is out of the robot's reach"),
    JOINT_LIMIT: ("MOCK_JOINT_LIMIT", "Target pose violates a software joint limit"),
    MOTOR_OFF: ("MOCK_MOTOR_OFF", "Motor power is off"),
    ROBOT_BUSY: ("MOCK_ROBOT_BUSY", "Robot is moving (NEXT move in progress)"),
    INJECTED_MOVE_ERROR: ("MOCK_INJECTED_MOVE_ERROR", "Injected fault: motion command failed"),
}
#: functions whose failed replies still carry one (EMPTY) argument, as the reference server's do
VALUE_RETURNING = frozenset({3, 7, 8, 9, 13, 17, 62, 64, 101})
_POSE_RE = re.compile(r"^\s*(@(?:P|E|0|\d+))?\s*P\s*\(([^()]*)\)\s*$", re.IGNORECASE)



class CallFailed(Exception):  # noqa: N818 (internal control flow, never escapes the module)
    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(message)
        self.code = code
        self.message = message


def error_description(code: int) -> str:
    code = w.unsigned(code)
    if code in MOCK_ERRORS:
        return MOCK_ERRORS[code][1]
    return w.DESCRIPTIONS.get(code, "No description for this code")


def _number(v: Variant, what: str) -> float:
    if v.vt & VT_ARRAY or isinstance(v.value, bool) or not isinstance(v.value, int | float):
        raise CallFailed(w.DISP_E_TYPEMISMATCH, f"{what}: expected a number, got vt=0x{v.vt:04X}")
    return float(v.value)


def _integer(v: Variant, what: str) -> int:
    """A whole number (any numeric VARIANT holding one); NaN, infinities and fractions → E_INVALIDARG."""
    value = _number(v, what)
    if not math.isfinite(value) or value != int(value):
        raise CallFailed(w.E_INVALIDARG, f"{what}: {value!r} is not a whole number")
    return int(value)


def _numbers(v: Variant, what: str) -> list[float]:
    if v.vt & VT_ARRAY:
        values = v.to_python()
        if isinstance(values, bytes) or not all(isinstance(x, int | float) and not isinstance(x, bool)
                                                 for x in values):
            raise CallFailed(w.DISP_E_TYPEMISMATCH, f"{what}: expected numbers")
        return [float(x) for x in values]
    if v.vt == 0:
        return []
    return [_number(v, what)]


def _text(v: Variant, what: str) -> str:
    if v.vt != VT_BSTR:
        raise CallFailed(w.DISP_E_TYPEMISMATCH, f"{what}: expected BSTR, got vt=0x{v.vt:04X}")
    return str(v.value)


def parse_move_option(option: str) -> dict[str, float | bool]:
    """``SPEED=n,ACCEL=n,DECEL=n,TIME=n,NEXT`` → dict (keys upper case)."""
    out: dict[str, float | bool] = {}
    for part in filter(None, (p.strip() for p in option.split(","))):
        key, _, value = part.partition("=")
        key = key.strip().upper()
        if key == "NEXT" and not value:
            out["NEXT"] = True
        elif key in ("SPEED", "ACCEL", "DECEL", "TIME") and value:
            try:
                out[key] = float(value)
            except ValueError:
                raise CallFailed(w.E_INVALIDARG, f"option {part!r}: not a number") from None
        else:
            raise CallFailed(w.E_INVALIDARG, f"unknown Move option {part!r}")
    return out


def parse_pose(v: Variant) -> tuple[list[float], int | None]:
    """P pose from ``"@P P(x,y,z,rx,ry,rz[,fig])"`` or ``[[x..fig], "P", "@E"]`` → (6 values, fig)."""
    if v.vt == VT_BSTR:
        match = _POSE_RE.match(v.value)
        if not match:
            raise CallFailed(w.E_INVALIDARG, f"pose {v.value!r}: expected '@P P(x,y,z,rx,ry,rz,fig)'")
        try:
            values = [float(t) for t in match.group(2).split(",")]
        except ValueError:
            raise CallFailed(w.E_INVALIDARG, f"pose {v.value!r}: not numbers") from None
    elif v.vt == VT_ARRAY | VT_VARIANT and v.value:
        kind = v.value[1].value if len(v.value) > 1 else "P"
        if kind not in ("P", 0):
            raise CallFailed(w.E_NOTIMPL, f"pose type {kind!r}: the mock moves to P poses only")
        values = _numbers(v.value[0], "pose")
    else:
        values = _numbers(v, "pose")
    if len(values) not in (6, 7) or not all(math.isfinite(x) for x in values):
        raise CallFailed(w.E_INVALIDARG, f"pose has {len(values)} values; expected 6 or 7 finite numbers")
    fig = int(values[6]) if len(values) == 7 else None
    return values[:6], fig

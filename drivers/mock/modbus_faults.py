"""Fault injection for the mock VFD (:mod:`drivers.mock.vfd_server`): what can go wrong, parsed from the
command line (``--fault KIND[:PARAM]``) or set by tests, and which faults are due at each request."""

from __future__ import annotations

import threading
from dataclasses import dataclass

from drivers.mock.vfd_drive import FAULT_OVERLOAD

__all__ = ["FAULTS", "FAULT_KINDS", "RTU_UNPLUG_S", "Fault", "FaultPlan", "parse_fault"]

# kind → (meaning of PARAM on the command line, default PARAM)
FAULT_KINDS: dict[str, tuple[str, float]] = {
    "late": ("every reply is sent PARAM s late", 1.0),
    "no_reply": ("every PARAM-th request is executed but not answered", 1),
    "trip": ("the drive trips with fault code PARAM as soon as it runs", FAULT_OVERLOAD),
    "busy": ("every PARAM-th request is refused with exception 06 (busy), not executed", 1),
    "disconnect": ("after every PARAM requests the link drops (TCP: connection closed; RTU: cable pulled "
                   "for 1 s)", 10),
    "bad_crc": ("every PARAM-th reply has a corrupted CRC (TCP: MBAP protocol id)", 1),
    "twice": ("every PARAM-th reply is sent twice", 1),
    "previous": ("every PARAM-th request is answered with the reply to the request before it", 1),
    "drop": ("every reply loses PARAM bytes from its middle", 1),
}
FAULTS = (*FAULT_KINDS, "exception")
_EVERY_KINDS = ("no_reply", "busy", "bad_crc", "twice", "previous", "exception")
RTU_UNPLUG_S = 1.0


@dataclass
class Fault:
    """One injected fault: ``kind`` (see :data:`FAULT_KINDS`), its ``value`` (seconds, fault code,
    exception code or byte count), applying to every ``every``-th request, ``count`` times (None: until
    cleared)."""

    kind: str
    value: float | None = None
    every: int = 1
    count: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in FAULTS:
            raise ValueError(f"fault kind {self.kind!r}: must be one of {list(FAULTS)}")
        if self.every < 1:
            raise ValueError(f"fault {self.kind}: every={self.every!r} must be >= 1")
        if self.count is not None and self.count < 1:
            raise ValueError(f"fault {self.kind}: count={self.count!r} must be >= 1 or None")


def parse_fault(text: str) -> Fault:
    """``KIND[:PARAM]`` from the command line → a permanent :class:`Fault` (ValueError naming the problem)."""
    kind, _, param = text.partition(":")
    if kind not in FAULT_KINDS:
        raise ValueError(f"--fault {text!r}: unknown kind {kind!r}; allowed: {', '.join(FAULT_KINDS)}")
    default = FAULT_KINDS[kind][1]
    try:
        value = float(param) if param else float(default)
    except ValueError:
        raise ValueError(f"--fault {text!r}: PARAM {param!r} is not a number") from None
    if kind == "late":
        if not 0 < value <= 60:
            raise ValueError(f"--fault {text!r}: a late reply is 0 < PARAM <= 60 s late")
        return Fault(kind, value)
    if value != int(value) or value < 1:
        raise ValueError(f"--fault {text!r}: PARAM must be a whole number >= 1")
    if kind in _EVERY_KINDS:
        return Fault(kind, None, every=int(value))
    if kind == "disconnect":
        return Fault(kind, RTU_UNPLUG_S, every=int(value))
    return Fault(kind, int(value))


class FaultPlan:
    """Active faults and the request counter (thread-safe)."""

    def __init__(self) -> None:
        self._faults: list[Fault] = []
        self._lock = threading.Lock()
        self.requests = 0

    def add(self, fault: Fault) -> None:
        with self._lock:
            self._faults = [f for f in self._faults if f.kind != fault.kind] + [fault]

    def clear(self) -> None:
        with self._lock:
            self._faults = []

    def next_request(self) -> dict[str, Fault]:
        """Count one request; the faults that apply to it (each consumed once)."""
        with self._lock:
            self.requests += 1
            due: dict[str, Fault] = {}
            for fault in list(self._faults):
                if fault.kind == "trip" or self.requests % fault.every:
                    continue
                due[fault.kind] = fault
                if fault.count is not None:
                    fault.count -= 1
                    if fault.count <= 0:
                        self._faults.remove(fault)
            return due

    def take_trip(self) -> int | None:
        """The fault code of an active "trip" fault (consumed when it has a count), else None."""
        with self._lock:
            fault = next((f for f in self._faults if f.kind == "trip"), None)
            if fault is None:
                return None
            if fault.count is not None:
                fault.count -= 1
                if fault.count <= 0:
                    self._faults.remove(fault)
            return int(fault.value or FAULT_OVERLOAD)

"""Errors of the simulated rig and the argument checks that raise them."""

from __future__ import annotations

import math

__all__ = ["SimCommandError"]


class SimCommandError(ValueError):
    """A command to a simulated body is invalid (bad value, time going backwards, robot busy)."""


def _finite(value: float, name: str, *, positive: bool = False, nonneg: bool = False) -> float:
    v = float(value)
    if not math.isfinite(v) or (positive and v <= 0.0) or (nonneg and v < 0.0):
        need = "> 0" if positive else "≥ 0" if nonneg else "finite"
        raise SimCommandError(f"{name} must be a finite number {need}, got {value!r}")
    return v

"""What the devices themselves report after the runner made them safe (the stop document's ``safe_state``).

``read_back(devices, results, clock) -> {device: {...}}`` asks every device whose safe-state action
succeeded for its own state, over its own protocol — the record then shows that the exciter *is* at rest
and the arm *is* still, not only that the commands were sent:

- a VFD axis (exciter, rotor: ``read_sample``): ``frequency_hz`` (the drive's output, mechanical Hz),
  ``setpoint_hz`` (its commanded frequency) and ``status`` (the drive's status word: "stopped",
  "running", "decelerating", ...);
- the arm (``position``): ``pose`` (x, y, z mm; rx, ry, rz deg) read twice ``settle_s`` apart on the rig
  clock, and ``moved_mm`` — how far the flange moved in between (0 for a halted arm);
- the generator + shaker (``generator.output()``): ``output_on``.

A device that does not answer gets ``{"error": "<type>: <message>"}``; a device without a read-back (or
whose safe-state action failed: that failure is already recorded) is left out. Never raises.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

__all__ = ["read_back"]

log = logging.getLogger("rig.readback")


def _axis(dev: Any) -> dict[str, Any]:
    sample = dev.read_sample(fault_is_error=False)
    return {"frequency_hz": float(sample.frequency_hz), "setpoint_hz": float(sample.setpoint_hz),
            "status": str(sample.status)}


def _arm(dev: Any, clock: Any, settle_s: float) -> dict[str, Any]:
    first = np.asarray(dev.position(), dtype=float)
    clock.sleep_s(settle_s)
    second = np.asarray(dev.position(), dtype=float)
    return {"pose": [float(v) for v in second], "settle_s": settle_s,
            "moved_mm": float(np.linalg.norm(second[:3] - first[:3]))}


def read_back(devices: dict[str, Any], results: list[Any], clock: Any, *,
              settle_s: float = 0.2) -> dict[str, dict[str, Any]]:
    """Each safely stopped device's own report (see the module docstring). ``results`` are
    :func:`rig.safety.make_safe`'s (``device``, ``error``); ``settle_s`` (s, rig clock, > 0) is the
    interval between the arm's two position reads."""
    ok = {r.device for r in results if r.error is None}
    out: dict[str, dict[str, Any]] = {}
    for name, dev in devices.items():
        if name not in ok:
            continue
        try:
            if callable(getattr(dev, "read_sample", None)):
                out[name] = _axis(dev)
            elif callable(getattr(dev, "position", None)):
                out[name] = _arm(dev, clock, settle_s)
            elif callable(getattr(getattr(dev, "generator", None), "output", None)):
                out[name] = {"output_on": bool(dev.generator.output())}
        except Exception as exc:
            log.error("reading back the state of %s failed: %s", name, exc)
            out[name] = {"error": f"{type(exc).__name__}: {exc}"}
    return out

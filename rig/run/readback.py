"""What the devices themselves report after the runner made them safe (the stop document's ``safe_state``).

``read_back(roster, results) -> {device: {...}}`` asks every device whose safe-state action succeeded for
its own state (:meth:`drivers.roles.Device.read_back`, over its own protocol) — the record then shows
that the exciter *is* at rest and the arm *is* still, not only that the commands were sent:

- a vibration source (exciter, rotor): ``frequency_hz`` (the drive's output, mechanical Hz),
  ``setpoint_hz`` (its commanded frequency) and ``status`` (the drive's status word: "stopped",
  "running", "decelerating", ...);
- the arm: ``pose`` (x, y, z mm; rx, ry, rz deg) read twice ``settle_s`` apart on the rig clock, and
  ``moved_mm`` — how far the flange moved in between (0 for a halted arm);
- the generator + shaker: ``output_on``; a camera: ``recording``.

A device that does not answer gets ``{"error": "<type>: <message>"}``; a device whose safe-state action
failed (that failure is already recorded) is left out. Never raises.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from drivers.roles import Assignment

__all__ = ["read_back"]

log = logging.getLogger("rig.run.readback")


def read_back(roster: Sequence[Assignment], results: Sequence[Any]) -> dict[str, dict[str, Any]]:
    """Each safely stopped device's own report (see the module docstring). ``results`` are
    :func:`rig.run.safety.make_safe`'s (``device``, ``error``)."""
    ok = {r.device for r in results if r.error is None}
    out: dict[str, dict[str, Any]] = {}
    for entry in roster:
        if entry.name not in ok:
            continue
        try:
            out[entry.name] = entry.device.read_back()
        except Exception as exc:
            log.error("reading back the state of %s failed: %s", entry.name, exc)
            out[entry.name] = {"error": f"{type(exc).__name__}: {exc}"}
    return out

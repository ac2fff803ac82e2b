"""The camera timing model and its record: row-corrected exposure instants and ``timing.json``.

Timing model (all in seconds, on the reference camera's clock): an observation of camera *c* in the frame
with time stamp τ (the camera's own clock) at image row v (pixels, origin at the centre of the top row) was
exposed at

    t = τ + offset_s[c] + drift_ppm[c]·1e-6·(τ − epoch_s[c]) + v·line_time_s[c]

The reference camera has offset 0 and drift 0 by definition; a constant such as half the exposure time is
absorbed into the offsets (it cancels when both cameras expose equally long). ``epoch_s`` is the camera-clock
instant about which the drift is applied (the middle of the record used to estimate it), so that offset and
drift are nearly uncorrelated. Both estimators (:mod:`rig.stereo.timing_joint`,
:mod:`rig.stereo.timing_rotor`, dispatched by :mod:`rig.stereo.timing`) return a :class:`TimingResult`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rig.stereo._arrays import FloatArray
from rig.stereo.errors import InputArrayError


def corrected_times(
    timestamp_s: object,
    v_px: object,
    *,
    offset_s: float = 0.0,
    line_time_s: float = 0.0,
    drift_ppm: float = 0.0,
    epoch_s: float = 0.0,
) -> FloatArray:
    """Exposure instant of each observation on the reference clock (s), from its frame time stamp and row.

    ``timestamp_s``: frame time stamps (camera clock, s); ``v_px``: the marker's image row (px).
    """
    tau = np.asarray(timestamp_s, dtype=float)
    v = np.asarray(v_px, dtype=float)
    if tau.shape != v.shape:
        raise InputArrayError(f"timestamp_s {tau.shape} and v_px {v.shape} must have the same shape")
    return tau + offset_s + drift_ppm * 1e-6 * (tau - epoch_s) + v * line_time_s


@dataclass
class TimingResult:
    """Content of ``timing.json`` (contracts.md): per camera offset, line time and drift, with uncertainty.

    ``uncertainty`` holds standard uncertainties (k = 1) as ``{"offset_s": {cam: s}, "line_time_s": {cam: s},
    "drift_ppm": {cam: ppm}}``; ``details`` holds diagnostics (residual RMS, number of observations, …).
    """

    reference_camera: str
    offset_s: dict[str, float]
    line_time_s: dict[str, float]
    drift_ppm: dict[str, float]
    method: str
    uncertainty: dict[str, dict[str, float]] = field(default_factory=dict)
    epoch_s: dict[str, float] = field(default_factory=dict)
    details: dict[str, Any] = field(default_factory=dict)

    def times(self, camera: str, timestamp_s: object, v_px: object) -> FloatArray:
        """Row-corrected exposure instants of ``camera``'s observations on the reference clock (s)."""
        if camera not in self.offset_s:
            raise InputArrayError(
                f"camera {camera!r} not in the timing result (have {sorted(self.offset_s)})"
            )
        return corrected_times(
            timestamp_s,
            v_px,
            offset_s=self.offset_s[camera],
            line_time_s=self.line_time_s.get(camera, 0.0),
            drift_ppm=self.drift_ppm.get(camera, 0.0),
            epoch_s=self.epoch_s.get(camera, 0.0),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict in the ``timing.json`` layout."""

        def fl(d: dict[str, float]) -> dict[str, float]:
            return {k: float(v) for k, v in d.items()}

        return {
            "reference_camera": self.reference_camera,
            "offset_s": fl(self.offset_s),
            "line_time_s": fl(self.line_time_s),
            "drift_ppm": fl(self.drift_ppm),
            "epoch_s": fl(self.epoch_s),
            "method": self.method,
            "uncertainty": {k: fl(v) for k, v in self.uncertainty.items()},
            "details": _jsonable(self.details),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TimingResult:
        """Inverse of :meth:`to_dict`; raises InputArrayError naming a missing or malformed key."""
        try:
            ref = str(d["reference_camera"])
            offset = {str(k): float(v) for k, v in d["offset_s"].items()}
            method = str(d["method"])
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputArrayError(
                f"timing dict needs reference_camera, offset_s {{cam: s}} and method: {exc!r}"
            ) from exc
        if ref not in offset:
            raise InputArrayError(f"reference_camera {ref!r} has no entry in offset_s {sorted(offset)}")

        def opt(key: str) -> dict[str, float]:
            try:
                return {str(k): float(v) for k, v in (d.get(key) or {}).items()}
            except (TypeError, ValueError, AttributeError) as exc:
                raise InputArrayError(f"timing dict: {key} must map camera → number: {exc!r}") from exc

        unc_raw = d.get("uncertainty") or {}
        if not isinstance(unc_raw, dict):
            raise InputArrayError(f"timing dict: uncertainty must be a dict, got {type(unc_raw).__name__}")
        try:
            unc = {str(k): {str(c): float(x) for c, x in v.items()} for k, v in unc_raw.items()}
        except (TypeError, ValueError, AttributeError) as exc:
            raise InputArrayError(
                "timing dict: uncertainty must map quantity → {camera: standard uncertainty}, e.g. "
                f'{{"offset_s": {{"right": 2e-5}}}}: {exc!r}'
            ) from exc
        return cls(
            ref,
            offset,
            opt("line_time_s"),
            opt("drift_ppm"),
            method,
            unc,
            opt("epoch_s"),
            dict(d.get("details") or {}),
        )


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj

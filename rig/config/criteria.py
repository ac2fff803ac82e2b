"""``[criteria]``: the certificate's acceptance thresholds and decision rule (the one source of their
defaults)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from rig.config.schema import spec

_POSITIVE = spec(lo=0.0, lo_open=True)


@dataclass(frozen=True)
class CriteriaConfig:
    """Acceptance thresholds of the certificate (each a maximum unless named ``min_``)."""

    calibration_rms_px: float = field(default=0.5, metadata=_POSITIVE)
    position_rms_mm: float = field(default=0.5, metadata=_POSITIVE)
    position_max_mm: float = field(default=1.5, metadata=_POSITIVE)
    repeatability_mm: float = field(default=0.5, metadata=_POSITIVE)
    amplitude_error_pct: float = field(default=5.0, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    amplitude_error_up_to_hz: float = field(default=10.0, metadata=_POSITIVE)
    min_usable_frequency_hz: float = field(default=10.0, metadata=_POSITIVE)
    sync_uncertainty_ms: float = field(default=1.0, metadata=_POSITIVE)
    frequency_error_pct: float = field(default=1.0, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    radius_error_mm: float = field(default=0.5, metadata=_POSITIVE)
    detection_pct: float = field(default=100.0, metadata=spec(lo=0.0, hi=100.0))
    length_error_mm: float = field(default=1.0, metadata=_POSITIVE)
    # the controller's clock against the cameras' (issue 18): 0.5 ms is 1.8° at 10 Hz, 4.5° at 25 Hz
    phase_delay_ms: float = field(default=0.5, metadata=_POSITIVE)
    controller_clock_u_ms: float = field(default=0.05, metadata=_POSITIVE)
    # the band beyond the crank sweep, swept by the shaker (certify's band step): required only when set
    # (a rig without a shaker certifies without them); the built-in rig sets them
    band_amplitude_error_pct: float | None = field(default=None,
                                                   metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    band_phase_deg: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True, hi=180.0))
    band_min_hz: float | None = field(default=None, metadata=_POSITIVE)
    # phase per steady step of a stepped profile (reports.step_phase): required only when set
    step_phase_deg: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True, hi=180.0))
    # settings of the decision (reports/certificate.py)
    decision_rule: str = field(default="guarded", metadata=spec(choices=("guarded", "simple")))
    reference_u_mm: float = field(default=0.02, metadata=spec(lo=0.0, hi=100.0))
    fit_max_hz: float | None = field(default=None, metadata=_POSITIVE)
    frequency_bin_hz: float = field(default=1.0, metadata=_POSITIVE)
    identification_gate_mm: float = field(default=50.0, metadata=_POSITIVE)
    step_settle_s: float = field(default=0.1, metadata=spec(lo=0.0, hi=60.0))  # a step's transient, s


# Fields of [criteria] that configure the decision rather than bound a measured value.
SETTING_FIELDS = ("decision_rule", "amplitude_error_up_to_hz", "reference_u_mm", "fit_max_hz",
                  "frequency_bin_hz", "identification_gate_mm", "step_settle_s")


def default_limits() -> dict[str, float | None]:
    """The default limit of every criterion, by criterion id (the certificate's ``limit``); None: the
    criterion is required only when ``[criteria]`` sets it."""
    defaults = dataclasses.asdict(CriteriaConfig())
    return {name: None if value is None else float(value) for name, value in defaults.items()
            if name not in SETTING_FIELDS}


def default_settings() -> dict[str, Any]:
    """The default settings of the decision (rule, reference uncertainty, fit band, bins, gate)."""
    defaults = dataclasses.asdict(CriteriaConfig())
    return {name: value for name, value in defaults.items() if name in SETTING_FIELDS}

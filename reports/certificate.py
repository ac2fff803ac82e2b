"""The certificate: acceptance criteria, PASS/FAIL with the expanded uncertainty, and the decision rule.

Limits come from the ``[criteria]`` table of ``rig.toml`` (``rig.config.criteria.CriteriaConfig``; the run's
``start.rig["criteria"]`` snapshot), merged over its defaults (:data:`DEFAULT_LIMITS`,
:data:`DEFAULT_SETTINGS`, read from :mod:`rig.config.criteria`). Every criterion reports
its measured value, limit, expanded uncertainty U = k·u (k = 2, or Student's t for fitted values with
few degrees of freedom), its uncertainty budget and a decision.

Decision rule (``criteria.decision_rule``):

* ``"guarded"`` (default) — ILAC-G8:09/2019 §4.2.3 guarded acceptance with guard band w = U: a criterion
  "value ≤ limit" PASSES only if value + U ≤ limit (for "≥": value − U ≥ limit). When the interval
  [value − U, value + U] straddles the limit the result is FAIL, zone "indeterminate": a setup is certified
  only when conformity is demonstrated at ≈ 95 % confidence (the client's risk of a false accept ≤ 2.5 %).
* ``"simple"`` — ILAC-G8 §4.2.1 simple acceptance (w = 0): PASS if value ≤ limit; the zone is still
  reported, and a false accept can reach 50 % at the limit.

A criterion without data is ``NOT EVALUATED``; the overall result is FAIL if any criterion fails,
INCOMPLETE if none fails but one is not evaluated or the run did not stop with success, else PASS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from reports.errors import CriteriaError
from rig.config.criteria import default_limits, default_settings


@dataclass(frozen=True)
class CriterionSpec:
    """One acceptance criterion: its limit key in ``[criteria]``, what is compared and how."""

    id: str
    description: str
    unit: str
    comparison: str  # "<=" or ">="


# the controller's clock against the cameras' (issue 18): kept apart from the cameras' own sync
TIMING_CRITERIA: tuple[CriterionSpec, ...] = (
    CriterionSpec("phase_delay_ms", "Delay |τ| of the measured sweep motion against the excitation", "ms",
                  "<="),
    CriterionSpec("controller_clock_u_ms",
                  "Standard uncertainty of the controller↔camera clock offset (timing fiducial)", "ms", "<="),
)
# the band beyond the crank sweep (certify's shaker step; reports.band_phase): required when configured
BAND_CRITERIA: tuple[CriterionSpec, ...] = (
    CriterionSpec("band_amplitude_error_pct",
                  "Largest amplitude error |e| of the interleaved fit over the shaker's band", "%", "<="),
    CriterionSpec("band_phase_deg",
                  "Largest phase error |φ| over the shaker's band against the generator's waveform", "°",
                  "<="),
    CriterionSpec("band_min_hz", "Certified upper edge of the shaker's band (amplitude and phase within "
                                 "their limits in every bin from its start)", "Hz", ">="),
)
# phase per steady step of a stepped profile (reports.step_phase): required when configured
STEP_CRITERIA: tuple[CriterionSpec, ...] = (
    CriterionSpec("step_phase_deg", "Largest phase error |φ| over the sweep's steady steps against the "
                                    "excitation", "°", "<="),
)
CRITERIA: tuple[CriterionSpec, ...] = (
    CriterionSpec("position_max_mm", "Largest 3D position error over the commanded poses", "mm", "<="),
    CriterionSpec("position_rms_mm", "RMS 3D position error over the commanded poses", "mm", "<="),
    CriterionSpec("detection_pct", "Share of commanded marker poses that were measured", "%", ">="),
    CriterionSpec("repeatability_mm", "Largest ISO 9283 repeatability RP_l over the targets", "mm", "<="),
    CriterionSpec(
        "length_error_mm", "Largest VDI/VDE 2634-1 length error |ΔL| over marker pairs", "mm", "<="
    ),
    CriterionSpec(
        "amplitude_error_pct",
        "Largest amplitude error |e(f)| of the fit up to the required frequency",
        "%",
        "<=",
    ),
    CriterionSpec(
        "min_usable_frequency_hz", "Highest frequency with |e(f)| within the amplitude tolerance", "Hz", ">="
    ),
    CriterionSpec(
        "frequency_error_pct", "Largest error of a measured steady frequency (plate, rotor)", "%", "<="
    ),
    CriterionSpec("radius_error_mm", "Rotor radius error |r̄ − r_ref|", "mm", "<="),
    CriterionSpec("calibration_rms_px", "Largest calibration reprojection RMS over the cameras", "px", "<="),
    CriterionSpec("sync_uncertainty_ms", "Standard uncertainty of the camera offset estimate", "ms", "<="),
    *TIMING_CRITERIA,
    *BAND_CRITERIA,
    *STEP_CRITERIA,
)
CRITERION_IDS = tuple(c.id for c in CRITERIA)

# The defaults of [criteria] (rig.config.criteria is their one source).
DEFAULT_LIMITS: dict[str, float | None] = default_limits()
DEFAULT_SETTINGS: dict[str, Any] = default_settings()
DECISION_RULES: dict[str, str] = {
    "guarded": (
        "Guarded acceptance, ILAC-G8:09/2019 §4.2.3, guard band w = U (k = 2): PASS only when the "
        "whole interval value ± U lies on the accepted side of the limit; an interval straddling the "
        "limit is a FAIL (zone 'indeterminate')."
    ),
    "simple": (
        "Simple acceptance, ILAC-G8:09/2019 §4.2.1, guard band w = 0: PASS when the measured value "
        "is on the accepted side of the limit, whatever its uncertainty (zone reported)."
    ),
}


@dataclass(frozen=True)
class Measured:
    """A measured value, its standard uncertainty ``u`` and coverage factor ``k`` (U = k·u).

    ``budget`` lists the components (name, "A" | "B", standard uncertainty in the value's unit, already
    multiplied by its sensitivity coefficient); :meth:`from_budget` combines them in quadrature.
    ``decidable`` False: the value is stated but cannot be compared with its limit at this uncertainty
    (the criterion is NOT EVALUATED, zone "undecidable", the note says why).
    """

    value: float
    u: float = 0.0
    k: float = 2.0
    note: str = ""
    budget: tuple[tuple[str, str, float], ...] = ()
    decidable: bool = True

    @classmethod
    def from_budget(
        cls, value: float, budget: list[tuple[str, str, float]], *, k: float = 2.0, note: str = ""
    ) -> Measured:
        u = math.sqrt(sum(c[2] ** 2 for c in budget if math.isfinite(c[2])))
        return cls(value, u, k, note, tuple(budget))

    @property
    def expanded(self) -> float:
        return self.k * self.u if math.isfinite(self.u) else float("nan")


def acceptance_from_config(rig: dict[str, Any] | None) -> dict[str, Any]:
    """Limits and settings from ``rig["criteria"]`` merged over the defaults; unknown keys raise."""
    table = dict((rig or {}).get("criteria") or {})
    allowed = set(DEFAULT_LIMITS) | set(DEFAULT_SETTINGS)
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise CriteriaError(f"criteria: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    out: dict[str, Any] = {**DEFAULT_LIMITS, **DEFAULT_SETTINGS}
    for key, value in table.items():
        if key == "decision_rule":
            if value not in DECISION_RULES:
                raise CriteriaError(
                    f"criteria.decision_rule must be one of {sorted(DECISION_RULES)}, got {value!r}"
                )
            out[key] = value
            continue
        if value is None and out.get(key, 0) is None:  # an optional limit or setting left unset
            continue
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
            or value < 0
        ):
            raise CriteriaError(f"criteria.{key} must be a finite number ≥ 0, got {value!r}")
        out[key] = float(value)
    for key in ("frequency_bin_hz", "identification_gate_mm", "amplitude_error_pct"):
        if not out[key] > 0:
            raise CriteriaError(f"criteria.{key} must be > 0, got {out[key]!r}")
    return out


def decide(value: float, expanded_u: float, limit: float, comparison: str, rule: str) -> tuple[str, str]:
    """Return (status, zone) for one criterion; status PASS | FAIL | NOT EVALUATED.

    zone: "conforming" (the whole interval is accepted), "non-conforming" (the whole interval is rejected),
    "indeterminate" (the interval straddles or touches the limit from the wrong side).
    """
    if comparison not in ("<=", ">="):
        raise CriteriaError(f"comparison must be '<=' or '>=', got {comparison!r}")
    if rule not in DECISION_RULES:
        raise CriteriaError(f"decision rule must be one of {sorted(DECISION_RULES)}, got {rule!r}")
    if value is None or not math.isfinite(value):
        return "NOT EVALUATED", "no data"
    U = expanded_u if expanded_u is not None and math.isfinite(expanded_u) else 0.0
    sign = 1.0 if comparison == "<=" else -1.0
    worst, best = sign * value + U, sign * value - U  # in "≤" orientation
    if worst <= sign * limit:
        zone = "conforming"
    elif best > sign * limit:
        zone = "non-conforming"
    else:
        zone = "indeterminate"
    accepted = zone == "conforming" if rule == "guarded" else sign * value <= sign * limit
    return ("PASS" if accepted else "FAIL"), zone


def beyond_resolution(expanded_u: float, limit: float, comparison: str, zone: str) -> bool:
    """Whether a "≤ limit" criterion (a magnitude ≥ 0) cannot be decided at this uncertainty: U ≥ limit, so
    no measured value could demonstrate conformance, and the value is not demonstrably over the limit either
    (zone "non-conforming" stays FAIL); an exact value (U = 0) is always decided. Such a criterion is stated
    but NOT EVALUATED, under either rule."""
    return (comparison == "<=" and math.isfinite(expanded_u) and expanded_u > 0.0 and expanded_u >= limit
            and zone != "non-conforming")


def evaluate(measured: dict[str, Measured | None], acceptance: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per criterion of :data:`CRITERIA` (in order) whose limit is set (a limit None: not required
    by this rig, no row); ``measured`` misses or None → NOT EVALUATED."""
    unknown = sorted(set(measured) - set(CRITERION_IDS))
    if unknown:
        raise CriteriaError(f"measured: unknown criterion id(s) {unknown}; known: {list(CRITERION_IDS)}")
    rule = acceptance["decision_rule"]
    rows = []
    for spec in CRITERIA:
        if acceptance.get(spec.id) is None:
            continue
        m = measured.get(spec.id)
        limit = float(acceptance[spec.id])
        value = m.value if m is not None else float("nan")
        U = m.expanded if m is not None else float("nan")
        status, zone = decide(value, U, limit, spec.comparison, rule)
        note = m.note if m is not None else "no data in this run"
        if m is not None and not m.decidable:
            status, zone = "NOT EVALUATED", "undecidable"
        elif beyond_resolution(U, limit, spec.comparison, zone):
            status, zone = "NOT EVALUATED", "undecidable"
            note += f"; cannot be decided: U = {U:.3g} reaches the limit {limit:g}"
        rows.append(
            {
                "id": spec.id,
                "description": spec.description,
                "unit": spec.unit,
                "comparison": spec.comparison,
                "limit": limit,
                "value": value,
                "expanded_uncertainty": U,
                "coverage_factor": m.k if m is not None else float("nan"),
                "status": status,
                "zone": zone,
                "note": note,
                "budget": [{"component": c[0], "type": c[1], "u": c[2]} for c in (m.budget if m else ())],
            }
        )
    return rows


def overall_result(rows: list[dict[str, Any]], exit_status: str | None) -> str:
    """FAIL if any criterion fails; INCOMPLETE if one is not evaluated or the run aborted/failed; else PASS.

    ``exit_status`` None (no stop document yet) is not held against the result: the procedures build the
    report as the run's last step, before the runner writes ``stop``; a run killed earlier lacks data for
    some criterion and is INCOMPLETE through it.
    """
    statuses = [r["status"] for r in rows]
    if "FAIL" in statuses:
        return "FAIL"
    if "NOT EVALUATED" in statuses or exit_status not in ("success", None):
        return "INCOMPLETE"
    return "PASS"


SIMULATED_NOTE = "simulated rig — not a certificate of hardware"


def is_simulated(rig: dict[str, Any] | None) -> bool:
    """True when the run's rig snapshot is a simulated station or films with simulated cameras.

    A station that reaches standalone mock servers (``rig mock …``) through ordinary addresses cannot be
    told from a bench by its configuration; its ``station.simulated`` is false, and so is this.
    """
    rig = rig or {}
    station = s if isinstance(s := rig.get("station"), dict) else {}
    cameras = c if isinstance(c := rig.get("cameras"), dict) else {}
    sim_camera = any(isinstance(c, dict) and c.get("driver") == "sim" for c in cameras.values())
    return bool(station.get("simulated")) or sim_camera


def build_certificate(
    measured: dict[str, Measured | None],
    acceptance: dict[str, Any],
    conditions: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The certificate document (plain JSON types; NaN left as float, turned into null when written)."""
    rows = evaluate(measured, acceptance)
    rule = acceptance["decision_rule"]
    simulated = is_simulated(conditions.get("rig"))
    return {
        "certificate_version": 1,
        "result": overall_result(rows, conditions.get("exit_status")),
        "simulated": simulated,
        **({"simulated_note": SIMULATED_NOTE} if simulated else {}),
        "run_id": conditions.get("run_id"),
        "date_utc": conditions.get("date_utc"),
        "decision_rule": {"name": rule, "text": DECISION_RULES[rule], "coverage_factor_default": 2.0},
        "criteria": rows,
        "criteria_settings": {k: acceptance[k] for k in sorted(acceptance)},
        "conditions": conditions,
        **(extra or {}),
    }

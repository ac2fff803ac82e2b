"""Certificate decisions at the boundaries, with uncertainty, under both decision rules; configuration."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reports.certificate import (
    CRITERION_IDS,
    DEFAULT_LIMITS,
    Measured,
    acceptance_from_config,
    build_certificate,
    decide,
    evaluate,
    is_simulated,
    overall_result,
)
from reports.errors import CriteriaError

# binary-exact values so "just inside" and "touching" are exact
U = 0.25
LIMIT = 1.0


@pytest.mark.parametrize(
    ("value", "guarded", "simple", "zone"),
    [
        (0.5, "PASS", "PASS", "conforming"),  # far inside
        (0.75, "PASS", "PASS", "conforming"),  # value + U touches the limit: still demonstrated
        (0.875, "FAIL", "PASS", "indeterminate"),  # inside, but the interval straddles the limit
        (1.0, "FAIL", "PASS", "indeterminate"),  # on the limit
        (1.125, "FAIL", "FAIL", "indeterminate"),  # just outside, interval straddles
        (1.25, "FAIL", "FAIL", "indeterminate"),  # value − U touches the limit
        (1.5, "FAIL", "FAIL", "non-conforming"),  # far outside
    ],
)
def test_upper_limit_boundaries(value: float, guarded: str, simple: str, zone: str) -> None:
    assert decide(value, U, LIMIT, "<=", "guarded") == (guarded, zone)
    assert decide(value, U, LIMIT, "<=", "simple") == (simple, zone)


@pytest.mark.parametrize(
    ("value", "guarded", "simple", "zone"),
    [
        (20.5, "PASS", "PASS", "conforming"),  # 20.5 − 0.5 = 20 touches the lower limit
        (20.25, "FAIL", "PASS", "indeterminate"),
        (19.75, "FAIL", "FAIL", "indeterminate"),
        (19.25, "FAIL", "FAIL", "non-conforming"),
    ],
)
def test_lower_limit_boundaries(value: float, guarded: str, simple: str, zone: str) -> None:
    assert decide(value, 0.5, 20.0, ">=", "guarded") == (guarded, zone)
    assert decide(value, 0.5, 20.0, ">=", "simple") == (simple, zone)


def test_without_uncertainty_both_rules_agree_at_the_limit() -> None:
    assert decide(1.0, 0.0, 1.0, "<=", "guarded") == ("PASS", "conforming")
    assert decide(1.0 + 2**-40, 0.0, 1.0, "<=", "guarded") == ("FAIL", "non-conforming")


def test_missing_value_is_not_evaluated() -> None:
    assert decide(float("nan"), 0.1, 1.0, "<=", "guarded") == ("NOT EVALUATED", "no data")


def test_expanded_uncertainty_uses_the_coverage_factor() -> None:
    acc = acceptance_from_config({"criteria": {"position_max_mm": 1.0}})
    # u = 0.125, k = 2 → U = 0.25: 0.75 passes, 0.875 does not (guarded)
    rows = {r["id"]: r for r in evaluate({"position_max_mm": Measured(0.75, 0.125)}, acc)}
    assert rows["position_max_mm"]["expanded_uncertainty"] == 0.25
    assert rows["position_max_mm"]["status"] == "PASS"
    rows = {r["id"]: r for r in evaluate({"position_max_mm": Measured(0.875, 0.125)}, acc)}
    assert rows["position_max_mm"]["status"] == "FAIL"
    assert rows["position_max_mm"]["zone"] == "indeterminate"
    # k from Student's t widens U
    rows = {r["id"]: r for r in evaluate({"position_max_mm": Measured(0.75, 0.125, k=2.2)}, acc)}
    assert rows["position_max_mm"]["status"] == "FAIL"


def test_simple_rule_from_the_configuration() -> None:
    acc = acceptance_from_config({"criteria": {"decision_rule": "simple", "position_max_mm": 1.0}})
    rows = {r["id"]: r for r in evaluate({"position_max_mm": Measured(0.875, 0.125)}, acc)}
    assert rows["position_max_mm"]["status"] == "PASS"
    assert rows["position_max_mm"]["zone"] == "indeterminate"


def test_defaults_and_derived_settings() -> None:
    acc = acceptance_from_config({})
    for key, value in DEFAULT_LIMITS.items():
        assert acc[key] == value
    assert acc["decision_rule"] == "guarded"
    assert acc["amplitude_error_up_to_hz"] == 10.0 and acc["reference_u_mm"] == 0.02
    acc = acceptance_from_config({"criteria": {"min_usable_frequency_hz": 12, "amplitude_error_up_to_hz": 8}})
    assert acc["min_usable_frequency_hz"] == 12.0 and acc["amplitude_error_up_to_hz"] == 8.0


def test_defaults_match_the_rig_configuration() -> None:
    """The limits the reports assume are the same as rig.config.rig_config's [criteria] defaults and keys."""
    import dataclasses

    from rig.config.criteria import CriteriaConfig

    config_defaults = {f.name: f.default for f in dataclasses.fields(CriteriaConfig)}
    for key, value in config_defaults.items():
        assert key in DEFAULT_LIMITS or key in acceptance_from_config({}), key
        assert acceptance_from_config({})[key] == value, key


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ({"position_error_max": 1.0}, "unknown key"),
        ({"position_max_mm": -1.0}, "position_max_mm"),
        ({"position_max_mm": "1 mm"}, "position_max_mm"),
        ({"position_max_mm": True}, "position_max_mm"),
        ({"decision_rule": "optimistic"}, "decision_rule"),
        ({"frequency_bin_hz": 0.0}, "frequency_bin_hz"),
    ],
)
def test_bad_configuration_raises(table: dict, match: str) -> None:
    with pytest.raises(CriteriaError, match=match):
        acceptance_from_config({"criteria": table})


def test_overall_result() -> None:
    acc = acceptance_from_config({})
    good = {cid: Measured(0.0, 0.0) for cid in CRITERION_IDS}
    good["detection_pct"] = Measured(100.0)
    good["min_usable_frequency_hz"] = Measured(30.0)
    rows = evaluate(good, acc)
    assert overall_result(rows, "success") == "PASS"
    assert overall_result(rows, "abort") == "INCOMPLETE"
    assert overall_result(rows, "fail") == "INCOMPLETE"
    assert overall_result(rows, None) == "PASS"  # report built as the run's last step, before `stop`
    partial = dict(good)
    partial["radius_error_mm"] = None
    assert overall_result(evaluate(partial, acc), "success") == "INCOMPLETE"
    bad = dict(partial, position_max_mm=Measured(5.0))
    assert overall_result(evaluate(bad, acc), "success") == "FAIL"


def test_certificate_states_rule_and_conditions() -> None:
    acc = acceptance_from_config({})
    cert = build_certificate(
        {}, acc, {"run_id": "r1", "date_utc": "2026-11-21T23:15:00+00:00", "exit_status": "success"}
    )
    assert cert["run_id"] == "r1" and cert["date_utc"].startswith("2026")
    assert "ILAC-G8" in cert["decision_rule"]["text"]
    # the band and step criteria are required only when [criteria] sets them (a rig without a shaker)
    assert [r["id"] for r in cert["criteria"]] == [c for c in CRITERION_IDS
                                                   if not c.startswith(("band_", "step_"))]
    assert cert["result"] == "INCOMPLETE"
    acc = acceptance_from_config({"criteria": {"band_min_hz": 45.0}})
    rows = {r["id"]: r for r in build_certificate({}, acc, {"exit_status": "success"})["criteria"]}
    assert rows["band_min_hz"]["status"] == "NOT EVALUATED" and "band_phase_deg" not in rows


@pytest.mark.parametrize(
    ("rig", "simulated"),
    [
        ({"station": {"simulated": True}}, True),
        ({"station": {"simulated": False}, "cameras": {"left": {"driver": "sim"}}}, True),
        ({"station": {"simulated": False}, "cameras": {"left": {"driver": "opencv"}}}, False),
        (None, False),
    ],
)
def test_a_simulated_run_says_so_at_the_top_of_its_certificate(rig: dict | None, simulated: bool) -> None:
    cert = build_certificate({}, acceptance_from_config({}), {"run_id": "r1", "rig": rig})
    assert is_simulated(rig) is simulated
    assert cert["simulated"] is simulated
    assert ("simulated_note" in cert) is simulated
    if simulated:
        assert "not a certificate of hardware" in cert["simulated_note"]


def test_unknown_measured_id_raises() -> None:
    with pytest.raises(CriteriaError, match="unknown criterion"):
        evaluate({"speed_mm_s": Measured(1.0)}, acceptance_from_config({}))


@settings(max_examples=200, deadline=None)
@given(
    value=st.floats(0, 10),
    u_small=st.floats(0, 2),
    extra=st.floats(0, 2),
    limit=st.floats(0.01, 10),
    comparison=st.sampled_from(["<=", ">="]),
)
def test_guarded_is_never_more_lenient_than_simple_and_more_uncertainty_never_helps(
    value: float, u_small: float, extra: float, limit: float, comparison: str
) -> None:
    guarded_small = decide(value, u_small, limit, comparison, "guarded")[0]
    guarded_large = decide(value, u_small + extra, limit, comparison, "guarded")[0]
    simple = decide(value, u_small, limit, comparison, "simple")[0]
    if guarded_small == "PASS":
        assert simple == "PASS"
    if guarded_large == "PASS":
        assert guarded_small == "PASS"

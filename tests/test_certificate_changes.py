"""changes.json of a revision: exactly the criteria whose value or decision differ from the issued ones."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from reports.build import certificate_changes

IDS = ("position_max_mm", "amplitude_error_pct", "min_usable_frequency_hz", "radius_error_mm")
ROW = st.fixed_dictionaries({
    "value": st.one_of(st.none(), st.floats(-1e6, 1e6, allow_nan=False)),
    "status": st.sampled_from(["PASS", "FAIL", "NOT EVALUATED"]),
    "unit": st.sampled_from(["mm", "%", "Hz"]),
})
CERT = st.dictionaries(st.sampled_from(IDS), ROW).map(
    lambda rows: {"result": "PASS", "criteria": [{"id": k, **v} for k, v in rows.items()]})


@given(CERT, CERT)
def test_changes_list_exactly_the_criteria_that_differ(issued: dict, revised: dict) -> None:
    changes = certificate_changes(issued, revised, revision=1, sync="linear")
    before = {r["id"]: (r["value"], r["status"]) for r in issued["criteria"]}
    after = {r["id"]: (r["value"], r["status"]) for r in revised["criteria"]}
    none = (None, None)
    differ = {i for i in set(before) | set(after) if before.get(i, none) != after.get(i, none)}
    assert {c["id"] for c in changes["criteria"]} == differ
    assert len(changes["summary"]) == 1 + len(differ)
    for c in changes["criteria"]:
        assert (c["issued_value"], c["issued_status"]) == before.get(c["id"], (None, None))
        assert (c["revised_value"], c["revised_status"]) == after.get(c["id"], (None, None))


@given(CERT)
def test_a_revision_equal_to_the_issued_certificate_changes_nothing(issued: dict) -> None:
    changes = certificate_changes(issued, issued, revision=3, sync="trajectory")
    assert changes["criteria"] == [] and changes["summary"] == ["result PASS (same)"]
    assert changes["revision"] == 3 and changes["issued_result"] == changes["revised_result"] == "PASS"

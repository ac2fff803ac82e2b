"""The shaker band step's per-bin table, edge and criteria (reports/band_phase.py) on synthetic bins."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reports.band import BAND_COLUMNS
from reports.band_phase import band_edge, extended_band, measured_values, per_bin, section

SWEEP = {"profile": [[100.0, 27.0], [109.0, 50.0]], "amplitude_mm": 2.0, "t_start_s": 101.6,
         "t_stop_s": 109.0, "body": "shaker", "phase_origin": "PHASe:SYNChronize of the timing fiducial",
         "phase_origin_s": [99.9, 100.1]}


def _bins(phases_deg: dict[int, list[float]], errors_pct: float = 0.05, refused: dict[int, str] | None = None,
          ) -> pd.DataFrame:
    rows = []
    for b, phases in phases_deg.items():
        for k, p in enumerate(phases):
            rows.append({"track": f"m{k}", "bin": b, "frequency_lo_hz": float(b), "frequency_hi_hz": b + 1.0,
                         "frequency_hz": b + 0.5, "n_observations": 60, "alpha_frames": 0.5,
                         "amplitude_ref_mm": 2.0, "amplitude_meas_mm": 2.0 * (1 + errors_pct / 100),
                         "u_amplitude_mm": 0.001, "amplitude_error_pct": errors_pct,
                         "u_amplitude_error_pct": 0.05, "alias_dchi2": math.inf,
                         "refused": (refused or {}).get(b, ""), "phase_deg": p, "u_phase_deg": 0.03})
    return pd.DataFrame(rows, columns=BAND_COLUMNS)


def test_phases_are_averaged_on_the_circle_and_the_clock_enters_the_budget() -> None:
    table = per_bin(_bins({40: [179.0, -179.0], 41: [0.5, 0.7]}), u_clock_s=5e-6)
    assert abs(abs(table["phase_deg"].iloc[0]) - 180.0) < 1e-9  # not 0: ±179° are 2° apart
    assert table["phase_deg"].iloc[1] == pytest.approx(0.6)
    assert table["u_phase_deg"].iloc[1] == pytest.approx(math.hypot(0.03, 360.0 * 41.5 * 5e-6))
    assert table["delay_ms"].iloc[1] == pytest.approx(-0.6 / (360.0 * 41.5) * 1000.0)


@settings(max_examples=60, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(0.0, 1e-4))
def test_delay_and_phase_agree_at_every_bin(phase_deg: float, u_clock_s: float) -> None:
    table = per_bin(_bins({b: [phase_deg] for b in range(30, 50, 4)}), u_clock_s=u_clock_s)
    f = table["frequency_hz"].to_numpy()
    np.testing.assert_allclose(-table["delay_ms"] * 360.0 * f / 1000.0, phase_deg, atol=1e-9)
    np.testing.assert_allclose(table["u_delay_ms"] * 360.0 * f / 1000.0, table["u_phase_deg"], rtol=1e-12)


def test_the_edge_ends_at_the_first_bin_failing_amplitude_phase_or_refused() -> None:
    bins = _bins({b: [0.1, 0.1] for b in range(30, 50)})
    assert band_edge(per_bin(bins, 0.0), 5.0, 2.0, 2.0)[1] == 50.0
    bins.loc[bins["bin"] == 45, "phase_deg"] = 1.95  # + 2u > 2°: guarded rule fails, simple passes
    start, edge, why = band_edge(per_bin(bins, 0.0), 5.0, 2.0, 2.0)
    assert (start, edge) == (30.0, 45.0) and "45.5 Hz |phase|" in why
    assert band_edge(per_bin(bins, 0.0), 5.0, 2.0, 0.0)[1] == 50.0
    assert band_edge(per_bin(bins, 0.0), 5.0, None, 2.0)[1] == 50.0  # no phase limit configured
    refused = per_bin(_bins({b: [0.1] for b in range(30, 50)}, refused={33: "alias"}), 0.0)
    assert band_edge(refused, 5.0, 2.0, 2.0)[1:] == (33.0, "the bin at 33.5 Hz is refused: alias")


def test_the_criteria_take_the_worst_bin_and_the_section_states_the_reference() -> None:
    bins = _bins({b: [0.2 + 0.01 * b] for b in range(30, 50)}, errors_pct=-0.3)
    ext = extended_band(bins, SWEEP, u_clock_s=4e-6, clock_source="timing fiducial: 40 edges",
                        acceptance={"band_amplitude_error_pct": 5.0, "band_phase_deg": 2.0,
                                    "decision_rule": "guarded"})
    m = measured_values(ext)
    assert m["band_amplitude_error_pct"].value == pytest.approx(0.3)
    assert m["band_phase_deg"].value == pytest.approx(0.2 + 0.49)
    components = {c[0]: c[2] for c in m["band_phase_deg"].budget}
    assert components["controller↔camera clock"] == pytest.approx(360.0 * 49.5 * 4e-6)
    assert m["band_min_hz"].value == 50.0 and "highest frequency swept" in m["band_min_hz"].note
    doc = section(ext)
    assert doc is not None and doc["sweep_hz"] == [27.0, 50.0] and doc["certified_to_hz"] == 50.0
    assert "generator's own linear sweep" in doc["reference"] and len(doc["bins"]) == 20
    assert measured_values(None) == {} and section(None) is None

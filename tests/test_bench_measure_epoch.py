"""benchmarks/measure.py: the estimated offset is compared with the truth at the estimate's own epoch."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from rig.stereo.timing_model import corrected_times

_SPEC = importlib.util.spec_from_file_location(
    "bench_measure", Path(__file__).resolve().parents[1] / "benchmarks" / "measure.py")
assert _SPEC is not None and _SPEC.loader is not None
bench = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(bench)  # benchmarks/measure.py, not on the import path

TRUTH = {"offset_s": {"left": 0.0, "right": 0.16229}, "drift_ppm": {"left": 0.0, "right": -47.0},
         "epoch_s": {"left": 0.0, "right": 0.0}}


def test_the_truth_restated_at_another_epoch_maps_every_instant_alike() -> None:
    epoch_s = 9.983
    offset_s = bench.offset_at_epoch_s(TRUTH, "right", epoch_s)
    tau = np.linspace(0.0, 20.0, 7)
    at_zero = corrected_times(tau, np.zeros(7), offset_s=0.16229, drift_ppm=-47.0, epoch_s=0.0)
    restated = corrected_times(tau, np.zeros(7), offset_s=offset_s, drift_ppm=-47.0, epoch_s=epoch_s)
    np.testing.assert_allclose(restated, at_zero, rtol=0, atol=1e-12)
    assert offset_s == pytest.approx(0.16229 - 47e-6 * epoch_s, abs=1e-12)  # 0.47 ms apart


def test_an_exact_estimate_at_its_own_epoch_shows_no_error() -> None:
    epoch_s = 9.983
    estimate = {"offset_s": {"right": bench.offset_at_epoch_s(TRUTH, "right", epoch_s)},
                "drift_ppm": {"right": -47.0}, "epoch_s": {"right": epoch_s},
                "uncertainty": {"offset_s": {"right": 37e-6}}}
    assert "error +0.0000 ms = +0.00 σ (σ 0.0370 ms)" in bench.offset_error(estimate, TRUTH, "right")
    estimate["offset_s"]["right"] += 74e-6
    assert "error +0.0740 ms = +2.00 σ" in bench.offset_error(estimate, TRUTH, "right")

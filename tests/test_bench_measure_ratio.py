"""benchmarks/measure.py: the ratio's bracketed runs and the distribution-free interval of their median."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

_SPEC = importlib.util.spec_from_file_location(
    "bench_measure_ratio", Path(__file__).resolve().parents[1] / "benchmarks" / "measure.py")
assert _SPEC is not None and _SPEC.loader is not None
bench = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(bench)  # benchmarks/measure.py, not on the import path


def test_the_interval_is_the_textbook_order_statistics() -> None:
    values = [float(v) for v in range(10, 0, -1)]  # 1 … 10, unordered
    low, high, coverage = bench.median_interval(values)
    assert (low, high) == (2.0, 9.0)  # n = 10: x(2), x(9), coverage 1 − 2·11/1024
    assert coverage == 1.0 - 22.0 / 1024.0
    assert bench.median_interval(values[:6])[:2] == (5.0, 10.0)  # n = 6: (min, max), 1 − 2/64 = 0.969
    assert bench.median_interval(values[:5]) is None  # n = 5: (min, max) covers only 0.9375


@pytest.mark.parametrize("n", range(6, 16))
def test_the_interval_covers_the_median_as_often_as_it_states(n: int) -> None:
    """Drawn from a skewed distribution whose median is known (lognormal: e^μ), the interval holds the true
    median in a share of 4,000 seeded samples within 4 binomial σ of its stated coverage (≥ 0.95; seeded,
    not hypothesis-drawn: a statistical bound must not fail one random run in a few hundred)."""
    rng = np.random.default_rng(1000 + n)
    mu = 0.25
    samples = rng.lognormal(mu, 0.3, size=(4000, n))
    ordered = np.sort(samples, axis=1)
    low, high, stated = bench.median_interval(list(samples[0]))
    k = int(np.flatnonzero(ordered[0] == low)[0])  # order statistics k and n − 1 − k (0-based)
    assert high == ordered[0, n - 1 - k]
    held = (ordered[:, k] <= math.exp(mu)) & (ordered[:, n - 1 - k] >= math.exp(mu))
    sigma = math.sqrt(stated * (1 - stated) / len(held))
    assert stated >= 0.95
    assert abs(held.mean() - stated) <= 4 * sigma


def test_each_measure_run_is_compared_with_its_own_two_decode_runs() -> None:
    """A machine slowing down linearly: the bracketed ratio is the true one, a decode run is never shared."""
    clock = {"t": 0}

    def speed() -> float:
        clock["t"] += 1
        return 1.0 + 0.1 * clock["t"]  # each run 10 % slower than the one before

    calls: list[str] = []

    def decode() -> float:
        calls.append("d")
        return 10.0 * speed()

    def measure() -> tuple[float, float, object]:
        calls.append("m")
        return 13.0 * speed(), 0.0, object()

    ratios, runs = bench.bracketed_ratios(3, decode, measure)
    assert calls == ["d", "m", "d"] * 3
    assert len(runs) == 3
    np.testing.assert_allclose(ratios, 1.3, rtol=1e-12)


def test_the_verdict_needs_the_whole_interval_on_one_side() -> None:
    assert bench.ratio_verdict([1.1, 1.2, 1.15, 1.25, 1.22, 1.18], 1.3).endswith("met")
    assert bench.ratio_verdict([1.4, 1.5, 1.35, 1.45, 1.38, 1.42], 1.3).endswith("missed")
    assert bench.ratio_verdict([1.1, 1.2, 1.25, 1.35, 1.4, 1.28], 1.3).endswith("not shown")
    assert "needs ≥ 6" in bench.ratio_verdict([1.1, 1.2], 1.3)

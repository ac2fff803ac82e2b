"""rig.stereo.fiducial: ramp-model levels, and the camera clock fitted from LED rows against known edges."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from rig.stereo.errors import AmbiguousOffsetError, InputArrayError, NoCommonMotionError, TooFewSamplesError
from rig.stereo.fiducial import DriveEdges, RowSamples, fit_fiducial_clock, mean_levels, row_profile

FPS, HEIGHT = 60.0, 1080
LINE_S = 0.9 / FPS / HEIGHT
EXPOSURE_S = 1 / 6000
# incommensurate with the frame period, so that edges walk through the frame and cross the LED's rows
PULSE_PERIOD_S = 0.0973


def square_edges(first_s: float, period_s: float, n: int, u_s: float = 0.0) -> DriveEdges:
    t = first_s + 0.5 * period_s * np.arange(n)
    return DriveEdges(t, np.arange(n) % 2 == 0, u_s)


def led_rows(seconds: float, rows: tuple[int, int] = (400, 520)) -> np.ndarray:
    """Camera-clock exposure starts of the LED's rows in every frame (frame k stamped k/fps)."""
    k = np.arange(int(seconds * FPS))
    return (k[:, None] / FPS + np.arange(*rows)[None, :] * LINE_S).ravel()


def brute_levels(start_s: np.ndarray, exposure_s: float, edges: DriveEdges, rise_s: float) -> np.ndarray:
    """The same mean level by sampling the ramp waveform densely (midpoint rule, 4000 samples)."""
    tau = start_s[:, None] + (np.arange(4000) + 0.5)[None, :] / 4000 * exposure_s
    level = np.full(tau.shape, edges.initial_level)
    for e, sign in zip(edges.times_s, edges.signs, strict=True):
        with np.errstate(over="ignore"):  # a subnormal rise divides to ±inf: clipped, the step it is
            ramp = np.clip((tau - e) / rise_s, 0, 1) if rise_s > 0 else (tau >= e).astype(float)
        level += sign * ramp
    return level.mean(axis=1)


def numpy_levels(start_s: np.ndarray, exposure_s: float, edges: DriveEdges, rise_s: float) -> np.ndarray:
    """The mean levels in numpy, as rig.stereo.fiducial computed them before its compiled walk along the
    edges (the same operations in the same order: the reference its kernel must equal to the bit)."""
    def ramp_integral(x: np.ndarray) -> np.ndarray:
        if rise_s <= 0:
            return np.maximum(x, 0.0)
        rising = np.clip(x, 0.0, rise_s)
        return np.where(x <= 0, 0.0, np.where(x < rise_s, 0.5 * rising * rising / rise_s, x - 0.5 * rise_s))

    e, sign = edges.times_s, edges.signs
    lo = np.searchsorted(e, start_s - rise_s, side="left")  # edges before lo are complete
    hi = np.searchsorted(e, start_s + exposure_s, side="left")  # edges from hi on have not begun
    level = edges.states[lo].astype(float)
    span = hi - lo
    for j in range(int(span.max()) if span.size else 0):
        sel = np.nonzero(span > j)[0]
        k = lo[sel] + j
        x_end, x_start = start_s[sel] + exposure_s - e[k], start_s[sel] - e[k]
        level[sel] += sign[k] * (ramp_integral(x_end) - ramp_integral(x_start)) / exposure_s
    return level


@settings(max_examples=40, deadline=None)
@given(first=st.floats(0.0, 0.01), period=st.floats(2e-3, 0.05), rise=st.floats(0.0, 2e-4),
       exposure=st.floats(2e-5, 2e-3), starts=st.lists(st.floats(-0.01, 0.1), min_size=1, max_size=30))
def test_mean_levels_match_the_sampled_ramp_waveform(first: float, period: float, rise: float,
                                                      exposure: float, starts: list[float]) -> None:
    edges = square_edges(first, period, 8)
    s = np.array(starts)
    got = mean_levels(s, exposure, edges, rise)
    assert np.all(got >= -1e-12) and np.all(got <= 1 + 1e-12)
    assert np.allclose(got, brute_levels(s, exposure, edges, rise), atol=2e-3)


def synthetic_brightness(start_s: np.ndarray, edges: DriveEdges, *, offset_s: float, rate: float,
                         t_ref_s: float, time_constant_s: float, noise_dn: float, seed: int) -> np.ndarray:
    """LED rows as a first-order (exponential) rise renders them, not the fit's ramp, plus read noise."""
    tc = start_s + offset_s + rate * (start_s - t_ref_s)

    def light(x: np.ndarray) -> np.ndarray:  # ∫ (1 − e^(−u/T)) du from 0 to x, 0 before the edge
        xp = np.maximum(x, 0.0)
        return np.where(x > 0, xp - time_constant_s * -np.expm1(-xp / time_constant_s), 0.0)

    level = np.full(tc.shape, edges.initial_level)
    for e, sign in zip(edges.times_s, edges.signs, strict=True):
        level += sign * (light(tc + EXPOSURE_S - e) - light(tc - e)) / EXPOSURE_S
    return 30.0 + 180.0 * level + np.random.default_rng(seed).normal(0.0, noise_dn, tc.size)


@settings(max_examples=12, deadline=None, phases=[Phase.explicit, Phase.generate])
@given(offset=st.floats(-0.008, 0.008), prior_error=st.floats(-0.008, 0.008), first=st.floats(0.0, 0.05),
       ppm=st.floats(-60.0, 60.0), tc=st.floats(1e-6, 2e-5), seed=st.integers(0, 2**16))
def test_fit_recovers_the_offset_within_its_uncertainty(  # noqa: PLR0917 (hypothesis draws)
        offset: float, prior_error: float, first: float, ppm: float, tc: float, seed: int) -> None:
    s = led_rows(6.0)
    edges = square_edges(first - 0.2, PULSE_PERIOD_S, 140)
    t_ref = float(np.median(s))
    b = synthetic_brightness(s, edges, offset_s=offset, rate=ppm * 1e-6, t_ref_s=t_ref, time_constant_s=tc,
                             noise_dn=0.5, seed=seed)
    # the LED's datasheet rise time (10–90 %) of a first-order rise: 2.2 time constants
    fit = fit_fiducial_clock(RowSamples(s, b, EXPOSURE_S), edges, prior_offset_s=offset + prior_error,
                             prior_half_width_s=0.0085, rise_time_s=2.2 * tc, t_ref_s=t_ref)
    assert fit.rate_fitted and fit.n_edges_seen >= 2
    assert abs(fit.offset_s - offset) <= 3.0 * fit.u_offset_s
    assert abs(fit.rate - ppm * 1e-6) <= 5.0 * fit.u_rate + 1e-9
    assert fit.u_offset_s < 2e-5  # the target is 5e-5 s; the fit alone is far inside it
    # the residual is the noise rendered, plus the ramp's misfit of the first-order rise
    assert 0.45 < fit.residual_dn < 1.0


def test_edge_knowledge_enters_the_uncertainty() -> None:
    s = led_rows(3.0)
    edges = square_edges(0.013, PULSE_PERIOD_S, 80, u_s=3e-5)
    b = synthetic_brightness(s, edges, offset_s=0.002, rate=0.0, t_ref_s=1.5, time_constant_s=5e-6,
                             noise_dn=0.5, seed=1)
    fit = fit_fiducial_clock(RowSamples(s, b, EXPOSURE_S), edges, prior_offset_s=0.0,
                             prior_half_width_s=0.0085)
    assert fit.u_offset_s >= 3e-5 > fit.u_fit_s
    assert not fit.rate_fitted or fit.n_edges_seen >= 2


def test_a_pattern_repeating_within_the_prior_is_refused_with_the_reason() -> None:
    s = led_rows(1.0)
    edges = square_edges(0.0, 0.01, 200)  # repeats every 10 ms: a ±8.5 ms prior cannot tell which edge
    with pytest.raises(AmbiguousOffsetError, match=r"repeats every 10\.000 ms"):
        fit_fiducial_clock(RowSamples(s, np.zeros(s.size), EXPOSURE_S), edges, prior_offset_s=0.0,
                           prior_half_width_s=0.0085)


def test_no_edge_in_the_recording_is_refused() -> None:
    s = led_rows(1.0)
    edges = square_edges(50.0, 0.1, 4)  # all edges long after the recording
    with pytest.raises(NoCommonMotionError, match="no drive edge"):
        fit_fiducial_clock(RowSamples(s, 30 + np.random.default_rng(0).normal(0, 1, s.size), EXPOSURE_S),
                           edges, prior_offset_s=0.0, prior_half_width_s=0.0085)


def test_bad_inputs_name_the_field() -> None:
    with pytest.raises(InputArrayError, match="strictly increasing"):
        DriveEdges(np.array([0.0, 0.0]), np.array([True, False]))
    with pytest.raises(InputArrayError, match="exposure_s"):
        RowSamples(np.zeros(3), np.zeros(3), 0.0)
    with pytest.raises(TooFewSamplesError, match="≥ 8"):
        fit_fiducial_clock(RowSamples(np.zeros(3), np.zeros(3), 1e-4), square_edges(0, 0.1, 4),
                           prior_offset_s=0.0, prior_half_width_s=0.008)


def test_row_profile_is_the_row_mean_of_the_region_clipped_to_the_image() -> None:
    img = np.arange(20 * 30, dtype=np.uint8).reshape(20, 30)
    rows, mean = row_profile(img, (25, 18, 40, 25))
    assert rows.tolist() == [18, 19]
    assert np.allclose(mean, img[18:20, 25:30].mean(axis=1))
    with pytest.raises(InputArrayError, match="outside"):
        row_profile(img, (40, 0, 50, 5))


def test_a_wrong_line_time_in_the_row_instants_is_measured_and_corrected() -> None:
    """The rows' instants assume a line time 455 ns/row (3.3 %) short, as the joint timing model had it on
    rig certify; the LED's rows (400–520) measure the difference, and the offset at another row has it."""
    k = np.arange(int(6.0 * FPS))
    rows = np.tile(np.arange(400, 520), k.size).astype(float)
    true_start = (k[:, None] / FPS + np.arange(400, 520)[None, :] * LINE_S).ravel()
    assumed_start = true_start - 455e-9 * rows
    edges = square_edges(-0.2, PULSE_PERIOD_S, 140)
    b = synthetic_brightness(true_start, edges, offset_s=0.003, rate=0.0, t_ref_s=3.0, time_constant_s=5e-6,
                             noise_dn=0.5, seed=3)
    fit = fit_fiducial_clock(RowSamples(assumed_start, b, EXPOSURE_S, rows), edges, prior_offset_s=0.0,
                             prior_half_width_s=0.0085, rise_time_s=1.1e-5, t_ref_s=3.0)
    assert fit.line_time_fitted
    assert abs(fit.line_time_error_s - 455e-9) <= 5.0 * fit.u_line_time_error_s
    offset_row0, u_row0 = fit.offset_at_row_s(0.0)  # the instant of row 0 needs the whole correction
    assert abs(offset_row0 - 0.003) <= 3.0 * u_row0 < 2e-5


@pytest.mark.parametrize("seed", range(6))
def test_the_coarse_search_picks_the_node_a_lstsq_per_node_picks_refitting_only_the_nearest(
        seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The grid search (fiducial._grid_offset_s) ranks the offsets by the compiled residual sums and fits
    again only those within their rounding of the least; its choice is the node of the least residual of an
    affine lstsq fit at every node (ties: the first)."""
    from rig.stereo import fiducial

    rng = np.random.default_rng(seed)
    s = led_rows(2.0)
    edges = square_edges(0.01 * seed, PULSE_PERIOD_S, 60)
    offset = float(rng.uniform(-0.006, 0.006))
    b = synthetic_brightness(s, edges, offset_s=offset, rate=0.0, t_ref_s=1.0, time_constant_s=5e-6,
                             noise_dn=0.5 + seed, seed=seed)
    shuffled = rng.permutation(s.size)  # any row order
    rows = RowSamples(s[shuffled], b[shuffled], EXPOSURE_S)
    grid = offset + float(rng.uniform(-1e-3, 1e-3)) + np.arange(-0.0085, 0.0085 + 5e-4, 1e-3)
    sse = np.full(grid.size, np.inf)
    for i, off in enumerate(grid):  # the oracle: a level and a lstsq fit per node
        level = mean_levels(s + off, EXPOSURE_S, edges, 1e-5)
        if np.ptp(level) > 0:
            a = np.column_stack([np.ones_like(level), level])
            sse[i] = float(np.sum((b - a @ np.linalg.lstsq(a, b, rcond=None)[0]) ** 2))
    calls = []

    def counted(*args: object, **kwargs: object) -> np.ndarray:
        calls.append(1)
        return mean_levels(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(fiducial, "mean_levels", counted)
    assert fiducial._grid_offset_s(rows, edges, grid, 1e-5) == float(grid[int(np.argmin(sse))])
    assert 1 <= len(calls) < grid.size


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.0, 1e-6, 1e-5, 2e-4, 1e-3]),
       st.sampled_from([1e-4, EXPOSURE_S, 2e-3]), st.booleans())
def test_the_compiled_levels_are_the_numpy_forms_and_the_residual_sums_those_of_a_centred_fit(
        seed: int, rise_s: float, exposure_s: float, rising_first: bool) -> None:
    """fiducial_kernel: each row's level is the numpy form's to the bit, at any offset (rows before, between
    and after the edges, ramps inside and across exposures), through mean_levels too (rows in any order);
    each offset's residual sum of squares is the centred closed form's to 1e-9 (its sums run in another
    order)."""
    from rig.stereo.fiducial_kernel import grid_sse, levels

    rng = np.random.default_rng(seed)
    start = np.sort(rng.uniform(0.0, 0.5, int(rng.integers(2, 400))))
    times = np.cumsum(rng.uniform(1e-5, 0.05, int(rng.integers(1, 12))))
    rising = (np.arange(times.size) % 2 == 0) == rising_first
    edges = DriveEdges(times, rising)
    offsets = rng.uniform(-0.1, 0.1, 7)
    b = rng.normal(100.0, 20.0, start.size)
    got = grid_sse(start, b, exposure_s, edges.times_s, edges.signs, edges.states, rise_s, offsets)
    level = np.empty(start.size)
    shuffled = rng.permutation(start.size)
    for offset, sse in zip(offsets, got, strict=True):
        expected = numpy_levels(offset + start, exposure_s, edges, rise_s)
        levels(start, offset, exposure_s, edges.times_s, edges.signs, edges.states, rise_s, level)
        np.testing.assert_array_equal(level, expected)
        np.testing.assert_array_equal(mean_levels((offset + start)[shuffled], exposure_s, edges, rise_s),
                                      expected[shuffled])
        if not np.ptp(expected) > 0:
            assert sse == np.inf
            continue
        lc, bc = expected - expected.mean(), b - b.mean()
        reference = float(np.sum((bc - (lc @ bc) / (lc @ lc) * lc) ** 2))
        assert sse == pytest.approx(reference, rel=1e-9, abs=1e-9 * float(bc @ bc))


def test_the_ramp_integral_of_a_subnormal_rise_time_is_exact_and_silent() -> None:
    # the numpy form's np.where evaluated both branches: the quadratic of times far past a subnormal rise
    # overflowed (a RuntimeWarning in make test's random examples); the compiled form takes one branch
    from rig.stereo.fiducial_kernel import ramp_integral

    x = np.array([-1.0, 0.0, 1e-330, 1.0, 1e300])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.array_equal([ramp_integral(v, 5e-324) for v in x], [0.0, 0.0, 0.0, 1.0, 1e300])

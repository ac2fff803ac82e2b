"""The band beyond one camera's Nyquist limit (rig/stereo/band.py) on the twin's known truth.

Twin: the simulated rig's default pair (tests/timing_twin.py: exact centres at exact row times, lens
distortion off, σ = 0.1 px), the crank exciter's column marker at 4 mm, observed for 1 s (one 1 Hz bin of a
sweep at ~1 Hz/s), times on the world clock (the timing is not under test). The second camera's start is
set so that the instants the marker is seen at (rolling-shutter rows included) are α of a frame apart.
Tolerances come from the noise: the fit's own standard uncertainty (residual-scaled covariance), 4 u.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from timing_twin import TwinRecord, twin_record

from rig.stereo.band import MIN_ALIAS_SEPARATION, BinFit, fit_bin, instants_alpha, pair_band
from rig.stereo.errors import InputArrayError

CRANK_MM = 4.0
FS_HZ = 60.0
AXIS = (0.0, 0.0, 1.0)


def _record(f_hz: float, alpha: float, *, duration_s: float = 1.0, seed: int = 0,
            setup=None) -> TwinRecord:
    """The column marker at ``f_hz`` with the cameras' instants ``alpha`` of a frame apart."""
    setup = setup or (lambda w: w.exciter.set_frequency(0.0, f_hz))

    def make(offset_s: float) -> TwinRecord:
        return twin_record("sweep_column", "col2", sigma_px=0.1, duration_s=duration_s,
                           right_start_offset_s=offset_s, seed=seed, setup=setup)

    base = make(0.0)
    return make((alpha - instants_alpha(base.true_left, base.true_right, FS_HZ)) / FS_HZ)


def _fit(rec: TwinRecord, f_hz: float, *, direction=AXIS, identify: bool = True) -> BinFit:
    phase = [rec.world.exciter.phase_rad(rec.true_left), rec.world.exciter.phase_rad(rec.true_right)]
    band = pair_band(FS_HZ, instants_alpha(rec.true_left, rec.true_right, FS_HZ) / FS_HZ)
    return fit_bin([rec.P_left, rec.P_right], [rec.true_left, rec.true_right], [rec.uv_left, rec.uv_right],
                   phase, AXIS, f_ref_hz=f_hz, direction=direction, identify=band if identify else None)


@pytest.mark.parametrize(("f_hz", "target_pct"), [(40.0, 1.0), (50.0, 5.0)])
def test_half_a_frame_apart_meets_the_issue_targets(f_hz: float, target_pct: float) -> None:
    b = _fit(_record(f_hz, 0.5), f_hz)
    assert b.refused == ""
    assert b.alias_dchi2 > 25
    err = b.amplitude - CRANK_MM
    assert abs(err) <= 4 * b.u_amplitude  # unbiased within the noise
    assert 100 * (abs(err) + 2 * b.u_amplitude) / CRANK_MM <= target_pct
    assert 0 < b.u_amplitude < 0.01 * CRANK_MM  # 1 s of σ = 0.1 px: ≈ 0.2 %


def test_a_quarter_frame_apart_is_measured_beyond_nyquist() -> None:
    b = _fit(_record(45.0, 0.25), 45.0)
    assert b.refused == "" and abs(b.amplitude - CRANK_MM) <= 4 * b.u_amplitude


def test_coincident_instants_are_refused_above_one_cameras_nyquist_with_the_reason() -> None:
    rec = _record(40.0, 0.002)
    b = _fit(rec, 40.0)
    assert "instants coincide" in b.refused and "0.002" in b.refused
    assert np.isfinite(b.amplitude)  # the amplitude at the known frequency is still given
    below = _fit(_record(20.0, 0.002), 20.0)
    assert below.refused == ""  # below fs/2 one camera suffices (the motion assumed band-limited to fs/2)


def test_the_pair_carries_a_line_motion_through_fs_over_2_where_a_free_ellipse_is_undetermined() -> None:
    rec = _record(30.0, 0.5)
    line = _fit(rec, 30.0)
    free = _fit(rec, 30.0, direction=None)
    assert abs(line.amplitude - CRANK_MM) <= 4 * line.u_amplitude
    assert line.u_amplitude < 0.01 * CRANK_MM
    assert free.u_amplitude > 10 * line.u_amplitude  # each camera alone sees one quadrature only
    near_zero = _fit(_record(30.0, 0.002), 30.0)
    assert near_zero.u_amplitude > 10 * line.u_amplitude  # ... unless the instants interleave


def test_a_chirped_window_costs_no_model_error() -> None:
    # a sweep 39.5 → 40.5 Hz in 1 s: the phase time makes it a steady tone
    rec = _record(40.0, 0.5, setup=lambda w: w.exciter.sweep(1.0, 39.5, 40.5, 1.0))
    b = _fit(rec, 40.0)
    assert b.refused == "" and abs(b.amplitude - CRANK_MM) <= 4 * b.u_amplitude


def test_the_alias_is_refused_when_the_data_cannot_tell_it() -> None:
    # α just above the degenerate threshold and the motion shrunk to 2 % (≈ 0.1 px, the noise's size):
    # the alias test itself refuses
    rec = _record(40.0, 0.004)
    mean_l, mean_r = rec.uv_left.mean(0), rec.uv_right.mean(0)
    rng = np.random.default_rng(5)
    rec.uv_left[:] = mean_l + 0.02 * (rec.uv_left - mean_l) + rng.normal(0, 0.1, rec.uv_left.shape)
    rec.uv_right[:] = mean_r + 0.02 * (rec.uv_right - mean_r) + rng.normal(0, 0.1, rec.uv_right.shape)
    b = _fit(rec, 40.0)
    assert "not identifiable" in b.refused and b.alias_dchi2 < 25


@given(st.floats(1.0, 1000.0), st.floats(-1.0, 1.0), st.integers(-50, 50))
def test_pair_band_depends_on_the_offset_modulo_a_frame(fs_hz: float, offset_frames: float, k: int) -> None:
    a = pair_band(fs_hz, offset_frames / fs_hz)
    b = pair_band(fs_hz, (offset_frames + k) / fs_hz)
    assert abs(a.alias_separation - b.alias_separation) < 1e-6
    assert 0 <= a.alias_separation <= 1 and 0 <= a.alpha < 1
    assert a.single_nyquist_hz == pytest.approx(fs_hz / 2)
    assert a.combined_rate_hz == pytest.approx(fs_hz if a.degenerate else 2 * fs_hz)
    assert a.degenerate == (a.alias_separation < MIN_ALIAS_SEPARATION)
    assert (a.degenerate_reason() != "") == a.degenerate


def test_pair_band_and_fit_bin_refuse_bad_input() -> None:
    with pytest.raises(InputArrayError, match="fs_hz"):
        pair_band(0.0, 0.001)
    rec = _record(40.0, 0.5)
    with pytest.raises(InputArrayError, match="axis"):
        fit_bin([rec.P_left], [rec.true_left], [rec.uv_left], [np.arange(rec.true_left.size)], (0, 0, 0),
                f_ref_hz=40.0)
    with pytest.raises(InputArrayError, match="phase_rad"):
        fit_bin([rec.P_left], [rec.true_left], [rec.uv_left], [np.zeros(rec.true_left.size)], AXIS,
                f_ref_hz=40.0)

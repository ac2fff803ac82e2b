"""Reference-marker stabilization (Kabsch / Umeyama): exact recovery, vectorized frames, degeneracy."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rig.stereo import errors
from rig.stereo.reference import rigid_transform, stabilize

REFS = np.array([[0.0, 0.0, 0.0], [400.0, 0.0, 0.0], [0.0, 300.0, 0.0], [380.0, 320.0, 150.0]])

finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    quat=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    t=st.lists(finite, min_size=3, max_size=3),
    s=st.floats(0.5, 2.0),
    with_scale=st.booleans(),
    seed=st.integers(0, 2**31),
)
def test_recovers_random_transform(quat, t, s, with_scale, seed) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-500, 500, (int(rng.integers(3, 12)), 3))
    R = Rotation.from_quat(quat).as_matrix()
    scale = s if with_scale else 1.0
    dst = scale * src @ R.T + np.asarray(t)
    tf = rigid_transform(src, dst, scale=with_scale)
    np.testing.assert_allclose(tf.R, R, atol=1e-9)
    np.testing.assert_allclose(tf.t_mm, t, atol=1e-6)
    assert tf.scale == pytest.approx(scale, rel=1e-10)
    assert np.linalg.det(tf.R) == pytest.approx(1.0)
    assert tf.rms_mm < 1e-6
    np.testing.assert_allclose(tf.inverse().apply(tf.apply(src)), src, atol=1e-6)


def test_reflection_is_never_returned() -> None:
    """Mirrored data has no proper rotation fit; Kabsch must still return det(R) = +1."""
    dst = REFS * np.array([1.0, 1.0, -1.0])
    tf = rigid_transform(REFS, dst)
    assert np.linalg.det(tf.R) == pytest.approx(1.0)
    assert tf.rms_mm > 1.0


def test_noisy_fit_residual_matches_noise() -> None:
    rng = np.random.default_rng(1)
    src = rng.uniform(-500, 500, (200, 3))
    sigma = 0.1
    dst = src + rng.normal(0, sigma, src.shape)
    tf = rigid_transform(src, dst)
    # residual RMS of a 6-parameter fit to 3N coordinates: σ·sqrt(3(N − 2)/N)
    assert tf.rms_mm == pytest.approx(sigma * np.sqrt(3 * (200 - 2) / 200), rel=0.1)


def test_stabilize_removes_camera_shake_from_targets() -> None:
    """Every frame the whole scene is seen through a small random rigid motion (camera shake);
    the target really moves sinusoidally. Stabilization must return the true target motion."""
    rng = np.random.default_rng(5)
    n = 500
    t_s = np.arange(n) / 60.0
    target_true = np.zeros((n, 2, 3))
    target_true[:, 0] = [200.0, 150.0, 50.0]
    target_true[:, 1] = [250.0, 150.0, 50.0]
    target_true[:, :, 2] += 3.0 * np.sin(2 * np.pi * 4.0 * t_s)[:, None]
    rot = Rotation.from_rotvec(rng.normal(0, np.deg2rad(0.2), (n, 3))).as_matrix()
    shift = rng.normal(0, 2.0, (n, 3))
    seen_ref = np.einsum("tij,kj->tki", rot, REFS) + shift[:, None]
    seen_tgt = np.einsum("tij,tmj->tmi", rot, target_true) + shift[:, None]
    seen_ref[10, 1] = np.nan  # one reference marker lost: 3 left, still valid
    seen_ref[20, :2] = np.nan  # two lost: frame invalid
    out = stabilize(seen_ref, REFS, seen_tgt)
    assert out.valid.sum() == n - 1 and not out.valid[20]
    assert np.isnan(out.targets_mm[20]).all()
    np.testing.assert_allclose(out.targets_mm[out.valid], target_true[out.valid], atol=1e-9)
    # Vectorized frames agree with the single-frame function.
    single = rigid_transform(seen_ref[10], REFS)
    np.testing.assert_allclose(out.R[10], single.R, atol=1e-12)
    np.testing.assert_allclose(single.apply(seen_tgt[10]), out.targets_mm[10], atol=1e-9)


def test_stabilize_with_scale() -> None:
    seen = 1.01 * REFS + [1.0, 2.0, 3.0]
    out = stabilize(seen[None], REFS, (1.01 * REFS[:1] + [1.0, 2.0, 3.0])[None], scale=True)
    assert out.scale[0] == pytest.approx(1 / 1.01)
    np.testing.assert_allclose(out.targets_mm[0], REFS[:1], atol=1e-9)


@pytest.mark.parametrize(
    ("src", "match"),
    [
        (REFS[:2], "≥ 3"),
        (np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2], [5, 5, 5]]), "collinear"),
        (np.array([[0.0, 0, 0], [100, 0, 0], [200, 0.01, 0], [np.nan, 1, 1]]), "collinear"),
    ],
)
def test_degenerate_reference_markers(src, match) -> None:
    with pytest.raises(errors.DegenerateReferenceError, match=match):
        rigid_transform(src, src)


def test_stabilize_refuses_degenerate_home_and_bad_shapes() -> None:
    line = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(errors.DegenerateReferenceError, match="collinear"):
        stabilize(line[None], line, np.zeros((1, 1, 3)))
    with pytest.raises(errors.InputArrayError, match=r"\(T frames"):
        stabilize(REFS, REFS, np.zeros((1, 1, 3)))
    with pytest.raises(errors.InputArrayError, match="shapes must agree"):
        stabilize(REFS[None], REFS[:3], np.zeros((1, 1, 3)))
    with pytest.raises(errors.InputArrayError, match="same markers"):
        rigid_transform(REFS, REFS[:3])
    with pytest.raises(errors.InputArrayError, match="weights"):
        rigid_transform(REFS, REFS, weights=[1, 1, -1, 1])

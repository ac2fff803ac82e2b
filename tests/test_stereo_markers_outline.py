"""The outline's edge points: crossings found through flat indices are numpy's n-D ``nonzero``, exactly."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays

from rig.stereo.markers_outline import _nonzero, edge_points


@given(arrays(np.bool_, array_shapes(min_dims=1, max_dims=4, min_side=0, max_side=7)))
def test_nonzero_through_flat_indices_is_numpys_nonzero(mask: np.ndarray) -> None:
    got, want = _nonzero(mask), np.nonzero(mask)
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g.dtype == w.dtype and np.array_equal(g, w)


@given(k=st.integers(1, 5), half_px=st.integers(3, 12), seed=st.integers(0, 2**16))
def test_edge_points_are_the_sign_changes_between_neighbours(k: int, half_px: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    w = 2 * half_px + 1
    d = rng.normal(0.0, 50.0, (k, w, w)).astype(np.float32)
    level = rng.uniform(-20.0, 20.0, k).astype(np.float32)
    k_idx, x, y, step = edge_points(d, level)
    below = d < level[:, None, None]
    # one point per pair of neighbours on opposite sides of the level, window by window
    per_window = (below[:, :, :-1] != below[:, :, 1:]).sum(axis=(1, 2)) + (below[:, :-1] != below[:, 1:]).sum(
        axis=(1, 2))
    assert np.array_equal(np.bincount(k_idx, minlength=k), per_window)
    assert np.all(np.diff(k_idx) >= 0) and np.all(step > 0)
    assert np.all((x >= 0) & (x <= w - 1) & (y >= 0) & (y <= w - 1))

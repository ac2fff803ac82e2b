"""Displacement stabilised by the reference markers (rig.deploy.series.stabilised_displacement): targets seen
at their own instants (starting late, between the references' samples) get the rigid transform of the
references interpolated to each of their instants — computed once per instant for all targets."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rig.deploy.series import stabilised_displacement
from rig.stereo import stabilize

FS_HZ = 60.0
HOME_MM = np.array([[0.0, 0.0, 1000.0], [300.0, 0.0, 1000.0], [0.0, 200.0, 1050.0], [250.0, 250.0, 980.0]])


def _shake(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera shake: rotation (T, 3, 3) by ≤ 2 mrad about a tilted axis and a translation ≤ 0.5 mm (T, 3),
    zero before 0.6 s (more than half the record: the references' medians are their true positions)."""
    on = t >= 0.6
    angle = 2e-3 * np.sin(2 * np.pi * 3.0 * t) * on
    axis = np.array([0.3, 0.9, 0.3]) / np.linalg.norm([0.3, 0.9, 0.3])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle)[:, None, None] * K + (1 - np.cos(angle))[:, None, None] * (K @ K)
    return R, 0.5 * np.sin(2 * np.pi * 5.0 * t)[:, None] * on[:, None] * np.array([1.0, -0.5, 0.2])


def _seen(t: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    R, shift = _shake(t)
    return np.einsum("tij,tj->ti", R, xyz) + shift


def _target_mm(t: np.ndarray) -> np.ndarray:
    return np.array([100.0, 100.0, 1000.0]) + np.outer(2.0 * np.sin(2 * np.pi * 7.0 * t), [0.0, 0.0, 1.0])


def test_targets_at_their_own_instants_are_stabilised_as_each_alone() -> None:
    t_ref = np.arange(0.0, 1.5, 1 / FS_HZ)
    t_late = t_ref[20:] + 0.004  # starts late, between the references' samples (its last after theirs)
    refs_seen = [_seen(t_ref, np.broadcast_to(h, (len(t_ref), 3))) for h in HOME_MM]
    rows = [pd.DataFrame({"time_s": t_ref, "track_id": k, "x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2]})
            for k, p in enumerate(refs_seen)]
    for tid, t in ((4, t_ref), (5, t_late)):
        p = _seen(t, _target_mm(t))
        rows.append(pd.DataFrame({"time_s": t, "track_id": tid, "x_mm": p[:, 0], "y_mm": p[:, 1],
                                  "z_mm": p[:, 2]}))
    tracks = pd.concat(rows, ignore_index=True).sort_values("time_s", kind="stable", ignore_index=True)
    disp = stabilised_displacement(tracks, [0, 1, 2, 3])
    assert disp.groupby("track_id")["role"].first().tolist() == ["reference"] * 4 + ["target"] * 2
    xyz = {tid: g[["x_mm", "y_mm", "z_mm"]].to_numpy() for tid, g in disp.groupby("track_id")}
    # at the references' own instants the shake is undone exactly (rounding: 1e-9 mm at a metre)
    np.testing.assert_allclose(xyz[4], _target_mm(t_ref), rtol=0, atol=1e-9)
    # between samples: the transform of the references interpolated to the target's instants, as alone
    ref_at = np.stack([np.column_stack([np.interp(t_late, t_ref, r[:, k], left=np.nan, right=np.nan)
                                        for k in range(3)]) for r in refs_seen], axis=1)
    alone = stabilize(ref_at, HOME_MM, _seen(t_late, _target_mm(t_late))[:, None, :]).targets_mm[:, 0]
    assert np.isnan(alone[-1]).all()  # after the references' last sample: no transform
    np.testing.assert_allclose(xyz[5], alone, rtol=0, atol=1e-9)
    d = disp[disp.track_id == 4][["dx_mm", "dy_mm", "dz_mm"]].to_numpy()
    np.testing.assert_allclose(d, _target_mm(t_ref) - np.median(_target_mm(t_ref), axis=0), rtol=0, atol=1e-9)

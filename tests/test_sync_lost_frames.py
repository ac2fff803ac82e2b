"""A rotor recording that lost frames (a camera, or a host too loaded to render or read it, skipping bursts):
the joint sync bridges gaps of up to MAX_BRIDGED_GAP_FRAMES frames in B's track but leaves out every instant
of A within the kernel's reach of a longer one, and when too few are left the error names the gaps and each
camera's frames missing — not only a lack of overlap."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from timing_synth import observe, rotor, stereo_pair

from procedures import sync
from rig.run.acquire import Recording
from rig.stereo.errors import NoCommonMotionError
from rig.stereo.timing import estimate_offset
from rig.stereo.timing_joint import GAP_GUARD, MAX_BRIDGED_GAP_FRAMES

FS_HZ = 60.0


def test_gaps_in_b_that_leave_too_little_are_named_in_the_overlap_error() -> None:
    traj, _, _ = rotor(frequency_hz=10.0)
    cam_a, cam_b = stereo_pair(height_b_mm=120.0)
    rng = np.random.default_rng(4)
    tau = np.arange(180) / FS_HZ  # the sync's 3-s recording
    ta, ua, _ = observe(cam_a, traj, tau, line_time_s=12e-6, sigma_px=0.1, rng=rng)
    tb, ub, _ = observe(cam_b, traj, tau, offset_s=0.0043, line_time_s=12e-6, sigma_px=0.1, rng=rng)
    keep = np.ones(tau.size, bool)
    keep[70:80] = keep[120:124] = False  # two bursts skipped: 14 frames, 8 % of the recording
    with pytest.raises(NoCommonMotionError) as caught:
        estimate_offset(cam_a, cam_b, (ta, ua), (tb[keep], ub[keep]), offset_guess_s=0.0043,
                        search_half_width_s=2 / FS_HZ)
    message = str(caught.value)
    # both bursts are longer than the bridged gaps (MAX_BRIDGED_GAP_FRAMES): guarded, not bridged
    assert (f"within {GAP_GUARD} frames of the 2 gap(s) in camera B's track that could not be bridged "
            "(14 frames missing in 2 gap(s)") in message, message
    assert f"0 gap(s) of at most {MAX_BRIDGED_GAP_FRAMES} frames bridged" in message
    # the same recording without the gaps overlaps (the error is the gaps')
    res = estimate_offset(cam_a, cam_b, (ta, ua), (tb, ub), offset_guess_s=0.0043,
                          search_half_width_s=2 / FS_HZ)
    assert abs(res.offset_s["b"] - 0.0043) <= 5 * res.uncertainty["offset_s"]["b"]


def _observations(stamps_s: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"frame_index": np.arange(stamps_s.size), "timestamp_s": stamps_s,
                         "u_px": 1.0, "v_px": 2.0})


def test_frame_loss_counts_the_missing_frames_from_the_stamps() -> None:
    stamps = np.arange(180) / FS_HZ
    kept = np.delete(stamps, np.r_[70:80, 120:124])
    assert sync.frame_loss(stamps, FS_HZ, 3.0) == (180, 0, 0, 0)
    assert sync.frame_loss(np.repeat(kept, 3), FS_HZ, 3.0) == (166, 14, 2, 0)  # (a row per marker)
    # a stream that skipped ahead past the stop: its last 58 frames never came (57 beyond ±1 frame)
    assert sync.frame_loss(stamps[:122], FS_HZ, 3.0) == (122, 0, 0, 57)


def test_a_sync_that_lost_frames_names_each_cameras_share() -> None:
    stamps = 12.0 + np.arange(180) / FS_HZ
    rec = Recording("sync", None, 10.0, 13.0, {"left": _observations(stamps),
                                                "right": _observations(np.delete(stamps, np.r_[30:66]))})
    cause = NoCommonMotionError("only 0 observations of camera A fall inside camera B's record")
    error = sync.lost_frames_error(rec, FS_HZ, cause)
    assert error is not None
    text = str(error)
    assert "camera 'left': 0 of 180 frames missing (0%): 0 in 0 gap(s), 0 at the ends" in text
    assert "camera 'right': 36 of 180 frames missing (20%): 36 in 1 gap(s), 0 at the ends" in text
    assert "3.0-s rotor recording lost frames" in text and "only 0 observations" in text
    whole = Recording("sync", None, 10.0, 13.0, {name: _observations(stamps) for name in ("left", "right")})
    assert sync.lost_frames_error(whole, FS_HZ, cause) is None  # nothing lost: the original error stands

"""`rig measure` without --timing on videos whose right camera (the joint estimate's B) lost frames.

The pair is written as Motion-JPEG in Matroska, each frame at its camera's own time stamp, so a lost frame
shows as a gap in the time stamps (as on site; OpenCV's AVI writer would close the gap). About 15 % of the
right camera's frames are lost at random, in single-frame gaps. The joint estimate bridges gaps of B of
≤ 3 frames when B's track is a line spectrum (prediction gain ≥ 1e3, rig/stereo/timing_joint.py), else it
leaves out A's instants around them.

Tolerances as in tests/test_measure_hard_scenarios.py (derived, never tuned): the offset within 4 of its
stated standard uncertainties (modulo the period when the ambiguity is stated), amplitudes within 4 of the
sine fit's standard uncertainties plus the calibration's scale floor and the trajectory method's bias.
"""

from __future__ import annotations

import re
from pathlib import Path

import measure_twin as mt
import numpy as np
import pytest
from test_measure_hard_scenarios import _check_amplitudes, _check_offset, _targets

from drivers.sim.world import World
from rig.deploy.measure import MeasureError, MeasureOptions, measure_videos
from rig.stereo.timing_joint import MAX_BRIDGED_GAP_FRAMES, MIN_PREDICTION_GAIN

DURATION_S = 2.5
RIGHT_START_S = 0.15
LOSS_FRACTION = 0.15  # of the right camera's frames, before single-frame gaps are enforced


@pytest.fixture(scope="module")
def site(calibrated_site: dict) -> dict:
    return calibrated_site  # built once per session (tests/conftest.py)


def _single_frame_losses(first_k: int, last_k: int, seed: int) -> list[int]:
    """Sensor frames lost at random (``LOSS_FRACTION``) strictly inside ``first_k`` … ``last_k`` (a few frames
    clear of both ends), no two adjacent: every gap is one frame."""
    rng = np.random.default_rng(seed)
    lost: list[int] = []
    for k in range(first_k + 3, last_k - 2):
        if rng.random() < LOSS_FRACTION and (not lost or k > lost[-1] + 1):
            lost.append(k)
    return lost


def _lossy_pair(folder: Path, world: World, *, seed: int = 11) -> tuple[dict[str, Path], dict, int]:
    """The pair of ``world`` as MKV, the right camera losing frames in single-frame gaps; returns (paths,
    truth, frames lost)."""
    _, lossless = mt.camera_pair(world)  # same sensor frames, none lost: where the right video starts/stops
    span = lossless.frame_indices_between(RIGHT_START_S, RIGHT_START_S + DURATION_S)
    lost = _single_frame_losses(lossless.sensor_frame(span[0]), lossless.sensor_frame(span[-1]), seed)
    left, right = mt.camera_pair(world, right={"dropped_frames": lost})
    right_s = (RIGHT_START_S, RIGHT_START_S + DURATION_S)
    paths = {"left": mt.write_mkv_video(left, folder / "left.mkv", 0.0, DURATION_S, date_utc_ns=None),
             "right": mt.write_mkv_video(right, folder / "right.mkv", *right_s, date_utc_ns=None)}
    n_frames = round(DURATION_S * 60)
    assert 0.10 * n_frames <= len(lost) <= 0.20 * n_frames, len(lost)
    return paths, mt.truth_timing(left, right, 0.0, RIGHT_START_S), len(lost)


@pytest.mark.slow
def test_steady_tone_with_lost_frames_is_timed_across_the_bridged_gaps(site: dict, tmp_path: Path) -> None:
    paths, truth, n_lost = _lossy_pair(tmp_path, mt.steady_world())
    res = measure_videos(paths, site["calibration"], tmp_path / "out", options=MeasureOptions())
    # the container's time stamps show each lost frame as a one-frame gap, not as a duplicate
    right = res.frame_reports["right"]
    assert [g["missing_frames"] for g in right["dropped"]] == [1] * n_lost and not right["duplicated"]
    assert res.timing["method"] == "joint"
    gaps = res.timing["details"]["gaps_b"]
    # every used track of B has each lost frame as a one-frame gap, and each is bridged: nothing left out
    n_tracks = res.timing["details"]["pairs_used"]
    assert gaps["tracks"] == n_tracks
    assert gaps["gaps"] == gaps["frames_missing"] == gaps["bridged"] == n_lost * n_tracks, gaps
    assert gaps["left_out_near_unbridged_gaps"] == 0, gaps
    assert min(gaps["prediction_gain"]) >= MIN_PREDICTION_GAIN, gaps
    _check_offset(res, truth, period_s=1 / mt.FREQUENCY_HZ)
    assert len(_targets(res)) == 5
    _check_amplitudes(res, mt.CRANK_MM, mt.FREQUENCY_HZ, site)


@pytest.mark.slow
def test_chirp_with_lost_frames_is_refused_naming_the_unbridged_gaps(site: dict, tmp_path: Path) -> None:
    # a chirp 3 → 20 Hz is no line spectrum (B's prediction gain ≈ 2): its gaps are guarded, not bridged, and
    # with a one-frame gap every ≈ 7 frames the guard leaves nothing to estimate — an error that says so,
    # never a silently wrong offset
    paths, _, n_lost = _lossy_pair(tmp_path, mt.chirp_world(3.0, 20.0, 0.4, 2.4))
    with pytest.raises(MeasureError, match="estimating the timing from the videos") as info:
        measure_videos(paths, site["calibration"], tmp_path / "out", options=MeasureOptions())
    message = str(info.value)
    found = re.search(r"\((\d+) frames missing in (\d+) gap\(s\), counted in each of B's (\d+) track\(s\)",
                      message)
    assert found is not None, message
    missing, n_gaps, n_tracks = int(found[1]), int(found[2]), int(found[3])
    assert missing == n_gaps == n_lost * n_tracks, message  # one-frame gaps, each in every track of B
    assert f"0 gap(s) of at most {MAX_BRIDGED_GAP_FRAMES} frames bridged" in message, message
    assert "could not be bridged" in message and "(not a line spectrum)" in message, message
    assert "give --timing timing.json" in message, message

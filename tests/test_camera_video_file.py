"""Video files as camera records: container time stamps, duplicated and dropped frames, broken files."""

from __future__ import annotations

from pathlib import Path

import measure_twin as mt
import numpy as np
import pytest
from camera_mkv import write_mkv
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.camera.base import FrameSource
from drivers.camera.video_file import (
    VideoFile,
    VideoOpenError,
    VideoTruncatedError,
    find_gaps,
)


def _noise_frames(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    base = rng.integers(20, 60, (96, 128)).astype(np.uint8)
    return [np.clip(base + rng.normal(0, 6, base.shape), 0, 255).astype(np.uint8) for _ in range(n)]


def test_mkv_time_stamps_duplicates_and_gaps_are_reported_not_shifted(tmp_path: Path) -> None:
    frames = _noise_frames(30)
    stamps = [k / 60 for k in range(30)]
    frames[8], stamps[8] = frames[7], stamps[7]  # a duplicate: same image, same time stamp
    for k in range(15, 30):
        stamps[k] += 3 / 60  # 3 frames missing after index 14
    write_mkv(tmp_path / "a.mkv", frames, stamps)
    video = VideoFile(tmp_path / "a.mkv", fps=60)
    assert isinstance(video, FrameSource)
    got = list(video.frames())
    assert [f.index for f in got] == list(range(30))
    assert np.allclose([f.timestamp_s for f in got], stamps, atol=1e-5)  # 10 µs container resolution
    rep = video.report
    assert rep.duplicate_indices == [8] and rep.duplicated[0]["pts_repeated"]
    # frame 8 repeats 7, so frame 9 follows a 2-period gap (sensor frame 8 was replaced by the copy)
    assert [(d["after_index"], d["missing_frames"]) for d in rep.dropped] == [(8, 1), (14, 3)]
    assert rep.missing_frames == 4 and not rep.truncated
    assert video.duplicate_indices == {8}
    assert "1 duplicated" in rep.summary() and "4 dropped" in rep.summary()


@pytest.mark.parametrize(("fourcc", "ext"), [("mp4v", "mp4"), ("MJPG", "avi")])
def test_constant_rate_duplicates_found_by_image_and_policy_applied(tmp_path: Path, fourcc: str,
                                                                   ext: str) -> None:
    world = mt.measurement_world()
    left, _ = mt.camera_pair(world, left={"duplicated_frames": (36, 47)})
    path = tmp_path / f"d.{ext}"
    n = left.write_video(path, 0.5, 0.9, fourcc=fourcc)
    replace = VideoFile(path)
    got = list(replace.frames())
    assert len(got) == n and replace.report.frames_read == n
    first = left.first_frame_index_at_or_after(0.5)
    expected = [i - first for i in range(first, first + n) if i > first and
                left.sensor_frame(i) == left.sensor_frame(i - 1)]
    assert replace.report.duplicate_indices == expected and len(expected) == 2
    assert not any(d["pts_repeated"] for d in replace.report.duplicated)  # CFR: the stamp advanced
    assert [f.timestamp_s for f in got] == pytest.approx([k / 60 for k in range(n)])
    inserted = VideoFile(path, duplicate_policy="insert")
    stamps = [f.timestamp_s for f in inserted.frames()]
    k1, k2 = expected
    assert stamps[k1 + 1] == pytest.approx((k1 + 1 - 1) / 60)  # one period earlier after an insert
    assert stamps[k2 + 1] == pytest.approx((k2 + 1 - 2) / 60)
    assert [c["from_index"] for c in inserted.report.corrections] == [k1 + 1, k2 + 1]


def test_luma_plane_used_when_it_matches_the_grey_conversion(tmp_path: Path) -> None:
    world = mt.measurement_world()
    left, _ = mt.camera_pair(world)
    left.write_video(tmp_path / "l.avi", 0.0, 0.1, fourcc="MJPG")
    video = VideoFile(tmp_path / "l.avi")
    img = next(iter(video.frames())).image
    assert video.report.luma_plane and img.shape == (540, 960) and img.dtype == np.uint8
    slow = next(iter(VideoFile(tmp_path / "l.avi", luma=False).frames())).image
    assert np.abs(img.astype(int) - slow.astype(int)).mean() < 2.0  # full-range JPEG luma = grey


def test_truncated_avi_keeps_frames_read_and_raises_clearly(tmp_path: Path) -> None:
    world = mt.measurement_world()
    left, _ = mt.camera_pair(world)
    n = left.write_video(tmp_path / "l.avi", 0.0, 0.5, fourcc="MJPG")
    data = (tmp_path / "l.avi").read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: len(data) // 2])
    video = VideoFile(tmp_path / "cut.avi")
    got = []
    with pytest.raises(VideoTruncatedError, match=r"decoding stopped after \d+ of the 30 frames") as info:
        got.extend(video.frames())
    assert 0 < len(got) < n and info.value.frames_read == len(got)
    assert info.value.report.truncated


def test_unopenable_files_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(VideoOpenError, match="no such video file"):
        VideoFile(tmp_path / "missing.mp4")
    (tmp_path / "empty.mp4").write_bytes(b"")
    with pytest.raises(VideoOpenError, match="empty"):
        VideoFile(tmp_path / "empty.mp4")
    (tmp_path / "junk.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    with pytest.raises(VideoOpenError, match="no decoder can open it"):
        VideoFile(tmp_path / "junk.mp4")
    with pytest.raises(ValueError, match="duplicate_policy"):
        VideoFile(tmp_path / "junk.mp4", duplicate_policy="guess")


@settings(max_examples=60, deadline=None)
@given(gaps=st.lists(st.integers(min_value=1, max_value=6), min_size=5, max_size=80),
       jitter=st.floats(min_value=0.0, max_value=0.2))
def test_gaps_recover_the_missing_frame_counts(gaps: list[int], jitter: float) -> None:
    """Frames at integer periods (steps of 1…6 periods) with time-stamp jitter below 0.2 period: every
    step of k periods is k − 1 missing frames, and nothing else is reported."""
    period = 1 / 60
    rng = np.random.default_rng(len(gaps))
    t = np.concatenate([[0.0], np.cumsum(gaps)]) * period
    t = t + rng.uniform(-jitter / 2, jitter / 2, t.size) * period
    found = find_gaps(t, period)
    expected = [(i, k - 1) for i, k in enumerate(gaps) if k > 1]
    assert [(g["after_index"], g["missing_frames"]) for g in found] == expected

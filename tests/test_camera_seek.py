"""Frame-exact seeking (drivers/camera/seek.py, VideoFile.frames(start_s=…)): every landing is checked
against a sequential decode of the same file — the frame's time stamp and a hash of its pixels — in the
containers and codecs OpenCV writes (and the twin uses: MP4 mp4v, AVI MJPG), Matroska, and MP4 files whose
sample table was rewritten to hold dropped frames, a variable frame rate (where OpenCV's own
CAP_PROP_POS_FRAMES lands on another frame) or a repeated time stamp."""

from __future__ import annotations

import hashlib
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.camera.seek import frame_times_s, seek_frame
from drivers.camera.video_file import SEEK_PREROLL_FRAMES, VideoFile

N_FRAMES = 150
FPS = 60.0
CODECS = [("mp4v", "mp4"), ("MJPG", "avi"), ("mp4v", "mkv"), ("MJPG", "mkv"), ("XVID", "avi")]


def _image(i: int, rng: np.random.Generator) -> np.ndarray:
    """A noisy frame whose content says its index (every frame differs from every other)."""
    img = rng.integers(0, 200, (96, 128, 3), dtype=np.uint8)
    cv2.putText(img, str(i), (8, 60), cv2.FONT_HERSHEY_SIMPLEX, 1.5, (255, 255, 255), 3)
    return img


def write_video(path: Path, fourcc: str, n: int = N_FRAMES, repeat: int | None = None) -> Path:
    """``n`` frames at 60 fps; frame ``repeat`` (if given) is the previous frame's image again."""
    rng = np.random.default_rng(7)
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), FPS, (128, 96), True)
    if not w.isOpened():
        pytest.skip(f"this OpenCV cannot write {fourcc} into .{path.suffix}")
    prev = None
    for i in range(n):
        img = prev if i == repeat and prev is not None else _image(i, rng)
        w.write(img)
        prev = img
    w.release()
    return path


def sequential(path: Path) -> list[tuple[float, str]]:
    """(time stamp s, pixel hash) of every frame of a decode from the first frame."""
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        out.append((cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0, hashlib.sha1(img.tobytes()).hexdigest()))
    cap.release()
    return out


def landed(path: Path, index: int, times: np.ndarray) -> tuple[float, str] | None:
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    try:
        if not seek_frame(cap, times, index):
            return None
        ok, img = cap.retrieve()
        assert ok
        first = (cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0, hashlib.sha1(img.tobytes()).hexdigest())
        ok, img = cap.read()  # and the next frame is the next one
        if index + 1 < N_FRAMES:
            assert ok
        return first
    finally:
        cap.release()


def _mp4_with_stts(src: Path, dst: Path, entries: list[tuple[int, int]]) -> Path:
    """``src`` (an MP4 written by OpenCV: moov after mdat, so no chunk offset moves) with the video track's
    time-to-sample table replaced by ``entries`` [(sample count, duration in the track's time scale)] and
    its edit list removed (it would cut the frames that now end later)."""
    stts = bytes(4) + struct.pack(">I", len(entries)) + b"".join(struct.pack(">II", c, d) for c, d in entries)
    edits = {(b"moov", b"trak", b"mdia", b"minf", b"stbl", b"stts"): stts, (b"moov", b"trak", b"edts"): None}

    def rewrite(buf: bytes, path: tuple[bytes, ...]) -> bytes:
        out, pos = b"", 0
        while pos < len(buf):
            size, kind = struct.unpack(">I4s", buf[pos:pos + 8])
            body: bytes | None = buf[pos + 8:pos + size]
            here = (*path, kind)
            if here in edits:
                body = edits[here]
            elif any(key[:len(here)] == here for key in edits):
                body = rewrite(buf[pos + 8:pos + size], here)
            if body is not None:
                out += struct.pack(">I4s", len(body) + 8, kind) + body
            pos += size
        return out
    dst.write_bytes(rewrite(src.read_bytes(), ()))
    return dst


def _stts(path: Path) -> tuple[int, int]:
    """The (count, duration) of an OpenCV-written MP4's one time-to-sample entry."""
    data = path.read_bytes()
    at = data.index(b"stts")
    n_entries, count, delta = struct.unpack(">III", data[at + 8:at + 20])
    assert n_entries == 1 and count == N_FRAMES
    return count, delta


@pytest.mark.parametrize(("fourcc", "ext"), CODECS)
def test_frame_times_and_every_landing_match_a_sequential_decode(tmp_path: Path, fourcc: str, ext: str
                                                                 ) -> None:
    path = write_video(tmp_path / f"v.{ext}", fourcc)
    truth = sequential(path)
    assert len(truth) == N_FRAMES
    times = frame_times_s(str(path))
    assert times is not None
    np.testing.assert_allclose(times, [t for t, _ in truth], rtol=0, atol=1e-9)
    for index in (0, 1, 11, 12, 13, 59, 60, 61, 100, N_FRAMES - 2, N_FRAMES - 1):
        assert landed(path, index, times) == truth[index], index
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    assert not seek_frame(cap, times, N_FRAMES) and not seek_frame(cap, times, -1)
    cap.release()


@pytest.mark.parametrize(("kind", "opencv_misses"),
                         [("dropped", True), ("variable", True), ("repeated", False)])
def test_seek_is_exact_where_opencv_lands_on_another_frame(tmp_path: Path, kind: str, opencv_misses: bool
                                                           ) -> None:
    """Ten frames dropped after frame 70 (its duration 11 periods), a variable rate (frames 50… at 30 fps)
    or a repeated stamp (frame 71 lasting 0): OpenCV's own seek (a frame number from the stamp and the
    average rate) lands frames early or late in the first two; the verified seek decodes forward or backs
    off and is exact in all three."""
    src = write_video(tmp_path / "v.mp4", "mp4v")
    _, d = _stts(src)
    entries = {"dropped": [(71, d), (1, 11 * d), (N_FRAMES - 72, d)],
               "variable": [(50, d), (N_FRAMES - 50, 2 * d)],
               "repeated": [(71, d), (1, 0), (N_FRAMES - 72, d)]}[kind]
    path = _mp4_with_stts(src, tmp_path / f"{kind}.mp4", entries)
    truth = sequential(path)
    assert len(truth) == N_FRAMES
    times = frame_times_s(str(path))
    assert times is not None
    np.testing.assert_allclose(times, [t for t, _ in truth], rtol=0, atol=1e-9)
    wrong = 0
    for index in (10, 60, 70, 71, 72, 73, 100, 130, N_FRAMES - 1):
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        cap.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, img = cap.read()
        wrong += not ok or hashlib.sha1(img.tobytes()).hexdigest() != truth[index][1]
        cap.release()
        assert landed(path, index, times) == truth[index], index
    assert (wrong >= 5) == opencv_misses  # the case is real: OpenCV's seek alone misses these frames


@pytest.mark.parametrize(("fourcc", "ext"), [("mp4v", "mp4"), ("MJPG", "avi"), ("mp4v", "mkv")])
def test_video_file_from_a_start_gives_the_frames_of_a_whole_decode(tmp_path: Path, fourcc: str, ext: str
                                                                    ) -> None:
    """frames(start_s) delivers from SEEK_PREROLL_FRAMES before the start on exactly what frames() does
    there: index, time stamp, pixels and the duplicate judged (frame 120 repeats frame 119)."""
    path = write_video(tmp_path / f"v.{ext}", fourcc, repeat=120)
    whole_video = VideoFile(path)
    whole = [(f.index, f.timestamp_s, hashlib.sha1(f.image.tobytes()).hexdigest())
             for f in whole_video.frames()]
    assert 120 in whole_video.duplicate_indices
    start_s = whole[100][1]
    video = VideoFile(path)
    part = [(f.index, f.timestamp_s, hashlib.sha1(f.image.tobytes()).hexdigest())
            for f in video.frames(start_s=start_s)]
    assert part[0][0] == 100 - SEEK_PREROLL_FRAMES
    assert part == whole[100 - SEEK_PREROLL_FRAMES:]
    assert video.duplicate_indices == whole_video.duplicate_indices
    assert video.report.frames_read == whole_video.report.frames_read == N_FRAMES
    assert video.report.first_pts_s == whole_video.report.first_pts_s
    assert not video.report.truncated


def test_video_file_start_near_the_beginning_or_with_insert_policy_decodes_from_frame_0(tmp_path: Path
                                                                                        ) -> None:
    path = write_video(tmp_path / "v.mp4", "mp4v")
    early = [f.index for f in VideoFile(path).frames(start_s=10 / FPS)]
    assert early[0] == 0 and len(early) == N_FRAMES
    # "insert" shifts every stamp after a duplicate: the stamps depend on every earlier frame
    insert = [f.index for f in VideoFile(path, duplicate_policy="insert").frames(start_s=100 / FPS)]
    assert insert[0] == 0 and len(insert) == N_FRAMES


def _damage_mp4_sample(path: Path, dst: Path, index: int) -> Path:
    """``path`` (an OpenCV-written MP4: one chunk) with the payload of video sample ``index`` overwritten by
    random bytes (its size and the container intact): a packet the decoder reports damaged and conceals."""
    data = bytearray(path.read_bytes())

    def table(kind: bytes) -> tuple[int, ...]:
        at = data.index(kind) + 4  # version/flags
        if kind == b"stsz":
            at += 4  # the common sample size (0: one size per sample)
        (count,) = struct.unpack(">I", data[at + 4:at + 8])
        return struct.unpack(f">{count}I", data[at + 8:at + 8 + 4 * count])
    sizes, (chunk,) = table(b"stsz"), table(b"stco")
    start = chunk + sum(sizes[:index])
    noise = np.random.default_rng(1).integers(0, 256, sizes[index] - 12, dtype=np.uint8).tobytes()
    data[start + 8:start + sizes[index] - 4] = noise
    dst.write_bytes(bytes(data))
    return dst


def test_windows_before_across_and_after_a_damaged_packet_get_the_frames_of_a_whole_decode(tmp_path: Path
                                                                                          ) -> None:
    """A damaged P-frame packet (frame 75: the decoder conceals it, and its error runs on to the next key
    frame, 82): a window seeking to a start before, inside or after the damage decodes what a decode from
    frame 0 decodes there — the concealed frames included — and judges the same duplicates in its range."""
    damaged = _damage_mp4_sample(write_video(tmp_path / "v.mp4", "mp4v"), tmp_path / "damaged.mp4", 75)
    clean, broken = sequential(tmp_path / "v.mp4"), sequential(damaged)
    assert len(broken) == N_FRAMES and broken[75] != clean[75]  # the damage is real and visible
    whole_video = VideoFile(damaged)
    whole = [(f.index, f.timestamp_s, hashlib.sha1(f.image.tobytes()).hexdigest())
             for f in whole_video.frames()]
    for start in (60, 78, 90, 120):
        video = VideoFile(damaged)
        part = [(f.index, f.timestamp_s, hashlib.sha1(f.image.tobytes()).hexdigest())
                for f in video.frames(start_s=whole[start][1])]
        first = part[0][0]
        assert first == start - SEEK_PREROLL_FRAMES and part == whole[first:], start
        assert video.duplicate_indices == {i for i in whole_video.duplicate_indices if i >= first}, start

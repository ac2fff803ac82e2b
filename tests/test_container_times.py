"""Container creation times, durations and frame counts (drivers/camera/container_times.py) on hand-built
MP4/MOV, Matroska and AVI bytes and on files OpenCV and the tests' Matroska writer make; the offset window
they give (rig/deploy/container_prior.py). Malformed or truncated input is a ContainerError, never a crash."""

from __future__ import annotations

import struct
from datetime import UTC, datetime, timedelta
from pathlib import Path

import cv2
import numpy as np
import pytest
from camera_mkv import _el, _str, _uint, write_mkv
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.camera.container_times import (
    MATROSKA_EPOCH,
    MP4_EPOCH,
    ContainerError,
    ContainerTimes,
    read_container_times,
)
from rig.deploy.container_prior import FALLBACK_MAX_OFFSET_S, offset_window

T0 = datetime(2026, 5, 4, 10, 20, 30, tzinfo=UTC)


# ------------------------------------------------------------------ MP4 builders (ISO/IEC 14496-12 layouts)

def box(kind: bytes, payload: bytes, *, large: bool = False) -> bytes:
    if large:
        return struct.pack(">I4sQ", 1, kind, 16 + len(payload)) + payload
    return struct.pack(">I4s", 8 + len(payload), kind) + payload


def mvhd(created_s: int, timescale: int, duration: int, version: int = 0) -> bytes:
    if version == 1:
        body = struct.pack(">QQIQ", created_s, created_s, timescale, duration)
    else:
        body = struct.pack(">IIII", created_s, created_s, timescale, duration)
    return box(b"mvhd", bytes([version, 0, 0, 0]) + body + bytes(80))


def video_trak(*, created_s: int = 0, timescale: int = 15360, frames: int = 120, delta: int = 256,
               handler: bytes = b"vide") -> bytes:
    tkhd = box(b"tkhd", bytes(4) + struct.pack(">II", created_s, created_s) + bytes(72))
    mdhd = box(b"mdhd", bytes(4) + struct.pack(">IIII", created_s, created_s, timescale, frames * delta)
               + bytes(4))
    hdlr = box(b"hdlr", bytes(8) + handler + bytes(12) + b"VideoHandler\0")
    # two stts runs: frames − 1 at delta and a last one
    stts = box(b"stts", bytes(4) + struct.pack(">IIIII", 2, frames - 1, delta, 1, delta))
    stbl = box(b"stbl", stts)
    return box(b"trak", tkhd + box(b"mdia", mdhd + hdlr + box(b"minf", stbl)))


def mp4(*, created: datetime | None = T0, track_created: datetime | None = None, version: int = 0,
        large_mdat: bool = False, moov_first: bool = False) -> bytes:
    def secs(t: datetime | None) -> int:
        return 0 if t is None else int((t - MP4_EPOCH).total_seconds())

    moov = box(b"moov", mvhd(secs(created), 1000, 2000, version)
               + box(b"trak", box(b"mdia", box(b"hdlr", bytes(8) + b"soun" + bytes(12))))
               + video_trak(created_s=secs(track_created)))
    ftyp = box(b"ftyp", b"isom\0\0\2\0isomiso2mp41")
    mdat = box(b"mdat", bytes(1000), large=large_mdat)
    return ftyp + (moov + mdat if moov_first else mdat + moov)


def test_mp4_creation_duration_and_frame_count(tmp_path: Path) -> None:
    p = tmp_path / "a.mp4"
    p.write_bytes(mp4())
    t = read_container_times(p)
    assert t.container == "mp4" and t.creation == T0 and t.creation_utc_known
    assert t.creation_resolution_s == 1.0 and t.creation_source == "mvhd creation_time"
    assert t.frame_count == 120
    assert t.duration_s == pytest.approx(120 * 256 / 15360)  # the video track's, not the movie's 2 s
    assert t.frame_period_s == pytest.approx(1 / 60)


@pytest.mark.parametrize("kwargs", [{"version": 1}, {"large_mdat": True}, {"moov_first": True}])
def test_mp4_layouts(tmp_path: Path, kwargs: dict) -> None:
    p = tmp_path / "a.mov"
    p.write_bytes(mp4(**kwargs))
    t = read_container_times(p)
    assert t.creation == T0 and t.frame_count == 120


def test_mp4_unset_movie_time_falls_back_to_the_video_track(tmp_path: Path) -> None:
    p = tmp_path / "a.mp4"
    p.write_bytes(mp4(created=None, track_created=T0 + timedelta(seconds=5)))
    t = read_container_times(p)
    assert t.creation == T0 + timedelta(seconds=5) and t.creation_source == "video tkhd creation_time"
    p.write_bytes(mp4(created=None))
    t = read_container_times(p)
    assert t.creation is None and t.creation_resolution_s is None and t.frame_count == 120


def test_creation_times_out_of_range_are_errors(tmp_path: Path) -> None:
    p = tmp_path / "a.mp4"
    p.write_bytes(mp4(version=1).replace(mvhd(int((T0 - MP4_EPOCH).total_seconds()), 1000, 2000, 1),
                                         mvhd(2**63, 1000, 2000, 1)))
    with pytest.raises(ContainerError, match="out of range"):
        read_container_times(p)
    p = tmp_path / "a.mkv"  # Matroska's signed ns reach ±292 years from 2001: always in range
    p.write_bytes(mkv(date_ns=-(2**63)))
    assert read_container_times(p).creation == MATROSKA_EPOCH + timedelta(microseconds=round(-(2**63) / 1000))


def test_mp4_truncated_before_its_index_is_named(tmp_path: Path) -> None:
    data = mp4()
    p = tmp_path / "cut.mp4"
    p.write_bytes(data[:-40])  # the moov box runs past the end
    with pytest.raises(ContainerError, match=r"cut\.mp4: top-level box b'moov' declares .*\(truncated"):
        read_container_times(p)


# ------------------------------------------------------------------ Matroska

def ebml_header(doctype: str = "matroska") -> bytes:
    return _el(0x1A45DFA3, _uint(0x4286, 1) + _str(0x4282, doctype))


def block(track: int, rel: int, payload: bytes = b"xx", lace: int | None = None) -> bytes:
    flags = 0x80 | (0x02 if lace is not None else 0)
    head = bytes([0x80 | track]) + struct.pack(">hB", rel, flags)
    return head + (bytes([lace]) if lace is not None else b"") + payload


def mkv(*, date_ns: int | None = 1000, unknown_sizes: bool = False, doctype: str = "matroska") -> bytes:
    info = _el(0x1549A966, _uint(0x2AD7B1, 1_000_000) + _el(0x4489, struct.pack(">d", 2000.0))
               + (b"" if date_ns is None else _el(0x4461, date_ns.to_bytes(8, "big", signed=True))))
    tracks = _el(0x1654AE6B,
                 _el(0xAE, _uint(0xD7, 2) + _uint(0x83, 2))  # audio first
                 + _el(0xAE, _uint(0xD7, 1) + _uint(0x83, 1) + _uint(0x23E383, 16_666_667)))
    clusters = []
    for c in range(3):
        children = _uint(0xE7, c * 1000)
        children += b"".join(_el(0xA3, block(1, k)) for k in range(10))
        children += _el(0xA3, block(2, 0))  # audio: not counted
        children += _el(0xA0, _el(0xA1, block(1, 11)))  # a BlockGroup
        children += _el(0xA3, block(1, 12, lace=2))  # a laced block of 3 frames
        if unknown_sizes:
            clusters.append(bytes.fromhex("1F43B675") + b"\x01\xff\xff\xff\xff\xff\xff\xff" + children)
        else:
            clusters.append(_el(0x1F43B675, children))
    body = info + tracks + b"".join(clusters)
    if unknown_sizes:
        segment = bytes.fromhex("18538067") + b"\x01\xff\xff\xff\xff\xff\xff\xff" + body
    else:
        segment = _el(0x18538067, body)
    return ebml_header(doctype) + segment


@pytest.mark.parametrize("unknown_sizes", [False, True])
def test_matroska_date_duration_and_frames(tmp_path: Path, unknown_sizes: bool) -> None:
    p = tmp_path / "a.mkv"
    p.write_bytes(mkv(date_ns=123_456_789_000_000_000 + 1000, unknown_sizes=unknown_sizes))
    t = read_container_times(p)
    assert t.container == "matroska" and t.creation_utc_known and t.creation_resolution_s == 1e-9
    assert t.creation == MATROSKA_EPOCH + timedelta(seconds=123_456_789, microseconds=1)
    assert t.duration_s == pytest.approx(2.0) and t.frame_period_s == pytest.approx(1 / 60, abs=1e-9)
    assert t.frame_count == 3 * (10 + 1 + 3)


def test_matroska_without_date_and_a_negative_one(tmp_path: Path) -> None:
    p = tmp_path / "a.webm"
    p.write_bytes(mkv(date_ns=None, doctype="webm"))
    assert read_container_times(p).creation is None
    p.write_bytes(mkv(date_ns=-86_400 * 10**9))
    assert read_container_times(p).creation == MATROSKA_EPOCH - timedelta(days=1)
    p.write_bytes(mkv(doctype="notmkv"))
    with pytest.raises(ContainerError, match="DocType 'notmkv'"):
        read_container_times(p)


def test_the_tests_matroska_writer_states_its_date(tmp_path: Path) -> None:
    imgs = [np.full((24, 32), 10 * k, np.uint8) for k in range(7)]
    write_mkv(tmp_path / "w.mkv", imgs, [k / 60 for k in range(7)], date_utc_ns=5_000_000_123)
    t = read_container_times(tmp_path / "w.mkv")
    assert t.frame_count == 7 and t.creation == MATROSKA_EPOCH + timedelta(seconds=5, microseconds=0.123)


# ------------------------------------------------------------------ AVI

def chunk(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<4sI", kind, len(payload)) + payload + (b"\0" if len(payload) % 2 else b"")


def riff_list(kind: bytes, payload: bytes) -> bytes:
    return chunk(b"LIST", kind + payload)


def avi(*, frames: int = 90, idit: bytes | None = b"MON MAY 04 10:20:30 2026\n\0") -> bytes:
    avih = chunk(b"avih", struct.pack("<10I", 16667, 0, 0, 0, frames, 0, 1, 0, 64, 48) + bytes(16))
    strh = chunk(b"strh", b"vids" + b"MJPG" + struct.pack("<IHHIIIII", 0, 0, 0, 0, 1, 60, 0, frames)
                 + bytes(20))
    hdrl = riff_list(b"hdrl", avih + riff_list(b"strl", strh) + (chunk(b"IDIT", idit) if idit else b""))
    body = b"AVI " + hdrl + riff_list(b"movi", chunk(b"00dc", b"abc"))
    return b"RIFF" + struct.pack("<I", len(body)) + body


def test_avi_frames_and_idit_local_time(tmp_path: Path) -> None:
    p = tmp_path / "a.avi"
    p.write_bytes(avi())
    t = read_container_times(p)
    assert t.container == "avi" and t.frame_count == 90 and t.frame_period_s == pytest.approx(1 / 60)
    assert t.creation == datetime(2026, 5, 4, 10, 20, 30) and not t.creation_utc_known  # no time zone
    assert t.duration_s == pytest.approx(1.5) and t.creation_resolution_s == 1.0
    p.write_bytes(avi(idit=b"some day\0"))  # a date in a form not known: none rather than a guess
    assert read_container_times(p).creation is None


# ------------------------------------------------------------------ real writers

@pytest.mark.parametrize(("fourcc", "ext"), [("mp4v", "mp4"), ("MJPG", "avi")])
def test_opencv_files_carry_frame_counts_and_no_creation_time(tmp_path: Path, fourcc: str, ext: str) -> None:
    p = tmp_path / f"a.{ext}"
    w = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*fourcc), 60.0, (64, 48), True)
    for k in range(17):
        w.write(np.full((48, 64, 3), 10 * k, np.uint8))
    w.release()
    t = read_container_times(p)
    assert t.frame_count == 17 and t.creation is None
    assert t.frame_period_s == pytest.approx(1 / 60) and t.duration_s == pytest.approx(17 / 60)


def test_a_creation_time_written_into_an_opencv_mp4_is_read(tmp_path: Path) -> None:
    # OpenCV (ffmpeg's muxer) leaves mvhd creation_time 0; a camera's file has it set: set it in place
    p = tmp_path / "a.mp4"
    w = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"mp4v"), 60.0, (64, 48), True)
    for k in range(5):
        w.write(np.full((48, 64, 3), 10 * k, np.uint8))
    w.release()
    data = bytearray(p.read_bytes())
    at = data.index(b"mvhd") + 4
    assert data[at] == 0 and data[at + 4:at + 8] == bytes(4)  # version 0, creation_time unset
    data[at + 4:at + 8] = struct.pack(">I", int((T0 - MP4_EPOCH).total_seconds()))
    p.write_bytes(bytes(data))
    t = read_container_times(p)
    assert t.creation == T0 and t.creation_resolution_s == 1.0 and t.frame_count == 5


# ------------------------------------------------------------------ malformed input: an error, never a crash

def test_not_a_container(tmp_path: Path) -> None:
    p = tmp_path / "x.mp4"
    p.write_bytes(b"hello world, no video here")
    with pytest.raises(ContainerError, match="not an MP4/MOV, Matroska/WebM or AVI"):
        read_container_times(p)
    with pytest.raises(ContainerError, match="cannot open"):
        read_container_times(tmp_path / "missing.mp4")


VALID = {"mp4": mp4(), "mkv": mkv(), "mkv_unknown": mkv(unknown_sizes=True), "avi": avi()}


def _read(tmp_path: Path, data: bytes) -> ContainerTimes | None:
    p = tmp_path / "f.bin"
    p.write_bytes(data)
    try:
        return read_container_times(p)
    except ContainerError as exc:
        assert str(p) in str(exc)
        return None


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(sorted(VALID)), cut=st.integers(0, 4000))
def test_truncated_files_raise_or_parse(tmp_path: Path, kind: str, cut: int) -> None:
    data = VALID[kind]
    _read(tmp_path, data[:cut % (len(data) + 1)])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(sorted(VALID)),
       edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=6))
def test_corrupted_bytes_raise_or_parse(tmp_path: Path, kind: str, edits: list[tuple[int, int]]) -> None:
    data = bytearray(VALID[kind])
    for pos, value in edits:
        data[pos % len(data)] = value
    _read(tmp_path, bytes(data))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(prefix=st.sampled_from([b"", b"\0\0\0\x18ftyp", bytes.fromhex("1A45DFA3"), b"RIFF\0\0\0\0AVI "]),
       tail=st.binary(max_size=300))
def test_random_bytes_behind_a_signature_raise_or_parse(tmp_path: Path, prefix: bytes, tail: bytes) -> None:
    _read(tmp_path, prefix + tail)


# ------------------------------------------------------------------ the offset window

def _times(created: datetime | None, duration_s: float = 10.0, resolution_s: float = 1.0) -> ContainerTimes:
    return ContainerTimes("mp4", created, resolution_s if created else None, "mvhd creation_time" if created
                          else None, duration_s, 600, 1 / 60)


def test_window_from_creation_times_states_resolution_and_conventions() -> None:
    w = offset_window({"a": _times(T0), "b": _times(T0 + timedelta(seconds=3), duration_s=11.0)},
                      {"a": 0.0, "b": 0.0}, reference="a", clock_agreement_s=0.5)
    # start convention +3 s, end convention +2 s: centre 2.5, half 0.5 + 1 + 1 + 0.5
    assert w.source == "containers"
    assert w.prior_offset_s == pytest.approx(2.5) and w.max_offset_s == pytest.approx(3.0)
    assert "whole seconds" in w.statement and "+3.000 or +2.000 s" in w.statement
    assert w.containers["estimate"]["resolution_s"] == [1.0, 1.0]


def test_window_first_stamps_and_options_win() -> None:
    times = {"a": _times(T0, resolution_s=1e-9), "b": _times(T0 + timedelta(seconds=0.25), resolution_s=1e-9)}
    w = offset_window(times, {"a": 0.1, "b": 0.0}, reference="a", clock_agreement_s=0.01)
    assert w.prior_offset_s == pytest.approx(0.35) and w.max_offset_s == pytest.approx(0.01, abs=1e-8)
    w = offset_window(times, {"a": 0.0, "b": 0.0}, reference="a", max_offset_s=4.0)
    assert (w.prior_offset_s, w.max_offset_s, w.source) == (pytest.approx(0.25), 4.0, "containers")
    w = offset_window(times, {"a": 0.0, "b": 0.0}, reference="a", prior_offset_s=-1.0)
    assert (w.prior_offset_s, w.max_offset_s, w.source) == (-1.0, FALLBACK_MAX_OFFSET_S, "options")


def test_window_without_usable_times_is_the_default_and_says_why() -> None:
    w = offset_window({"a": _times(T0), "b": _times(None)}, {}, reference="a")
    assert (w.prior_offset_s, w.max_offset_s, w.source) == (0.0, FALLBACK_MAX_OFFSET_S, "default")
    assert "the other video's container states no creation time" in w.statement
    local = ContainerTimes("avi", datetime(2026, 5, 4, 10, 20, 30), 1.0, "IDIT (local time)")
    w = offset_window({"a": _times(T0), "b": local}, {}, reference="a")
    assert w.source == "default" and "not comparable" in w.statement
    w = offset_window({"a": ContainerError("x: bad"), "b": local}, {}, reference="a", max_offset_s=3.0)
    assert w.source == "options" and w.containers["a"] == {"error": "x: bad"}
    with pytest.raises(ValueError, match="clock_agreement_s"):
        offset_window({"a": local, "b": local}, {}, reference="a", clock_agreement_s=-1.0)

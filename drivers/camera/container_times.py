"""When a video file says it was recorded, how long it lasts and how many frames it holds: read from the
container's own headers (pure Python, no decoding).

- **MP4 / MOV** (ISO BMFF, QuickTime): ``moov/mvhd`` creation_time (whole seconds since 1904-01-01, UTC by
  the standard — many cameras write local time), the video track's ``tkhd``/``mdhd`` creation_time when the
  movie's is unset, its ``mdhd`` duration and the sample count of its ``stts`` (the frame count). A
  creation_time of 0 is "not set" (what ffmpeg/OpenCV write without metadata).
- **Matroska / WebM** (EBML): ``Segment/Info/DateUTC`` (ns since 2001-01-01 UTC; signed), ``Duration``
  (in ``TimestampScale`` units), and the frame count by counting the video track's blocks (laced blocks
  count their frames) — block headers only.
- **AVI** (RIFF): the ``avih``/``strh``/``dmlh`` frame counts and frame period, and an ``IDIT`` chunk's
  date (DateTimeOriginal, whole seconds, local time: no time zone) when the camera wrote one.

A creation time is the camera's own clock, stated with the container's **resolution** (1 s for MP4/MOV and
AVI; the stored unit for Matroska — the camera's clock may be coarser, the file cannot say) and whether it
is on UTC or an unstated local time. Whether it marks the start or the end of the recording the containers
do not say either; :mod:`rig.deploy.container_prior` allows for both.

Malformed or truncated input raises :class:`ContainerError` naming the file, the element/box and the byte
offset; a file in none of these containers raises it too. Nothing else escapes (no ``struct.error``,
``IndexError``, ``UnicodeDecodeError``).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any, BinaryIO

__all__ = ["ContainerError", "ContainerTimes", "read_container_times"]

MP4_EPOCH = datetime(1904, 1, 1, tzinfo=UTC)
MATROSKA_EPOCH = datetime(2001, 1, 1, tzinfo=UTC)
MAX_HEADER_BYTES = 64 << 20  # a moov box or an AVI header list larger than this is not a header


class ContainerError(ValueError):
    """The file's container headers cannot be read (the message names the file, the part and the offset)."""


@dataclass(frozen=True)
class ContainerTimes:
    """What a container states about its recording (units in the names; None: not stated).

    ``creation``: the creation time as written (tz-aware UTC when the container defines UTC, naive when it
    is an unstated local time); ``creation_resolution_s``: its unit; ``creation_source``: the field read.
    """

    container: str  # "mp4", "matroska", "avi"
    creation: datetime | None = None
    creation_resolution_s: float | None = None
    creation_source: str | None = None
    duration_s: float | None = None
    frame_count: int | None = None
    frame_period_s: float | None = None

    @property
    def creation_utc_known(self) -> bool:
        return self.creation is not None and self.creation.tzinfo is not None

    def creation_s(self) -> float | None:
        """The creation time as seconds since 1970-01-01 on its own clock (a naive local time is read as
        if it were UTC: only differences between two such times mean anything)."""
        if self.creation is None:
            return None
        c = self.creation if self.creation.tzinfo is not None else self.creation.replace(tzinfo=UTC)
        return (c - datetime(1970, 1, 1, tzinfo=UTC)).total_seconds()

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["creation"] = self.creation.isoformat() if self.creation is not None else None
        out["creation_utc_known"] = self.creation_utc_known
        return out


class _Reader:
    """Bounded reads of one open file: every short read is a :class:`ContainerError`."""

    def __init__(self, f: BinaryIO, path: Path, size: int) -> None:
        self.f, self.path, self.size = f, path, size

    def read(self, offset: int, n: int, what: str) -> bytes:
        if offset < 0 or n < 0 or offset + n > self.size:
            raise self.error(f"{what} ({n} bytes) runs past the end of the file", offset)
        self.f.seek(offset)
        data = self.f.read(n)
        if len(data) != n:
            raise self.error(f"{what}: only {len(data)} of {n} bytes could be read", offset)
        return data

    def error(self, message: str, offset: int) -> ContainerError:
        return ContainerError(f"{self.path}: {message} (byte {offset})")


def _after(epoch: datetime, seconds: float, r: _Reader, offset: int) -> datetime:
    """``epoch`` + ``seconds`` (to the µs), or a :class:`ContainerError` when out of datetime's range."""
    try:
        return epoch + timedelta(microseconds=round(seconds * 1e6))
    except OverflowError:
        raise r.error(f"creation time {seconds!r} s after {epoch.date()}: out of range", offset) from None


# ------------------------------------------------------------------ MP4 / MOV

_MP4_CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl", b"edts"}


def _boxes(data: bytes, start: int, end: int, base: int, r: _Reader) -> Iterator[tuple[bytes, int, int]]:
    """(type, payload start, payload end) of the boxes in ``data[start:end]`` (``base``: file offset of
    ``data[0]``, for messages)."""
    pos = start
    while pos < end:
        if end - pos < 8:
            raise r.error(f"a box header needs 8 bytes, {end - pos} left", base + pos)
        size, kind = struct.unpack_from(">I4s", data, pos)
        header = 8
        if size == 1:
            if end - pos < 16:
                raise r.error(f"box {kind!r}: a 64-bit size needs 16 header bytes", base + pos)
            (size,) = struct.unpack_from(">Q", data, pos + 8)
            header = 16
        elif size == 0:
            size = end - pos
        if size < header or pos + size > end:
            raise r.error(f"box {kind!r} declares {size} bytes: outside its parent (header {header}, "
                          f"{end - pos} left)", base + pos)
        yield kind, pos + header, pos + size
        pos += size


def _top_level_moov(r: _Reader) -> tuple[bytes, int]:
    """The ``moov`` box's bytes (header included) and its file offset; top-level boxes are skipped by size."""
    pos = 0
    while pos + 8 <= r.size:
        size, kind = struct.unpack(">I4s", r.read(pos, 8, "box header"))
        header = 8
        if size == 1:
            (size,) = struct.unpack(">Q", r.read(pos + 8, 8, f"box {kind!r} 64-bit size"))
            header = 16
        elif size == 0:
            size = r.size - pos
        if size < header or pos + size > r.size:
            raise r.error(f"top-level box {kind!r} declares {size} bytes; the file has {r.size - pos} left "
                          "(truncated: a recording cut short before its index was written?)", pos)
        if kind == b"moov":
            if size > MAX_HEADER_BYTES:
                raise r.error(f"moov box of {size} bytes: larger than any header ({MAX_HEADER_BYTES})", pos)
            return r.read(pos, size, "moov box"), pos
        pos += size
    raise r.error("no moov box (the movie header): truncated, or a fragmented MP4 without one", pos)


def _full_box_times(data: bytes, start: int, end: int, *, what: str, r: _Reader, base: int
                    ) -> tuple[int, int, int]:
    """(creation_time s since 1904, timescale, duration) of an mvhd/mdhd payload."""
    if end - start < 4:
        raise r.error(f"{what}: payload of {end - start} bytes", base + start)
    version = data[start]
    layout, need = ((">QQIQ", 28), (">IIII", 16))[version == 0] if version in (0, 1) else (None, 0)
    if layout is None:
        raise r.error(f"{what}: version {version} (0 or 1 allowed)", base + start)
    if end - start < 4 + need:
        raise r.error(f"{what} version {version}: payload of {end - start} bytes, needs {4 + need}",
                      base + start)
    created, _, timescale, duration = struct.unpack_from(layout, data, start + 4)
    return created, timescale, duration


def _tkhd_created(data: bytes, start: int, end: int, r: _Reader, base: int) -> int:
    version = data[start] if end > start else -1
    need = {0: 8, 1: 16}.get(version)
    if need is None or end - start < 4 + need:
        raise r.error(f"tkhd: version {version}, payload of {end - start} bytes", base + start)
    return int(struct.unpack_from(">Q" if version == 1 else ">I", data, start + 4)[0])


@dataclass
class _Track:
    handler: bytes = b""
    created: int = 0
    media_created: int = 0
    timescale: int = 0
    duration: int = 0
    samples: int | None = None


def _mp4_track(data: bytes, start: int, end: int, r: _Reader, base: int) -> _Track:
    tr = _Track()
    stack = [(start, end)]
    while stack:
        s, e = stack.pop()
        for kind, ps, pe in _boxes(data, s, e, base, r):
            if kind in _MP4_CONTAINERS:
                stack.append((ps, pe))
            elif kind == b"tkhd":
                tr.created = _tkhd_created(data, ps, pe, r, base)
            elif kind == b"mdhd":
                times = _full_box_times(data, ps, pe, what="mdhd", r=r, base=base)
                tr.media_created, tr.timescale, tr.duration = times
            elif kind == b"hdlr":
                if pe - ps < 12:
                    raise r.error(f"hdlr: payload of {pe - ps} bytes, needs 12", base + ps)
                tr.handler = data[ps + 8:ps + 12]
            elif kind == b"stts":
                if pe - ps < 8:
                    raise r.error(f"stts: payload of {pe - ps} bytes, needs 8", base + ps)
                (n,) = struct.unpack_from(">I", data, ps + 4)
                if pe - ps < 8 + 8 * n:
                    raise r.error(f"stts: {n} entries declared, {(pe - ps - 8) // 8} present", base + ps)
                tr.samples = sum(struct.unpack_from(f">{2 * n}I", data, ps + 8)[0::2])
    return tr


def _mp4(r: _Reader) -> ContainerTimes:
    moov, base = _top_level_moov(r)
    header = 16 if struct.unpack_from(">I", moov, 0)[0] == 1 else 8
    movie: tuple[int, int, int] | None = None
    tracks: list[_Track] = []
    for kind, ps, pe in _boxes(moov, header, len(moov), base, r):
        if kind == b"mvhd":
            movie = _full_box_times(moov, ps, pe, what="mvhd", r=r, base=base)
        elif kind == b"trak":
            tracks.append(_mp4_track(moov, ps, pe, r, base))
    if movie is None:
        raise r.error("the moov box has no mvhd (movie header)", base)
    video = next((t for t in tracks if t.handler == b"vide"), None)
    created, source = movie[0], "mvhd creation_time"
    if not created and video is not None:
        created, source = ((video.created, "video tkhd creation_time") if video.created
                           else (video.media_created, "video mdhd creation_time"))
    duration_s = movie[2] / movie[1] if movie[1] else None
    frames, period = None, None
    if video is not None:
        if video.timescale:
            duration_s = video.duration / video.timescale
        frames = video.samples
        if frames and duration_s:
            period = duration_s / frames
    return ContainerTimes("mp4", _after(MP4_EPOCH, created, r, base) if created else None,
                          1.0 if created else None, source if created else None, duration_s, frames, period)


# ------------------------------------------------------------------ Matroska / WebM

_EBML, _SEGMENT, _INFO, _TRACKS, _CLUSTER = 0x1A45DFA3, 0x18538067, 0x1549A966, 0x1654AE6B, 0x1F43B675
_LEVEL1 = {_INFO, _TRACKS, _CLUSTER, 0x114D9B74, 0x1C53BB6B, 0x1941A469, 0x1043A770, 0x1254C367, 0xEC}
_UNKNOWN = -1


def _vint(r: _Reader, pos: int, what: str, *, keep_marker: bool) -> tuple[int, int]:
    """(value, length) of an EBML variable-length integer at ``pos``; an all-ones size is ``_UNKNOWN``."""
    first = r.read(pos, 1, what)[0]
    if first == 0:
        raise r.error(f"{what}: invalid EBML length byte 0x00", pos)
    length = 9 - first.bit_length()
    raw = int.from_bytes(r.read(pos, length, what), "big")
    value = raw if keep_marker else raw & ((1 << (7 * length)) - 1)
    if not keep_marker and value == (1 << (7 * length)) - 1:
        return _UNKNOWN, length
    return value, length


def _elements(r: _Reader, start: int, end: int) -> Iterator[tuple[int, int, int, int]]:
    """(id, header start, payload start, payload end) of the EBML elements in ``start``…``end``; an
    unknown-size element runs to ``end`` (an unknown-size cluster ends at the next level-1 id)."""
    pos = start
    while pos < end:
        eid, n_id = _vint(r, pos, "element id", keep_marker=True)
        if n_id > 4:
            raise r.error(f"element id of {n_id} bytes (at most 4)", pos)
        size, n_size = _vint(r, pos + n_id, f"element 0x{eid:X} size", keep_marker=False)
        ps = pos + n_id + n_size
        pe = end if size == _UNKNOWN else ps + size
        if pe > end:
            raise r.error(f"element 0x{eid:X} declares {size} bytes; only {end - ps} left in its parent "
                          "(truncated?)", pos)
        yield eid, pos, ps, pe
        pos = pe


def _uint_el(r: _Reader, ps: int, pe: int, what: str) -> int:
    if pe - ps > 8:
        raise r.error(f"{what}: integer of {pe - ps} bytes (at most 8)", ps)
    return int.from_bytes(r.read(ps, pe - ps, what), "big")


def _matroska_info(r: _Reader, ps: int, pe: int) -> tuple[int, float | None, int | None]:
    scale, duration, date = 1_000_000, None, None
    for eid, _, s, e in _elements(r, ps, pe):
        if eid == 0x2AD7B1:
            scale = _uint_el(r, s, e, "TimestampScale")
            if scale <= 0:
                raise r.error("TimestampScale 0", s)
        elif eid == 0x4489:
            if e - s not in (4, 8):
                raise r.error(f"Duration: a float of {e - s} bytes (4 or 8)", s)
            duration = struct.unpack(">f" if e - s == 4 else ">d", r.read(s, e - s, "Duration"))[0]
            if not math.isfinite(duration) or duration < 0:
                raise r.error(f"Duration {duration!r}: not a finite non-negative number", s)
        elif eid == 0x4461:
            if e - s != 8:
                raise r.error(f"DateUTC: {e - s} bytes (8)", s)
            date = int.from_bytes(r.read(s, 8, "DateUTC"), "big", signed=True)
    return scale, duration, date


def _matroska_video_track(r: _Reader, ps: int, pe: int) -> tuple[int | None, int | None]:
    """(track number, DefaultDuration ns) of the first video track."""
    for eid, _, s, e in _elements(r, ps, pe):
        if eid != 0xAE:
            continue
        number, kind, default = None, None, None
        for cid, _, cs, ce in _elements(r, s, e):
            if cid == 0xD7:
                number = _uint_el(r, cs, ce, "TrackNumber")
            elif cid == 0x83:
                kind = _uint_el(r, cs, ce, "TrackType")
            elif cid == 0x23E383:
                default = _uint_el(r, cs, ce, "DefaultDuration")
        if kind == 1:
            return number, default
    return None, None


def _block_frames(r: _Reader, ps: int, pe: int, track: int) -> int:
    """Frames of ``track`` in a (Simple)Block payload: 1, or the lace count for a laced block."""
    number, n = _vint(r, ps, "block track number", keep_marker=False)
    if number != track:
        return 0
    if pe - ps < n + 3:
        raise r.error(f"block of {pe - ps} bytes: shorter than its header", ps)
    flags = r.read(ps + n + 2, 1, "block flags")[0]
    if not flags & 0x06:
        return 1
    if pe - ps < n + 4:
        raise r.error("laced block without its lace count", ps)
    return r.read(ps + n + 3, 1, "lace count")[0] + 1


def _cluster_frames(r: _Reader, ps: int, pe: int, track: int) -> tuple[int, int]:
    """(frames of ``track``, where the cluster ends): an unknown-size cluster ends at the next level-1 id."""
    frames = 0
    for eid, hs, s, e in _elements(r, ps, pe):
        if eid in _LEVEL1:
            return frames, hs
        if eid == 0xA3:
            frames += _block_frames(r, s, e, track)
        elif eid == 0xA0:
            frames += sum(_block_frames(r, bs, be, track) for bid, _, bs, be in _elements(r, s, e)
                          if bid == 0xA1)
    return frames, pe


def _matroska(r: _Reader) -> ContainerTimes:
    elements = _elements(r, 0, r.size)
    _, _, ps, pe = next(elements)
    doctype = "matroska"
    for cid, _, s, e in _elements(r, ps, pe):
        if cid == 0x4282:
            doctype = r.read(s, e - s, "DocType").decode("ascii", "replace")
    if doctype not in ("matroska", "webm"):
        raise r.error(f"EBML DocType {doctype!r}: not Matroska/WebM", ps)
    segment = next(((s, e) for cid, _, s, e in elements if cid == _SEGMENT), None)
    if segment is None:
        raise r.error("no Segment element", pe)
    scale, duration, date, track, default, frames = 1_000_000, None, None, None, None, 0
    pos, end = segment
    while pos < end:
        eid, _, s, e = next(_elements(r, pos, end))
        if eid == _INFO:
            scale, duration, date = _matroska_info(r, s, e)
        elif eid == _TRACKS:
            track, default = _matroska_video_track(r, s, e)
        elif eid == _CLUSTER and track is not None:
            n, e = _cluster_frames(r, s, e, track)
            frames += n
        pos = e
    created = _after(MATROSKA_EPOCH, date * 1e-9, r, segment[0]) if date is not None else None
    duration_s = duration * scale * 1e-9 if duration is not None else None
    period = default * 1e-9 if default else None  # Duration/frames would be an estimate
    return ContainerTimes("matroska", created, 1e-9 if created else None,
                          "Info/DateUTC" if created else None, duration_s,
                          frames if track is not None else None, period)


# ------------------------------------------------------------------ AVI

_IDIT_FORMATS = ("%a %b %d %H:%M:%S %Y", "%Y:%m:%d %H:%M:%S", "%Y-%m-%d %H:%M:%S", "%Y-%m-%dT%H:%M:%S")


def _chunks(data: bytes, start: int, end: int, r: _Reader) -> Iterator[tuple[bytes, int, int]]:
    pos = start
    while pos + 8 <= end:
        kind, size = struct.unpack_from("<4sI", data, pos)
        if pos + 8 + size > end:
            raise r.error(f"chunk {kind!r} declares {size} bytes; {end - pos - 8} left", pos)
        yield kind, pos + 8, pos + 8 + size
        pos += 8 + size + (size & 1)


def _idit(text: bytes) -> datetime | None:
    s = text.split(b"\0")[0].decode("latin-1").strip()
    for fmt in _IDIT_FORMATS:
        try:
            return datetime.strptime(s, fmt)
        except ValueError:
            continue
    return None  # a date in a form not listed: no creation time rather than a guess


def _avi(r: _Reader) -> ContainerTimes:
    pos, hdrl = 12, None
    while pos + 12 <= r.size:
        kind, size = struct.unpack("<4sI", r.read(pos, 8, "RIFF chunk header"))
        if kind == b"LIST" and r.read(pos + 8, 4, "LIST type") == b"hdrl":
            if size > MAX_HEADER_BYTES or pos + 8 + size > r.size:
                raise r.error(f"hdrl list of {size} bytes: truncated or not a header", pos)
            hdrl = r.read(pos, 8 + size, "hdrl list")
            break
        pos += 8 + size + (size & 1)
    if hdrl is None:
        raise r.error("no hdrl list (the AVI header)", pos)
    micro, frames, created, length, rate = 0, None, None, None, None
    stack = [(12, len(hdrl))]
    while stack:
        s, e = stack.pop()
        for kind, cs, ce in _chunks(hdrl, s, e, r):
            if kind == b"LIST" and ce - cs >= 4:
                stack.append((cs + 4, ce))
            elif kind == b"avih" and ce - cs >= 20:
                micro, = struct.unpack_from("<I", hdrl, cs)
                frames = frames or struct.unpack_from("<I", hdrl, cs + 16)[0]
            elif kind == b"strh" and ce - cs >= 36 and hdrl[cs:cs + 4] == b"vids" and length is None:
                scale, rate_num, _, length = struct.unpack_from("<IIII", hdrl, cs + 20)
                rate = rate_num / scale if scale and rate_num else None
            elif kind == b"dmlh" and ce - cs >= 4:
                frames = struct.unpack_from("<I", hdrl, cs)[0] or frames  # OpenDML: all RIFF parts
            elif kind == b"IDIT":
                created = _idit(hdrl[cs:ce])
    frames = frames if frames else length
    period = 1.0 / rate if rate else (micro * 1e-6 if micro else None)
    return ContainerTimes("avi", created, 1.0 if created else None, "IDIT (local time)" if created else None,
                          frames * period if frames and period else None, frames or None, period)


def read_container_times(path: str | Path) -> ContainerTimes:
    """The container's times and frame count (module doc); :class:`ContainerError` when unreadable."""
    p = Path(path)
    try:
        f = p.open("rb")
    except OSError as exc:
        raise ContainerError(f"{p}: cannot open ({exc.strerror or exc})") from exc
    with f:
        size = p.stat().st_size
        r = _Reader(f, p, size)
        head = f.read(12)
        if len(head) >= 8 and head[4:8] in (b"ftyp", b"moov", b"mdat", b"wide", b"free", b"skip", b"pnot"):
            return _mp4(r)
        if head[:4] == bytes.fromhex("1A45DFA3"):
            return _matroska(r)
        if head[:4] == b"RIFF" and head[8:12] in (b"AVI ", b"AVIX"):
            return _avi(r)
        raise ContainerError(f"{p}: not an MP4/MOV, Matroska/WebM or AVI file (first bytes {head[:12]!r})")

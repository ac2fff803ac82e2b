"""A live Matroska stream of JPEG frames, each stamped with the camera's own clock: the bytes GStreamer's
``matroskamux streamable=true`` or ``ffmpeg -f matroska -listen 1`` serve (``video/x-matroska``), which
FFmpeg (``cv2.VideoCapture(url, cv2.CAP_FFMPEG)``) opens and reports per frame (``CAP_PROP_POS_MSEC``).

Layout (EBML, Matroska DocType version 4): the EBML header; a **Segment of unknown size** (a live stream
ends when the connection does) holding ``Info`` (``TimestampScale`` :data:`TIMESTAMP_SCALE_NS` = 1 µs per
tick, muxing and writing application), ``Tracks`` (one video ``TrackEntry``: number 1, ``V_MJPEG``, no
lacing, the image size), then **one Cluster per frame** (known size; ``Timestamp`` = the frame's time stamp
in ticks, one keyframe ``SimpleBlock`` at relative time 0). One cluster per frame keeps every frame
self-contained and its stamp exact at any magnitude (a SimpleBlock's relative time is only 16 bits).
"""

from __future__ import annotations

import math

__all__ = ["CONTENT_TYPE", "TIMESTAMP_SCALE_NS", "frame_cluster", "stream_header", "ticks"]

CONTENT_TYPE = "video/x-matroska"
TIMESTAMP_SCALE_NS = 1000  # 1 µs per tick
UNKNOWN_SIZE = b"\x01\xff\xff\xff\xff\xff\xff\xff"  # an 8-byte EBML size with every value bit set
TRACK = 1

# EBML and Matroska element IDs (RFC 8794, RFC 9559)
EBML, EBML_VERSION, EBML_READ_VERSION = 0x1A45DFA3, 0x4286, 0x42F7
EBML_MAX_ID_LENGTH, EBML_MAX_SIZE_LENGTH = 0x42F2, 0x42F3
DOC_TYPE, DOC_TYPE_VERSION, DOC_TYPE_READ_VERSION = 0x4282, 0x4287, 0x4285
SEGMENT, INFO, TIMESTAMP_SCALE, MUXING_APP, WRITING_APP = 0x18538067, 0x1549A966, 0x2AD7B1, 0x4D80, 0x5741
TRACKS, TRACK_ENTRY, TRACK_NUMBER, TRACK_UID, TRACK_TYPE = 0x1654AE6B, 0xAE, 0xD7, 0x73C5, 0x83
FLAG_LACING, CODEC_ID, VIDEO, PIXEL_WIDTH, PIXEL_HEIGHT = 0x9C, 0x86, 0xE0, 0xB0, 0xBA
CLUSTER, CLUSTER_TIMESTAMP, SIMPLE_BLOCK = 0x1F43B675, 0xE7, 0xA3


def _size(n: int) -> bytes:
    """EBML variable-length size of ``n`` bytes (the shortest; all-ones is reserved for 'unknown')."""
    for length in range(1, 9):
        if n < (1 << (7 * length)) - 1:
            return (n | (1 << (7 * length))).to_bytes(length, "big")
    raise ValueError(f"EBML element of {n} bytes is too large")


def _element(element_id: int, payload: bytes) -> bytes:
    return element_id.to_bytes((element_id.bit_length() + 7) // 8, "big") + _size(len(payload)) + payload


def _uint(element_id: int, value: int) -> bytes:
    if value < 0:
        raise ValueError(f"EBML unsigned integer element 0x{element_id:X}: {value} < 0")
    return _element(element_id, value.to_bytes(max(1, (value.bit_length() + 7) // 8), "big"))


def _text(element_id: int, value: str) -> bytes:
    return _element(element_id, value.encode("ascii"))


def stream_header(width_px: int, height_px: int, *, app: str = "rig mock lab") -> bytes:
    """EBML header, the open (unknown-size) Segment, Info and Tracks of a ``width_px``×``height_px`` MJPEG
    stream: everything before the first frame."""
    if width_px < 1 or height_px < 1:
        raise ValueError(f"width_px={width_px}, height_px={height_px}; allowed: ≥ 1 each")
    ebml = _element(EBML, _uint(EBML_VERSION, 1) + _uint(EBML_READ_VERSION, 1) + _uint(EBML_MAX_ID_LENGTH, 4)
                    + _uint(EBML_MAX_SIZE_LENGTH, 8) + _text(DOC_TYPE, "matroska")
                    + _uint(DOC_TYPE_VERSION, 4) + _uint(DOC_TYPE_READ_VERSION, 2))
    info = _element(INFO, _uint(TIMESTAMP_SCALE, TIMESTAMP_SCALE_NS) + _text(MUXING_APP, app)
                    + _text(WRITING_APP, app))
    video = _element(VIDEO, _uint(PIXEL_WIDTH, width_px) + _uint(PIXEL_HEIGHT, height_px))
    entry = _element(TRACK_ENTRY, _uint(TRACK_NUMBER, TRACK) + _uint(TRACK_UID, TRACK) + _uint(TRACK_TYPE, 1)
                     + _uint(FLAG_LACING, 0) + _text(CODEC_ID, "V_MJPEG") + video)
    segment_start = SEGMENT.to_bytes(4, "big") + UNKNOWN_SIZE
    return ebml + segment_start + info + _element(TRACKS, entry)


def ticks(timestamp_s: float) -> int:
    """``timestamp_s`` (≥ 0, finite) in :data:`TIMESTAMP_SCALE_NS` ticks, rounded to the nearest."""
    if not (math.isfinite(timestamp_s) and timestamp_s >= 0.0):
        raise ValueError(f"timestamp_s={timestamp_s!r}; allowed: finite and ≥ 0 (stamps are unsigned)")
    return round(timestamp_s * 1e9 / TIMESTAMP_SCALE_NS)


def frame_cluster(timestamp_s: float, jpeg: bytes) -> bytes:
    """One Cluster: ``jpeg`` as a keyframe SimpleBlock of track 1 at ``timestamp_s`` (camera clock, s)."""
    block = _element(SIMPLE_BLOCK, bytes([0x80 | TRACK]) + b"\x00\x00" + b"\x80" + jpeg)
    return _element(CLUSTER, _uint(CLUSTER_TIMESTAMP, ticks(timestamp_s)) + block)

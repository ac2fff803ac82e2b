"""Test support: write a Matroska (MKV) file of Motion-JPEG frames with a chosen time stamp per frame.

OpenCV's writer only makes constant-frame-rate files; a camera's own time stamps (gaps where frames were
dropped, repeats where a frame was duplicated) need a container that stores one time stamp per frame.
Matroska does (EBML elements, SimpleBlocks with a time relative to their cluster). Time stamp unit 10 µs.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from drivers.mock.mkv_stream import _element as _el  # the EBML writing is the lab stream's
from drivers.mock.mkv_stream import _text as _str
from drivers.mock.mkv_stream import _uint

_SCALE_NS = 10_000  # TimestampScale: 10 µs per tick
_CLUSTER_TICKS = 30_000  # a new cluster every 0.3 s keeps relative times within int16


def write_mkv(path: str | Path, images: Iterable[np.ndarray], timestamps_s: Iterable[float],
              *, quality: int = 92, date_utc_ns: int | None = None, duration: bool = True) -> int:
    """Write grey or BGR uint8 ``images`` as MJPEG in MKV at ``timestamps_s`` (non-decreasing); return the
    number of frames. ``date_utc_ns``: the Info/DateUTC (ns since 2001-01-01 UTC) to state, if any;
    ``duration``: whether Info states the Duration (a live recording's file may not)."""
    imgs, stamps = list(images), [float(t) for t in timestamps_s]
    if len(imgs) != len(stamps) or not imgs:
        raise ValueError(f"{len(imgs)} images and {len(stamps)} time stamps: need equal, non-zero counts")
    h, w = imgs[0].shape[:2]
    header = _el(0x1A45DFA3, _uint(0x4286, 1) + _uint(0x42F7, 1) + _uint(0x42F2, 4) + _uint(0x42F3, 8)
                 + _str(0x4282, "matroska") + _uint(0x4287, 4) + _uint(0x4285, 2))
    ticks = [round(t * 1e9 / _SCALE_NS) for t in stamps]
    span = struct.pack(">d", float(ticks[-1] - ticks[0] + 1))
    info = _el(0x1549A966, _uint(0x2AD7B1, _SCALE_NS) + _str(0x4D80, "rig-tests") + _str(0x5741, "rig-tests")
               + (_el(0x4489, span) if duration else b"")
               + (b"" if date_utc_ns is None else _el(0x4461, date_utc_ns.to_bytes(8, "big", signed=True))))
    video = _el(0xE0, _uint(0xB0, w) + _uint(0xBA, h))
    track = _el(0xAE, _uint(0xD7, 1) + _uint(0x73C5, 1) + _uint(0x83, 1) + _str(0x86, "V_MJPEG") + video)
    tracks = _el(0x1654AE6B, track)
    clusters = b""
    start = 0
    t0 = ticks[0]
    while start < len(ticks):
        base = ticks[start] - t0
        blocks = b""
        k = start
        while k < len(ticks) and ticks[k] - t0 - base < _CLUSTER_TICKS:
            ok, jpg = cv2.imencode(".jpg", imgs[k], [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:
                raise ValueError(f"frame {k} could not be JPEG-encoded")
            rel = ticks[k] - t0 - base
            blocks += _el(0xA3, b"\x81" + struct.pack(">hB", rel, 0x80) + jpg.tobytes())
            k += 1
        clusters += _el(0x1F43B675, _uint(0xE7, base) + blocks)
        start = k
    segment = _el(0x18538067, info + tracks + clusters)
    Path(path).write_bytes(header + segment)
    return len(imgs)

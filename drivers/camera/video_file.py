"""A recorded video file as a camera device: frames by decode index with the container's time stamps.

Consumer cameras record to files with no common clock, and their frame times cannot be taken for granted
(metrology notes §3: duplicated frames and variable frame rates shifted cameras by whole frames in other
tools). :class:`VideoFile` therefore

- decodes frames **in order, by index** (a start by a verified frame-exact seek: :meth:`VideoFile.frames`),
  and gives each frame the container's presentation time stamp (``CAP_PROP_POS_MSEC``, converted to seconds);
- detects **duplicated frames** only on evidence (see :class:`DuplicateJudge`): a repeated presentation time
  stamp; or, with advancing stamps (a constant-frame-rate container), an image that is the previous one
  again — its sensor noise not renewed (the median 8×8-block difference to the previous frame, over every
  4th block, below ``duplicate_ratio`` × the video's typical one, when the video carries sensor noise), or,
  in a video without usable noise, unchanged where the markers move: the frames that every 4th block cannot
  tell from a copy are judged at full resolution in the region where the markers moved — its change there
  at most 0.25 × the changes of the frames before and after it (both showing motion) while the change
  across it (frame k−2 → k+1) shows the motion continuing (a genuine frame at a turning point of an
  oscillation can repeat its predecessor's image, but then the frames either side mirror each other). A
  frame that repeats its predecessor with no such evidence (a still scene) is not counted: it is listed as
  ``undecided``. Each duplicate carries its evidence (the numbers compared) in the report. Deciding needs
  the next frame, so frames are delivered one decode behind;
- detects **dropped frames**: a gap between consecutive time stamps longer than (1 + ``gap_tolerance``)
  frame periods (``round(gap / period) − 1`` frames missing);
- reports all of them in a :class:`FrameTimeReport` (``.report``), and never shifts a time silently. A
  duplicate whose time stamp advanced (a constant-frame-rate container) is ambiguous: either the camera
  repeated the last image in place of a frame it missed (``duplicate_policy="replace"``, the default: later
  time stamps are right) or it inserted the copy (``"insert"``: every later time stamp is one period late
  and is corrected). The policy used and the corrections made are in the report;
- raises :class:`VideoTruncatedError` (with the report and the number of frames read; the frames were
  already delivered) when decoding stops before the frame count the container declares (counted in its
  own headers where it has them — MP4/MOV, Matroska, AVI — else the decoder's estimate), and
  :class:`VideoOpenError` when the file cannot be opened at all.

Images are 2-D uint8: the decoder's luma plane when it delivers one (verified on the first frame against
OpenCV's colour → grey conversion; about twice as fast), else the BGR image converted to grey.

``decoder_threads``: FFmpeg's decoding threads for this file (None: OpenCV's default, one per core). Where
several files are read at once, one each per core share (:func:`decoder_threads_per_file`) costs less CPU:
each frame is decoded in the reading thread, which then reads it from its own cache, and no frame is handed
between threads (two 1080p60 videos on 2 cores: ≈ 10 % less CPU decoding alone, ≈ 15 % less for ``rig
measure``, benchmarks/measure.py). The frames are the same.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TypedDict, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.camera.base import Frame, FrameGap
from drivers.camera.container_times import ContainerError, read_container_times
from drivers.camera.seek import frame_times_s, seek_frame
from drivers.cores import usable_cores
from drivers.roles import Camera

__all__ = ["DUPLICATE_POLICIES", "MAX_DECODER_THREADS", "FrameTimeReport", "VideoFile", "VideoFileError",
           "VideoOpenError", "VideoTruncatedError", "declared_frames", "decoder_threads_per_file",
           "find_gaps"]

DUPLICATE_POLICIES = ("replace", "insert")
_SUB = 4  # subsampling of the luma-plane check
# frames(start_s=…) starts this many frames early: the duplicate judge's history (31 noise floors) and its
# k−2 … k+1 neighbours are then those of a decode from the first frame when the wanted frames come
SEEK_PREROLL_FRAMES = 40
MAX_DECODER_THREADS = 64


def decoder_threads_per_file(files: int) -> int:
    """FFmpeg threads for each of ``files`` (≥ 1) videos decoded at once: the cores this process may use
    (:func:`drivers.cores.usable_cores`: its affinity, capped by a container's CPU quota) shared among them,
    at least 1 each."""
    if files < 1:
        raise ValueError(f"files={files!r}; allowed: an integer ≥ 1")
    return min(MAX_DECODER_THREADS, max(1, usable_cores() // files))


class VideoFileError(RuntimeError):
    """A video file cannot be read as a camera record."""


class VideoOpenError(VideoFileError):
    """The file does not exist or no decoder can open it."""


class VideoTruncatedError(VideoFileError):
    """Decoding stopped before the declared end; ``frames_read`` frames were delivered (see ``report``)."""

    def __init__(self, message: str, report: FrameTimeReport) -> None:
        super().__init__(message)
        self.report = report
        self.frames_read = report.frames_read


class StampCorrection(TypedDict):
    """From frame ``from_index`` on, ``shift_s`` is added to the time stamps (duplicate policy "insert")."""

    from_index: int
    shift_s: float


@dataclass
class FrameTimeReport:
    """What reading a video file found about its frames (times in s, on the file's clock).

    ``duplicated``: frames repeating the previous image and/or its time stamp, each as
    ``{"index", "pts_s", "pts_repeated", "image_repeated", "evidence", "change_dn", "noise_floor_dn",
    "typical_noise_dn", "change_before_dn", "change_after_dn", "change_across_dn", "identity_ratio",
    "across_ratio", "region_blocks"}`` (block-mean absolute differences in DN, see :class:`DuplicateJudge`:
    the largest changes over the ``region_blocks`` 8×8 blocks where the markers moved when the image was
    compared there, else over every 4th block; None where not computed); ``undecided``: indices of
    frames that repeat their predecessor's image with no evidence of a duplicate (a still scene; counted as
    genuine frames); ``dropped``: gaps as
    ``{"after_index", "gap_s", "missing_frames"}``; ``corrections``: ``{"from_index", "shift_s"}`` applied
    under ``duplicate_policy="insert"``; ``truncated``: decoding stopped before ``frames_declared``.
    """

    path: str
    frames_read: int = 0
    frames_declared: int | None = None
    frames_declared_source: str | None = None  # "container" (counted in its headers) or "decoder estimate"
    frames_decoder_estimate: int | None = None  # OpenCV's CAP_PROP_FRAME_COUNT (duration × rate for MKV)
    fps_nominal: float | None = None
    frame_period_s: float | None = None
    width_px: int = 0
    height_px: int = 0
    duration_s: float = 0.0
    first_pts_s: float | None = None  # the first frame's time stamp (s on the file's clock)
    duplicate_policy: str = "replace"
    luma_plane: bool = False
    duplicated: list[dict[str, Any]] = field(default_factory=list)
    undecided: list[int] = field(default_factory=list)
    dropped: list[FrameGap] = field(default_factory=list)
    corrections: list[StampCorrection] = field(default_factory=list)
    non_monotonic: list[int] = field(default_factory=list)
    truncated: bool = False
    error: str | None = None

    @property
    def duplicate_indices(self) -> list[int]:
        return [int(d["index"]) for d in self.duplicated]

    @property
    def missing_frames(self) -> int:
        return int(sum(d["missing_frames"] for d in self.dropped))

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["missing_frames"] = self.missing_frames
        return out

    def summary(self) -> str:
        """One line for a console or a report."""
        parts = [f"{Path(self.path).name}: {self.frames_read} frames, {self.duration_s:.3f} s"]
        if self.duplicated:
            parts.append(f"{len(self.duplicated)} duplicated (indices {self.duplicate_indices[:8]}"
                         f"{' …' if len(self.duplicated) > 8 else ''})")
        if self.undecided:
            parts.append(f"{len(self.undecided)} repeating the previous image with no evidence of a "
                         "duplicate (a still or barely moving scene; kept as genuine)")
        if self.dropped:
            parts.append(f"{self.missing_frames} dropped in {len(self.dropped)} gap(s) after indices "
                         f"{[d['after_index'] for d in self.dropped[:8]]}")
        if self.corrections:
            parts.append(f"time stamps corrected after {len(self.corrections)} inserted duplicate(s)")
        if self.non_monotonic:
            parts.append(f"{len(self.non_monotonic)} non-increasing time stamps")
        if self.truncated:
            parts.append(f"TRUNCATED ({self.error})")
        return "; ".join(parts)


_quiet_lock = threading.Lock()
_quiet_state = {"readers": 0, "level": 0}


def _quiet(step: int) -> None:
    """OpenCV's log level is process-wide: lowered while any file is being read, restored after the last."""
    with _quiet_lock:
        if step > 0 and _quiet_state["readers"] == 0:
            _quiet_state["level"] = cv2.utils.logging.getLogLevel()
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        _quiet_state["readers"] += step
        if step < 0 and _quiet_state["readers"] == 0:
            cv2.utils.logging.setLogLevel(_quiet_state["level"])


@dataclass
class _Decoded:
    index: int
    pts_s: float
    image: NDArray[np.uint8]
    tested: NDArray[np.uint8]  # the image the duplicate test reads: cropped to sides multiples of 8
    sampled: NDArray[np.uint32] | None  # its half-size image on every 4th 8×8 block, packed in 32-bit words
    # (change_kernel.sampled_words; None: too small to test)
    change: _Sampled | None = None  # to the previous image (None for the first frame)
    half: NDArray[np.uint8] | None = None  # the whole half-size image, once a still frame needed it


@dataclass(frozen=True)
class _Sampled:
    """The 8×8-block mean |image − previous image| (DN) on every 4th block (even block rows and columns:
    a 16-px grid of 8×8 blocks), its largest value and its median (the noise floor)."""

    map: NDArray[np.float32]
    max_dn: float
    floor_dn: float


def _tested(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The image cropped to sides multiples of 8 (the last < 8 rows and columns are not tested; every
    common video size is whole), C-contiguous: the change kernel reads its rows as 64-bit words."""
    h, w = image.shape
    if h % 8 == 0 and w % 8 == 0 and image.flags.c_contiguous:
        return image
    return np.ascontiguousarray(image[:h - h % 8, :w - w % 8])


@functools.cache
def _sampled_words() -> Callable[[NDArray[np.uint8], NDArray[np.uint32] | None],
                                 tuple[NDArray[np.uint32], NDArray[np.float32], float, float]]:
    """:func:`drivers.camera.change_kernel.sampled_words` (numba: loaded by the first frame, not by the
    import; a cached call, not an import statement in each frame's path)."""
    from drivers.camera.change_kernel import sampled_words

    return sampled_words


def _sample(tested: NDArray[np.uint8], prev: NDArray[np.uint32] | None,
            ) -> tuple[NDArray[np.uint32] | None, _Sampled | None]:
    """(the sampled half-size image, its change to the previous frame's ``prev`` or None for the first
    frame), in one compiled pass (:func:`drivers.camera.change_kernel.sampled_words`); (None, None) for an
    image smaller than one 8×8 block."""
    if tested.size == 0:
        return None, None
    sampled, change, max_dn, floor_dn = _sampled_words()(tested, prev)
    return sampled, (_Sampled(change, max_dn, floor_dn) if prev is not None else None)


def _largest_change(cur: _Decoded, prev: _Decoded) -> float:
    """The largest 8×8-block change from ``prev`` to ``cur`` over every block of the frame (DN); the
    half-size images are kept on the frames (a still scene needs them frame after frame)."""
    from drivers.camera import change_kernel

    if prev.half is None:
        prev.half = change_kernel.half_only(prev.tested)
    cur.half, _, largest_dn, _ = change_kernel.half_change_stats(cur.tested, prev.half)
    return largest_dn


def _motion_region(before: _Sampled, after: _Sampled, shape: tuple[int, int],
                   ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(block rows, block columns), row-major, where the markers moved: the sampled blocks whose change
    before or after reaches a quarter of that side's largest (and ``MIN_MOTION_DN`` / 2), with their 8
    neighbours (the blocks between the sampled ones). ``shape``: the frame's blocks (rows, columns)."""
    from drivers.camera import change_kernel

    return change_kernel.motion_region(
        before.map, after.map, max(0.25 * before.max_dn, 0.5 * DuplicateJudge.MIN_MOTION_DN),
        max(0.25 * after.max_dn, 0.5 * DuplicateJudge.MIN_MOTION_DN), shape)


# the region's change maps, for frames [k−2, k−1, k, k+1]: before (k−2 → k−1), after (k → k+1), the
# candidate's own change (k−1 → k) and the change across it (k−2 → k+1)
_REGION_PAIRS = np.array([[0, 1], [2, 3], [1, 2], [0, 3]], np.int64)


def _where_moved(motion: NDArray[np.float32], largest_dn: float) -> tuple[NDArray[np.bool_], float]:
    """The blocks where ``motion`` reaches half its largest value ``largest_dn`` (DN) and its mean there
    (DN, at least 1e-9): computed once per neighbour for the two ratios that use it."""
    where = motion >= 0.5 * largest_dn
    return where, max(float(motion[where].mean()), 1e-9)


def _ratio_where_moved(change: NDArray[np.float32], moved: tuple[NDArray[np.bool_], float]) -> float:
    """Mean of ``change`` over the blocks where a neighbour's markers moved (``moved``: :func:`_where_moved`)
    relative to the neighbour's mean there: ≈ 0 when the image did not change where its markers moved."""
    where, motion_mean_dn = moved
    return float(change[where].mean() / motion_mean_dn)


def _median(values: deque[float]) -> float:
    """``statistics.median`` of a few values (a frame's call: without the module's generality)."""
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


@dataclass
class _Stamps:
    """Time-stamp state while delivering: the latest stamp seen and the insert-policy correction (s)."""

    prev_pts_s: float = -math.inf
    shift_s: float = 0.0


class DuplicateJudge:
    """Decides, on evidence, whether a decoded frame repeats its predecessor (module docstring).

    Per frame k (DN = 8-bit levels, statistics of the 8×8-block mean absolute differences), computed on
    every 4th block (even block rows and columns: a 16-px grid of 8×8 blocks, half the frame's rows read):
    ``change`` s_k = largest block change from frame k−1; ``noise_floor`` f_k = median block change (the
    sensor noise renewed between two exposures); ``typical_noise`` F = running median of f over recent
    genuine frames. Evidence of a duplicate, either of:

    - *noise not renewed* (videos with F ≥ ``MIN_FLOOR_DN``): f_k < ``noise_ratio`` · F;
    - *identical where the markers move*: a candidate is a frame whose neighbours show motion
      (s_{k−1}, s_{k+1} ≥ ``MIN_MOTION_DN`` / ``CANDIDATE_MARGIN``) and whose change is at most
      ``CANDIDATE_MARGIN`` · ``IDENTICAL_RATIO`` × each neighbour's (the sampled blocks may miss a marker's
      largest change: the margin leaves those frames to the next test). A candidate is then judged at full
      resolution in the region where the markers moved (every block near a sampled block whose change
      before or after is large: :func:`_motion_region`): the neighbours' motion there is well above what a
      codec swallows (≥ ``MIN_MOTION_DN``); its change there is at most ``IDENTICAL_RATIO`` × each
      neighbour's, both as largest block changes and as means over the blocks where the neighbour's change
      reaches half its largest; and the change across, frame k−2 → k+1, is at least ``ACROSS_RATIO`` × the
      neighbours' in the same two ways (the motion goes on: at a turning point of an oscillation
      I_{k+1} ≈ I_{k−2}, and a genuine frame there may repeat its predecessor's image).

    Both ways are required because a codec (MPEG-4 part 2 at its default quality) swallows sub-pixel changes
    and renews the picture at each key frame, which can make a genuine frame look like a copy in one of them.
    A marker whose motion touches no sampled block (smaller than 8 px and moving between them) is not seen.
    """

    IDENTICAL_RATIO = 0.25
    ACROSS_RATIO = 0.75
    MIN_MOTION_DN = 4.0
    MIN_FLOOR_DN = 0.5
    UNDECIDED_DN = 1.5  # a frame whose largest block change is at most this repeats its predecessor (DN)
    CANDIDATE_MARGIN = 2.0  # the sampled blocks' gate is this much looser than the region's test

    def __init__(self, noise_ratio: float) -> None:
        self.noise_ratio = float(noise_ratio)
        self._floors: deque[float] = deque(maxlen=31)

    def judge(self, frames: list[_Decoded | None]) -> dict[str, Any] | None:
        """Evidence that ``frames[-2]`` (or the last frame when ``frames[-1]`` is None) duplicates its
        predecessor, or None. ``frames``: [k−2 | None, k−1, k, k+1 | None], k−1 and k decoded."""
        before2, prev, cur, nxt = frames
        assert prev is not None and cur is not None and cur.change is not None
        s_k = cur.change.max_dn
        floor = cur.change.floor_dn
        typical = _median(self._floors) if len(self._floors) >= 3 else None
        out = {"change_dn": s_k, "noise_floor_dn": floor, "typical_noise_dn": typical,
               "change_before_dn": prev.change.max_dn if prev.change is not None else None,
               "change_after_dn": nxt.change.max_dn if nxt is not None and nxt.change is not None else None,
               "change_across_dn": None, "identity_ratio": None, "across_ratio": None, "region_blocks": None}
        if typical is not None and typical >= self.MIN_FLOOR_DN and floor < self.noise_ratio * typical:
            return {**out, "evidence": f"sensor noise not renewed: median block change {floor:.1f} DN < "
                                       f"{self.noise_ratio:g} × typical {typical:.1f} DN"}
        self._floors.append(floor)
        before, after = out["change_before_dn"], out["change_after_dn"]
        if before is None or after is None or before2 is None or nxt is None:
            return None
        # the sampled blocks decide a moving frame at once; the others are judged in the markers' region
        margin, motion = self.CANDIDATE_MARGIN, min(before, after)
        if motion < self.MIN_MOTION_DN / margin or s_k > margin * self.IDENTICAL_RATIO * motion:
            return None
        return self._judge_region(before2, prev, cur, nxt, out)

    def _judge_region(self, before2: _Decoded, prev: _Decoded, cur: _Decoded, nxt: _Decoded,
                      out: dict[str, Any]) -> dict[str, Any] | None:
        """A candidate's evidence from every block where the markers moved (see the class docstring)."""
        assert prev.change is not None and nxt.change is not None
        h, w = cur.tested.shape
        rows, cols = _motion_region(prev.change, nxt.change, (h // 8, w // 8))
        from drivers.camera import change_kernel

        moved_before, moved_after, change, across_map = change_kernel.region_changes(
            (before2.tested, prev.tested, cur.tested, nxt.tested), rows, cols, _REGION_PAIRS)
        before, after = float(moved_before.max()), float(moved_after.max())
        out.update(change_dn=float(change.max()), change_before_dn=before, change_after_dn=after,
                   region_blocks=len(rows))
        if min(before, after) < self.MIN_MOTION_DN:
            return None
        ratio = float(change.max()) / min(before, after)
        if ratio > self.IDENTICAL_RATIO:
            return None
        moved_b, moved_a = _where_moved(moved_before, before), _where_moved(moved_after, after)
        ratio = max(ratio, _ratio_where_moved(change, moved_b), _ratio_where_moved(change, moved_a))
        out["identity_ratio"] = ratio
        if ratio > self.IDENTICAL_RATIO:
            return None
        across = min(_ratio_where_moved(across_map, moved_b), _ratio_where_moved(across_map, moved_a),
                     float(across_map.max()) / max(before, after))
        out["change_across_dn"], out["across_ratio"] = float(across_map.max()), across
        if across < self.ACROSS_RATIO:
            return None  # the scene turned round: a genuine frame at a turning point may repeat the image
        return {**out, "evidence": f"unchanged where the markers move: change {ratio:.2f} × the motion "
                                   f"before ({before:.1f} DN) and after ({after:.1f} DN) in the same blocks "
                                   f"(≤ {self.IDENTICAL_RATIO:g}); motion continuing across it (frame k−2 → "
                                   f"k+1: {across:.2f} × ≥ {self.ACROSS_RATIO:g})"}

    def forget(self, floor_dn: float) -> None:
        """A frame found duplicated by its time stamp: its noise floor is not a genuine frame's."""
        if self._floors and self._floors[-1] == floor_dn:
            self._floors.pop()


def declared_frames(path: Path, decoder_count: int) -> tuple[int | None, str | None]:
    """(frame count, where it comes from): the container's own count where its headers state one (MP4/MOV
    ``stts`` samples, Matroska video blocks, AVI headers: :mod:`drivers.camera.container_times`), else the
    decoder's ``decoder_count`` when positive (OpenCV's CAP_PROP_FRAME_COUNT, which for Matroska is the
    duration × the frame rate: wrong when frames were dropped), else (None, None)."""
    try:
        count = read_container_times(path).frame_count
    except ContainerError:  # not one of those containers, or its headers damaged: the decoder's word
        count = None
    if count is not None and count > 0:
        return count, "container"
    if decoder_count > 0:
        return decoder_count, "decoder estimate"
    return None, None


def find_gaps(timestamps_s: NDArray[np.float64], period_s: float,
              gap_tolerance: float = 0.5) -> list[FrameGap]:
    """Gaps longer than (1 + gap_tolerance) periods in increasing time stamps: after which index, how long,
    how many frames are missing (``round(gap/period) − 1``, at least 1)."""
    t = np.asarray(timestamps_s, dtype=float)
    if not (period_s > 0 and math.isfinite(period_s)):
        raise ValueError(f"period_s must be a positive finite number of seconds, got {period_s!r}")
    if not 0.0 < gap_tolerance < 1.0:
        raise ValueError(f"gap_tolerance must be within (0, 1) frame periods, got {gap_tolerance!r}")
    gaps = np.diff(t)
    out: list[FrameGap] = []
    for i in np.nonzero(gaps > (1.0 + gap_tolerance) * period_s)[0]:
        missing = max(1, round(gaps[i] / period_s) - 1)
        out.append({"after_index": int(i), "gap_s": float(gaps[i]), "missing_frames": missing})
    return out


class VideoFile(Camera):
    """A video file as a ``FrameSource`` (see the module docstring).

    ``name``: camera name (default: the file stem). ``fps``: nominal frame rate if the container's is wrong
    or missing (Hz). ``duplicate_ratio``: an image is a duplicate when its difference to the previous one is
    below this fraction of the running median difference (0 < r < 1). ``gap_tolerance``: a time-stamp gap
    longer than (1 + tolerance) periods is a drop. ``duplicate_policy``: ``"replace"`` or ``"insert"``.
    ``decoder_threads``: FFmpeg's threads, 1 … ``MAX_DECODER_THREADS`` (None: OpenCV's default).
    """

    def __init__(self, path: str | Path, *, name: str | None = None, fps: float | None = None,
                 duplicate_ratio: float = 0.3, gap_tolerance: float = 0.5,
                 duplicate_policy: str = "replace", luma: bool = True,
                 decoder_threads: int | None = None) -> None:
        self.path = Path(path)
        self.name = str(name) if name is not None else self.path.stem
        if duplicate_policy not in DUPLICATE_POLICIES:
            raise ValueError(f"duplicate_policy={duplicate_policy!r}; allowed: {DUPLICATE_POLICIES}")
        if not 0.0 < duplicate_ratio < 1.0:
            raise ValueError(f"duplicate_ratio={duplicate_ratio!r}; allowed: within (0, 1)")
        if not 0.0 < gap_tolerance < 1.0:
            raise ValueError(f"gap_tolerance={gap_tolerance!r}; allowed: within (0, 1) frame periods")
        if fps is not None and not (math.isfinite(fps) and 0 < fps <= 10000):
            raise ValueError(f"fps={fps!r}; allowed: a frame rate within (0, 10000] Hz")
        if decoder_threads is not None and (
                isinstance(decoder_threads, bool) or not isinstance(decoder_threads, int)
                or not 1 <= decoder_threads <= MAX_DECODER_THREADS):
            raise ValueError(f"decoder_threads={decoder_threads!r}; allowed: None (OpenCV's default) or an "
                             f"integer from 1 to {MAX_DECODER_THREADS}")
        self.decoder_threads = decoder_threads
        self.duplicate_ratio, self.gap_tolerance = float(duplicate_ratio), float(gap_tolerance)
        self.duplicate_policy, self.luma = duplicate_policy, bool(luma)
        cap = self._open()
        try:
            self.width_px = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
            self.height_px = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            container_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            decoder_count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        finally:
            cap.release()
        if fps is None and not (math.isfinite(container_fps) and 0 < container_fps <= 10000):
            raise VideoOpenError(f"{self.path}: the container states no usable frame rate "
                                 f"({container_fps!r}); pass fps= (the camera's nominal rate, Hz)")
        self.fps = float(fps) if fps is not None else container_fps
        self.frames_decoder_estimate = decoder_count if decoder_count > 0 else None
        self.frames_declared, self.frames_declared_source = declared_frames(self.path, decoder_count)
        self.report = self._new_report()
        self.duplicate_indices: set[int] = set()
        self._first_pts_s = 0.0
        self._start_index = 0  # the frame a seek landed on (frames(start_s=…)), for the next decode

    def _new_report(self) -> FrameTimeReport:
        return FrameTimeReport(str(self.path), frames_declared=self.frames_declared,
                               frames_declared_source=self.frames_declared_source,
                               frames_decoder_estimate=self.frames_decoder_estimate, fps_nominal=self.fps,
                               frame_period_s=1.0 / self.fps, width_px=self.width_px,
                               height_px=self.height_px, duplicate_policy=self.duplicate_policy)

    def _open(self) -> cv2.VideoCapture:
        if not self.path.is_file():
            raise VideoOpenError(f"{self.path}: no such video file")
        if self.path.stat().st_size == 0:
            raise VideoOpenError(f"{self.path}: the file is empty (0 bytes)")
        params = [] if self.decoder_threads is None else [cv2.CAP_PROP_N_THREADS, self.decoder_threads]
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG, params)
        if not cap.isOpened():
            cap.release()
            raise VideoOpenError(
                f"{self.path}: no decoder can open it — a corrupt file, or a recording cut short before its "
                "container index was written (MP4/MOV written by a camera that lost power); no frames "
                "could be read")
        return cap

    # FrameSource: a file is already recorded
    def start(self) -> None:
        """Nothing to start: the file was recorded by the camera (kept for the ``FrameSource`` protocol)."""

    def stop(self) -> None:
        """Nothing to stop (``FrameSource`` protocol)."""

    def safe_state(self) -> None:
        """Nothing to make safe: a file does not record."""

    def read_back(self) -> dict[str, Any]:
        return {"recording": False}

    def heartbeat(self, *, wait: bool = False) -> bool:
        return True

    def snapshot(self) -> dict[str, Any]:
        return {"driver": "file", "path": str(self.path)}

    def _gray(self, cap: cv2.VideoCapture) -> NDArray[np.uint8] | None:
        """The decoded image as 2-D gray levels; OpenCV decodes 8-bit video to uint8 (its stubs say only
        MatLike) and :class:`Frame` refuses any other dtype."""
        ok, img = cap.retrieve()
        if not ok or img is None:
            return None
        if img.ndim == 2 and img.shape == (self.height_px, self.width_px):
            return cast("NDArray[np.uint8]", img)
        if img.ndim == 3:
            return cast("NDArray[np.uint8]", cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
        return None

    def _luma_capture(self) -> tuple[cv2.VideoCapture, bool, tuple[float, NDArray[np.uint8]] | None]:
        """A capture delivering the luma plane if that plane is verified equal (up to a linear range change)
        to OpenCV's grey conversion of the first frame — then with that first frame already read, as
        (time stamp s, luma image), so that it is decoded once more only for the check; else a capture
        delivering BGR, from the start."""
        if self.luma:
            cap = self._open()
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
            probe_bgr = self._open()
            try:
                ok_a, bgr = probe_bgr.read()
            finally:
                probe_bgr.release()
            raw = None
            if cap.grab():
                pts = float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
                ok_b, raw = cap.retrieve()
                raw = raw if ok_b else None
            if (ok_a and raw is not None and raw.ndim == 2 and raw.dtype == np.uint8
                    and raw.shape == (self.height_px, self.width_px) and bgr is not None and bgr.ndim == 3):
                g = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[::_SUB, ::_SUB].ravel().astype(float)
                y = raw[::_SUB, ::_SUB].ravel().astype(float)
                if g.std() > 0 and y.std() > 0 and np.corrcoef(g, y)[0, 1] > 0.995:
                    return cap, True, (pts, cast("NDArray[np.uint8]", raw))
            cap.release()
        return self._open(), False, None

    def frames(self, start_s: float | None = None) -> Iterator[Frame]:
        """Every decodable frame in order (see the module docstring); ``.report`` is filled as they go.

        ``start_s``: begin at least :data:`SEEK_PREROLL_FRAMES` frames before the first frame stamped at or
        after it, reached by a verified frame-exact seek (:mod:`drivers.camera.seek`) with the default
        ``duplicate_policy`` ("replace": stamps are never shifted, so they do not depend on the frames
        skipped); the frames keep their indices and stamps, the report covers the frames decoded. Without a
        verified seek (or with "insert"), every frame from the first."""
        rep = self.report = self._new_report()
        self.duplicate_indices = set()
        period = 1.0 / self.fps
        _quiet(+1)  # the luma plane makes OpenCV warn once a frame
        try:
            cap, rep.luma_plane, first = self._luma_capture()
            if start_s is not None and self.duplicate_policy == "replace":
                cap, first = self._seek(cap, first, start_s)
            yield from self._decode(cap, rep, period, first)
        finally:
            _quiet(-1)
        # the decoder's frame count may be an estimate (duration × rate, e.g. Matroska) that dropped frames
        # undercut: the file is truncated when its frames also end early in time
        end_expected_s = self._first_pts_s + (self.frames_declared or 0) * period
        if (self.frames_declared is not None and rep.frames_read < self.frames_declared
                and rep.duration_s < end_expected_s - 1.5 * period):
            rep.truncated = True
            rep.error = (f"the video is truncated or corrupt: decoding stopped after {rep.frames_read} of "
                         f"the {self.frames_declared} frames the container declares (the last frame read is "
                         f"frame {rep.frames_read - 1}, ending at {rep.duration_s:.3f} s)")
            raise VideoTruncatedError(f"{self.path}: {rep.error}; the {rep.frames_read} frames read are kept",
                                      rep)

    def _seek(self, cap: cv2.VideoCapture, first: tuple[float, NDArray[np.uint8]] | None, start_s: float
              ) -> tuple[cv2.VideoCapture, tuple[float, NDArray[np.uint8]] | None]:
        """The capture and its first frame after a verified seek towards ``start_s`` (:meth:`frames`); the
        capture from the first frame again when the seek cannot be verified."""
        times = frame_times_s(str(self.path))
        if times is None:
            return cap, first
        index = max(0, int(np.searchsorted(times, start_s - 1e-9)) - SEEK_PREROLL_FRAMES)
        if index == 0:
            return cap, first
        if seek_frame(cap, times, index) and (img := self._gray(cap)) is not None:
            self._start_index, self._first_pts_s = index, float(times[0])
            return cap, (float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0, img)
        cap.release()  # position unknown: from the first frame, as without a start
        cap, self.report.luma_plane, first = self._luma_capture()
        return cap, first

    def _stamped(self, cap: cv2.VideoCapture, first: tuple[float, NDArray[np.uint8]] | None
                 ) -> Iterator[tuple[float, NDArray[np.uint8] | None]]:
        """(time stamp s, grey image or None if undecodable) of each frame in order, ``first`` (already
        read) first."""
        if first is not None:
            yield first
        while cap.grab():
            yield float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0, self._gray(cap)

    def _grab(self, cap: cv2.VideoCapture, rep: FrameTimeReport,
              first: tuple[float, NDArray[np.uint8]] | None) -> Iterator[_Decoded]:
        """Decoded frames in order with their time stamps and block change to the previous frame."""
        prev: NDArray[np.uint32] | None = None  # the previous image's sampled half-size image
        index, self._start_index = self._start_index, 0  # after a seek, the frame it landed on
        if index:
            rep.first_pts_s = self._first_pts_s
        try:
            for pts, img in self._stamped(cap, first):
                if img is None:
                    rep.error = f"frame {index} could not be decoded"
                    break
                if index == 0:
                    self._first_pts_s = rep.first_pts_s = pts
                tested = _tested(img)
                sampled, change = _sample(tested, prev)
                yield _Decoded(index, pts, img, tested, sampled, change)
                prev = sampled
                index += 1
        finally:
            cap.release()

    def _decode(self, cap: cv2.VideoCapture, rep: FrameTimeReport, period: float,
                first: tuple[float, NDArray[np.uint8]] | None) -> Iterator[Frame]:
        judge = DuplicateJudge(self.duplicate_ratio)
        state = _Stamps()
        if not self._start_index:
            self._first_pts_s = 0.0
        window: deque[_Decoded | None] = deque([None, None], maxlen=4)  # k−2, k−1, k, k+1
        for item in self._grab(cap, rep, first):
            window.append(item)
            if len(window) == 4 and window[2] is not None:
                yield self._deliver(list(window), judge, rep, period, state)
        if window[-1] is not None:
            window.append(None)
            yield self._deliver(list(window), judge, rep, period, state)

    def _deliver(self, frames: list[_Decoded | None], judge: DuplicateJudge, rep: FrameTimeReport,
                 period: float, state: _Stamps) -> Frame:
        """Frame ``frames[2]`` with its time stamp, after deciding (on evidence) whether it is a duplicate."""
        cur = frames[2]
        assert cur is not None
        pts, index, prev_pts = cur.pts_s, cur.index, state.prev_pts_s
        repeated = pts <= prev_pts + 1e-6 * period
        if repeated and pts < prev_pts - 1e-6 * period:
            rep.non_monotonic.append(index)
            repeated = False
        evidence = judge.judge(frames) if cur.change is not None and frames[1] is not None else None
        if repeated:
            evidence = evidence or {"evidence": "time stamp repeated"}
            if cur.change is not None:
                judge.forget(cur.change.floor_dn)
        if evidence is not None:
            self.duplicate_indices.add(index)
            rep.duplicated.append({"index": index, "pts_s": pts, "pts_repeated": bool(repeated),
                                   "image_repeated": "time stamp" not in evidence["evidence"], **evidence})
            if not repeated and self.duplicate_policy == "insert":
                state.shift_s -= period
                rep.corrections.append({"from_index": index + 1, "shift_s": state.shift_s})
            stamp = pts + state.shift_s if not repeated else prev_pts
        else:
            prev = frames[1]
            if (cur.change is not None and prev is not None and cur.change.max_dn <= judge.UNDECIDED_DN
                    and _largest_change(cur, prev) <= judge.UNDECIDED_DN):
                rep.undecided.append(index)  # unchanged on the sampled blocks, then on every block
            if prev_pts > -math.inf and not repeated:
                gap = pts - prev_pts
                if gap > (1.0 + self.gap_tolerance) * period:
                    rep.dropped.append({"after_index": index - 1, "gap_s": gap,
                                        "missing_frames": max(1, round(gap / period) - 1)})
            stamp = pts + state.shift_s
        state.prev_pts_s = max(prev_pts, pts)
        rep.frames_read = index + 1
        rep.duration_s = max(rep.duration_s, pts + period)
        return Frame(index=index, timestamp_s=stamp, image=cur.image)

"""A simulated consumer video camera filming the simulated world: rolling shutter, exposure, noise, clock.

Timing model (world time is the rig's virtual time; the camera never sees it):

* sensor frame k starts (row 0 begins its exposure) at ``start_offset_s + k·T`` with the true period
  T = 1 / (fps·(1 + clock_ppm·1e-6)) — a camera whose oscillator runs fast by ``clock_ppm``;
* row y begins its exposure ``y·line_time_s`` later and integrates for ``exposure_s``;
* the camera stamps sensor frame k with its own clock: ``timestamp_origin_s + k / fps``;
* frames are delivered with a running ``frame_index``; a dropped sensor frame is skipped (its time stamp
  gap shows), a duplicated one is delivered twice with the same image and time stamp.
"""

from __future__ import annotations

import math
import threading
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from drivers.sim.fiducial import SyncLed
from drivers.sim.render import (
    NoiseModel,
    conic_extents,
    coverage_patches,
    disc_conics,
    exposure_samples,
    project_points,
)
from drivers.sim.render_kernel import add_patches
from drivers.sim.world import World

__all__ = ["SimCamera", "look_at"]

_CHUNK = 4096
_NORMAL_POOL = 1 << 20
_LedFootprint = tuple[int, int, NDArray[np.float32], NDArray[np.float64]]
"""An LED's first image row and column, coverage (rows, cols) 0..1 and rows' starts after the frame's (s)."""


def look_at(eye_mm: Iterable[float], target_mm: Iterable[float],
            up: Iterable[float] = (0.0, 0.0, 1.0)) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """OpenCV pose (rvec, tvec mm; base → camera) of a camera at ``eye_mm`` looking at ``target_mm``."""
    eye, tgt, upv = (np.asarray(v, float) for v in (eye_mm, target_mm, up))
    z = tgt - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, upv)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError(f"up={tuple(upv)} is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    rot = np.stack([x, np.cross(z, x), z])  # rows: camera axes in base coordinates
    rvec, _ = cv2.Rodrigues(rot)
    tvec: NDArray[np.float64] = -rot @ eye
    return np.asarray(rvec, dtype=np.float64).ravel(), tvec


@dataclass(frozen=True)
class _Patches:
    """A frame's marker coverage: per exposure-sample count, (patches (M, Hp, Wp) 0..1, first image rows (M,),
    first image columns (M,)), in drawing order; ``span_s``: the world times the positions were taken at,
    as (earliest, latest) after the frame's start (s); ``pose_key``: the markers' positions and normals at
    the frame's start, as bytes, when they were at rest over the span (else empty)."""

    stacks: list[tuple[NDArray[np.float32], NDArray[np.int_], NDArray[np.int_]]]
    span_s: tuple[float, float]
    pose_key: bytes


class SimCamera:
    """A 1920×1080 rolling-shutter camera of the simulated rig (see the module docstring for timing).

    Intrinsics in pixels, ``distortion`` = (k1, k2, p1, p2) (OpenCV model), pose ``rvec``/``tvec`` maps base
    coordinates (mm) to camera coordinates. ``line_time_s`` defaults to 0.9·(1/fps)/height (readout takes
    90 % of the frame period). ``seed`` (default: the world's) makes rendering deterministic per frame.
    Sensor frames listed in ``dropped_frames`` are lost, and each other one with ``drop_probability``
    (only those starting within ``drop_window_s`` = (start, stop) world s, when given).
    """

    def __init__(self, name: str, world: World, *, fx_px: float = 2400.0, fy_px: float | None = None,
                 cx_px: float = 959.5, cy_px: float = 539.5, width_px: int = 1920, height_px: int = 1080,
                 distortion: Iterable[float] = (0.0, 0.0, 0.0, 0.0), rvec: Iterable[float] = (0.0, 0.0, 0.0),
                 tvec: Iterable[float] = (0.0, 0.0, 0.0), fps: float = 60.0, clock_ppm: float = 0.0,
                 start_offset_s: float = 0.0, timestamp_origin_s: float = 0.0,
                 line_time_s: float | None = None,
                 exposure_s: float = 1 / 6000, noise: NoiseModel | None = None, psf_sigma_px: float = 0.6,
                 dropped_frames: Iterable[int] = (), duplicated_frames: Iterable[int] = (),
                 drop_probability: float = 0.0, duplicate_probability: float = 0.0,
                 drop_window_s: tuple[float, float] | None = None, seed: int | None = None) -> None:
        self.name, self.world = str(name), world
        fy = fx_px if fy_px is None else fy_px
        for label, v in (("fx_px", fx_px), ("fy_px", fy), ("fps", fps)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{label} must be a finite number > 0, got {v!r}")
        if width_px < 16 or height_px < 16:
            raise ValueError(f"width_px and height_px must be ≥ 16, got {width_px}×{height_px}")
        if not (math.isfinite(clock_ppm) and abs(clock_ppm) < 1e4):
            raise ValueError(f"clock_ppm must be finite and within ±10000 ppm, got {clock_ppm!r}")
        self.width_px, self.height_px, self.fps = int(width_px), int(height_px), float(fps)
        self.camera_matrix = np.array([[fx_px, 0.0, cx_px], [0.0, fy, cy_px], [0.0, 0.0, 1.0]], dtype=float)
        self.distortion = np.asarray(tuple(distortion), dtype=float)
        if self.distortion.shape != (4,) or not np.all(np.isfinite(self.distortion)):
            raise ValueError(f"distortion must be 4 finite numbers (k1, k2, p1, p2), got {distortion!r}")
        self.rvec = np.asarray(tuple(rvec), dtype=float).reshape(3)
        self.tvec = np.asarray(tuple(tvec), dtype=float).reshape(3)
        self.rotation = cv2.Rodrigues(self.rvec)[0]
        self.clock_ppm, self.start_offset_s = float(clock_ppm), float(start_offset_s)
        self.timestamp_origin_s = float(timestamp_origin_s)
        self.frame_period_true_s = 1.0 / (self.fps * (1.0 + self.clock_ppm * 1e-6))
        lt = 0.9 / self.fps / self.height_px if line_time_s is None else float(line_time_s)
        if not (0.0 <= lt <= self.frame_period_true_s / self.height_px):
            raise ValueError(f"line_time_s must be within 0..frame period/height = "
                             f"{self.frame_period_true_s / self.height_px:.3e} s, got {line_time_s!r}")
        if not (0.0 < exposure_s <= self.frame_period_true_s):
            raise ValueError(f"exposure_s must be within (0, {self.frame_period_true_s:.6f}] s, "
                             f"got {exposure_s!r}")
        if not (0.0 <= psf_sigma_px <= 5.0):
            raise ValueError(f"psf_sigma_px must be within 0..5 px, got {psf_sigma_px!r}")
        probabilities = (("drop_probability", drop_probability),
                         ("duplicate_probability", duplicate_probability))
        for label, p in probabilities:
            if not (0.0 <= p < 0.5):
                raise ValueError(f"{label} must be within [0, 0.5), got {p!r}")
        self.line_time_s, self.exposure_s, self.psf_sigma_px = lt, float(exposure_s), float(psf_sigma_px)
        self.noise = noise if noise is not None else NoiseModel()
        self.seed = world.seed if seed is None else int(seed)
        self._name_id = zlib.crc32(self.name.encode())
        self._dropped = {int(k) for k in dropped_frames}
        self._duplicated = {int(k) for k in duplicated_frames}
        self._p_drop, self._p_dup = float(drop_probability), float(duplicate_probability)
        window_ok = drop_window_s is None or (len(drop_window_s) == 2 and drop_window_s[0] < drop_window_s[1])
        if not window_ok:
            raise ValueError(f"drop_window_s must be (start_s, stop_s) with start_s < stop_s, "
                             f"got {drop_window_s!r}")
        self._drop_window_s = drop_window_s
        self._index_buffer = np.empty(2 * _CHUNK, dtype=np.int64)
        self._n_indexed = 0
        self._sensor_of_index = self._index_buffer[:0]  # delivered index → sensor frame
        self._chunks = 0
        self._pool: NDArray[np.uint8] | None = None
        self._normal_pool: NDArray[np.float32] | None = None
        self._led_footprints: dict[SyncLed, _LedFootprint | None] = {}
        self._last_patches: tuple[tuple[str, ...], float, _Patches] | None = None  # ids, frame start, patches
        self._index_lock = threading.RLock()  # the frame map and the noise pools are built lazily

    # ------------------------------------------------------------------ clock and frame indices
    def _extend(self, sensor_frame: int) -> None:
        with self._index_lock:
            self._extend_locked(sensor_frame)

    def _extend_locked(self, sensor_frame: int) -> None:
        while self._chunks * _CHUNK <= sensor_frame:
            rng = np.random.default_rng((self.seed, self._name_id, 1, self._chunks))
            ks = np.arange(self._chunks * _CHUNK, (self._chunks + 1) * _CHUNK)
            drop = rng.random(_CHUNK) < self._p_drop
            if self._drop_window_s is not None:  # random drops only for frames starting inside the window
                t0_s, t1_s = self._drop_window_s
                starts_s = self.start_offset_s + ks * self.frame_period_true_s
                drop &= (starts_s >= t0_s) & (starts_s < t1_s)
            dup = rng.random(_CHUNK) < self._p_dup
            drop |= np.isin(ks, list(self._dropped))
            dup |= np.isin(ks, list(self._duplicated))
            keep = ks[~drop]
            reps = 1 + (dup[~drop]).astype(int)
            new = np.repeat(keep, reps)
            if self._n_indexed + new.size > self._index_buffer.size:  # grow by doubling (long recordings)
                grown = np.empty(max(2 * self._index_buffer.size, self._n_indexed + new.size), dtype=np.int64)
                grown[: self._n_indexed] = self._index_buffer[: self._n_indexed]
                self._index_buffer = grown
            self._index_buffer[self._n_indexed : self._n_indexed + new.size] = new
            self._n_indexed += new.size
            self._sensor_of_index = self._index_buffer[: self._n_indexed]
            self._chunks += 1

    def sensor_frame(self, frame_index: int) -> int:
        """Sensor frame number k delivered as ``frame_index`` (≥ 0)."""
        i = int(frame_index)
        if i < 0:
            raise ValueError(f"frame_index must be ≥ 0, got {frame_index!r}")
        while self._sensor_of_index.size <= i:
            self._extend(self._chunks * _CHUNK)
        return int(self._sensor_of_index[i])

    def frame_start_true_s(self, frame_index: int) -> float:
        """World time at which row 0 of this frame starts its exposure."""
        return self.start_offset_s + self.sensor_frame(frame_index) * self.frame_period_true_s

    def frame_timestamp_s(self, frame_index: int) -> float:
        """The camera's own time stamp of this frame (its clock, not world time)."""
        return self.timestamp_origin_s + self.sensor_frame(frame_index) / self.fps

    def row_time_true_s(self, frame_index: int, row_px: float) -> float:
        """World time of the middle of the exposure of image row ``row_px`` (0 = top) of this frame."""
        return self.frame_start_true_s(frame_index) + float(row_px) * self.line_time_s + 0.5 * self.exposure_s

    @property
    def readout_s(self) -> float:
        """From the start of row 0 to the end of the last row's exposure."""
        return (self.height_px - 1) * self.line_time_s + self.exposure_s

    def first_frame_index_at_or_after(self, t_world_s: float) -> int:
        """Smallest delivered index whose exposure starts (row 0) at or after world time ``t_world_s``."""
        k = max(0, math.ceil((t_world_s - self.start_offset_s) / self.frame_period_true_s - 1e-9))
        self._extend(k)
        while self._sensor_of_index[-1] < k:
            self._extend(self._chunks * _CHUNK)
        return int(np.searchsorted(self._sensor_of_index, k, side="left"))

    def frame_indices_between(self, t_start_s: float, t_stop_s: float) -> range:
        """Delivered indices whose whole exposure (all rows) lies within [t_start_s, t_stop_s] world time."""
        first = self.first_frame_index_at_or_after(t_start_s)
        period = self.frame_period_true_s
        last_k = math.floor((t_stop_s - self.readout_s - self.start_offset_s) / period + 1e-9)
        if last_k < 0:
            return range(first, first)
        stop = self.first_frame_index_at_or_after(self.start_offset_s + (last_k + 0.5) * period)
        return range(first, max(first, stop))

    # ------------------------------------------------------------------ projection and truth
    def project(self, points_mm: NDArray[np.float64]) -> NDArray[np.float64]:
        """Pixels (..., 2) of base-frame points (..., 3) through ``cv2.projectPoints`` (with distortion)."""
        return project_points(np.asarray(points_mm, float), self.rvec, self.tvec, self.camera_matrix,
                              self.distortion)

    def _depth(self, points_mm: NDArray[np.float64]) -> NDArray[np.float64]:
        depth_mm: NDArray[np.float64] = points_mm @ self.rotation[2] + self.tvec[2]
        return depth_mm

    @staticmethod
    def _faces_camera(normals_cam: NDArray[np.float64],
                      centres_cam: NDArray[np.float64]) -> NDArray[np.bool_]:
        """True where the disc's front faces the camera at more than ~1° from edge-on."""
        cos: NDArray[np.float64] = (-np.sum(normals_cam * centres_cam, axis=-1)
                                    / np.linalg.norm(centres_cam, axis=-1))
        return cos > 0.02

    def truth_observations(self, t_start_s: float, t_stop_s: float,
                           marker_ids: list[str] | None = None) -> pd.DataFrame:
        """Exact projected marker centres, no rendering, for every frame between the two world times.

        Markers whose printed face turns away from the camera (or lies within ~1° of edge-on) are not seen.
        Each observation's time is the mid-exposure of the (fractional) image row where the centre is seen,
        found by fixed-point iteration v ← project(position(t_frame + v·line_time + exposure/2)).
        Columns: frame_index, timestamp_s (camera clock), t_true_s (world), marker_id, u_px, v_px.
        """
        frames = self.frame_indices_between(t_start_s, t_stop_s)
        rows: list[pd.DataFrame] = []
        groups: dict[tuple[str, ...], list[int]] = {}
        for i in frames:
            present = self.world.marker_ids_at(self.frame_start_true_s(i) + 0.5 * self.readout_s)
            ids = tuple(m for m in present if marker_ids is None or m in marker_ids)
            groups.setdefault(ids, []).append(i)
        for ids, idx in groups.items():
            if not ids:
                continue
            t0 = np.array([self.frame_start_true_s(i) for i in idx])
            v = np.full((len(ids), len(idx)), 0.5 * (self.height_px - 1))
            lt = self.line_time_s
            for _ in range(30):
                t = t0[None, :] + np.clip(v, 0.0, self.height_px - 1) * lt + 0.5 * self.exposure_s
                pts = self.world.positions(list(ids), t)
                uv = self.project(pts)
                done = np.max(np.abs(uv[..., 1] - v)) < 1e-9
                v = uv[..., 1]
                if done:
                    break
            t = t0[None, :] + np.clip(v, 0.0, self.height_px - 1) * self.line_time_s + 0.5 * self.exposure_s
            facing = self._faces_camera(self.world.normals(list(ids), t) @ self.rotation.T,
                                        pts @ self.rotation.T + self.tvec)
            inside = (facing & (self._depth(pts) > 0) & (uv[..., 0] >= -0.5)
                      & (uv[..., 0] <= self.width_px - 0.5) & (v >= -0.5) & (v <= self.height_px - 0.5))
            mi, fi = np.nonzero(inside)
            rows.append(pd.DataFrame({
                "frame_index": np.asarray(idx, dtype=np.int64)[fi],
                "timestamp_s": np.array([self.frame_timestamp_s(i) for i in idx])[fi],
                "t_true_s": t[mi, fi], "marker_id": np.asarray(ids, dtype=object)[mi],
                "u_px": uv[mi, fi, 0], "v_px": v[mi, fi]}))
        cols = ["frame_index", "timestamp_s", "t_true_s", "marker_id", "u_px", "v_px"]
        if not rows:
            return pd.DataFrame({c: pd.Series(dtype=object if c == "marker_id" else float) for c in cols})
        out = pd.concat(rows, ignore_index=True)
        return out.sort_values(["frame_index", "marker_id"], kind="stable", ignore_index=True)[cols]

    # ------------------------------------------------------------------ rendering
    def _background(self, rng: np.random.Generator) -> NDArray[np.uint8]:
        if self._pool is None:
            with self._index_lock:
                if self._pool is None:
                    self._pool = self.noise.background_pool(self.height_px, self.width_px,
                                                            seed=self.seed ^ self._name_id)
        m = self.noise.pool_margin_px
        b, r, c = rng.integers(self._pool.shape[0]), rng.integers(m), rng.integers(m)
        return self._pool[b, r : r + self.height_px, c : c + self.width_px].copy()

    def _normals(self, n: int, rng: np.random.Generator) -> NDArray[np.float32]:
        """n standard normal numbers: a slice at a random offset of a pre-drawn pool (fresh if n is large)."""
        if self._normal_pool is None:
            with self._index_lock:
                if self._normal_pool is None:
                    self._normal_pool = np.random.default_rng((self.seed, self._name_id, 3)).standard_normal(
                        _NORMAL_POOL, dtype=np.float32)
        if n > _NORMAL_POOL // 4:
            return rng.standard_normal(n, dtype=np.float32)
        start = int(rng.integers(_NORMAL_POOL - n))
        return self._normal_pool[start : start + n]

    def render(self, frame_index: int) -> NDArray[np.uint8]:
        """Frame ``frame_index`` as the sensor recorded it: (height, width) uint8, deterministic per seed."""
        k = self.sensor_frame(frame_index)
        t0 = self.start_offset_s + k * self.frame_period_true_s
        rng = np.random.default_rng((self.seed, self._name_id, 2, k))
        frame = self._background(rng)
        ids = self.world.marker_ids_at(t0 + 0.5 * self.readout_s)
        if ids:
            self._draw(frame, ids, t0, rng)
        for led in self.world.leds:
            self._draw_led(frame, led, t0, rng)
        return frame

    def _led_footprint(self, led: SyncLed) -> _LedFootprint | None:
        """The :data:`_LedFootprint` of the LED's projected rectangle (area-covered at 1/16 px), or None when
        it is not in view. The rectangle is fixed, so each camera computes it once per LED."""
        if led in self._led_footprints:
            return self._led_footprints[led]
        footprint: _LedFootprint | None = None
        corners = led.corners_mm()
        uv = self.project(corners)
        x_lo, y_lo = (int(max(math.floor(v), 0)) for v in uv.min(axis=0))
        x_hi, y_hi = int(min(math.ceil(uv[:, 0].max()), self.width_px - 1)), int(
            min(math.ceil(uv[:, 1].max()), self.height_px - 1))
        if np.all(self._depth(corners) > 1.0) and x_hi >= x_lo and y_hi >= y_lo:
            mask = np.zeros((y_hi - y_lo + 1, x_hi - x_lo + 1), dtype=np.uint8)
            pts = np.rint((uv - [x_lo, y_lo]) * 16).astype(np.int32)
            cv2.fillConvexPoly(mask, pts, 255, lineType=cv2.LINE_AA, shift=4)
            coverage: NDArray[np.float32] = mask.astype(np.float32) / np.float32(255.0)
            row_offsets_s = np.arange(y_lo, y_hi + 1, dtype=np.int64) * np.float64(self.line_time_s)
            footprint = (y_lo, x_lo, coverage, row_offsets_s)
        self._led_footprints[led] = footprint
        return footprint

    def _draw_led(self, frame: NDArray[np.uint8], led: SyncLed, t0: float, rng: np.random.Generator) -> None:
        """Add a timing fiducial: its footprint lit per row by the mean of its light over that row's exposure
        (rolling shutter: rows see the edges at their own times)."""
        footprint = self._led_footprint(led)
        if footprint is None:
            return
        y_lo, x_lo, coverage, row_offsets_s = footprint
        level = led.mean_levels((t0 + row_offsets_s).astype(np.float64), self.exposure_s)
        scale = led.contrast_dn / max(self.noise.marker_level_dn - self.noise.background_level_dn, 1.0)
        cov = coverage * (level[:, None] * scale).astype(np.float32)
        self._blend(frame, cov[None], np.array([y_lo]), np.array([x_lo]), rng)

    def _draw(self, frame: NDArray[np.uint8], ids: list[str], t0: float, rng: np.random.Generator) -> None:
        """Add the markers ``ids`` of the frame starting at world time ``t0`` onto ``frame``: their coverage
        patches (reused from the previous frame when nothing moved: the same numbers), then their signal."""
        patches = self._still_patches(ids, t0)
        if patches is None:
            patches = self._patches(ids, t0)
            self._last_patches = (tuple(ids), t0, patches)
        for cov, row0, col0 in patches.stacks:
            self._blend(frame, cov, row0, col0, rng)

    def _still_patches(self, ids: list[str], t0: float) -> _Patches | None:
        """The previous frame's patches if they are this frame's: the same markers, at rest over the times
        both frames' patches were computed from, at the same positions with the same normals."""
        if self._last_patches is None:
            return None
        last_ids, last_t0, patches = self._last_patches
        if last_ids != tuple(ids) or not patches.pose_key:
            return None
        t_lo, t_hi = min(t0, last_t0) + patches.span_s[0], max(t0, last_t0) + patches.span_s[1]
        if not self.world.at_rest_between(ids, t_lo - 1e-6, t_hi + 1e-6):
            return None
        return patches if self._pose_key(ids, t0) == patches.pose_key else None

    def _pose_key(self, ids: list[str], t_s: float) -> bytes:
        """The markers' positions and normals at ``t_s``, as bytes (the world's plan may have changed since
        a frame was drawn: a command for a time before it)."""
        return self.world.positions(ids, t_s).tobytes() + self.world.normals(ids, t_s).tobytes()

    def _patches(self, ids: list[str], t0: float) -> _Patches:
        """The markers' coverage patches of the frame starting at ``t0`` (each exposure-sample count's stack
        of patches with its first rows and columns; world times queried span ``span_s`` from ``t0``)."""
        h, w, lt, te = self.height_px, self.width_px, self.line_time_s, self.exposure_s
        world = self.world
        # 1. motion around mid-readout → predicted row where each centre is seen (one Newton step of the
        #    fixed point v = v(t0 + v·line_time)), then the exact centre at that row's time.
        y_mid = 0.5 * (h - 1)
        dt = max(0.5 * te, 5e-4)
        pts = world.positions(ids, t0 + y_mid * lt + 0.5 * te + np.array([-dt, 0.0, dt]))
        keep = np.nonzero(self._depth(pts[:, 1]) > 1.0)[0]
        if keep.size == 0:
            return _Patches([], (0.0, 0.0), b"")
        uv = self.project(pts[keep])
        vel = (uv[:, 2] - uv[:, 0]) / (2 * dt)  # px/s
        gain = np.clip(vel[:, 1] * lt, -0.75, 0.75)
        v_star = np.clip((uv[:, 1, 1] - gain * y_mid) / (1.0 - gain), 0.0, h - 1)
        t_c = t0 + v_star * lt + 0.5 * te
        kept_ids = [ids[i] for i in keep]
        centre = world.positions(kept_ids, t_c[:, None])[:, 0]
        cam = centre @ self.rotation.T + self.tvec
        q0 = cam[:, :2] / cam[:, 2:3]
        fov = 2.0 * np.array([w, h]) / np.diag(self.camera_matrix)[:2]
        ok = (cam[:, 2] > 1.0) & np.all(np.abs(q0) < fov, axis=1)
        if not ok.any():
            return _Patches([], (0.0, 0.0), b"")
        normals = world.normals(kept_ids, t_c) @ self.rotation.T
        ok &= self._faces_camera(normals, cam)  # printed discs are one-sided
        if not ok.any():
            return _Patches([], (0.0, 0.0), b"")
        t_c, cam, q0, vel, centre, normals = t_c[ok], cam[ok], q0[ok], vel[ok], centre[ok], normals[ok]
        kept_ids = [m for m, o in zip(kept_ids, ok, strict=True) if o]
        uc = self.project(centre)
        eps = 1e-6
        probe = np.concatenate([q0, q0 + np.array([eps, 0.0]), q0 + np.array([0.0, eps])])
        pp = project_points(np.column_stack([probe, np.ones(len(probe))]), np.zeros(3), np.zeros(3),
                            self.camera_matrix, self.distortion).reshape(3, -1, 2)
        jac = np.stack([(pp[1] - pp[0]) / eps, (pp[2] - pp[0]) / eps], axis=2)
        radii = np.array([world.marker_diameter_mm(m) / 2 for m in kept_ids])
        conics = disc_conics(cam, normals, radii, jac)
        ext = conic_extents(conics)
        ksamp = exposure_samples(np.hypot(vel[:, 0], vel[:, 1]) * te)
        # excursion of the centre during the exposure (du_min, du_max, dv_min, dv_max), sampled on the path
        # so that curved motion in long exposures (a rotor) stays inside the patch
        exc = np.zeros((len(kept_ids), 4))
        moving = np.nonzero(ksamp > 1)[0]
        if moving.size:
            ts = t_c[moving, None] + te * np.linspace(-0.5, 0.5, 9)[None, :]
            d = self.project(world.positions([kept_ids[i] for i in moving], ts)) - uc[moving, None, :]
            exc[moving] = np.column_stack([d[..., 0].min(1), d[..., 0].max(1),
                                           d[..., 1].min(1), d[..., 1].max(1)])
        pad = 2.0 + 3.0 * self.psf_sigma_px + 0.02 * (exc[:, 1] - exc[:, 0] + exc[:, 3] - exc[:, 2])
        g = np.clip(1.0 - vel[:, 1] * lt, 0.25, None)
        y_lo = np.floor(uc[:, 1] + (ext[:, 2] + exc[:, 2] - pad) / g).astype(int)
        y_hi = np.ceil(uc[:, 1] + (ext[:, 3] + exc[:, 3] + pad) / g).astype(int)
        shift = (vel[:, 0] * lt)[:, None] * np.stack([y_lo - uc[:, 1], y_hi - uc[:, 1]], axis=1)
        x_lo = np.floor(uc[:, 0] + ext[:, 0] + exc[:, 0] - pad + shift.min(axis=1)).astype(int)
        x_hi = np.ceil(uc[:, 0] + ext[:, 1] + exc[:, 1] + pad + shift.max(axis=1)).astype(int)
        on = (y_hi >= 0) & (y_lo < h) & (x_hi >= 0) & (x_lo < w)
        y_lo, y_hi = np.clip(y_lo, -h, 2 * h), np.clip(y_hi, -h, 2 * h)
        x_lo, x_hi = np.clip(x_lo, -w, 2 * w), np.clip(x_hi, -w, 2 * w)
        stacks: list[tuple[NDArray[np.float32], NDArray[np.int_], NDArray[np.int_]]] = []
        t_mid = y_mid * lt + 0.5 * te
        span_s = [float(t_c.min()) - t0 - 0.5 * te, float(t_c.max()) - t0 + 0.5 * te, t_mid - dt, t_mid + dt]
        for kk in np.unique(ksamp[on]):
            sel = np.nonzero(on & (ksamp == kk))[0]
            hp = int(np.max(y_hi[sel] - y_lo[sel])) + 1
            wp = int(np.max(x_hi[sel] - x_lo[sel])) + 1
            rows = y_lo[sel, None] + np.arange(hp)[None, :]
            times = (t0 + rows[:, :, None] * lt + (np.arange(kk) + 0.5)[None, None, :] / kk * te)
            centres = self.project(world.positions([kept_ids[i] for i in sel], times.reshape(len(sel), -1)))
            cov = coverage_patches(conics[sel], centres.reshape(len(sel), hp, kk, 2), y_lo[sel], x_lo[sel],
                                   width_px=wp, psf_sigma_px=self.psf_sigma_px)
            stacks.append((cov, y_lo[sel], x_lo[sel]))
            span_s += [float(times.min()) - t0, float(times.max()) - t0]
        span = (min(span_s), max(span_s))
        still = self.world.at_rest_between(ids, t0 + span[0] - 1e-6, t0 + span[1] + 1e-6)
        return _Patches(stacks, span, self._pose_key(ids, t0) if still else b"")  # b"": never reused

    def _blend(self, frame: NDArray[np.uint8], cov: NDArray[np.float32], r0: NDArray[np.int_],
               c0: NDArray[np.int_], rng: np.random.Generator) -> None:
        """Add marker signal (coverage × contrast) plus its extra shot noise onto the noisy background."""
        shot = np.float32(self.noise.shot_noise_dn2_per_dn)
        normals = self._normals(cov.size, rng) if shot > 0 else np.zeros(0, np.float32)
        add_patches(frame, cov, np.asarray(r0, np.int64), np.asarray(c0, np.int64),
                    np.float32(self.noise.marker_level_dn - self.noise.background_level_dn), shot, normals)

    # ------------------------------------------------------------------ video
    def write_video(self, path: str | Path, t_start_s: float, t_stop_s: float, fourcc: str = "mp4v") -> int:
        """Render the frames between two world times into a video file (``'mp4v'`` → .mp4, ``'MJPG'`` → .avi)
        at the nominal fps; return the number of frames written. Raises OSError if OpenCV cannot open it."""
        if len(fourcc) != 4:
            raise ValueError(f"fourcc must be 4 characters such as 'mp4v' or 'MJPG', got {fourcc!r}")
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*fourcc), self.fps,
                                 (self.width_px, self.height_px), True)
        if not writer.isOpened():
            raise OSError(f"OpenCV cannot write {str(path)!r} with fourcc {fourcc!r}")
        n = 0
        try:
            for i in self.frame_indices_between(t_start_s, t_stop_s):
                writer.write(cv2.cvtColor(self.render(i), cv2.COLOR_GRAY2BGR))
                n += 1
        finally:
            writer.release()
        return n

"""Bodies of the simulated rig whose pose is an exact function of time, kept for all past times.

* :class:`RobotBody` — the Denso flange: rests, or moves between P poses (x, y, z mm; rx, ry, rz deg,
  Denso convention R = Rz(rz)·Ry(ry)·Rx(rx), rotations about the fixed base axes) with a trapezoidal
  velocity profile in Cartesian space; orientation follows the same normalised profile (slerp).
* :class:`OscillatorBody` — a body driven at frequency f(t) with phase φ(t) = φ0 + ∫ 2π f dt computed in
  closed form for constant, linear-ramp and linear/log-sweep segments (phase-continuous across commands);
  displacement = A(t)·sin φ(t) for the exciter and the shaker, angle = φ(t) for the rotor.

Thread safety and the command rule: mock servers drive the bodies from their own threads. Every command
takes a time ``t_s`` that must be ≥ the time of the previous command on that body (else
:class:`SimCommandError`); a command only replaces the planned future (segments at t ≥ t_s) and never the
past, so frames of a camera can be rendered for any past instant after the fact. Writers hold a lock;
readers take an immutable snapshot (a tuple) and need no lock. All query methods accept a float or an
array of times and return the matching shape.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from drivers.sim.errors import SimCommandError, _finite
from drivers.sim.oscillator import OscillatorBody  # re-exported: the bodies of the world live in two files

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

__all__ = ["OscillatorBody", "RobotBody", "SimCommandError", "euler_deg_to_matrix", "trapezoid_duration_s"]


def _rotation() -> type[Rotation]:
    """SciPy's ``Rotation``, imported by the first use of an orientation (≈ 0.5 CPU-s of imports): the mock
    servers of the drives and the generator build the whole world but never turn the arm."""
    from scipy.spatial.transform import Rotation

    rotation: type[Rotation] = Rotation
    return rotation


def euler_deg_to_matrix(rxyz_deg: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrix (…, 3, 3) of Denso angles rx, ry, rz in degrees: R = Rz·Ry·Rx (fixed axes)."""
    rotation = _rotation().from_euler("xyz", np.asarray(rxyz_deg, float), degrees=True)
    matrix: NDArray[np.float64] = rotation.as_matrix()
    return matrix


def trapezoid_duration_s(distance: float, speed: float, accel: float) -> tuple[float, float, float]:
    """(t_accel_s, t_cruise_s, v_peak) of a rest-to-rest trapezoidal profile over ``distance`` (≥ 0)."""
    if distance <= 0.0:
        return 0.0, 0.0, 0.0
    if distance >= speed * speed / accel:
        return speed / accel, (distance - speed * speed / accel) / speed, speed
    v_peak = math.sqrt(distance * accel)
    return v_peak / accel, 0.0, v_peak


def _rodrigues(rotvec: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices (N, 3, 3) of rotation vectors (N, 3) (radians)."""
    theta = np.linalg.norm(rotvec, axis=1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = rotvec / safe[:, None]
    kx = np.zeros((len(k), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx[:, 1, 0], kx[:, 2, 0], kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], (1.0 - np.cos(theta))[:, None, None]
    matrices: NDArray[np.float64] = np.eye(3) + s * kx + c * (kx @ kx)
    return matrices


@dataclass(frozen=True)
class _Move:
    """One move of the flange; the path parameter s ∈ [0, 1] runs through constant-acceleration phases."""

    t_start_s: float
    t_end_s: float
    p0_mm: NDArray[np.float64]
    dp_mm: NDArray[np.float64]
    r0: Rotation
    rotvec: NDArray[np.float64]  # rotation from start to target orientation, base frame, as r0⁻¹·r1 rotvec
    phases: tuple[tuple[float, float, float, float], ...]  # (t0, s0, v0 per s, a per s²)
    s_end: float
    decel_norm: float  # per s² (for halt)
    rest_pose: NDArray[np.float64]  # (6,) pose at rest after the move
    linear: bool
    rest_rot: NDArray[np.float64]  # (3, 3) rotation at rest after the move

    def s_at(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Path parameter s and its rate ds/dt at times t (clamped to the move's interval)."""
        tc = np.clip(t, self.t_start_s, self.t_end_s)
        table = np.array(self.phases)
        k = np.clip(np.searchsorted(table[:, 0], tc, side="right") - 1, 0, len(table) - 1)
        ph = table[k]
        tau = tc - ph[..., 0]
        s = ph[..., 1] + ph[..., 2] * tau + 0.5 * ph[..., 3] * tau * tau
        v = ph[..., 2] + ph[..., 3] * tau
        done = t >= self.t_end_s
        return np.where(done, self.s_end, np.minimum(s, self.s_end)), np.where(done, 0.0, v)


class RobotBody:
    """The robot flange. ``home_pose`` is its pose before the first move (x, y, z mm; rx, ry, rz deg).

    ``rot_speed_deg_s`` / ``rot_accel_deg_s2`` bound the orientation change; a move lasts as long as the
    slower of translation and rotation needs, and both follow that one normalised trapezoid. The twin has
    no joint model: a PTP move (``linear=False``) follows the same straight Cartesian path as a linear one
    (end pose and duration are right; the path between differs on a real arm).
    """

    def __init__(self,
                 home_pose: NDArray[np.float64] | tuple[float, ...] = (350.0, 0.0, 300.0, 90.0, 0.0, 90.0),
                 *, rot_speed_deg_s: float = 120.0, rot_accel_deg_s2: float = 480.0) -> None:
        self._home = self._check_pose(home_pose, "home_pose")
        self.rot_speed_deg_s = _finite(rot_speed_deg_s, "rot_speed_deg_s", positive=True)
        self.rot_accel_deg_s2 = _finite(rot_accel_deg_s2, "rot_accel_deg_s2", positive=True)
        self._moves: tuple[_Move, ...] = ()
        self._starts_cache: tuple[tuple[_Move, ...] | None, NDArray[np.float64]] = (None, np.zeros(0))
        self._last_command_s = -math.inf
        self._lock = threading.Lock()

    @cached_property
    def _home_rot(self) -> NDArray[np.float64]:
        """(3, 3) rotation of the home pose (tool → base), computed at its first use."""
        return euler_deg_to_matrix(self._home[3:])

    @staticmethod
    def _check_pose(pose: NDArray[np.float64] | tuple[float, ...], name: str) -> NDArray[np.float64]:
        p = np.asarray(pose, dtype=float)
        if p.shape != (6,) or not np.all(np.isfinite(p)):
            raise SimCommandError(f"{name} must be 6 finite numbers (x, y, z mm, rx, ry, rz deg), "
                                  f"got {pose!r}")
        return p.copy()

    def _check_time(self, t_s: float) -> float:
        t = _finite(t_s, "t_s")
        if t < self._last_command_s:
            raise SimCommandError(f"t_s={t!r} is before the previous command at {self._last_command_s!r}; "
                                  "commands must not go back in time")
        return t

    @property
    def last_command_s(self) -> float:
        return self._last_command_s

    def move(self, t_start_s: float, target_pose: NDArray[np.float64] | tuple[float, ...], speed_mm_s: float,
             accel_mm_s2: float, linear: bool = True) -> float:
        """Start a move at ``t_start_s`` to ``target_pose``; return the time it ends (at rest).

        Raises :class:`SimCommandError` if the robot is still moving at ``t_start_s`` (halt first).
        """
        target = self._check_pose(target_pose, "target_pose")
        speed = _finite(speed_mm_s, "speed_mm_s", positive=True)
        accel = _finite(accel_mm_s2, "accel_mm_s2", positive=True)
        with self._lock:
            t0 = self._check_time(t_start_s)
            if self._moves and t0 < self._moves[-1].t_end_s:
                raise SimCommandError(f"robot is moving until t={self._moves[-1].t_end_s:.6f} s; cannot "
                                      f"start a move at t_start_s={t0:.6f} (halt first or start later)")
            self._last_command_s = t0
            start = self._moves[-1].rest_pose if self._moves else self._home
            rotation = _rotation()
            r0 = rotation.from_euler("xyz", start[3:], degrees=True)
            r1 = rotation.from_euler("xyz", target[3:], degrees=True)
            rotvec = (r0.inv() * r1).as_rotvec()
            dist_mm = float(np.linalg.norm(target[:3] - start[:3]))
            angle_deg = math.degrees(float(np.linalg.norm(rotvec)))
            ta, tc, vp = trapezoid_duration_s(dist_mm, speed, accel)
            ra, rc, rvp = trapezoid_duration_s(angle_deg, self.rot_speed_deg_s, self.rot_accel_deg_s2)
            if max(2 * ta + tc, 2 * ra + rc) <= 0.0:  # already there
                return t0
            if 2 * ta + tc >= 2 * ra + rc:
                t_acc, t_cruise = ta, tc
                v_n, a_n = vp / dist_mm, accel / dist_mm
            else:
                t_acc, t_cruise, v_n, a_n = ra, rc, rvp / angle_deg, self.rot_accel_deg_s2 / angle_deg
            duration = 2 * t_acc + t_cruise
            s1 = 0.5 * a_n * t_acc * t_acc
            phases = [(t0, 0.0, 0.0, a_n)]
            if t_cruise > 0.0:
                phases.append((t0 + t_acc, s1, v_n, 0.0))
            phases.append((t0 + t_acc + t_cruise, s1 + v_n * t_cruise, v_n, -a_n))
            mv = _Move(t0, t0 + duration, start[:3].copy(), target[:3] - start[:3], r0, rotvec, tuple(phases),
                       1.0, a_n, target.copy(), bool(linear), r1.as_matrix())
            self._moves = (*self._moves, mv)
            return mv.t_end_s

    def halt(self, t_s: float) -> None:
        """Decelerate to rest from ``t_s`` at the move's acceleration; the rest of the planned move is cut."""
        with self._lock:
            t = self._check_time(t_s)
            self._last_command_s = t
            if not self._moves or not (self._moves[-1].t_start_s <= t < self._moves[-1].t_end_s):
                return
            mv = self._moves[-1]
            s_h, v_h = (float(x) for x in mv.s_at(np.array(t)))
            t_stop = t + v_h / mv.decel_norm
            s_end = min(1.0, s_h + v_h * v_h / (2.0 * mv.decel_norm))
            phases = (*(p for p in mv.phases if p[0] < t), (t, s_h, v_h, -mv.decel_norm))
            rest = self._interp_pose(mv, np.array([s_end]))[0]
            cut = _Move(mv.t_start_s, t_stop, mv.p0_mm, mv.dp_mm, mv.r0, mv.rotvec, phases, s_end,
                        mv.decel_norm, rest, mv.linear, euler_deg_to_matrix(rest[3:]))
            self._moves = (*self._moves[:-1], cut)

    @staticmethod
    def _interp_pose(mv: _Move, s: NDArray[np.float64]) -> NDArray[np.float64]:
        pos = mv.p0_mm + s[:, None] * mv.dp_mm
        rot = mv.r0 * _rotation().from_rotvec(s[:, None] * mv.rotvec)
        return np.concatenate([pos, rot.as_euler("xyz", degrees=True)], axis=1)

    def is_moving(self, t_s: float) -> bool:
        """True while a move (or the deceleration of a halt) is under way at ``t_s``."""
        return any(m.t_start_s <= t_s < m.t_end_s for m in reversed(self._moves))

    def at_rest_between(self, t0_s: float, t1_s: float) -> bool:
        """True when the flange rests in one pose over the whole of [t0_s, t1_s] (no move under way in it)."""
        moves, idx = self._segments(np.array([t0_s, t1_s], dtype=float))
        return bool(idx[0] == idx[1] and (idx[0] < 0 or t0_s >= moves[idx[0]].t_end_s))

    def t_end_s(self) -> float:
        """Time at which the last commanded move ends (−inf if none)."""
        moves = self._moves
        return moves[-1].t_end_s if moves else -math.inf

    def _segments(self, t: NDArray[np.float64]) -> tuple[tuple[_Move, ...], NDArray[np.intp]]:
        moves = self._moves
        cached = self._starts_cache  # start times of the current move tuple, rebuilt when it changes
        if cached[0] is not moves:
            cached = (moves, np.array([m.t_start_s for m in moves]))
            self._starts_cache = cached
        idx = np.searchsorted(cached[1], t, side="right") - 1 if moves else np.full(t.shape, -1)
        return moves, idx

    def pose_at(self, t_s: float | NDArray[np.float64]) -> NDArray[np.float64]:
        """Pose (6,) — or (N, 6) for N times — in the Denso convention; at rest, the commanded pose."""
        t = np.asarray(t_s, dtype=float)
        flat = np.atleast_1d(t).ravel()
        out = np.tile(self._home, (flat.size, 1))
        moves, idx = self._segments(flat)
        for k in np.unique(idx[idx >= 0]):
            mv = moves[k]
            sel = idx == k
            s, _ = mv.s_at(flat[sel])
            moving = flat[sel] < mv.t_end_s
            vals = np.tile(mv.rest_pose, (int(sel.sum()), 1))
            if moving.any():
                vals[moving] = self._interp_pose(mv, s[moving])
            out[sel] = vals
        return out[0] if t.ndim == 0 else out.reshape((*t.shape, 6))

    def transform_at(self, t_s: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Flange position (N, 3) mm and rotation matrices (N, 3, 3) (tool → base) at times t_s (N,)."""
        flat = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        moves, idx = self._segments(flat)
        lo, hi = (int(idx.min()), int(idx.max())) if flat.size else (-1, -1)
        if lo == hi and (lo < 0 or flat.min() >= moves[lo].t_end_s):  # all at rest in one place
            p0, r0 = ((self._home[:3], self._home_rot) if lo < 0
                      else (moves[lo].rest_pose[:3], moves[lo].rest_rot))
            return np.broadcast_to(p0, (flat.size, 3)).copy(), np.broadcast_to(r0, (flat.size, 3, 3)).copy()
        pos = np.tile(self._home[:3], (flat.size, 1))
        rot = np.tile(self._home_rot, (flat.size, 1, 1))
        for k in np.unique(idx[idx >= 0]):
            mv = moves[k]
            sel = idx == k
            s, _ = mv.s_at(flat[sel])
            moving = flat[sel] < mv.t_end_s
            p = np.tile(mv.rest_pose[:3], (s.size, 1))
            r = np.tile(mv.rest_rot, (s.size, 1, 1))
            if moving.any():
                sm = s[moving]
                p[moving] = mv.p0_mm + sm[:, None] * mv.dp_mm
                r[moving] = mv.r0.as_matrix() @ _rodrigues(sm[:, None] * mv.rotvec)
            pos[sel], rot[sel] = p, r
        return pos, rot

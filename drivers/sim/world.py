"""The simulated rig world: bodies moving in virtual time and the markers they carry.

Every marker position is an exact function of time for all past and planned times (the bodies keep their
segments), so cameras can render any instant after the fact. Which target is mounted is itself a timeline
(:meth:`World.set_scene`), so a frame rendered late still shows what was mounted when it was exposed.
Positions in mm in the robot base frame (see :mod:`drivers.sim.targets` for frames and marker ids).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from drivers.sim.bodies import OscillatorBody, RobotBody, SimCommandError
from drivers.sim.clock import VirtualClock
from drivers.sim.fiducial import SyncLed
from drivers.sim.targets import TargetSet, unit

__all__ = ["SCENES", "World", "WorldLayout"]

SCENES = ("calibration_plate", "single_marker", "marker_frame", "plate", "rotor", "sweep_column",
          "band_column", "none")
_ARM_SCENES = {"calibration_plate", "single_marker", "marker_frame"}


@dataclass(frozen=True)
class WorldLayout:
    """Everything physical about the rig that is not a camera: robot home pose, targets, exciter data."""

    robot_home_pose: tuple[float, ...] = (350.0, 0.0, 300.0, 90.0, 0.0, 90.0)
    robot_rot_speed_deg_s: float = 120.0
    robot_rot_accel_deg_s2: float = 480.0
    crank_radius_mm: float = 4.0  # the crank exciter's fixed displacement amplitude
    shaker_amplitude_mm: float = 0.0  # set by the generator amplitude at run time
    targets: TargetSet = field(default_factory=TargetSet)
    initial_scene: str = "calibration_plate"


@dataclass(frozen=True)
class _Marker:
    kind: str  # "fixed" | "flange" | "osc" | "rotor"
    diameter_mm: float
    point: NDArray[np.float64]  # fixed: position; flange: tool offset; osc: rest position; rotor: centre
    normal: NDArray[np.float64]  # base frame, or tool frame for "flange"
    body: str = ""
    axis: NDArray[np.float64] | None = None  # osc: displacement direction; rotor: e0
    weight: float = 1.0  # osc: shape factor; rotor: radius
    e1: NDArray[np.float64] | None = None  # rotor


_PlanGroup = tuple[str, str, NDArray[np.intp], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
"""(kind, body, marker indices, stacked points, axes × weight, second axes × weight) of one group."""


def _weighted(direction: NDArray[np.float64] | None, weight: float) -> NDArray[np.float64]:
    """``direction`` × ``weight``; zeros for a marker without that direction."""
    return (direction if direction is not None else np.zeros(3)) * weight


class World:
    """The rig in software. ``clock`` defaults to an instant :class:`VirtualClock`; ``seed`` is kept for the
    cameras built on this world (the world itself is deterministic: truth has no noise)."""

    def __init__(self, clock: VirtualClock | None = None, seed: int = 0,
                 layout: WorldLayout | None = None) -> None:
        self.clock = clock if clock is not None else VirtualClock()
        self.seed = int(seed)
        self.layout = layout if layout is not None else WorldLayout()
        lay = self.layout
        self.robot = RobotBody(lay.robot_home_pose, rot_speed_deg_s=lay.robot_rot_speed_deg_s,
                               rot_accel_deg_s2=lay.robot_rot_accel_deg_s2)
        self.exciter = OscillatorBody("exciter", amplitude_mm=lay.crank_radius_mm)
        self.rotor = OscillatorBody("rotor")
        self.shaker = OscillatorBody("shaker", amplitude_mm=lay.shaker_amplitude_mm)
        self._bodies = {"exciter": self.exciter, "rotor": self.rotor, "shaker": self.shaker}
        self._markers, self._scene_ids = self._build(lay.targets)
        if lay.initial_scene not in SCENES:
            raise ValueError(f"initial_scene must be one of {SCENES}, got {lay.initial_scene!r}")
        self._scenes: tuple[tuple[float, str], ...] = ((-math.inf, lay.initial_scene),)
        self._lock = threading.Lock()
        self._plans: dict[tuple[str, ...], list[_PlanGroup]] = {}
        self.leds: tuple[SyncLed, ...] = ()  # timing fiducials in view (drivers.sim.fiducial)

    def add_led(self, led: SyncLed) -> SyncLed:
        """Put a timing fiducial LED into the world (the cameras render it in every scene)."""
        if any(other.name == led.name for other in self.leds):
            raise ValueError(f"an LED named {led.name!r} is already in the world")
        self.leds = (*self.leds, led)
        return led

    def _build(self, tg: TargetSet) -> tuple[dict[str, _Marker], dict[str, list[str]]]:
        markers: dict[str, _Marker] = {}
        scenes: dict[str, list[str]] = {name: [] for name in SCENES}
        z_tool = np.array([0.0, 0.0, 1.0])
        arm_targets = (("calibration_plate", tg.calibration_plate), ("single_marker", tg.single_marker),
                       ("marker_frame", tg.marker_frame))
        for scene, target in arm_targets:
            for mid, off in target.offsets_tool_mm().items():
                markers[mid] = _Marker("flange", target.marker_diameter_mm, off, z_tool)
                scenes[scene].append(mid)
        col = tg.sweep_column
        self._check_body(col.body, "sweep_column.body")
        for mid, pos in col.rest_positions_mm().items():
            markers[mid] = _Marker("osc", col.marker_diameter_mm, pos, unit(col.normal, "normal"), col.body,
                                   unit(col.axis, "axis"), 1.0)
            scenes["sweep_column"].append(mid)
        # the same column re-mounted on the shaker's armature (certify's band beyond the crank's limit)
        for k, pos in enumerate(col.rest_positions_mm().values()):
            markers[f"bcol{k}"] = _Marker("osc", col.marker_diameter_mm, pos, unit(col.normal, "normal"),
                                          "shaker", unit(col.axis, "axis"), 1.0)
            scenes["band_column"].append(f"bcol{k}")
        pl = tg.plate
        self._check_body(pl.body, "plate.body")
        for mid, (pos, w) in pl.rest_positions_mm().items():
            markers[mid] = _Marker("osc", pl.marker_diameter_mm, pos, unit(pl.normal, "normal"), pl.body,
                                   pl.displacement_axis(), w)
            scenes["plate"].append(mid)
        ro = tg.rotor
        e0, e1, ax = ro.basis()
        markers["rotor"] = _Marker("rotor", ro.marker_diameter_mm, np.asarray(ro.centre_mm, float), ax,
                                   "rotor", e0, float(ro.radius_mm), e1)
        scenes["rotor"].append("rotor")
        refs = tg.references
        for mid, pos in refs.positions().items():
            markers[mid] = _Marker("fixed", refs.marker_diameter_mm, pos, unit(refs.normal, "normal"))
        ref_ids = list(refs.positions())
        return markers, {k: v + ref_ids for k, v in scenes.items()}

    def _check_body(self, name: str, field_name: str) -> None:
        if name not in self._bodies:
            raise ValueError(f"{field_name} must be one of {sorted(self._bodies)}, got {name!r}")

    # ------------------------------------------------------------------ scenes
    def set_scene(self, name: str, t_s: float | None = None) -> None:
        """Mount target ``name`` (one of :data:`SCENES`) from ``t_s`` (default: now) on."""
        if name not in SCENES:
            raise ValueError(f"scene must be one of {SCENES}, got {name!r}")
        t = self.clock.now_s() if t_s is None else float(t_s)
        with self._lock:
            if t < self._scenes[-1][0]:
                raise SimCommandError(f"scene change at t_s={t} is before the previous one at "
                                      f"{self._scenes[-1][0]}")
            self._scenes = (*(s for s in self._scenes if s[0] < t), (t, name))

    def scene_at(self, t_s: float) -> str:
        scenes = self._scenes
        k = int(np.searchsorted([s[0] for s in scenes], t_s, side="right")) - 1
        return scenes[max(k, 0)][1]

    @property
    def scene(self) -> str:
        return self.scene_at(self.clock.now_s())

    def scene_marker_ids(self, scene: str) -> list[str]:
        if scene not in SCENES:
            raise ValueError(f"scene must be one of {SCENES}, got {scene!r}")
        return list(self._scene_ids[scene])

    def marker_ids_at(self, t_s: float) -> list[str]:
        return list(self._scene_ids[self.scene_at(t_s)])

    @property
    def marker_ids(self) -> list[str]:
        """Markers present now (mounted target + references)."""
        return self.marker_ids_at(self.clock.now_s())

    @property
    def all_marker_ids(self) -> list[str]:
        return list(self._markers)

    def _spec(self, marker_id: str) -> _Marker:
        try:
            return self._markers[marker_id]
        except KeyError:
            raise KeyError(f"unknown marker_id {marker_id!r}; known: {sorted(self._markers)}") from None

    def marker_diameter_mm(self, marker_id: str) -> float:
        return self._spec(marker_id).diameter_mm

    def is_static(self, marker_id: str) -> bool:
        return self._spec(marker_id).kind == "fixed"

    # ------------------------------------------------------------------ truth
    def _plan(self, marker_ids: list[str]) -> list[_PlanGroup]:
        """Per (kind, body): indices, stacked points, axes (× weight), second axes; cached per id list."""
        key = tuple(marker_ids)
        plan = self._plans.get(key)
        if plan is None:
            specs = [self._spec(m) for m in marker_ids]
            groups: dict[tuple[str, str], list[int]] = {}
            for i, sp in enumerate(specs):
                groups.setdefault((sp.kind, sp.body), []).append(i)
            plan = []
            for (kind, body), idx in groups.items():
                pts = np.stack([specs[i].point for i in idx])
                ax = np.stack([_weighted(specs[i].axis, specs[i].weight) for i in idx])
                e1 = np.stack([_weighted(specs[i].e1, specs[i].weight) for i in idx])
                plan.append((kind, body, np.array(idx), pts, ax, e1))
            if len(self._plans) > 256:
                self._plans.clear()
            self._plans[key] = plan
        return plan

    def _flange_at(self, t_s: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Flange position (..., 3) mm and rotation (..., 3, 3) at times ``t_s`` (any shape), each distinct
        time computed once: the markers of a plate share the times of the rows they cross (the same
        numbers per time as computing every entry)."""
        unique_s, inverse = np.unique(t_s, return_inverse=True)
        pos, rot = self.robot.transform_at(unique_s)
        return pos[inverse].reshape((*t_s.shape, 3)), rot[inverse].reshape((*t_s.shape, 3, 3))

    def at_rest_between(self, marker_ids: list[str], t0_s: float, t1_s: float) -> bool:
        """True when every one of the markers keeps its position and normal over [t0_s, t1_s]: fixed ones,
        and those on the flange while the robot rests; a marker on an oscillator or the rotor counts as moving
        (not examined)."""
        kinds = {kind for kind, *_ in self._plan(marker_ids)}
        if not kinds <= {"fixed", "flange"}:
            return False
        return "flange" not in kinds or self.robot.at_rest_between(t0_s, t1_s)

    def positions(self, marker_ids: list[str], t_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Centres (M, N, 3) mm of M markers at times ``t_s``: (N,) shared by all, or (M, N) each its own."""
        t = np.asarray(t_s, dtype=float)
        m = len(marker_ids)
        tt = t.reshape(1, -1) if t.ndim <= 1 else t
        tt = np.broadcast_to(tt, (m, tt.shape[1]))
        out = np.empty((m, tt.shape[1], 3))
        for kind, body, idx, pts, ax, e1 in self._plan(marker_ids):
            ts = tt[idx]
            if kind == "fixed":
                out[idx] = pts[:, None, :]
            elif kind == "flange":
                pos, rot = self._flange_at(ts)
                out[idx] = pos + np.einsum("mnij,mj->mni", rot, pts)
            elif kind == "osc":
                disp = np.asarray(self._bodies[body].displacement_mm(ts))
                out[idx] = pts[:, None, :] + disp[..., None] * ax[:, None, :]
            else:  # rotor: centre + r (cos φ e0 + sin φ e1)
                phi = np.asarray(self._bodies[body].phase_rad(ts))[..., None]
                out[idx] = pts[:, None, :] + np.cos(phi) * ax[:, None, :] + np.sin(phi) * e1[:, None, :]
        return out

    def normals(self, marker_ids: list[str], t_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Unit normals of the marker discs: (M, 3) for one time each (scalar or (M,) times), or (M, N, 3)
        for (M, N) times."""
        t = np.asarray(t_s, dtype=float)
        shape = t.shape if t.ndim == 2 else (len(marker_ids),)
        t = np.broadcast_to(t, shape)
        specs = [self._spec(m) for m in marker_ids]
        base = np.array([sp.normal for sp in specs]).reshape(-1, 3)
        out = np.broadcast_to(base.reshape((len(specs),) + (1,) * (t.ndim - 1) + (3,)), (*shape, 3)).copy()
        flange = [i for i, sp in enumerate(specs) if sp.kind == "flange"]
        if flange:
            _, rot = self._flange_at(t[flange].ravel())
            n = np.repeat(base[flange], t[flange].size // len(flange), axis=0)
            out[flange] = np.einsum("mij,mj->mi", rot, n).reshape(out[flange].shape)
        return out

    def marker_normal(self, marker_id: str, t_s: float) -> NDArray[np.float64]:
        normal: NDArray[np.float64] = self.normals([marker_id], t_s)[0]
        return normal

    def markers(self, t_s: float | NDArray[np.float64],
                marker_ids: list[str] | None = None) -> dict[str, NDArray[np.float64]]:
        """Every marker's centre in the base frame (mm): (3,) for a scalar time, (N, 3) for N times.

        Without ``marker_ids``: the markers present at ``t_s`` (at the earliest of several times)."""
        t = np.asarray(t_s, dtype=float)
        ids = marker_ids if marker_ids is not None else self.marker_ids_at(float(np.min(t)))
        pos = self.positions(ids, np.atleast_1d(t).ravel())
        return {m: (pos[i, 0] if t.ndim == 0 else pos[i].reshape((*t.shape, 3))) for i, m in enumerate(ids)}

"""The procedure API: what a scripted procedure module provides and what it may call.

A procedure is a plain module (``procedures/<name>.py``) with three things::

    from dataclasses import dataclass, field
    from rig.run.procedure import Context, param

    NAME = "sweep"                      # letters, digits, '_' / '-'; names the run folder
    DESCRIPTION = "Constant amplitude, frequency rising to 30 Hz."   # optional, shown by `rig list`

    @dataclass(frozen=True)
    class Parameters:                   # typed defaults and ranges; `rig run sweep --set max_hz=25`
        max_hz: float = field(default=30.0, metadata=param(lo=1.0, hi=60.0, doc="highest frequency, Hz"))
        dwell_s: float = field(default=2.0, metadata=param(lo=0.0, hi=600.0))
        spacing: str = field(default="linear", metadata=param(choices=("linear", "log")))

    def run(ctx: Context, params: Parameters) -> dict | None:
        exciter = ctx.exciter()                 # typed: the station's Exciter (ParameterError if none)
        with ctx.step("ramp") as step:          # recorded begin/done; skipped on --resume if done
            if not step.skipped:
                ...
                ctx.event("exciter", {"frequency_hz": f, "setpoint_hz": s, "status": st})
                ctx.checkpoint()                # abort/interlock point
                ctx.sleep_s(0.5)                # sleeps in slices, checkpointing
                step.output(ctx.write_json("timing.json", timing))
        return {"passed": True, "summary": "..."}   # optional verdict (``passed`` False → exit code 1)

A built-in procedure keeps ``NAME``, ``DESCRIPTION`` and ``Parameters`` in ``procedures/params/<module>.py``
(importing no numpy or pandas) and imports them: ``rig list`` reads those without the procedures' machinery.

Rules: a procedure never cleans up hardware (no safety ``try/finally``): the runner stops every device
whatever happens. It records the truth it commands and what devices report with :meth:`Context.event`
(streams of ``docs/contracts.md``). It calls :meth:`Context.checkpoint` between motions; the runner
raises :class:`Abort` there after a first Ctrl-C, and :class:`InterlockTripped` after a trip.

A procedure that moves anything also defines ``plan(params, config) -> rig.run.plan.Plan``: its whole plan
(poses, speeds, frequency profiles, amplitudes, durations) from the parameters and the configuration alone;
the runner checks it against every limit before any device is connected (:mod:`rig.run.plan`; exit 4), and
``run`` carries out that same plan.

Parameters are validated before anything moves (:func:`validate_parameters`): unknown name, wrong type,
out of range → :class:`ParameterError` naming ``<procedure>.<field>``, the value and what is allowed.
``param(...)`` accepts ``lo``, ``hi``, ``lo_open``, ``choices``, ``length`` (arrays) and ``doc``.
A ``__post_init__`` on ``Parameters`` may raise ``ValueError`` for cross-field checks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import tomllib
import types
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from drivers.roles import Camera, Device
from drivers.sim.clock import VirtualClock
from rig.config.schema import ConfigError, build, spec, to_dict
from rig.record.events import Event
from rig.run.clock import Clock

if TYPE_CHECKING:  # the devices, the configuration and the record import the protocols' codecs, numpy or
    # pandas: `rig list` reads the procedures' parameters without them (the typed accessors import them)
    from drivers.denso.arm import DensoArm
    from drivers.exciter.axis import VfdAxis
    from drivers.exciter.exciter import Exciter
    from drivers.exciter.rotor import Rotor
    from drivers.exciter.shaker import Shaker
    from rig.config.rig_config import RigConfig
    from rig.record.observations import ObservationWriter
    from rig.record.writer import RunRecord

__all__ = [
    "Abort",
    "Context",
    "InterlockTripped",
    "ParameterError",
    "StationView",
    "Step",
    "param",
    "parameter_table",
    "parse_set",
    "validate_parameters",
]

D = TypeVar("D", bound=Device)

param = spec  # same metadata as the configuration schema: lo, hi, lo_open, choices, length, check, doc


class ParameterError(ConfigError):
    """A procedure parameter (or ``--set`` override) is unknown, of the wrong type or out of range."""


class Abort(Exception):  # noqa: N818 — a request, not an error
    """Raised at a checkpoint when an abort was requested (first Ctrl-C, ``request_abort``)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class InterlockTripped(Abort):
    """An interlock tripped (limit, envelope, lost heartbeat): the run aborts and never resumes motion."""

    def __init__(self, device: str, reason: str) -> None:
        super().__init__(f"interlock on {device}: {reason}")
        self.device = device
        self.interlock_reason = reason


def check_declaration(module: types.ModuleType) -> None:
    """Raise TypeError unless ``module`` has ``NAME`` (str) and a ``Parameters`` dataclass: what ``rig list``
    reads (from the procedure module, or its light declaration ``procedures/params/<module>.py``)."""
    name = getattr(module, "NAME", None)
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "_-" for c in name):
        raise TypeError(f"procedure module {module.__name__!r}: NAME must be a non-empty str of letters, "
                        f"digits, '_' or '-', got {name!r}")
    if not dataclasses.is_dataclass(getattr(module, "Parameters", None)):
        raise TypeError(f"procedure module {module.__name__!r}: Parameters must be a dataclass")


def check_procedure_module(module: types.ModuleType) -> None:
    """Raise TypeError unless ``module`` has ``NAME`` (str), a ``Parameters`` dataclass and ``run``."""
    check_declaration(module)
    if not callable(getattr(module, "run", None)):
        raise TypeError(f"procedure module {module.__name__!r}: run(ctx, params) is missing")


def parse_set(items: list[str]) -> dict[str, Any]:
    """``["max_hz=25", "spacing=log", "poses=[1,2]"]`` → dict. Values are TOML literals when they parse as
    one (numbers, booleans, arrays, quoted strings), plain strings otherwise."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ParameterError("--set", f"{item!r} is not KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        out[key] = value
    return out


def validate_parameters(module: types.ModuleType, overrides: dict[str, Any] | None = None) -> object:
    """Build ``module.Parameters`` from its defaults and ``overrides``; raise :class:`ParameterError`."""
    check_procedure_module(module)
    try:
        parameters: object = build(module.Parameters, dict(overrides or {}), module.NAME)
        return parameters
    except ParameterError:
        raise
    except ConfigError as exc:
        raise ParameterError(exc.field, str(exc).removeprefix(f"{exc.field}: ")) from exc


def parameter_table(module: types.ModuleType) -> list[dict[str, Any]]:
    """One row per parameter: name, type, default, range/choices, doc (for ``rig list`` and ``--help``)."""
    rows = []
    for f in dataclasses.fields(module.Parameters):
        meta = dict(f.metadata)
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        allowed = ""
        if meta.get("choices"):
            allowed = "one of " + ", ".join(map(repr, meta["choices"]))
        elif meta.get("lo") is not None or meta.get("hi") is not None:
            lo, hi = meta.get("lo"), meta.get("hi")
            allowed = f"{'' if lo is None else f'{lo:g} ≤ '}value{'' if hi is None else f' ≤ {hi:g}'}"
        rows.append({"name": f.name, "type": str(f.type), "default": to_dict(default), "allowed": allowed,
                     "doc": meta.get("doc", "")})
    return rows


@dataclass
class Step:
    """A recorded step. ``skipped`` is True when it completed in an earlier session (``--resume``): the
    body must then not redo the work; ``outputs`` holds what that session recorded."""

    name: str
    skipped: bool
    outputs: list[str] = field(default_factory=list)

    def output(self, relative_path: str | os.PathLike[str]) -> str:
        """Declare a file written by this step (path relative to the run folder); returns it."""
        rel = Path(relative_path).as_posix()
        if rel not in self.outputs:
            self.outputs.append(rel)
        return rel


class StationView(Protocol):
    """What a procedure sees of the station (:class:`rig.run.station.Station`): its devices and cameras
    by name, whether it is the simulated twin, and target mounting."""

    @property
    def devices(self) -> Mapping[str, Device]: ...

    @property
    def cameras(self) -> Mapping[str, Camera]: ...

    @property
    def simulated(self) -> bool:
        """True on the twin (targets are mounted by :meth:`mount`), False on a real bench."""
        ...

    def mount(self, scene: str) -> None:
        """Mount a target on the twin (a real bench raises: the operator mounts it)."""
        ...


class Context:
    """What a procedure sees. Built by the runner; see the module docstring for the rules.

    Attributes: ``station`` (devices by name), ``config`` (the frozen
    :class:`rig.config.rig_config.RigConfig`),
    ``clock`` (rig time), ``record`` (the :class:`rig.record.writer.RunRecord`), ``run_dir``, ``params``,
    ``resumed`` (True in a ``--resume`` session), ``log`` (a :class:`logging.Logger`).
    Devices come typed by what the procedure needs of them: :meth:`arm`, :meth:`exciter`, :meth:`rotor`,
    :meth:`vfd_axis`, :meth:`shaker` (:meth:`device` gives any device by name, as the runner knows it).
    """

    def __init__(self, *, station: StationView, config: RigConfig, clock: Clock, record: RunRecord,
                 params: object, log: logging.Logger, checkpoint: Callable[[], None],
                 progress: Callable[[float | None, str], None]) -> None:
        self.station = station
        self.config = config
        self.clock = clock
        self.record = record
        self.run_dir: Path = record.run_dir
        self.params = params
        self.log = log
        self.resumed = record.session > 0
        self._checkpoint = checkpoint
        self._progress = progress

    # -- control
    def checkpoint(self) -> None:
        """Raise :class:`Abort` / :class:`InterlockTripped` if requested or tripped; else return at once."""
        self._checkpoint()

    def progress(self, fraction: float | None, message: str = "") -> None:
        """Report progress (0–1, or None when unknown) with a short message; never recorded."""
        if fraction is not None and not 0.0 <= fraction <= 1.0:
            raise ValueError(f"progress fraction {fraction!r} not allowed; allowed: 0 ≤ fraction ≤ 1 or None")
        self._progress(fraction, message)

    def sleep_s(self, duration_s: float, *, slice_s: float = 0.1) -> None:
        """Wait ``duration_s`` of rig time, checkpointing at least every ``slice_s`` (instant on a virtual
        instant clock)."""
        end = self.clock.now_s() + float(duration_s)
        self.checkpoint()
        while (remaining := end - self.clock.now_s()) > 0:
            instant = isinstance(self.clock, VirtualClock) and self.clock.is_instant
            self.clock.sleep_s(remaining if instant else min(remaining, slice_s))
            self.checkpoint()

    # -- devices
    def device(self, name: str) -> Device:
        """The device ``name`` of the station; :class:`ParameterError` if this rig has none."""
        devices = self.station.devices
        if name not in devices:
            have = ", ".join(devices) or "none"
            raise ParameterError(f"devices.{name}", f"procedure needs [devices.{name}], which this rig "
                                                    f"configuration lacks (has: {have})")
        return devices[name]

    def _device_of(self, name: str, kind: type[D]) -> D:
        device = self.device(name)
        if not isinstance(device, kind):
            raise TypeError(f"devices.{name} is a {type(device).__name__}; the procedure needs a "
                            f"{kind.__name__}")
        return device

    def arm(self) -> DensoArm:
        """The robot arm (``[devices.robot]``)."""
        from drivers.denso.arm import DensoArm

        return self._device_of("robot", DensoArm)

    def vfd_axis(self, name: str) -> VfdAxis:
        """The VFD axis ``name`` (``exciter`` or ``rotor``)."""
        from drivers.exciter.axis import VfdAxis

        return self._device_of(name, VfdAxis)

    def exciter(self) -> Exciter:
        """The crank exciter (``[devices.exciter]``)."""
        from drivers.exciter.exciter import Exciter

        return self._device_of("exciter", Exciter)

    def rotor(self) -> Rotor:
        """The rotor (``[devices.rotor]``)."""
        from drivers.exciter.rotor import Rotor

        return self._device_of("rotor", Rotor)

    def shaker(self) -> Shaker:
        """The function generator + amplifier + shaker (``[devices.generator]``)."""
        from drivers.exciter.shaker import Shaker

        return self._device_of("generator", Shaker)

    @property
    def cameras(self) -> Mapping[str, Camera]:
        """The station's cameras by name."""
        return self.station.cameras

    # -- record
    def event(self, stream: str, data: dict[str, Any] | Event) -> int:
        """Record an event of ``stream`` (see the streams of ``docs/contracts.md``; typed ones in
        :mod:`rig.record.events`); returns its seq."""
        return self.record.event(stream, data)

    def observation_writer(self, camera: str, **kwargs: Any) -> ObservationWriter:
        """A :class:`rig.record.writer.ObservationWriter` for ``camera``, tagged with the current step."""
        return self.record.observation_writer(camera, **kwargs)

    def is_done(self, step_name: str) -> bool:
        """True when ``step_name`` completed in this run (this or an earlier session)."""
        return step_name in self.record.completed_steps

    def outputs_of(self, step_name: str) -> list[str]:
        """Outputs recorded by a completed step (relative paths); KeyError if it did not complete."""
        return list(self.record.completed_steps[step_name])

    @contextlib.contextmanager
    def step(self, name: str) -> Iterator[Step]:
        """Record step ``name``: ``begin`` on entry, ``done`` with its outputs on normal exit (nothing on an
        exception: the step stays incomplete and a ``--resume`` redoes it). If it completed in an earlier
        session, yields ``Step(skipped=True, outputs=...)`` and records nothing."""
        if self.is_done(name):
            yield Step(name, True, self.outputs_of(name))
            return
        self.checkpoint()
        self.record.step_begin(name)
        step = Step(name, False)
        yield step
        self.record.step_done(name, step.outputs)

    def run_step(self, name: str, fn: Callable[[Step], Any]) -> Step:
        """Run ``fn(step)`` as step ``name`` unless it already completed; return the :class:`Step`."""
        with self.step(name) as step:
            if not step.skipped:
                fn(step)
        return step

    def path(self, relative_path: str | os.PathLike[str]) -> Path:
        """Absolute path inside the run folder (refuses paths that would leave it)."""
        return self.record.path_for(relative_path)

    def write_json(self, relative_path: str, obj: object) -> str:
        """Write ``obj`` as JSON into the run folder atomically (tmp + fsync + rename); return the path."""
        from rig.record.atomic import write_json
        from rig.record.jsonenc import to_jsonable

        target = self.path(relative_path)
        target.parent.mkdir(parents=True, exist_ok=True)
        write_json(target, to_jsonable(obj), indent=2, ensure_ascii=False, allow_nan=False)
        return Path(relative_path).as_posix()

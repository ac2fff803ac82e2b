"""The ``rig.toml`` schema: devices, cameras, target geometry, safety limits, acceptance criteria.

Load with :func:`load_config` (a file) or :func:`parse_config` (a TOML string); :func:`default_config`
returns the built-in simulated rig (``rig/data/sim.toml``). Validation is strict: an unknown field, a
wrong type, a value out of range, an unknown driver or a malformed address raises :class:`ConfigError`
whose message names the dotted field (``limits.exciter.max_frequency_hz``), the value and what is
allowed. The result is a tree of frozen dataclasses; :meth:`RigConfig.snapshot` gives the plain dict
written into the run record's ``start`` document.

Units: mm, degrees, seconds, Hz, pixels; names carry them. Sections (see ``rig/data/sim.toml`` for a
complete, commented example):

- ``[station]`` name, ``simulated`` (build the twin and its mock servers), ``runs_dir``, ``clock``.
- ``[devices.robot]`` ``driver = "denso-bcap"``, ``address``, ``controller = "rc8" | "rc7m"``, ``home_pose``.
- ``[devices.exciter]`` / ``[devices.rotor]`` ``driver = "modbus-vfd"``, ``address``, ``unit_id``,
  ``register_map`` (a name, e.g. ``"delta"``) or an inline ``[devices.exciter.registers]`` table,
  ``gear_ratio`` (motor Hz per mechanical Hz), ``crank_radius_mm`` (exciter: its fixed amplitude).
- ``[devices.generator]`` ``driver = "scpi-generator"``, ``address``, ``sensitivity_mm_per_v`` table.
- ``[cameras.<name>]`` ``driver = "sim" | "opencv" | "file"``, ``fps``, ``resolution_px``, ``source``,
  ``timestamps`` (opencv: ``"auto" | "stream" | "host"``, whose clock stamps the frames).
- ``[targets.*]`` marker geometry (mm): calibration plate, single marker, marker frame, sweep column,
  plate, rotor, reference markers.
- ``[limits.robot]`` envelope and speed; ``[limits.exciter|rotor|generator]`` frequency, displacement,
  acceleration (2πf)²·x and ramp-rate limits (as :class:`drivers.exciter.limits.MotionLimits`).
- ``[criteria]`` acceptance thresholds of the certificate and its decision rule.
- ``[fiducial]`` the timing fiducial LED (generator sync output, its image region per camera):
  :mod:`rig.config.fiducial`; absent = the start-event method relates the clocks.
- ``[analysis]`` ``sync`` method of the analysis (``trajectory`` default; ``linear`` = the paper's).
- ``[report]`` what a report computes beyond the certificate: ``comparison`` (sync methods analysed beside
  the primary one; default ``["linear"]``, ``[]`` none) and ``figures`` (default ``true``):
  :mod:`rig.config.report`. Neither changes a criterion.
- ``[sim]`` the twin's hidden truth (only for a simulated station): camera intrinsics, distortion,
  poses, clock errors, rolling-shutter line time, noise, seed.

Addresses: ``tcp://HOST:PORT``, ``serial:///dev/ttyUSB0?baud=115200`` or, on a simulated station,
``mock://tcp`` / ``mock://pty`` (the station starts the mock server and substitutes its real address).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from rig.config.address import endpoint, parse_address
from rig.config.analysis import AnalysisConfig
from rig.config.cameras import CameraConfig
from rig.config.criteria import CriteriaConfig
from rig.config.devices import DEVICE_NAMES, DevicesConfig, VfdConfig
from rig.config.fiducial import FiducialConfig, check_fiducial
from rig.config.limits import LimitsConfig
from rig.config.report import ReportConfig
from rig.config.schema import ConfigError, build, to_dict
from rig.config.sim import SimConfig
from rig.config.station import StationConfig
from rig.config.targets import TargetsConfig


@dataclass(frozen=True)
class RigConfig:
    """A validated rig configuration (frozen). ``source`` is where it was read from."""

    station: StationConfig
    devices: DevicesConfig
    cameras: dict[str, CameraConfig]
    targets: TargetsConfig
    limits: LimitsConfig
    criteria: CriteriaConfig = field(default_factory=CriteriaConfig)
    analysis: AnalysisConfig = field(default_factory=AnalysisConfig)
    report: ReportConfig = field(default_factory=ReportConfig)
    fiducial: FiducialConfig | None = None
    sim: SimConfig | None = None
    source: str = field(default="", init=False, compare=False)

    def snapshot(self) -> dict[str, Any]:
        """Plain-dict copy of the whole configuration (for the start document; round-trips via TOML)."""
        out = to_dict(self)
        out.pop("source", None)
        return {"source": self.source, **out}

    def camera_names(self) -> list[str]:
        return list(self.cameras)


def _check_distinct_endpoints(cfg: RigConfig) -> None:
    """Two devices must not resolve to one endpoint: the same host:port or serial device, unless both are
    Modbus drives with distinct unit ids (drives sharing an RS-485 line or a TCP gateway)."""
    seen: list[tuple[str, tuple[str, ...], int | None]] = []
    for name in DEVICE_NAMES:
        dev = getattr(cfg.devices, name)
        where = None if dev is None else endpoint(dev.address)
        if where is None:
            continue
        unit = dev.unit_id if isinstance(dev, VfdConfig) else None
        for other, other_where, other_unit in seen:
            if where == other_where and (unit is None or other_unit is None or unit == other_unit):
                ids = "" if unit is None or other_unit is None else f" and unit_id {unit}"
                raise ConfigError(f"devices.{name}.address",
                                  f"{dev.address!r}{ids} is the endpoint of devices.{other} too "
                                  f"({getattr(cfg.devices, other).address!r}): one physical device cannot be "
                                  f"configured as both {other} and {name} (it would be commanded against two "
                                  "limit sets); give each device its own address or unit_id")
        seen.append((name, where, unit))


def _check_configured_poses(cfg: RigConfig) -> None:
    """``devices.robot.home_pose`` and ``targets.calibration_plate.start_pose`` inside the arm's envelope
    (the driver's own check)."""
    from drivers.denso.arm import LimitError as ArmLimitError
    from drivers.denso.pose import check_pose

    if cfg.limits.robot is None:
        return
    envelope = cfg.limits.robot.envelope()
    poses = [("devices.robot.home_pose", cfg.devices.robot.home_pose if cfg.devices.robot else None)]
    plate = cfg.targets.calibration_plate
    poses.append(("targets.calibration_plate.start_pose", plate.start_pose if plate is not None else None))
    for path, pose in poses:
        if pose is None:
            continue
        try:
            envelope.check(check_pose(pose))
        except ArmLimitError as exc:
            limit = f"limits.robot.envelope_{exc.axis}" if exc.axis in ("x_mm", "y_mm", "z_mm") else \
                "the arm driver's orientation range"
            raise ConfigError(path, f"{[float(v) for v in pose]} is outside the arm's envelope: {exc} "
                                    f"({limit})") from exc


def _cross_check(cfg: RigConfig) -> None:
    if len(cfg.cameras) < 2:
        raise ConfigError("cameras", f"{len(cfg.cameras)} camera(s) configured; allowed: at least 2 (stereo)")
    for name, cam in cfg.cameras.items():
        if cam.driver == "sim" and (cfg.sim is None or name not in cfg.sim.cameras):
            raise ConfigError(f"cameras.{name}.driver", f"'sim' needs a [sim.cameras.{name}] table "
                                                       "describing the simulated camera")
        if cam.driver != "opencv" and cam.timestamps != "auto":
            raise ConfigError(f"cameras.{name}.timestamps",
                              f"{cam.timestamps!r} is for driver \"opencv\"; a {cam.driver!r} camera's "
                              "frames carry their own (leave it out)")
        if cam.driver in ("opencv", "file") and not cam.source:
            raise ConfigError(f"cameras.{name}.source", f"'' is empty; driver {cam.driver!r} needs a device "
                                                       "index/path or a video file")
    for dev_name in ("robot", "exciter", "rotor", "generator"):
        dev = getattr(cfg.devices, dev_name)
        if dev is None:
            continue
        if parse_address(dev.address)["scheme"] == "mock" and not cfg.station.simulated:
            raise ConfigError(f"devices.{dev_name}.address", f"{dev.address!r} is only allowed when "
                                                             "station.simulated = true")
        if dev_name in ("exciter", "rotor"):
            try:
                dev.resolved_register_map()
            except (ValueError, TypeError) as exc:
                raise ConfigError(f"devices.{dev_name}.registers", str(exc)) from exc
        if dev_name != "robot" and getattr(cfg.limits, dev_name) is None:
            raise ConfigError(f"limits.{dev_name}", f"required when [devices.{dev_name}] is configured")
    if cfg.devices.robot is not None and cfg.limits.robot is None:
        raise ConfigError("limits.robot", "required when [devices.robot] is configured")
    exciter = cfg.devices.exciter
    if exciter is not None:
        if exciter.crank_radius_mm is None:
            raise ConfigError("devices.exciter.crank_radius_mm", "required field missing (a number, mm)")
        if cfg.limits.exciter is None:
            raise ConfigError("limits.exciter", "required when [devices.exciter] is configured")
        limit = cfg.limits.exciter.max_displacement_mm
        if exciter.crank_radius_mm > limit:
            raise ConfigError("devices.exciter.crank_radius_mm",
                              f"{exciter.crank_radius_mm:g} exceeds limits.exciter.max_displacement_mm = "
                              f"{limit:g}")
    if cfg.station.simulated and cfg.sim is None:
        raise ConfigError("sim", "required when station.simulated = true")
    for name in ("exciter", "rotor"):
        dev, lim = getattr(cfg.devices, name), getattr(cfg.limits, name)
        if dev is not None and lim is not None and dev.ramp_rate_hz_per_s > lim.max_ramp_rate_hz_per_s:
            raise ConfigError(f"devices.{name}.ramp_rate_hz_per_s",
                              f"{dev.ramp_rate_hz_per_s:g} exceeds limits.{name}.max_ramp_rate_hz_per_s = "
                              f"{lim.max_ramp_rate_hz_per_s:g}")
        probe_interval_s = cfg.station.heartbeat_timeout_s / 4.0  # idle drives are probed this often
        armed = dev is not None and not dev.address.startswith("mock://")  # (in-process mocks: not armed)
        if armed and dev.comm_timeout_s <= 2.0 * probe_interval_s:
            raise ConfigError(f"devices.{name}.comm_timeout_s",
                              f"{dev.comm_timeout_s:g} s must exceed twice the heartbeat probe interval "
                              f"(station.heartbeat_timeout_s / 4 = {probe_interval_s:g} s), or an idle drive "
                              "would stop itself")
    _check_robot_watchdog(cfg)
    if cfg.devices.robot is not None and cfg.limits.robot is not None \
            and cfg.limits.robot.max_speed_mm_s > cfg.devices.robot.full_speed_mm_s:
        raise ConfigError("limits.robot.max_speed_mm_s", f"{cfg.limits.robot.max_speed_mm_s:g} exceeds "
                          f"devices.robot.full_speed_mm_s = {cfg.devices.robot.full_speed_mm_s:g}")
    if cfg.devices.robot is not None and cfg.limits.robot is not None \
            and cfg.limits.robot.max_accel_mm_s2 > cfg.devices.robot.full_accel_mm_s2:
        raise ConfigError("limits.robot.max_accel_mm_s2", f"{cfg.limits.robot.max_accel_mm_s2:g} exceeds "
                          f"devices.robot.full_accel_mm_s2 = {cfg.devices.robot.full_accel_mm_s2:g} (the "
                          "controller's 100 %): the arm cannot command more")
    if cfg.station.simulated and cfg.station.clock != "virtual":
        raise ConfigError("station.clock", f"{cfg.station.clock!r}: a simulated station runs on the "
                                           "virtual clock; allowed: 'virtual'")
    if cfg.station.clock == "virtual" and not cfg.station.simulated:
        raise ConfigError("station.clock", "'virtual' is only allowed when station.simulated = true")
    _check_distinct_endpoints(cfg)
    _check_configured_poses(cfg)
    _check_fiducial(cfg)


def _check_robot_watchdog(cfg: RigConfig) -> None:
    """``devices.robot.wdt_ms`` against the times that must exceed it: the heartbeat (a blocking move's only
    packets are the keep-alives) and the b-CAP receive time-out (each keep-alive restarts it)."""
    robot = cfg.devices.robot
    if robot is None:
        return
    wdt_s = robot.wdt_ms / 1000.0
    if wdt_s >= cfg.station.heartbeat_timeout_s:
        raise ConfigError("devices.robot.wdt_ms", f"{robot.wdt_ms} ms; allowed: 80 ≤ value < "
                          f"station.heartbeat_timeout_s = {cfg.station.heartbeat_timeout_s * 1000.0:g} ms "
                          "(keep-alives must arrive before the heartbeat counts the controller lost)")
    if 1.5 * wdt_s > robot.timeout_s:
        raise ConfigError("devices.robot.wdt_ms", f"{robot.wdt_ms} ms; allowed: 80 ≤ value ≤ "
                          f"devices.robot.timeout_s / 1.5 = {robot.timeout_s / 1.5 * 1000.0:g} ms (the "
                          "receive time-out must exceed 1.5 × WDT so keep-alives can arrive)")


def _check_fiducial(cfg: RigConfig) -> None:
    """``[fiducial]`` against the cameras, the generator that drives it and, simulated, the twin's LED."""
    fid = cfg.fiducial
    if fid is None:
        if cfg.sim is not None and cfg.sim.fiducial is not None:
            raise ConfigError("sim.fiducial", "a twin LED without [fiducial]: configure [fiducial] (its "
                                              "regions and generator) or remove [sim.fiducial]")
        return
    check_fiducial(fid, cfg.cameras)
    gen = getattr(cfg.devices, fid.device)
    if gen is None:
        raise ConfigError("fiducial.device", f"{fid.device!r} drives the LED but [devices.{fid.device}] is "
                                             "not configured")
    if fid.channel > gen.channels:
        raise ConfigError("fiducial.channel", f"{fid.channel}: devices.{fid.device}.channels = "
                                              f"{gen.channels} (a one-channel generator has no channel "
                                              f"{fid.channel}); allowed: 1..{gen.channels}")
    if cfg.station.simulated and (cfg.sim is None or cfg.sim.fiducial is None):
        raise ConfigError("sim.fiducial", "required when [fiducial] is configured on a simulated station "
                                          "(where the twin's LED is)")


def config_from_dict(table: dict[str, Any], source: str = "<dict>") -> RigConfig:
    """Validate a parsed TOML document and return the frozen :class:`RigConfig`."""
    cfg = build(RigConfig, table, "")
    _cross_check(cfg)
    object.__setattr__(cfg, "source", source)
    return cfg


def parse_config(text: str, source: str = "<string>") -> RigConfig:
    """Parse and validate TOML text."""
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("", f"{source}: not valid TOML ({exc})") from exc
    return config_from_dict(table, source)


def load_config(path: str | Path | None = None) -> RigConfig:
    """Load ``path`` (a ``rig.toml``), or the built-in simulated rig when ``path`` is None."""
    if path is None:
        return default_config()
    path = Path(path)
    if not path.is_file():
        raise ConfigError("", f"configuration file {str(path)!r} not found")
    return parse_config(path.read_text(encoding="utf-8"), str(path))


def default_config() -> RigConfig:
    """The built-in simulated rig (``rig/data/sim.toml``)."""
    text = resources.files("rig").joinpath("data/sim.toml").read_text(encoding="utf-8")
    return parse_config(text, "builtin:sim")


def override(cfg: RigConfig, dotted: str, value: Any) -> RigConfig:
    """Return a copy of ``cfg`` with one dotted field replaced (validated like the file)."""
    table = to_dict(cfg)
    table.pop("source", None)
    node = table
    keys = dotted.split(".")
    for key in keys[:-1]:
        if not isinstance(node.get(key), dict):
            raise ConfigError(dotted, "no such table in the configuration")
        node = node[key]
    node[keys[-1]] = value
    return config_from_dict(_drop_none(table), cfg.source + f" (+{dotted})")


def _drop_none(table: Any) -> Any:
    if isinstance(table, dict):
        return {k: _drop_none(v) for k, v in table.items() if v is not None}
    return table

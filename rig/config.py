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
- ``[cameras.<name>]`` ``driver = "sim" | "opencv" | "file"``, ``fps``, ``resolution_px``, ``source``.
- ``[targets.*]`` marker geometry (mm): calibration plate, single marker, marker frame, sweep column,
  plate, rotor, reference markers.
- ``[limits.robot]`` envelope and speed; ``[limits.exciter|rotor|generator]`` frequency, displacement,
  acceleration (2πf)²·x and ramp-rate limits (as :class:`drivers.exciter.limits.MotionLimits`).
- ``[criteria]`` acceptance thresholds of the certificate and its decision rule.
- ``[analysis]`` ``sync`` method of the analysis (``trajectory`` default; ``linear`` = the paper's).
- ``[sim]`` the twin's hidden truth (only for a simulated station): camera intrinsics, distortion,
  poses, clock errors, rolling-shutter line time, noise, seed.

Addresses: ``tcp://HOST:PORT``, ``serial:///dev/ttyUSB0?baud=115200`` or, on a simulated station,
``mock://tcp`` / ``mock://pty`` (the station starts the mock server and substitutes its real address).
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from rig.config_geometry import SimConfig, TargetsConfig
from rig.config_schema import ConfigError, build, spec, to_dict

__all__ = ["BAUD_RATES", "ConfigError", "RigConfig", "default_config", "endpoint", "load_config",
           "parse_address", "parse_config"]

BAUD_RATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)


def parse_address(address: str, path: str = "address") -> dict[str, Any]:
    """Split a device address into ``{"scheme", "host", "port"}`` / ``{"scheme", "device", "baud"}`` /
    ``{"scheme": "mock", "link": "tcp"|"pty"}``; raise ConfigError naming ``path`` when malformed."""
    from urllib.parse import parse_qs, urlsplit

    allowed = "tcp://HOST:PORT, serial:///dev/DEVICE?baud=N, mock://tcp or mock://pty"
    parts = urlsplit(address)
    if parts.scheme == "tcp":
        try:
            port = parts.port
        except ValueError:
            port = None
        if not parts.hostname or port is None or not 1 <= port <= 65535:
            raise ConfigError(path, f"{address!r} needs a host and a port 1-65535; allowed: {allowed}")
        return {"scheme": "tcp", "host": parts.hostname, "port": port}
    if parts.scheme == "serial":
        device = parts.netloc + parts.path
        if not device:
            raise ConfigError(path, f"{address!r} names no serial device; allowed: {allowed}")
        query = parse_qs(parts.query)
        unknown = sorted(set(query) - {"baud", "parity", "stopbits", "bytesize"})
        if unknown:
            raise ConfigError(path, f"{address!r}: unknown option {unknown[0]!r}; allowed: baud, parity, "
                                    "stopbits, bytesize")
        baud = query.get("baud", ["38400"])[-1]
        if not baud.isdigit() or int(baud) not in BAUD_RATES:
            raise ConfigError(path, f"{address!r}: baud {baud!r} not allowed; allowed: "
                                    f"{', '.join(map(str, BAUD_RATES))}")
        return {"scheme": "serial", "device": device, "baud": int(baud)}
    if parts.scheme == "mock":
        if parts.netloc not in ("tcp", "pty") or parts.path:
            raise ConfigError(path, f"{address!r} not allowed; allowed: mock://tcp or mock://pty")
        return {"scheme": "mock", "link": parts.netloc}
    raise ConfigError(path, f"{address!r} has an unknown scheme; allowed: {allowed}")


def _address(value: str, path: str) -> None:
    parse_address(value, path)


BUILTIN_REGISTER_MAPS = ("delta",)


def _register_map(value: str, path: str) -> None:
    if value in BUILTIN_REGISTER_MAPS:
        return
    if not Path(value).is_file():
        raise ConfigError(path, f"{value!r} is neither a built-in register map nor a TOML file; allowed: "
                                f"{', '.join(BUILTIN_REGISTER_MAPS)} or the path of a register-map TOML file")


@dataclass(frozen=True)
class StationConfig:
    name: str = field(metadata=spec(doc="Free text naming the bench."))
    simulated: bool = False
    runs_dir: str = "runs"
    clock: str = field(default="wall", metadata=spec(choices=("wall", "virtual")))
    heartbeat_timeout_s: float = field(default=2.0, metadata=spec(lo=0.5, hi=60.0, doc=(
        "Wall seconds without any reply from a device (b-CAP keep-alives count) before the watchdog trips "
        "the interlock (exit 3); an idle device is probed after a quarter of it. Above the b-CAP WDT "
        "(0.4 s).")))


@dataclass(frozen=True)
class RobotConfig:
    driver: str = field(metadata=spec(choices=("denso-bcap",)))
    address: str = field(metadata=spec(check=_address))
    controller: str = field(default="rc8", metadata=spec(choices=("rc8", "rc7m")))
    timeout_s: float = field(default=3.0, metadata=spec(lo=0.05, hi=120.0))
    home_pose: tuple[float, ...] | None = field(default=None, metadata=spec(length=6))
    full_speed_mm_s: float = field(default=1000.0, metadata=spec(lo=1.0, hi=10000.0))
    position_tolerance_mm: float = field(default=0.5, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    wait_mode: str | None = field(default=None, metadata=spec(choices=("next", "blocking"), doc="move end: "
                                  "NEXT + @BUSY_STATUS polls, halt works mid-move (rc8) or blocking (rc7m)"))
    busy_poll_interval_s: float = field(default=0.05, metadata=spec(lo=0.0, lo_open=True, hi=5.0))


@dataclass(frozen=True)
class VfdConfig:
    driver: str = field(metadata=spec(choices=("modbus-vfd",)))
    address: str = field(metadata=spec(check=_address))
    unit_id: int = field(default=1, metadata=spec(lo=1, hi=247))
    register_map: str = field(default="delta", metadata=spec(check=_register_map))
    registers: dict[str, Any] | None = None
    gear_ratio: float = field(default=1.0, metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    crank_radius_mm: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True, hi=500.0))
    timeout_s: float = field(default=1.0, metadata=spec(lo=0.05, hi=60.0))
    max_output_hz: float = field(default=50.0, metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    ramp_rate_hz_per_s: float = field(default=1.0, metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    comm_timeout_s: float = field(default=2.0, metadata=spec(lo=0.1, hi=100.0, doc=(
        "the drive's own communication-loss stop (Delta 09-03): no valid request for this long → it faults "
        "and ramps to a stop by itself, so a controller killed without cleanup (SIGKILL, power loss) "
        "leaves the motor stopped within comm_timeout_s + frequency / deceleration rate; armed when the "
        "station connects (not on mock:// drives), disarmed on a clean close. Must exceed twice the "
        "heartbeat probe interval (station.heartbeat_timeout_s / 4)")))

    def resolved_register_map(self) -> Any:
        """The :class:`drivers.exciter.register_map.RegisterMap`: the named map, overridden by ``registers``
        and with ``unit_id``."""
        from drivers.exciter.register_map import DELTA_MAP, load_register_map, register_map_from_dict

        builtin = self.register_map in BUILTIN_REGISTER_MAPS
        base = DELTA_MAP if builtin else load_register_map(self.register_map)
        regs = register_map_from_dict(dict(self.registers), base) if self.registers else base
        return dataclasses.replace(regs, unit_id=self.unit_id)


@dataclass(frozen=True)
class GeneratorConfig:
    driver: str = field(metadata=spec(choices=("scpi-generator",)))
    address: str = field(metadata=spec(check=_address))
    channel: int = field(default=1, metadata=spec(lo=1, hi=2))
    sensitivity_mm_per_v: tuple[tuple[float, ...], ...] = field(
        default=((1.0, 1.0), (100.0, 1.0)), metadata=spec(length=(1, 1000), lo=0.0, hi=1e6))
    max_amplitude_vpp: float = field(default=10.0, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    amplitude_step_vpp: float = field(default=0.5, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    step_interval_s: float = field(default=0.1, metadata=spec(lo=0.0, lo_open=True, hi=60.0))
    timeout_s: float = field(default=2.0, metadata=spec(lo=0.05, hi=60.0))

    def __post_init__(self) -> None:
        from drivers.exciter.shaker import SensitivityTable

        try:
            SensitivityTable(self.sensitivity_mm_per_v)
        except ValueError as exc:
            raise ConfigError("devices.generator.sensitivity_mm_per_v", str(exc)) from exc


@dataclass(frozen=True)
class DevicesConfig:
    robot: RobotConfig | None = None
    exciter: VfdConfig | None = None
    rotor: VfdConfig | None = None
    generator: GeneratorConfig | None = None


@dataclass(frozen=True)
class CameraConfig:
    driver: str = field(metadata=spec(choices=("sim", "opencv", "file")))
    fps: float = field(default=60.0, metadata=spec(lo=1.0, hi=1000.0))
    resolution_px: tuple[int, ...] = field(default=(1920, 1080), metadata=spec(length=2, lo=16, hi=16384))
    exposure_s: float = field(default=1 / 6000, metadata=spec(lo=0.0, lo_open=True, hi=1.0))
    source: str = ""


@dataclass(frozen=True)
class RobotLimits:
    envelope_x_mm: tuple[float, ...] = field(metadata=spec(length=2))
    envelope_y_mm: tuple[float, ...] = field(metadata=spec(length=2))
    envelope_z_mm: tuple[float, ...] = field(metadata=spec(length=2))
    max_speed_mm_s: float = field(metadata=spec(lo=0.0, lo_open=True, hi=5000.0))
    max_accel_mm_s2: float = field(default=2000.0, metadata=spec(lo=0.0, lo_open=True, hi=50000.0))

    def __post_init__(self) -> None:
        for axis in "xyz":
            lo, hi = getattr(self, f"envelope_{axis}_mm")
            if not lo < hi:
                raise ConfigError(f"limits.robot.envelope_{axis}_mm",
                                  f"[{lo:g}, {hi:g}]: allowed: [min, max] with min < max")

    def envelope(self) -> Any:
        """The arm driver's :class:`drivers.denso.arm.BoxEnvelope` of these limits."""
        from drivers.denso.arm import BoxEnvelope

        return BoxEnvelope(self.envelope_x_mm, self.envelope_y_mm, self.envelope_z_mm)


@dataclass(frozen=True)
class VibrationLimits:
    max_frequency_hz: float = field(metadata=spec(lo=0.0, lo_open=True, hi=2000.0))
    max_displacement_mm: float = field(metadata=spec(lo=0.0, lo_open=True, hi=500.0))
    max_acceleration_m_s2: float = field(metadata=spec(lo=0.0, lo_open=True, hi=10000.0))
    max_ramp_rate_hz_per_s: float = field(metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    max_velocity_mm_s: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True))

    def motion_limits(self) -> Any:
        """These limits as the drivers' :class:`drivers.exciter.limits.MotionLimits`."""
        from drivers.exciter.limits import MotionLimits

        return MotionLimits(**to_dict(self))


@dataclass(frozen=True)
class LimitsConfig:
    robot: RobotLimits | None = None
    exciter: VibrationLimits | None = None
    rotor: VibrationLimits | None = None
    generator: VibrationLimits | None = None


_POSITIVE = spec(lo=0.0, lo_open=True)


@dataclass(frozen=True)
class CriteriaConfig:
    """Acceptance thresholds of the certificate (each a maximum unless named ``min_``)."""

    calibration_rms_px: float = field(default=0.5, metadata=_POSITIVE)
    position_rms_mm: float = field(default=0.5, metadata=_POSITIVE)
    position_max_mm: float = field(default=1.5, metadata=_POSITIVE)
    repeatability_mm: float = field(default=0.5, metadata=_POSITIVE)
    amplitude_error_pct: float = field(default=5.0, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    amplitude_error_up_to_hz: float = field(default=10.0, metadata=_POSITIVE)
    min_usable_frequency_hz: float = field(default=10.0, metadata=_POSITIVE)
    sync_uncertainty_ms: float = field(default=1.0, metadata=_POSITIVE)
    frequency_error_pct: float = field(default=1.0, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    radius_error_mm: float = field(default=0.5, metadata=_POSITIVE)
    detection_pct: float = field(default=100.0, metadata=spec(lo=0.0, hi=100.0))
    length_error_mm: float = field(default=1.0, metadata=_POSITIVE)
    # settings of the decision (reports/certificate.py)
    decision_rule: str = field(default="guarded", metadata=spec(choices=("guarded", "simple")))
    reference_u_mm: float = field(default=0.02, metadata=spec(lo=0.0, hi=100.0))
    fit_max_hz: float | None = field(default=None, metadata=_POSITIVE)
    frequency_bin_hz: float = field(default=1.0, metadata=_POSITIVE)
    identification_gate_mm: float = field(default=50.0, metadata=_POSITIVE)


@dataclass(frozen=True)
class AnalysisConfig:
    """How observations become tracks (``rig.analysis``): the synchronization method (``linear`` is the
    paper's interpolation of camera B to camera A's instants; the others are ours)."""

    sync: str = field(default="trajectory", metadata=spec(choices=("trajectory", "bandlimited", "cubic",
                                                                    "linear")))


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
    sim: SimConfig | None = None
    source: str = field(default="", init=False, compare=False)

    def snapshot(self) -> dict[str, Any]:
        """Plain-dict copy of the whole configuration (for the start document; round-trips via TOML)."""
        out = to_dict(self)
        out.pop("source", None)
        return {"source": self.source, **out}

    def camera_names(self) -> list[str]:
        return list(self.cameras)


DEVICE_NAMES = ("robot", "exciter", "rotor", "generator")


def endpoint(address: str) -> tuple[str, ...] | None:
    """Where an address leads, normalised so that two spellings of one endpoint compare equal:
    ``("tcp", host, port)`` (``localhost`` and ``::1`` → ``127.0.0.1``, IP addresses in canonical form, names
    lower-cased), ``("serial", device)`` (symbolic links resolved: ``/dev/serial/by-id/…`` is the tty it
    names); None for a ``mock://`` address (the station starts one server per device)."""
    import ipaddress
    import os

    parts = parse_address(address)
    if parts["scheme"] == "serial":
        return ("serial", os.path.realpath(parts["device"]))
    if parts["scheme"] != "tcp":
        return None
    host = parts["host"].lower().rstrip(".")
    try:
        ip = ipaddress.ip_address(host)
        host = "127.0.0.1" if ip.is_loopback and (ip.version == 6 or host == "127.0.0.1") else ip.compressed
    except ValueError:
        host = "127.0.0.1" if host == "localhost" else host
    return ("tcp", host, str(parts["port"]))


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
    exc = cfg.devices.exciter
    if exc is not None:
        if exc.crank_radius_mm is None:
            raise ConfigError("devices.exciter.crank_radius_mm", "required field missing (a number, mm)")
        limit = cfg.limits.exciter.max_displacement_mm  # type: ignore[union-attr]
        if exc.crank_radius_mm > limit:
            raise ConfigError("devices.exciter.crank_radius_mm",
                              f"{exc.crank_radius_mm:g} exceeds limits.exciter.max_displacement_mm = "
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
    if cfg.devices.robot is not None and cfg.limits.robot is not None \
            and cfg.limits.robot.max_speed_mm_s > cfg.devices.robot.full_speed_mm_s:
        raise ConfigError("limits.robot.max_speed_mm_s", f"{cfg.limits.robot.max_speed_mm_s:g} exceeds "
                          f"devices.robot.full_speed_mm_s = {cfg.devices.robot.full_speed_mm_s:g}")
    if cfg.station.simulated and cfg.station.clock != "virtual":
        raise ConfigError("station.clock", f"{cfg.station.clock!r}: a simulated station runs on the "
                                           "virtual clock; allowed: 'virtual'")
    if cfg.station.clock == "virtual" and not cfg.station.simulated:
        raise ConfigError("station.clock", "'virtual' is only allowed when station.simulated = true")
    _check_distinct_endpoints(cfg)
    _check_configured_poses(cfg)


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


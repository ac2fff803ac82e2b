"""The station: builds the rig's devices from a :class:`rig.config.rig_config.RigConfig` and always tears
them down.

``with open_station(config, clock) as station:`` yields a :class:`Station` with

- ``devices``: name → driver object for everything that moves (``robot`` → :class:`DensoArm`,
  ``exciter`` → :class:`Exciter`, ``rotor`` → :class:`Rotor`, ``generator`` → :class:`Shaker` (SCPI
  generator + amplifier + shaker));
- ``cameras``: name → camera device (``FrameSource``: ``start()``, ``stop()``, ``frames()``);
- ``roles``: name → the :class:`drivers.roles.Role` the station declares for each device and camera
  (arm, vibration source, generator, camera); ``roster()`` lists them for the runner, which makes each
  safe in the order of its role (:data:`drivers.roles.SHUTDOWN_ORDER`) — names decide nothing;
- ``world``: the twin (:class:`drivers.sim.world.World`) on a simulated station, else None — procedures
  must not use it for truth (truth is what they command, from the configuration); it exists for scene
  changes a human would do on a real bench (mounting a target: ``station.mount(scene)``);
- ``snapshot()`` for the run record and ``check_interlocks()`` for the runner's watchdog (which also
  calls each device's ``heartbeat()``; ``station.heartbeat_timeout_s`` reaches every driver).

The simulated rig is not a special code path for the drivers: for each device whose address is
``mock://tcp`` or ``mock://pty`` the station starts the protocol-true mock server (b-CAP controller,
Modbus VFD, SCPI generator) on 127.0.0.1 or a pty, bound to one twin world, substitutes the server's
real address, and connects **the same driver over the same transport** as on a real bench. Everything
started is shut down on exit, in reverse order, each step attempted even if another fails.

``check_interlocks()`` is cheap and thread-safe (no device I/O; the drivers are not thread-safe): it
reports a device whose transport was closed by a failure, a mock server whose thread died, an arm whose
last reported pose lies outside the envelope, and an exciter/rotor whose setpoint breaks its limits.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.clock import Clock
from drivers.roles import Assignment, Camera, Device, Role
from rig.config.address import endpoint, parse_address
from rig.config.devices import GeneratorConfig, RobotConfig, VfdConfig
from rig.config.limits import VibrationLimits
from rig.config.rig_config import RigConfig
from rig.config.schema import ConfigError, to_dict

if TYPE_CHECKING:
    from drivers.exciter.axis import VfdAxis
    from drivers.exciter.vfd import VfdDriver
    from drivers.mock.bcap_server import BcapMockServer
    from drivers.mock.generator_instrument import GeneratorInstrument
    from drivers.mock.vfd_drive import DriveModel
    from drivers.modbus_link import ModbusLink
    from drivers.sim.bodies import OscillatorBody
    from drivers.sim.stereo_rig import CameraSpec
    from drivers.sim.world import World, WorldLayout

__all__ = ["Station", "StationError", "add_fiducial_led", "camera_specs", "mock_drive", "mock_generator",
           "mock_robot_server", "mount_in_lab", "open_station", "world_layout"]

log = logging.getLogger("rig.run.station")
SCENE_OF_TARGET = {"calibration_plate": "calibration_plate", "single_marker": "single_marker",
                   "marker_frame": "marker_frame", "plate": "plate", "rotor": "rotor",
                   "sweep_column": "sweep_column", "band_column": "band_column", "none": "none"}


class StationError(RuntimeError):
    """A device could not be built or reached; the message names it and its address."""


@dataclass
class Station:
    """The built devices (see the module docstring); built by :func:`open_station`."""

    config: RigConfig
    clock: Clock
    world: World | None = None
    devices: dict[str, Device] = field(default_factory=dict)
    cameras: dict[str, Camera] = field(default_factory=dict)
    roles: dict[str, Role] = field(default_factory=dict)  # device or camera → its declared role
    addresses: dict[str, str] = field(default_factory=dict)  # device → address actually connected
    unreachable: dict[str, str] = field(default_factory=dict)  # device → why (``keep_going`` only)
    _closers: list[tuple[str, Callable[[], None]]] = field(default_factory=list, repr=False)
    # one Modbus master per serial port / TCP endpoint: drives on one RS-485 line share it
    _modbus_links: dict[tuple[str, ...], ModbusLink] = field(default_factory=dict, repr=False)
    _liveness: list[tuple[str, Callable[[], str | None]]] = field(default_factory=list, repr=False)

    @property
    def simulated(self) -> bool:
        """True on the twin (a world is attached), False on a real bench."""
        return self.world is not None

    def add(self, name: str, role: Role, device: Device, address: str | None = None) -> None:
        """Declare a built device (not a camera: :meth:`add_camera`) with its role and address."""
        if role is Role.CAMERA:
            raise ValueError(f"{name}: cameras are added with add_camera()")
        self.devices[name] = device
        self.roles[name] = role
        if address is not None:
            self.addresses[name] = address

    def add_camera(self, name: str, camera: Camera) -> None:
        """Declare a built camera (role :attr:`Role.CAMERA`)."""
        self.cameras[name] = camera
        self.roles[name] = Role.CAMERA

    def roster(self) -> list[Assignment]:
        """Every device and camera with its declared role (what the runner makes safe, in build order)."""
        built = {**self.devices, **self.cameras}
        return [Assignment(name, role, built[name]) for name, role in self.roles.items()]

    def snapshot(self) -> dict[str, Any]:
        """Addresses, roles and each driver's own configuration snapshot."""
        return {"simulated": self.world is not None, "addresses": dict(self.addresses),
                "roles": {name: role.value for name, role in self.roles.items()},
                "devices": {name: dev.snapshot() for name, dev in self.devices.items()},
                "cameras": sorted(self.cameras)}

    def check_interlocks(self) -> list[tuple[str, str]]:
        """Devices found lost without any I/O (see the module docstring)."""
        trips = []
        for name, probe in self._liveness:
            reason = probe()
            if reason:
                trips.append((name, reason))
        return trips

    def mount(self, scene: str) -> None:
        """Mount a target (``calibration_plate``, ``single_marker``, ``marker_frame``, ``plate``, ``rotor``,
        ``sweep_column``, ``none``). On the twin this switches the scene at the current time; a real bench
        has an operator do it (the procedure asks and waits), so this raises there."""
        if self.world is None:
            raise StationError(f"mount {scene!r}: a real bench needs the operator to mount the target")
        self.world.set_scene(SCENE_OF_TARGET[scene])
        lab_url = self.config.sim.lab_url if self.config.sim is not None else None
        if lab_url is not None:  # the cameras film `rig mock lab`'s world: mount it there
            mount_in_lab(lab_url, SCENE_OF_TARGET[scene])

    def close(self) -> None:
        while self._closers:
            name, closer = self._closers.pop()
            try:
                closer()
            except Exception as exc:
                log.error("closing %s failed: %s", name, exc)


def mount_in_lab(lab_url: str, scene: str, timeout_s: float = 10.0) -> None:
    """Mount ``scene`` in the world of the ``rig mock lab`` at ``lab_url`` (``POST <lab_url>/mount/<scene>``);
    :class:`StationError` naming the lab when it does not confirm."""
    import urllib.error
    import urllib.request

    request = urllib.request.Request(f"{lab_url}/mount/{scene}", data=b"", method="POST")
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as reply:
            reply.read()
    except (urllib.error.URLError, OSError) as exc:
        raise StationError(f"mount {scene!r}: the lab at sim.lab_url = {lab_url!r} did not mount it: "
                           f"{exc}") from exc


# ------------------------------------------------------------------------------------------- twin
def _tuples(value: Any) -> Any:
    """Lists (from a config snapshot) back to tuples, recursively, as the twin's dataclasses hold them."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def add_fiducial_led(world: World, config: RigConfig) -> None:
    """The twin's timing fiducial LED (``[sim.fiducial]``), lit by the generator mock's sync output."""
    sim = config.sim.fiducial if config.sim is not None else None
    if config.fiducial is None or sim is None:
        return
    from drivers.sim.fiducial import SyncLed

    world.add_led(SyncLed("fiducial", sim.centre_mm, sim.half_u_mm, sim.half_v_mm,
                          time_constant_s=sim.time_constant_s, contrast_dn=sim.contrast_dn))


def world_layout(config: RigConfig) -> WorldLayout:
    """The twin's :class:`WorldLayout` described by ``config`` (targets, home pose, crank radius)."""
    from drivers.sim import targets as sim_targets
    from drivers.sim.world import WorldLayout

    tg = config.targets
    twin: dict[str, tuple[Any, type]] = {  # TargetSet field: ([targets.<field>], the twin's body)
        "calibration_plate": (tg.calibration_plate, sim_targets.CalibrationPlate),
        "single_marker": (tg.single_marker, sim_targets.SingleMarker),
        "marker_frame": (tg.marker_frame, sim_targets.MarkerFrame),
        "sweep_column": (tg.sweep_column, sim_targets.SweepColumn),
        "plate": (tg.plate, sim_targets.OscillatingPlate), "rotor": (tg.rotor, sim_targets.RotorTarget),
        "references": (tg.references, sim_targets.ReferenceMarkers)}
    procedure_only = ("start_pose", "slide_positions_mm")
    kwargs = {name: cls(**{k: _tuples(v) for k, v in to_dict(cfg).items() if k not in procedure_only})
              for name, (cfg, cls) in twin.items() if cfg is not None}
    layout: dict[str, Any] = {"targets": sim_targets.TargetSet(**kwargs)}
    if config.devices.robot is not None and config.devices.robot.home_pose is not None:
        layout["robot_home_pose"] = tuple(config.devices.robot.home_pose)
    if config.devices.exciter is not None and config.devices.exciter.crank_radius_mm is not None:
        layout["crank_radius_mm"] = config.devices.exciter.crank_radius_mm
    if config.sim is not None:
        layout.update(robot_rot_speed_deg_s=config.sim.robot_rot_speed_deg_s,
                      robot_rot_accel_deg_s2=config.sim.robot_rot_accel_deg_s2,
                      initial_scene=config.sim.initial_scene)
    return WorldLayout(**layout)


def camera_specs(config: RigConfig) -> list[CameraSpec]:
    """The twin's :class:`CameraSpec` of every ``sim`` camera of ``config``."""
    from drivers.sim.render import NoiseModel
    from drivers.sim.stereo_rig import CameraSpec

    specs = []
    for name, cam in config.cameras.items():
        if cam.driver != "sim":
            continue
        assert config.sim is not None, "the configuration's cross-check gives every sim camera [sim.cameras]"
        sc = config.sim.cameras[name]
        values = to_dict(sc)
        noise = NoiseModel(**values.pop("noise"))
        values = {k: _tuples(v) for k, v in values.items()}
        specs.append(CameraSpec(name=name, fps=cam.fps, exposure_s=cam.exposure_s, noise=noise, **values))
    return specs


# ------------------------------------------------------------------------------------------- mock devices
# The twin's devices as configured: what the station serves for ``mock://`` addresses and ``rig mock lab``
# (rig.run.lab) serves on its own endpoints, built the same way.
def mock_robot_server(rc: RobotConfig, world: World, *, client_watchdog: bool = False) -> BcapMockServer:
    """The b-CAP controller mock moving ``world``'s arm with the configured full speed and acceleration;
    ``client_watchdog``: end a session silent for 4 × its WDT (a controller in another process)."""
    from drivers.mock.bcap_server import BcapMockServer

    return BcapMockServer(world.robot, world.clock, full_speed_mm_s=rc.full_speed_mm_s,
                          full_accel_mm_s2=rc.full_accel_mm_s2, client_watchdog=client_watchdog)


def mock_drive(dc: VfdConfig, body: OscillatorBody, clock: Clock) -> DriveModel:
    """The VFD model driving ``body`` with the configured register map, gear ratio and output limit."""
    from drivers.mock.vfd_drive import DriveModel

    return DriveModel(body, clock, register_map=dc.resolved_register_map(), gear_ratio=dc.gear_ratio,
                      max_output_hz=dc.max_output_hz)


def mock_generator(gc: GeneratorConfig, world: World) -> GeneratorInstrument:
    """The SCPI generator instrument driving ``world``'s shaker (and its first LED from the Sync output)
    with the configured channels and shaker sensitivity."""
    from drivers.mock.generator_instrument import GeneratorInstrument, identity_for

    leds = world.leds
    return GeneratorInstrument(world.shaker, world.clock,
                               sensitivity_mm_per_v=[(p[0], p[1]) for p in gc.sensitivity_mm_per_v],
                               identity=identity_for(gc.channels), sync_led=leds[0] if leds else None)


# ------------------------------------------------------------------------------------------- builders
def _build_robot(st: Station, cfg: RigConfig) -> None:
    from drivers.denso.arm import DensoArm
    from drivers.denso.client import BcapClient
    from drivers.denso.motion import WaitSettings
    from drivers.transport import open_transport

    rc, lim = cfg.devices.robot, cfg.limits.robot
    assert rc is not None and lim is not None
    addr = parse_address(rc.address, "devices.robot.address")
    world = st.world
    serial_line = addr["scheme"] == "serial" or addr.get("link") == "pty"
    url = rc.address
    if addr["scheme"] == "mock":
        assert world is not None, "a mock:// address needs the simulated station (configuration check)"
        server = mock_robot_server(rc, world)
        st._closers.append(("robot mock server", server.close))
        if addr["link"] == "tcp":
            url = f"tcp://127.0.0.1:{server.serve_tcp('127.0.0.1', 0)}"
        else:
            url = f"serial://{server.serve_pty()}?baud=115200"
    transport = open_transport(url, timeout_s=rc.timeout_s)
    client = BcapClient(transport, serial_line=serial_line, timeout_s=rc.timeout_s,
                        rc7m=rc.controller == "rc7m",
                        reopen=lambda: open_transport(url, timeout_s=rc.timeout_s))  # same line settings
    # the link's transport, not the first one: a make-safe may have reconnected
    st._closers.append(("robot transport", lambda: client.link.transport.close()))  # noqa: PLW0108
    wait_mode = rc.wait_mode or ("blocking" if rc.controller == "rc7m" else "next")
    arm = DensoArm(client, envelope=lim.envelope(),
                   max_speed_mm_s=lim.max_speed_mm_s, position_tolerance_mm=rc.position_tolerance_mm,
                   clock=st.clock, full_speed_mm_s=rc.full_speed_mm_s,
                   max_accel_mm_s2=lim.max_accel_mm_s2, full_accel_mm_s2=rc.full_accel_mm_s2,
                   heartbeat_timeout_s=cfg.station.heartbeat_timeout_s,
                   wait=WaitSettings(wait_mode=wait_mode, poll_interval_s=rc.busy_poll_interval_s))
    arm.open(wdt_ms=rc.wdt_ms)
    st._closers.append(("robot session", arm.close))
    st.add("robot", Role.ARM, arm, url)

    def reported_pose_in_envelope() -> str | None:
        last = arm.last_move
        if last is None:
            return None
        try:
            arm.envelope.check(np.asarray(last.reported_pose, dtype=float))
        except ValueError as exc:
            return f"reported pose {list(last.reported_pose)} outside the envelope: {exc}"
        return None

    st._liveness.append(("robot", reported_pose_in_envelope))
    st._liveness.append(("robot", lambda: "b-CAP link closed" if client.link.transport.closed else None))


def _build_vfd(st: Station, cfg: RigConfig, name: str, *, dc: VfdConfig | None, lim: VibrationLimits | None,
               body: OscillatorBody | None) -> None:
    """Build the VFD axis ``name`` (``exciter`` or ``rotor``) from its device and limits sections; ``body``
    is the twin's body it drives (None on a real bench)."""
    from drivers.exciter.exciter import Exciter
    from drivers.exciter.rotor import Rotor
    from drivers.exciter.vfd import VfdDriver

    assert dc is not None and lim is not None, "the configuration check pairs devices and limits"
    regs = dc.resolved_register_map()
    addr = parse_address(dc.address, f"devices.{name}.address")
    url = dc.address
    mock = addr["scheme"] == "mock"
    if mock:
        from drivers.mock.vfd_server import VfdServer

        assert body is not None, "a mock:// address needs the simulated station (configuration check)"
        server = VfdServer(mock_drive(dc, body, st.clock),
                           mode="tcp" if addr["link"] == "tcp" else "rtu").start()
        st._closers.append((f"{name} mock server", server.stop))
        url = server.url if addr["link"] == "tcp" else f"serial://{server.client_port}?baud=115200"
        st._liveness.append((name, lambda: None if server.serving else "mock server died"))
    client = _modbus_link(st, name, url, dc.timeout_s)
    vfd = VfdDriver(client, regs, max_output_hz=dc.max_output_hz)
    if not mock:
        _arm_comm_timeout(st, name, vfd, dc.comm_timeout_s)
    common = {"clock": st.clock, "limits": lim.motion_limits(), "gear_ratio": dc.gear_ratio,
              "ramp_rate_hz_per_s": dc.ramp_rate_hz_per_s,
              "heartbeat_timeout_s": cfg.station.heartbeat_timeout_s}
    axis: VfdAxis
    if name == "exciter":
        assert dc.crank_radius_mm is not None, "the configuration check requires the exciter's crank radius"
        axis = Exciter(vfd, crank_radius_mm=dc.crank_radius_mm, **common)
    else:
        radius = cfg.targets.rotor.radius_mm if cfg.targets.rotor is not None else 0.0
        axis = Rotor(vfd, marker_radius_mm=radius, **common)
    st._closers.append((f"{name} stop", axis.close))
    st.add(name, Role.VIBRATION_SOURCE, axis, url)

    def setpoint_within_limits() -> str | None:
        try:
            axis.limits.check_point(axis.setpoint_hz, axis.amplitude_mm, f"{name} setpoint")
        except ValueError as exc:
            return str(exc)
        return None

    st._liveness.append((name, setpoint_within_limits))


def _modbus_link(st: Station, name: str, url: str, timeout_s: float) -> ModbusLink:
    """The Modbus master of ``url``: the one already open when another drive uses the same serial port or
    TCP endpoint (an RS-485 line with the exciter and the rotor as units 1 and 2; the configuration refuses
    one unit twice), else a new one. One owner of the port: its lock serialises every request of the
    drives on it (their heartbeats share it too, ``VfdDriver.contact``); it is closed once, after every
    drive on it was stopped (closers run in reverse order and it was registered by its first drive)."""
    from drivers.modbus_link import ModbusLink
    from drivers.transport import TransportError

    key = endpoint(url)
    shared = st._modbus_links.get(key) if key is not None else None
    if shared is not None:
        if shared.timeout_s != timeout_s:
            log.warning("%s shares %s with a drive configured with timeout_s = %g s: the line keeps that "
                        "time-out (devices.%s.timeout_s = %g s is not used)", name, url, shared.timeout_s,
                        name, timeout_s)
        log.info("%s: unit on the Modbus line %s already open (one master per port)", name, url)
        return shared
    try:
        link = ModbusLink(url, timeout_s=timeout_s, retries=1)
    except (TransportError, ValueError) as exc:
        raise StationError(f"{name}: cannot connect to the drive at {url}: {exc}") from exc
    if key is not None:
        st._modbus_links[key] = link
    st._closers.append((f"Modbus line {url}", link.close))
    return link


def _arm_comm_timeout(st: Station, name: str, vfd: VfdDriver, timeout_s: float) -> None:
    """Arm the drive's own communication-loss stop (``devices.<name>.comm_timeout_s``) and disarm it on a
    clean close (after the stop). Not done for ``mock://`` drives: they run in this process on its
    virtual clock and die with it. (The configuration checked the time-out against the heartbeat probes.)"""
    if not vfd.map.has_comm_timeout:
        log.warning("%s: register map %r has no communication time-out registers: after a SIGKILL or a "
                    "power loss the drive keeps running (set its time-out on the keypad)", name,
                    vfd.map.model)
        return
    vfd.set_comm_timeout_s(timeout_s)
    st._closers.append((f"{name} communication time-out off", lambda: vfd.set_comm_timeout_s(None)))


def _build_generator(st: Station, cfg: RigConfig) -> None:
    from drivers.exciter.generator import KNOWN_CHANNELS, ScpiGenerator
    from drivers.exciter.shaker import SensitivityTable, Shaker
    from drivers.transport import Transport, open_transport

    gc, lim = cfg.devices.generator, cfg.limits.generator
    assert gc is not None and lim is not None
    addr = parse_address(gc.address, "devices.generator.address")
    url = gc.address
    if addr["scheme"] == "mock":
        from drivers.mock.generator_server import GeneratorServer

        assert st.world is not None, "a mock:// address needs the simulated station (configuration check)"
        server = GeneratorServer(mock_generator(gc, st.world), mode=addr["link"]).start()
        st._closers.append(("generator mock server", server.stop))
        url = server.url if addr["link"] == "tcp" else f"serial://{server.client_port}?baud=115200"
    def reopen() -> Transport:
        return open_transport(url, timeout_s=gc.timeout_s)

    generator = ScpiGenerator(reopen(), channel=gc.channel, timeout_s=gc.timeout_s, reopen=reopen)
    st._closers.append(("generator transport", generator.close))
    identity = generator.identify()
    known = KNOWN_CHANNELS.get(identity.model.upper())
    if known is not None and known < gc.channels:
        raise StationError(f"generator: devices.generator.channels = {gc.channels} but the instrument at "
                           f"{url} is a {identity.model} with {known} channel(s)")
    shaker = Shaker(generator, clock=st.clock, limits=lim.motion_limits(),
                    sensitivity=SensitivityTable(gc.sensitivity_mm_per_v),
                    max_amplitude_vpp=gc.max_amplitude_vpp,
                    amplitude_step_vpp=gc.amplitude_step_vpp, step_interval_s=gc.step_interval_s,
                    heartbeat_timeout_s=cfg.station.heartbeat_timeout_s)
    st._closers.append(("generator output off", shaker.close))
    st.add("generator", Role.GENERATOR, shaker, url)
    st._liveness.append(("generator", lambda: "SCPI link closed" if generator.transport.closed else None))


def _build_cameras(st: Station, cfg: RigConfig) -> None:
    kept = []  # stream-stamped cameras: connected now, settled before the first recording
    for name, cam in cfg.cameras.items():
        if cam.driver == "opencv":
            from drivers.camera.opencv_device import OpenCVCamera

            width, height = cam.resolution_px
            live = OpenCVCamera(name, cam.source, fps=cam.fps, width_px=width, height_px=height,
                                timestamps=cam.timestamps)
            st._closers.append((f"camera {name}", live.close))  # a stream-stamped connection is kept
            live.connect()  # a stream-stamped camera streams (its clock runs) before the first recording
            kept.append(live)
            st.add_camera(name, live)
        elif cam.driver == "file":
            from drivers.camera.video_file import VideoFile, VideoFileError

            try:
                st.add_camera(name, VideoFile(cam.source, name=name, fps=cam.fps))
            except VideoFileError as exc:
                raise StationError(f"cameras.{name}.source: {exc}") from exc
    for live in kept:  # all connected at once; each clock mapped before a recording starts on it
        live.wait_settled()
    if st.world is None:
        return
    from drivers.sim.source import SimFrameSource
    from drivers.sim.stereo_rig import make_camera

    for spec in camera_specs(cfg):
        width, height = cfg.cameras[spec.name].resolution_px
        st.add_camera(spec.name, SimFrameSource(make_camera(spec, st.world, width_px=width,
                                                            height_px=height)))


def _builders(st: Station, cfg: RigConfig) -> list[tuple[str, str, Callable[[], None]]]:
    """(name, address, build) of every configured device, in build order."""
    dev, lim = cfg.devices, cfg.limits
    bodies = (None, None) if st.world is None else (st.world.exciter, st.world.rotor)
    out: list[tuple[str, str, Callable[[], None]]] = []
    if dev.robot is not None:
        out.append(("robot", dev.robot.address, lambda: _build_robot(st, cfg)))
    if dev.exciter is not None:
        out.append(("exciter", dev.exciter.address, lambda: _build_vfd(
            st, cfg, "exciter", dc=dev.exciter, lim=lim.exciter, body=bodies[0])))
    if dev.rotor is not None:
        out.append(("rotor", dev.rotor.address, lambda: _build_vfd(
            st, cfg, "rotor", dc=dev.rotor, lim=lim.rotor, body=bodies[1])))
    if dev.generator is not None:
        out.append(("generator", dev.generator.address, lambda: _build_generator(st, cfg)))
    return out


def _warn_if_cameras_film_another_world(config: RigConfig) -> None:
    """Simulated cameras render the station's own twin, which only its ``mock://`` devices move: a device
    on a stand-alone mock (``rig mock …``, its own twin in its own process) or on real hardware moves
    nothing the cameras film — a procedure that films it (calibrate, sync, sweep, …) cannot pass (the
    calibration finds no plate markers: the plate never reached its pose in the filmed world)."""
    if not config.station.simulated or not any(c.driver == "sim" for c in config.cameras.values()):
        return
    elsewhere = [f"devices.{name}.address = {d.address!r}" for name, d in config.devices.configured().items()
                 if parse_address(d.address, f"devices.{name}.address")["scheme"] != "mock"]
    if elsewhere:
        log.warning("the simulated cameras film the station's own twin, which %s does not move (a "
                    "stand-alone mock has its own twin): procedures that film the rig (calibrate, sync, "
                    "sweep, ...) cannot pass; use mock:// addresses for a filmed simulation",
                    ", ".join(elsewhere))


@contextlib.contextmanager
def open_station(config: RigConfig, clock: Clock, *, keep_going: bool = False) -> Iterator[Station]:
    """Build every configured device (starting mock servers on a simulated station) — the cameras first,
    then the arm, the drives and the generator — and always tear down.

    A device that cannot be built or reached raises :class:`StationError`, unless ``keep_going`` (what
    ``rig check`` uses): then every device is tried independently, and those that failed are left out of
    ``devices`` and listed in ``unreachable`` (name → the reason, naming the address)."""
    station = Station(config, clock)
    try:
        if config.station.simulated:
            from drivers.sim.clock import VirtualClock
            from drivers.sim.world import World

            if not isinstance(clock, VirtualClock):
                raise ConfigError("station.clock", "a simulated station needs the virtual clock")
            seed = config.sim.seed if config.sim else 0
            station.world = World(clock, seed=seed, layout=world_layout(config))
            add_fiducial_led(station.world, config)
        # cameras first: a network camera's connection and settling can take seconds on a loaded host, and
        # a device built before them would be silent that long, before the runner's heartbeats start — long
        # enough for its own communication-loss watchdog (b-CAP WDT, a drive's Modbus timeout) to stop it
        try:
            _build_cameras(station, config)
        except StationError as exc:
            if not keep_going:
                raise
            station.unreachable["cameras"] = str(exc)
        for name, address, build in _builders(station, config):
            try:
                try:
                    build()
                except (ConfigError, StationError):
                    raise
                except Exception as exc:
                    raise StationError(f"{name} at {address}: {type(exc).__name__}: {exc}") from exc
            except StationError as exc:
                if not keep_going:
                    raise
                station.unreachable[name] = str(exc)
        _warn_if_cameras_film_another_world(config)
        yield station
    finally:
        station.close()

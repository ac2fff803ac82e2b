"""``rig mock lab``: one simulated lab — every device a configuration names and both cameras — in one
process, on one simulated world, each on its own loopback endpoint, so that a ``rig.toml`` pointing at it
drives and films the same bench, as a lab's controller does (see the README's "The whole lab on mocks").

The world (:class:`drivers.sim.world.World`) is built from the configuration as the station builds its twin
(:func:`rig.run.station.world_layout`, the fiducial LED) on a virtual clock paced at real time (a controller
drives it live). On it run the mock servers the station starts for
``mock://`` addresses (b-CAP controller, exciter and rotor VFDs on Modbus TCP, SCPI generator; built by
:func:`rig.run.station.mock_robot_server`, :func:`~rig.run.station.mock_drive`,
:func:`~rig.run.station.mock_generator`) and one IP camera per ``[sim.cameras.*]``
(:class:`drivers.mock.mjpeg_camera.MjpegCameraServer`) rendering the same world, so what the arm and the
drives do is what the cameras film. Each camera streams over HTTP as time-stamped Matroska (``--stream
matroska``, the default: every frame carries the simulated camera's own clock, its drift and origin, which
the sub-frame sync needs) or as MJPEG (``--stream mjpeg``: no stamps, the client stamps frames on arrival,
as with most plain IP cameras; the sync then sees the host's arrival jitter).

Rendering two 60 fps cameras at 1920×1080 costs more than a shared 2-core host has next to ``rig``; the lab
serves the configured cameras scaled by ``--scale`` (default 0.5: 960×540), with intrinsics and fiducial
regions scaled consistently (pixel centres at integers: x' = (x + ½)·s − ½). The ``rig.toml`` it prints (or
writes with ``--write-config``) is the configuration the lab serves, with every device at its endpoint and
``[cameras.*] driver = "opencv"`` at its stream (``timestamps = "stream"`` for Matroska, ``"host"`` for
MJPEG); the watchdogs are raised for a host that may stall (b-CAP
WDT 2 s, heartbeat 6 s, drive communication time-out 5 s), as between any two processes on a loaded machine.

Targets: a procedure mounts one (``station.mount``); the lab's ``rig.toml`` names the lab's control endpoint
(``[sim] lab_url``), where the station mounts each target in the lab's world (``POST /mount/<scene>``, what
an operator does by hand at a real bench) as well as on its own twin. ``--scene`` mounts one at start.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import logging
import math
import sys
import threading
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from drivers.mock._serve import loopback_host, wait_for_interrupt
from drivers.sim.world import SCENES, World
from rig.config.rig_config import RigConfig, config_from_dict, load_config
from rig.config.schema import ConfigError, to_dict
from rig.config.toml_text import to_toml
from rig.record.atomic import write_text
from rig.run.exit_codes import EXIT_BAD_INPUT, EXIT_FAULT

if TYPE_CHECKING:
    from drivers.mock.mjpeg_camera import MjpegCameraServer

__all__ = ["Lab", "client_table", "lab_table", "main", "open_lab"]

log = logging.getLogger("rig.run.lab")
DEVICE_ORDER = ("robot", "exciter", "rotor", "generator")  # --port-base N: robot N, exciter N+1, …, cameras
TOLERANT = {"robot": {"wdt_ms": 2000}, "exciter": {"comm_timeout_s": 5.0}, "rotor": {"comm_timeout_s": 5.0}}
REAL_TIME = 1.0  # virtual s per wall s: a controller drives the lab live
STREAMS = ("matroska", "mjpeg")  # the cameras' stream forms (--stream)
# a stamped stream catches up stalls (its late frames keep their stamps), not a lasting deficit: 2 s, as
# rig's reading of a recording (decoding and reducing every frame) starves a loaded host's lab for seconds,
# and a burst skipped at 0.5 s behind swallowed whole 0.16-s still recordings
CATCH_UP_S = 2.0
HEARTBEAT_TIMEOUT_S = 6.0  # above the 2 s WDT; drives probed every 1.5 s, their 5 s time-out above 2 probes


def _scaled_px(value: float, scale: float) -> float:
    """A pixel coordinate (centres at integers) of an image scaled by ``scale``."""
    return (float(value) + 0.5) * scale - 0.5


def lab_table(config: RigConfig, scale: float, scene: str | None = None,
              fps: float | None = None) -> dict[str, Any]:
    """The configuration the lab serves, as a table: ``config`` with every simulated camera's resolution,
    intrinsics and fiducial region scaled by ``scale`` (0 < scale ≤ 1), its frame rate ``fps`` (None: as
    configured) and ``scene`` mounted at start."""
    if not (math.isfinite(scale) and 0.0 < scale <= 1.0):
        raise ConfigError("--scale", f"{scale!r}; allowed: within (0, 1] (1 = the configured resolution)")
    if not config.station.simulated or config.sim is None:
        raise ConfigError("station.simulated", "the lab simulates the rig: give a configuration with station."
                                               "simulated = true and its [sim] (e.g. the built-in one)")
    table: dict[str, Any] = _drop_none(to_dict(config))
    table.pop("source", None)
    sim = table["sim"]
    for name, cam in table["cameras"].items():
        if name not in sim["cameras"]:
            raise ConfigError(f"cameras.{name}", "the lab films only simulated cameras: it needs "
                                                 f"[sim.cameras.{name}]")
        cam["resolution_px"] = [max(16, round(n * scale)) for n in cam["resolution_px"]]
        if fps is not None:
            cam["fps"] = fps
        intrinsics = sim["cameras"][name]
        intrinsics["fx_px"] *= scale
        intrinsics["fy_px"] *= scale
        intrinsics["cx_px"] = _scaled_px(intrinsics["cx_px"], scale)
        intrinsics["cy_px"] = _scaled_px(intrinsics["cy_px"], scale)
    fiducial = table.get("fiducial")
    if fiducial is not None:
        fiducial["regions_px"] = {name: [math.floor(x0 * scale), math.floor(y0 * scale),
                                         math.ceil(x1 * scale), math.ceil(y1 * scale)]
                                  for name, (x0, y0, x1, y1) in fiducial["regions_px"].items()}
    if scene is not None:
        sim["initial_scene"] = scene
    config_from_dict(table, "rig mock lab")  # the scaled configuration is valid (raises ConfigError)
    return table


def client_table(served: dict[str, Any], endpoints: dict[str, str]) -> dict[str, Any]:
    """The ``rig.toml`` of a controller using the lab: ``served`` (see :func:`lab_table`) with every device at
    its lab endpoint, every camera an ``opencv`` camera at its stream, the station's virtual clock paced at
    real time as the lab's and the watchdogs of :data:`TOLERANT`."""
    table: dict[str, Any] = copy.deepcopy(served)
    table["station"]["heartbeat_timeout_s"] = HEARTBEAT_TIMEOUT_S
    table["sim"]["rate"] = REAL_TIME
    table["sim"]["lab_url"] = endpoints["control"]  # procedures mount their targets in the lab's world
    for name, device in table["devices"].items():
        device["address"] = endpoints[name]
        device.update(TOLERANT.get(name, {}))
    for name, cam in table["cameras"].items():
        source = endpoints[f"cameras.{name}"]
        cam["driver"], cam["source"] = "opencv", source
        cam["timestamps"] = "stream" if source.endswith(".mkv") else "host"  # Matroska carries its stamps
    config_from_dict(table, "rig mock lab (client)")
    return table


def _drop_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _drop_none(v) for k, v in value.items() if v is not None}
    return [_drop_none(v) for v in value] if isinstance(value, (list, tuple)) else value


@dataclass
class Lab:
    """The running lab: ``endpoints`` maps ``robot``/``exciter``/``rotor``/``generator`` and
    ``cameras.<name>`` to the address a client uses; ``cameras`` the camera servers (their stats)."""

    served: dict[str, Any]
    endpoints: dict[str, str] = field(default_factory=dict)
    cameras: dict[str, MjpegCameraServer] = field(default_factory=dict)
    _closers: list[tuple[str, Callable[[], None]]] = field(default_factory=list, repr=False)

    def client_config(self) -> dict[str, Any]:
        return client_table(self.served, self.endpoints)

    def close(self) -> None:
        while self._closers:
            name, closer = self._closers.pop()
            try:
                closer()
            except Exception as exc:  # every server is stopped even if one fails
                log.error("stopping %s failed: %s", name, exc)


def _port(base: int, offset: int) -> int:
    return 0 if base == 0 else base + offset


def _serve_devices(lab: Lab, config: RigConfig, world: World, host: str, port_base: int) -> None:
    from drivers.mock.generator_server import GeneratorServer
    from drivers.mock.vfd_server import VfdServer
    from rig.run.station import mock_drive, mock_generator, mock_robot_server

    dev = config.devices
    if dev.robot is not None:
        robot = mock_robot_server(dev.robot, world, client_watchdog=True)
        lab._closers.append(("robot", robot.close))
        lab.endpoints["robot"] = f"tcp://{host}:{robot.serve_tcp(host, _port(port_base, 0))}"
    drives = ((1, "exciter", dev.exciter, world.exciter), (2, "rotor", dev.rotor, world.rotor))
    for offset, name, vfd, body in drives:
        if vfd is not None:
            server = VfdServer(mock_drive(vfd, body, world.clock), host=host,
                               port=_port(port_base, offset)).start()
            lab._closers.append((name, server.stop))
            lab.endpoints[name] = server.url
    if dev.generator is not None:
        generator = GeneratorServer(mock_generator(dev.generator, world), host=host,
                                    port=_port(port_base, 3)).start()
        lab._closers.append(("generator", generator.stop))
        lab.endpoints["generator"] = generator.url


class _MountHandler(BaseHTTPRequestHandler):
    """``POST /mount/<scene>``: mount a target in the lab's world now (what an operator does by hand);
    ``GET /mount``: the target mounted now."""

    server: _ControlServer
    protocol_version = "HTTP/1.0"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("lab control %s: " + format, self.address_string(), *args)

    def _reply(self, status: int, text: str) -> None:
        body = (text + "\n").encode()
        self.send_response(status)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self) -> None:
        if self.path != "/mount":
            self._reply(404, "GET /mount (the target mounted now) or POST /mount/<scene>")
            return
        self._reply(200, self.server.world.scene)

    def do_POST(self) -> None:
        scene = self.path.removeprefix("/mount/")
        if not self.path.startswith("/mount/") or scene not in SCENES:
            self._reply(404, f"POST /mount/<scene>; scenes: {', '.join(SCENES)}")
            return
        self.server.world.set_scene(scene)
        log.info("lab: target %s mounted at t = %.3f s", scene, self.server.world.clock.now_s())
        self._reply(200, scene)


class _ControlServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, address: tuple[str, int], world: World) -> None:
        super().__init__(address, _MountHandler)
        self.world = world


def _serve_control(lab: Lab, world: World, *, host: str, port: int) -> None:
    server = _ControlServer((host, port), world)
    thread = threading.Thread(target=server.serve_forever, name="lab-control", daemon=True)
    thread.start()

    def stop() -> None:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5.0)

    lab._closers.append(("control", stop))
    lab.endpoints["control"] = f"http://{host}:{server.server_address[1]}"


def _serve_cameras(lab: Lab, config: RigConfig, world: World, *, host: str, port_base: int,
                   jpeg_quality: int, stream: str) -> None:
    from drivers.mock.mjpeg_camera import MjpegCameraServer
    from drivers.sim.stereo_rig import make_camera
    from rig.run.station import camera_specs

    for k, spec in enumerate(camera_specs(config)):
        width, height = config.cameras[spec.name].resolution_px
        camera = make_camera(spec, world, width_px=width, height_px=height)
        server = MjpegCameraServer(camera, host=host, port=_port(port_base, len(DEVICE_ORDER) + k),
                                   jpeg_quality=jpeg_quality,
                                   catch_up_s=CATCH_UP_S if stream == "matroska" else 0.0).start()
        lab._closers.append((f"camera {spec.name}", server.stop))
        lab.cameras[spec.name] = server
        lab.endpoints[f"cameras.{spec.name}"] = server.mkv_url if stream == "matroska" else server.url


@contextlib.contextmanager
def open_lab(config: RigConfig, *, scale: float = 0.5, port_base: int = 0,
             host: str = "127.0.0.1", scene: str | None = None, fps: float | None = None,
             jpeg_quality: int = 90, stream: str = "matroska") -> Iterator[Lab]:
    """Serve the lab of ``config`` (see the module docstring) until the context ends; every server is
    stopped on the way out. ``stream``: the cameras' endpoints, ``"matroska"`` or ``"mjpeg"``.
    ``port_base`` 0: any free ports; else robot N, exciter N+1, rotor N+2,
    generator N+3, cameras N+4, N+5, …, then the control endpoint."""
    from drivers.sim.clock import VirtualClock
    from rig.run.station import add_fiducial_led, world_layout

    if stream not in STREAMS:
        raise ConfigError("--stream", f"{stream!r}; allowed: {', '.join(STREAMS)}")
    served = lab_table(config, scale, scene, fps)
    lab_config = config_from_dict(served, "rig mock lab")
    assert lab_config.sim is not None  # lab_table requires [sim]
    world = World(VirtualClock(rate=REAL_TIME), seed=lab_config.sim.seed, layout=world_layout(lab_config))
    add_fiducial_led(world, lab_config)
    lab = Lab(served)
    try:
        control_port = _port(port_base, len(DEVICE_ORDER) + len(lab_config.cameras))
        _serve_control(lab, world, host=host, port=control_port)
        _serve_devices(lab, lab_config, world, host, port_base)
        _serve_cameras(lab, lab_config, world, host=host, port_base=port_base, jpeg_quality=jpeg_quality,
                       stream=stream)
        yield lab
    finally:
        lab.close()


# ------------------------------------------------------------------------------------------- command line
class _Parser(argparse.ArgumentParser):
    """argparse with a usage error exiting 4 (bad input), as ``rig``'s own, not argparse's 2 (aborted)."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _parser(prog: str | None) -> argparse.ArgumentParser:
    parser = _Parser(
        prog=prog or "python -m rig.run.lab",
        description="One simulated lab: every device of the configuration and one HTTP camera (time-stamped "
                    "Matroska, or MJPEG) per camera, on one simulated world, each on its own 127.0.0.1 "
                    "endpoint. Prints the endpoints and a rig.toml that uses them.")
    parser.add_argument("--config", default=None, help="the rig.toml to simulate (default: the built-in rig)")
    parser.add_argument("--port-base", type=int, default=0,
                        help="first TCP port: robot N, exciter N+1, rotor N+2, generator N+3, cameras "
                             "N+4…, then the control endpoint (default 0: any free ports)")
    parser.add_argument("--host", default="127.0.0.1", type=loopback_host,
                        help="loopback address to bind (default 127.0.0.1; other addresses are refused)")
    parser.add_argument("--scale", type=float, default=0.5,
                        help="camera image scale (default 0.5: 1920×1080 is served as 960×540)")
    parser.add_argument("--fps", type=float, default=None,
                        help="camera frame rate (default: the configuration's; each 60 fps camera at 960×540 "
                             "costs ≈ 0.4 CPU-s per second of streaming)")
    parser.add_argument("--stream", choices=STREAMS, default="matroska",
                        help="what the cameras' endpoints in the rig.toml serve: matroska (default: every "
                             "frame stamped with the simulated camera's clock) or mjpeg (no stamps: the "
                             "controller stamps frames on arrival, like plain IP cameras); both are served")
    parser.add_argument("--jpeg-quality", type=int, default=90, help="JPEG quality of the streams (1..100)")
    parser.add_argument("--scene", choices=SCENES, default=None,
                        help="target mounted in the lab (default: the configuration's [sim] initial_scene)")
    parser.add_argument("--write-config", metavar="PATH", default=None,
                        help="write the rig.toml that uses the lab to PATH (else it is printed)")
    return parser


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Serve the lab until Ctrl-C or SIGTERM (a clean stop of every server)."""
    parser = _parser(prog)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    with contextlib.ExitStack() as stack:  # every server is stopped on the way out
        try:
            config = load_config(args.config)
            lab = stack.enter_context(open_lab(config, scale=args.scale, port_base=args.port_base,
                                               host=args.host, scene=args.scene, fps=args.fps,
                                               jpeg_quality=args.jpeg_quality, stream=args.stream))
        except (ConfigError, ValueError) as exc:
            parser.error(str(exc))
        except OSError as exc:  # a port in use
            parser.error(f"--port-base {args.port_base}: cannot serve: {exc}")
        header = (f"rig.toml for `rig mock lab` ({config.source}, cameras scaled {args.scale:g}); "
                  "its devices and cameras are the lab's endpoints")
        text = to_toml(lab.client_config(), header)
        tomllib.loads(text)  # what is handed out reads back
        for name, url in lab.endpoints.items():
            print(f"lab {name}: {url}", flush=True)
        if args.write_config:
            try:
                write_text(Path(args.write_config), text)
            except OSError as exc:
                print(f"{parser.prog}: cannot write --write-config {args.write_config}: {exc}",
                      file=sys.stderr)
                return EXIT_FAULT
            print(f"lab rig.toml written to {args.write_config}", flush=True)
        else:
            print(f"--- rig.toml ---\n{text}--- end ---", flush=True)
        print("lab ready (Ctrl-C or SIGTERM stops it)", flush=True)
        wait_for_interrupt()
    for name, cam in lab.cameras.items():
        origins = [(index, cam.camera.frame_timestamp_s(index)) for index in cam.stats.first_frames]
        print(f"lab camera {name}: {cam.stats.published} frames sent, {cam.stats.skipped} skipped, "
              f"render + encode {cam.stats.render_cpu_s:.1f} CPU-s; Matroska connections' first frames "
              f"(index, camera clock s): {origins}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

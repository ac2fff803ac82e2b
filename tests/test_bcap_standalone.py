"""The mock RC8 as a program (``python -m drivers.mock.bcap_server``), its loopback-only binding, the
one-client rule over TCP and the serial line, and the channel interface.

The stand-alone test starts the mock in its own process on port 0, reads the bound port from the first
line it prints, and drives it with the real driver (connect, take the arm, move, read the position,
release) over real TCP, then stops it with SIGTERM (a clean stop, exit 0).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.clock import WallClock
from drivers.denso import hresult as hr
from drivers.denso.arm import BoxEnvelope, DensoArm, OrientationLimits
from drivers.denso.client import BcapClient
from drivers.mock import bcap_server
from drivers.mock._serve import require_loopback
from drivers.mock.bcap_channels import Channel
from drivers.mock.bcap_server import BcapMockServer
from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.generator_server import GeneratorServer
from drivers.mock.vfd_drive import DriveModel
from drivers.mock.vfd_server import VfdServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport

ROOT = Path(__file__).resolve().parents[1]
ENVELOPE = BoxEnvelope((200.0, 500.0), (-200.0, 200.0), (100.0, 500.0),
                       OrientationLimits(rx_deg=(-180, 180), ry_deg=(-30, 30), rz_deg=(-180, 180)))


def test_standalone_mock_serves_the_real_driver_and_stops_on_sigterm() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "drivers.mock.bcap_server", "--port", "0"], cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()  # "b-CAP mock RC8 on tcp://127.0.0.1:<port>"
        found = re.search(r"tcp://127\.0\.0\.1:(\d+)", line)
        assert found, f"no address in {line!r}; stderr: {proc.stderr.read() if proc.poll() else ''}"
        port = int(found.group(1))
        assert port > 0
        client = BcapClient(open_transport(f"tcp://127.0.0.1:{port}", 2.0), timeout_s=2.0)
        with DensoArm(client, envelope=ENVELOPE, max_speed_mm_s=250.0, position_tolerance_mm=0.05,
                      clock=WallClock()) as arm:
            start = arm.position()
            # the mock's own world starts the arm at 350, 0, 300 mm (90, 0, 90 deg)
            np.testing.assert_allclose(start, [350.0, 0.0, 300.0, 90.0, 0.0, 90.0], atol=1e-6)
            target = [370.0, 10.0, 290.0, 90.0, 0.0, 90.0]
            result = arm.move_to(target, 200.0)  # 24.5 mm at 200 mm/s: about 0.15 s of real time
            assert result.position_error_mm <= 0.05
            np.testing.assert_allclose(arm.position()[:3], target[:3], atol=0.05)
        # the arm was released (GiveArm, Service_Stop): a new client may take it at once
        again = BcapClient(open_transport(f"tcp://127.0.0.1:{port}", 2.0), timeout_s=2.0)
        again.service_start()
        again.service_stop()
        again.link.transport.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.0.10", "::", "example.org", ""])
def test_every_mock_refuses_a_non_loopback_address(host: str) -> None:
    world = World(VirtualClock())
    with pytest.raises(ValueError, match="loopback address only"):
        require_loopback(host)
    with BcapMockServer(world.robot, world.clock) as server:
        with pytest.raises(ValueError, match=re.escape(f"host={host!r}")):
            server.serve_tcp(host, 0)
        with pytest.raises(ValueError, match="loopback"):
            server.serve_udp(host, 0)
    with pytest.raises(ValueError, match="loopback"):
        GeneratorServer(GeneratorInstrument(world.shaker, world.clock), host=host)
    with pytest.raises(ValueError, match="loopback"):
        VfdServer(DriveModel(world.exciter, world.clock), host=host)


def test_loopback_addresses_are_accepted() -> None:
    assert require_loopback("127.0.0.1") == "127.0.0.1"
    assert require_loopback("localhost") == "127.0.0.1"
    assert require_loopback("127.0.0.2") == "127.0.0.2"


def test_standalone_host_option_refuses_other_addresses(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        bcap_server.main(["--port", "0", "--host", "0.0.0.0"])
    assert info.value.code == 4  # bad input (rig's exit code; argparse's own is 2)
    assert "--host='0.0.0.0' is not allowed" in capsys.readouterr().err


def test_an_idle_serial_line_does_not_lock_tcp_clients_out() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        pty_name = server.serve_pty()  # served, nobody talking on it
        port = server.serve_tcp()
        # every exchange here is answered (a refusal is a reply): time-outs for a loaded machine only
        tcp = BcapClient(open_transport(f"tcp://127.0.0.1:{port}", 30.0), timeout_s=30.0)
        tcp.service_start()  # was E_MAX_CONNECT: the pty took the only slot when it was opened
        serial = BcapClient(open_transport(f"serial://{pty_name}?baud=115200", 30.0), serial_line=True,
                            timeout_s=30.0, retries=1)
        with pytest.raises(hr.BcapError) as info:  # one client at a time: the TCP client holds it
            serial.service_start()
        assert info.value.hresult == hr.E_MAX_CONNECT
        tcp.service_stop()  # the TCP client is done: the serial line may take the controller
        serial.service_start()
        with pytest.raises(hr.BcapError) as info:
            tcp.service_start()
        assert info.value.hresult == hr.E_MAX_CONNECT
        serial.service_stop()
        tcp.service_start()
        tcp.service_stop()
        tcp.link.transport.close()
        serial.link.transport.close()


def test_channel_is_an_abstract_interface() -> None:
    with pytest.raises(TypeError, match="abstract"):
        Channel()  # type: ignore[abstract]

    class Half(Channel):
        def recv(self, timeout_s: float) -> bytes:
            return b""

    with pytest.raises(TypeError, match="send"):
        Half()  # type: ignore[abstract]


def test_rig_mock_robot_passes_faults_to_the_mock() -> None:
    """``rig mock robot --fault busy:1 --fault move-error`` (parsed by the mock's own argparse): the first
    request is refused with E_BUSY_PROC, then every Move fails with the injected controller error."""
    command = [sys.executable, "-m", "rig.cli", "mock", "robot", "--port", "0", "--fault", "busy:1",
               "--fault", "move-error"]
    proc = subprocess.Popen(command, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        found = re.search(r"tcp://127\.0\.0\.1:(\d+)", proc.stdout.readline())
        assert found
        client = BcapClient(open_transport(f"tcp://127.0.0.1:{found.group(1)}", 2.0), timeout_s=2.0)
        with pytest.raises(hr.BcapError) as busy:
            client.service_start(wdt_ms=None)
        assert busy.value.hresult == hr.E_BUSY_PROC
        client.open_robot(wdt_ms=None)
        start = client.cur_pos()
        with pytest.raises(hr.BcapError) as failed:
            client.move([start[0] + 10.0, *start[1:6]])
        assert failed.value.hresult == 0x8350A005
        client.close()
        client.link.transport.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0

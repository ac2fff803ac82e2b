"""`rig check` with unreachable devices: every device is tried on its own and listed as reachable or NOT
REACHABLE with the reason (naming the address); the exit code is 3; nothing crashes."""

from __future__ import annotations

import re
import socket
from pathlib import Path

import pytest

from rig.cli import main
from tests.certify_support import write_config


def _closed_port() -> int:
    """A loopback TCP port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _with_address(config: Path, device: str, address: str) -> None:
    text = config.read_text()
    section = text.index(f"[devices.{device}]")
    line = re.compile(r"^address = .*$", re.M).search(text, section)
    assert line is not None
    config.write_text(text[:line.start()] + f'address = "{address}"' + text[line.end():])


def _device_lines(out: str) -> dict[str, str]:
    return {m.group(1): m.group(2) for m in re.finditer(r"^  (\w+)\s+(.*)$", out, re.M)}


def test_unreachable_robot_is_reported_and_the_other_devices_still_checked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path)
    _with_address(config, "robot", "tcp://127.0.0.1:1")
    assert main(["check", "--config", str(config)]) == 3
    out = capsys.readouterr()
    lines = _device_lines(out.out)
    assert list(lines) == ["robot", "exciter", "rotor", "generator"], out.out
    assert lines["robot"].startswith("NOT REACHABLE: ") and "tcp://127.0.0.1:1" in lines["robot"]
    assert "refused" in lines["robot"].lower(), lines["robot"]
    for name in ("exciter", "rotor", "generator"):
        assert lines[name] == "reachable", out.out
    assert "Traceback" not in out.err


def test_several_unreachable_devices_are_all_listed(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path)
    rotor_port, generator_port = _closed_port(), _closed_port()
    _with_address(config, "robot", "tcp://127.0.0.1:1")
    _with_address(config, "rotor", f"tcp://127.0.0.1:{rotor_port}")
    _with_address(config, "generator", f"tcp://127.0.0.1:{generator_port}")
    assert main(["check", "--config", str(config)]) == 3
    lines = _device_lines(capsys.readouterr().out)
    assert lines["exciter"] == "reachable"
    for name, port in (("robot", 1), ("rotor", rotor_port), ("generator", generator_port)):
        assert lines[name].startswith("NOT REACHABLE: ") and f"127.0.0.1:{port}" in lines[name], lines


def test_all_reachable_exits_0(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "--config", str(write_config(tmp_path))]) == 0
    lines = _device_lines(capsys.readouterr().out)
    assert lines == dict.fromkeys(("robot", "exciter", "rotor", "generator"), "reachable")

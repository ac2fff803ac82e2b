"""`rig mock DEVICE` names itself ``rig mock DEVICE`` in the mock's --help, usage and errors."""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

from rig import cli

ROOT = Path(__file__).resolve().parents[1]


def test_rig_mock_passes_its_own_name_and_the_options_to_the_mock(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    fake = types.ModuleType("fake_mock_server")

    def main(argv: list[str] | None = None, prog: str | None = None) -> int:
        calls.append((argv, prog))
        return 0

    fake.main = main  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "fake_mock_server", fake)
    monkeypatch.setitem(cli.MOCK_MODULES, "rotor", ("fake_mock_server", ["--body", "rotor"]))
    assert cli.main(["mock", "rotor", "--port", "0", "--rate", "2"]) == 0
    assert calls == [(["--body", "rotor", "--port", "0", "--rate", "2"], "rig mock rotor")]


def test_rig_mock_help_lists_the_devices(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["mock", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: rig mock ") and "{exciter,generator,lab,robot,rotor}" in out


@pytest.mark.parametrize("device", ["robot", "exciter", "generator", "lab"])
def test_mock_help_usage_names_rig_mock_device(device: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "rig.cli", "mock", device, "--help"], capture_output=True,
                          text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)}, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"usage: rig mock {device} "), proc.stdout[:200]


@pytest.mark.parametrize(("device", "option"), [("robot", "--port=x"), ("exciter", "--rate=fast"),
                                                ("generator", "--no-such-option"), ("lab", "--scale=2")])
def test_a_bad_mock_option_exits_4_naming_it(device: str, option: str) -> None:
    """Bad input is exit 4 across ``rig`` (2 is a stop signal), the mock servers' own options included."""
    proc = subprocess.run([sys.executable, "-m", "rig.cli", "mock", device, option], capture_output=True,
                          text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)}, check=False)
    assert proc.returncode == 4, (proc.returncode, proc.stderr)
    name = option.partition("=")[0].lstrip("-")
    assert f"rig mock {device}" in proc.stderr and name in proc.stderr, proc.stderr

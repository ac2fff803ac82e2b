"""Every way out leaves the devices safe — on stand-alone mock servers, as a lab would first try it.

Three ``rig mock`` processes (exciter, rotor, robot) serve on 127.0.0.1; a ``rig.toml`` points at them;
``rig run tests/spin_procedure.py`` spins both drives through the real drivers. Then the controller is
stopped — by SIGTERM, SIGHUP, SIGQUIT, SIGINT once or twice, during the hold (checkpoints) or the report
step (none) — or killed with SIGKILL, and a **stock pymodbus client** reads each drive's output
frequency back afterwards. A clean stop leaves both at 0 Hz with the stop document naming the signal;
after SIGKILL nobody stops them but the drives themselves: their communication-loss stop (armed by the
station, ``devices.<name>.comm_timeout_s``) trips ``comm_timeout_s`` after the last request — on the
mock's own clock, from its log — and the output ramps to 0 within the stated bound.

Every watchdog here is wall time between processes, so the ``rig.toml`` sets them for a host that may stall
(a loaded CI machine): b-CAP WDT 2 s (the robot mock ends a session silent for 4 × WDT = 8 s), heartbeat
6 s (idle devices probed every 1.5 s), drive communication time-out 5 s. A rig process stopped outright for
``STALL_S`` (SIGSTOP … SIGCONT) keeps every device: with DENSO's 400 ms WDT the mock ended the session
after 1.6 s of silence.

The three mocks serve the whole module, as a lab keeps its mock servers running between runs (each test its
own ``rig.toml``, run folder and the mocks' log from its start on): every test begins with both drives at
rest and without a fault, which is what the test before it left. Only the SIGKILL test, whose drives stop
themselves with a latched communication fault, has mocks of its own.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient
from spin_procedure import END_REPORT

from drivers.denso.client import BcapClient
from drivers.transport import open_transport

ROOT = Path(__file__).resolve().parents[1]
SPIN_PROCEDURE = ROOT / "tests" / "spin_procedure.py"
FAULT, FREQ_OUT = 0x2100, 0x2103  # docs/exciter.md register map (wire addresses)
UNIT = {"exciter": 1, "rotor": 2}  # sim.toml and the stand-alone mocks' defaults
FAULT_COMM_TIMEOUT = 0x42  # the mock drive's CE10
WDT_MS = 2000  # devices.robot.wdt_ms (default 400)
HEARTBEAT_S = 6.0  # station.heartbeat_timeout_s (default 2): above the WDT
COMM_TIMEOUT_S = 5.0  # devices.<name>.comm_timeout_s (default 2): above 2 × the 1.5 s probe interval
STALL_S = 3.0  # a stall every watchdog above tolerates: the drives' 5 s less a probe interval, at least
TRIP = re.compile(r"drive fault 0x42 at t = ([\d.]+) s \(last request t = ([\d.]+) s\): output ([\d.]+) Hz "
                  r"ramps to 0 at ([\d.]+) Hz/s, at rest by t = ([\d.]+) s")  # the mock drive's log
# the spin (spin_procedure's exciter_hz, rotor_hz) and each drive's ramp (Hz/s: the exciter's drive default,
# the rotor's sim.toml ramp_rate_hz_per_s): ≈ 1 s of real-time ramp up and down each, not the
# procedure's default 3 and 5 Hz (2.5–3 s each way, per test); what is checked is rest after a stop
SPIN = {"exciter": (1.0, 1.0), "rotor": (2.0, 2.0)}
WAIT_S = 120.0  # generous bound for waits on a loaded machine; each ends as soon as its event is seen


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


@dataclass
class Mock:
    name: str
    proc: subprocess.Popen[str]
    port: int
    log_path: Path
    log_from: int = 0  # bytes of the log written before the current test

    def log(self) -> str:
        """The mock's log since the current test began (:meth:`mark`)."""
        return self.log_path.read_bytes()[self.log_from:].decode(errors="replace")

    def mark(self) -> None:
        self.log_from = self.log_path.stat().st_size


@dataclass
class StandaloneRig:
    config: Path
    runs: Path
    mocks: dict[str, Mock]


def _spawn_mock(tmp_path: Path, name: str) -> tuple[subprocess.Popen[str], Path]:
    log_path = tmp_path / f"mock-{name}.log"
    with open(log_path, "w") as log:  # the child keeps its own descriptor
        proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "mock", name, "--port", "0"], cwd=tmp_path,
                                env=_env(), stdout=subprocess.PIPE, stderr=log, text=True)
    return proc, log_path


def _serving(name: str, proc: subprocess.Popen[str], log_path: Path) -> Mock:
    """The mock once it serves: its first stdout line names its port."""
    line = proc.stdout.readline()  # type: ignore[union-attr]
    found = re.search(r"tcp://127\.0\.0\.1:(\d+)", line)
    assert found, (line, log_path.read_text())
    return Mock(name, proc, int(found.group(1)), log_path)


def _config(tmp_path: Path, ports: dict[str, int]) -> Path:
    """The built-in rig's configuration with the robot, exciter and rotor on the stand-alone mocks (each on
    its own TCP port), the station clock paced at real time, like the mocks, and the watchdogs above."""
    text = (ROOT / "rig" / "data" / "sim.toml").read_text()
    tables = text.split("\n[")
    for i, table in enumerate(tables):
        name = table.split("]", 1)[0]
        if name in ("devices.robot", "devices.exciter", "devices.rotor"):
            device = name.split(".")[1]
            address = f'address = "tcp://127.0.0.1:{ports[device]}"'
            address += f"\nwdt_ms = {WDT_MS}" if device == "robot" else f"\ncomm_timeout_s = {COMM_TIMEOUT_S}"
            # unit ids as in sim.toml: the mocks' defaults (exciter 1, rotor 2)
            tables[i] = re.sub(r'address = "mock://\w+"', address, table)
        elif name == "station":
            tables[i] = table.replace("\n", f"\nheartbeat_timeout_s = {HEARTBEAT_S}\n", 1)
        elif name == "sim":
            tables[i] = table.replace("\n", "\nrate = 1.0\n", 1)
    path = tmp_path / "rig.toml"
    path.write_text("\n[".join(tables))
    return path


@contextlib.contextmanager
def _serving_mocks(folder: Path) -> Iterator[dict[str, Mock]]:
    """The three stand-alone mocks serving (their logs in ``folder``), stopped by SIGTERM at the end."""
    # the three start together (each imports the twin: ≈ 1–2 CPU-s), then each is awaited on its port line
    spawned: dict[str, tuple[subprocess.Popen[str], Path]] = {}
    try:
        for name in ("exciter", "rotor", "robot"):
            spawned[name] = _spawn_mock(folder, name)
        yield {name: _serving(name, *started) for name, started in spawned.items()}
    finally:
        for proc, _ in spawned.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc, _ in spawned.values():
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.stdout.close()  # type: ignore[union-attr]


@pytest.fixture(scope="module")
def module_mocks(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Mock]]:
    with _serving_mocks(tmp_path_factory.mktemp("mocks")) as mocks:
        yield mocks


def _rig_on(tmp_path: Path, mocks: dict[str, Mock]) -> StandaloneRig:
    return StandaloneRig(_config(tmp_path, {n: m.port for n, m in mocks.items()}), tmp_path / "runs", mocks)


@pytest.fixture
def standalone(module_mocks: dict[str, Mock], tmp_path: Path) -> StandaloneRig:
    """The module's mocks, found as the previous test must leave them: serving, both drives at rest and
    without a fault; each mock's log read from here on."""
    for mock in module_mocks.values():
        assert mock.proc.poll() is None, (mock.name, mock.log())
        mock.mark()
    for device in ("exciter", "rotor"):
        assert (_read(module_mocks[device], FREQ_OUT), _read(module_mocks[device], FAULT)) == (0, 0), device
    return _rig_on(tmp_path, module_mocks)


@pytest.fixture
def own_standalone(tmp_path: Path) -> Iterator[StandaloneRig]:
    """Mocks of this test's own: for a test that leaves the drives faulted."""
    with _serving_mocks(tmp_path) as mocks:
        yield _rig_on(tmp_path, mocks)


def _start_rig(rig: StandaloneRig, *settings: str) -> tuple[subprocess.Popen[str], Path]:
    argv = [sys.executable, "-m", "rig.cli", "run", str(SPIN_PROCEDURE), "--config", str(rig.config),
            "--runs-dir", str(rig.runs), "--no-dashboard"]
    for s in (*(f"{name}_hz={hz:g}" for name, (hz, _) in SPIN.items()), *settings):
        argv += ["--set", s]
    with open(rig.config.parent / "rig.stderr", "w") as err:  # a file the tests watch while rig runs
        proc = subprocess.Popen(argv, cwd=rig.config.parent, env=_env(), stdout=subprocess.PIPE, stderr=err,
                                text=True)
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        records = list(rig.runs.glob("*/record.jsonl")) if rig.runs.is_dir() else []
        if records:
            return proc, records[0].parent
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.kill()
    raise AssertionError("rig did not create its run folder")


def _wait_for(run_dir: Path, proc: subprocess.Popen[str], needle: str) -> None:
    _wait_for_file(run_dir / "record.jsonl", proc, needle)


def _wait_for_file(path: Path, proc: subprocess.Popen[str], needle: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        if needle in path.read_text():
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"{needle} never appeared in {path.name}")


def _count(run_dir: Path, stream: str) -> int:
    return (run_dir / "record.jsonl").read_text().count(f'"stream":"{stream}"')


def _wait_for_count(path: Path, proc: subprocess.Popen[str], needle: str, count: int) -> None:
    """Until ``needle`` appears ``count`` times in ``path`` (rig still running)."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        if path.read_text().count(needle) >= count:
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"{needle} never appeared {count} times in {path.name}")


def _read(mock: Mock, address: int) -> int:
    """One FC03 with a stock pymodbus client (not our driver)."""
    client = ModbusTcpClient("127.0.0.1", port=mock.port, timeout=5.0, retries=1)
    assert client.connect()
    try:
        reply = client.read_holding_registers(address, count=1, device_id=UNIT[mock.name])
        assert not reply.isError(), reply
        return int(reply.registers[0])
    finally:
        client.close()


def _documents(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "record.jsonl").read_text().splitlines() if line.strip()]


def _signal_and_check(rig: StandaloneRig, phase: str, signals: list[signal.Signals], *,
                      stall: bool = False) -> None:
    # one signal in the report step (no checkpoint) takes effect when the step ends: the test ends the
    # step (spin_procedure's END_REPORT file) once rig has handled the signal
    settings = ("report_s=600",) if phase == "report" else ()
    proc, run_dir = _start_rig(rig, "hold_s=0" if phase == "report" else "hold_s=600", *settings)
    _wait_for(run_dir, proc, '"stream":"report_tick"' if phase == "report" else '"stream":"hold"')
    if stall:  # the whole rig process stopped, as a starved one is, then carrying on
        proc.send_signal(signal.SIGSTOP)
        time.sleep(STALL_S)  # the stall itself (nothing is timed)
        proc.send_signal(signal.SIGCONT)
        _wait_for_count(run_dir / "record.jsonl", proc, '"stream":"hold"', _count(run_dir, "hold") + 3)
    for i, sig in enumerate(signals):
        if i:  # only once rig handled the first: two signals sent before that are one (POSIX)
            _wait_for_file(rig.config.parent / "rig.stderr", proc, "abort requested; stopping at the next")
        proc.send_signal(sig)
    if phase == "report" and len(signals) == 1:
        _wait_for_file(rig.config.parent / "rig.stderr", proc, "abort requested; stopping at the next")
        (rig.config.parent / END_REPORT).touch()
    out, _ = proc.communicate(timeout=WAIT_S)
    err = (rig.config.parent / "rig.stderr").read_text()
    assert proc.returncode == 2, (out, err)
    stop = [d for d in _documents(run_dir) if d["type"] == "stop"]
    assert len(stop) == 1 and stop[0]["signal"] == signals[0].name and stop[0]["exit_status"] == "abort"
    assert stop[0]["safe_state_failures"] == []
    assert "client silent" not in rig.mocks["robot"].log()  # the controller kept the session to the end
    for device in ("exciter", "rotor"):
        assert _read(rig.mocks[device], FREQ_OUT) == 0, device  # at rest, read by a stock client
        assert _read(rig.mocks[device], FAULT) == 0, device  # stopped by the controller, no comm fault
        assert stop[0]["safe_state"][device]["frequency_hz"] == 0.0


@pytest.mark.slow
@pytest.mark.parametrize(("phase", "signals"), [
    ("hold", [signal.SIGTERM]),
    ("hold", [signal.SIGINT]),
    ("report", [signal.SIGHUP]),
    ("report", [signal.SIGQUIT]),
    ("report", [signal.SIGINT, signal.SIGINT]),
], ids=["hold-SIGTERM", "hold-SIGINT", "report-SIGHUP", "report-SIGQUIT", "report-SIGINTx2"])
def test_a_stop_signal_leaves_both_drives_at_rest(standalone: StandaloneRig, phase: str,
                                                  signals: list[signal.Signals]) -> None:
    _signal_and_check(standalone, phase, signals)


@pytest.mark.slow
def test_a_stalled_rig_keeps_every_device_then_stops_them_safely(standalone: StandaloneRig) -> None:
    """The rig process stopped for STALL_S mid-hold (a starved host): no watchdog trips — the robot mock
    keeps the session, the drives do not stop themselves, rig's heartbeat loses nothing — and a SIGTERM
    afterwards is the usual safe abort."""
    _signal_and_check(standalone, "hold", [signal.SIGTERM], stall=True)


@pytest.mark.slow
def test_sigkill_mid_run_the_drives_stop_themselves_within_the_bound(own_standalone: StandaloneRig) -> None:
    """Nothing of ``rig`` runs after SIGKILL: the drives' own communication-loss stop must act."""
    standalone = own_standalone
    proc, run_dir = _start_rig(standalone, "hold_s=600")
    _wait_for(run_dir, proc, '"stream":"hold"')
    proc.kill()
    proc.communicate(timeout=WAIT_S)
    assert not [d for d in _documents(run_dir) if d["type"] == "stop"]  # no cleanup ran
    for device, (spin_hz, ramp_hz_per_s) in SPIN.items():
        mock = standalone.mocks[device]
        deadline = time.monotonic() + WAIT_S
        trip = None
        while trip is None and time.monotonic() < deadline:  # no request before the trip (would reset it)
            trip = TRIP.search(mock.log())
            time.sleep(0.1)
        assert trip, mock.log()
        t_trip, t_last, f_hz, rate, t_rest = (float(v) for v in trip.groups())
        # on the mock's own clock: the trip comes comm_timeout_s after the last request, and the
        # output is at rest within comm_timeout_s + frequency / deceleration rate (docs/contracts.md)
        assert t_trip == pytest.approx(t_last + COMM_TIMEOUT_S, abs=1e-6)
        assert f_hz == pytest.approx(spin_hz, abs=0.01) and rate == pytest.approx(ramp_hz_per_s, rel=0.01)
        assert t_rest - t_last <= COMM_TIMEOUT_S + spin_hz / ramp_hz_per_s + 1e-6
        while time.monotonic() < deadline and _read(mock, FREQ_OUT) != 0:
            time.sleep(0.2)
        assert _read(mock, FREQ_OUT) == 0, device
        assert _read(mock, FAULT) & 0xFF == FAULT_COMM_TIMEOUT, device  # the drive stopped itself
    # the robot mock saw its client's connection end: the session ended (arm halted, motor off, handles
    # dropped), so the controller is free for a new client at once
    robot_url = f"tcp://127.0.0.1:{standalone.mocks['robot'].port}"
    client = BcapClient(open_transport(robot_url, 5.0), timeout_s=5.0)
    try:
        client.service_start()
        client.service_stop()
    finally:
        client.link.transport.close()


@pytest.mark.slow
def test_heartbeat_probes_keep_the_drives_armed_but_running_through_a_quiet_step(
        standalone: StandaloneRig) -> None:
    """No poll for two comm time-outs in the report step: the watchdog's probes are the keep-alives, the
    drives do not stop themselves, the run passes, and a clean close disarms them."""
    proc, _run_dir = _start_rig(standalone, "hold_s=0", f"report_s={2 * COMM_TIMEOUT_S:g}")
    out, _ = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, (out, (standalone.config.parent / "rig.stderr").read_text())
    with contextlib.suppress(FileNotFoundError):
        for device in ("exciter", "rotor"):
            assert "drive fault" not in standalone.mocks[device].log()
            assert _read(standalone.mocks[device], FAULT) == 0
            assert _read(standalone.mocks[device], 0x0903) == 0  # disarmed on the clean close

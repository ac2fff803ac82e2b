"""``rig mock lab`` end to end, as a new user runs it: the lab in one process (every device and both cameras
on one simulated world), ``rig run calibrate`` / ``sweep`` in another with the ``rig.toml`` the lab wrote,
the cameras read as IP cameras (``driver = "opencv"``) streaming time-stamped Matroska: every frame carries
the simulated camera's own clock, so the sub-frame sync (calibrate → sync → sweep) passes and its offset,
drift and line time are compared with the lab world's truth.

The calibrate and SIGTERM tests stream at 30 fps (``--fps 30``, cheaper); the sweep needs the configured
60 fps (the joint sync leaves out 32 frames of B around every gap in its track and 34 at its ends: a 3-s
rotor recording at 30 fps keeps too few). Waits are bounded generously; nothing is timed.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import ModbusTcpClient

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 900.0  # a calibrate on a loaded host; the run ends as soon as it is done
FREQ_OUT = 0x2103  # the drives' output frequency register (docs/exciter.md; 0.01 Hz)
UNIT = {"exciter": 1, "rotor": 2}  # the built-in rig's unit ids


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


@dataclass
class RunningLab:
    proc: subprocess.Popen[str]
    config: Path
    endpoints: dict[str, str]


@contextlib.contextmanager
def running_lab(tmp_path: Path, *options: str) -> Iterator[RunningLab]:
    """``rig mock lab`` with ``options`` in a subprocess, until it is ready; stopped with SIGTERM after."""
    config = tmp_path / "rig.toml"
    with open(tmp_path / "lab.log", "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "mock", "lab", *options,
                                 "--write-config", str(config)], cwd=tmp_path, env=_env(),
                                stdout=subprocess.PIPE, stderr=log, text=True)
    endpoints: dict[str, str] = {}
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # until "lab ready" (or the lab's exit: EOF)
            found = re.match(r"lab (\S+): (\S+://\S+)", line)
            if found:
                endpoints[found.group(1)] = found.group(2)
            if line.startswith("lab ready"):
                break
        assert proc.poll() is None, (tmp_path / "lab.log").read_text()
        yield RunningLab(proc, config, endpoints)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
        print(out)  # the lab's closing figures (frames sent and skipped, render CPU)


@pytest.fixture
def lab(tmp_path: Path) -> Iterator[RunningLab]:
    with running_lab(tmp_path, "--fps", "30") as running:
        yield running


@pytest.mark.slow
def test_rig_calibrates_against_the_lab(lab: RunningLab, tmp_path: Path) -> None:
    assert set(lab.endpoints) == {"robot", "exciter", "rotor", "generator", "cameras.left", "cameras.right",
                                  "control"}
    assert all("127.0.0.1" in url for url in lab.endpoints.values())
    text = lab.config.read_text()
    assert 'driver = "opencv"' in text and lab.endpoints["cameras.left"] in text
    runs = tmp_path / "runs"
    result = subprocess.run([sys.executable, "-m", "rig.cli", "run", "calibrate", "--config", str(lab.config),
                             "--runs-dir", str(runs), "--no-dashboard"], check=False, cwd=tmp_path,
                            env=_env(),
                            capture_output=True, text=True, timeout=WAIT_S)
    print(result.stdout[-3000:], result.stderr[-3000:])
    (path,) = runs.glob("*/calibration.json")
    calibration = json.loads(path.read_text())
    rms = {name: cam["residuals_rms_px"] for name, cam in calibration["cameras"].items()}
    print("calibration residuals (px rms):", rms)
    assert result.returncode == 0, (result.stdout[-2000:], result.stderr[-2000:])
    assert set(rms) == {"left", "right"}
    # the lab's camera served the plate the arm moved: the fit is the criterion's (calibration_rms_px)
    assert all(value <= 0.5 for value in rms.values()), rms


def _output_hz(url: str, device: str) -> float:
    """The drive's output frequency read with a stock pymodbus client (not our driver)."""
    host, port = url.removeprefix("tcp://").split(":")
    client = ModbusTcpClient(host, port=int(port), timeout=10.0, retries=1)
    assert client.connect()
    try:
        reply = client.read_holding_registers(FREQ_OUT, count=1, device_id=UNIT[device])
        assert not reply.isError(), reply
        return int(reply.registers[0]) / 100.0
    finally:
        client.close()


SPIN = ROOT / "tests" / "spin_procedure.py"  # spins both drives and holds (the safety tests' procedure)


@pytest.mark.slow
@pytest.mark.parametrize(("procedure", "spinning"),
                         [("sweep", ("rotor",)), (str(SPIN), ("exciter", "rotor"))],
                         ids=["sweep-sync-step", "spin-both-drives"])
def test_sigterm_while_drives_spin_leaves_both_drives_of_the_lab_at_rest(lab: RunningLab, tmp_path: Path,
                                                                         procedure: str,
                                                                         spinning: tuple[str, ...]) -> None:
    """``rig run sweep`` calibrates, then spins the rotor to sync the cameras; the spin procedure runs both
    drives. A SIGTERM while they turn (read from the lab by a stock Modbus client) stops both drives, exit 2,
    and the stop document names the signal."""
    runs = tmp_path / "runs"
    with open(tmp_path / "rig.stderr", "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "run", procedure, "--config",
                                 str(lab.config), "--runs-dir", str(runs), "--no-dashboard"], cwd=tmp_path,
                                env=_env(), stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        deadline = time.monotonic() + WAIT_S
        while min(_output_hz(lab.endpoints[d], d) for d in spinning) < 1.0:
            assert proc.poll() is None, (tmp_path / "rig.stderr").read_text()[-3000:]
            assert time.monotonic() < deadline, f"{spinning} never turned"
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 2, (tmp_path / "rig.stderr").read_text()[-3000:]
    (record,) = runs.glob("*/record.jsonl")
    stops = [d for line in record.read_text().splitlines() if line.strip()
             for d in [json.loads(line)] if d["type"] == "stop"]
    assert len(stops) == 1 and stops[0]["signal"] == "SIGTERM" and stops[0]["safe_state_failures"] == []
    for device in ("exciter", "rotor"):
        assert _output_hz(lab.endpoints[device], device) == 0.0, device


def _truth_offset_s(config: dict[str, object], origins: dict[str, float], ref: str, other: str,
                    other_stamp_s: float) -> float:
    """The lab world's offset t_ref − t_other (s) at ``other``'s stream stamp: each stream stamp is its
    simulated camera's clock (origin + sensor frames / fps, its oscillator ``clock_ppm`` fast) minus the
    clock at the connection's first frame (``origins``)."""
    sim = config["sim"]["cameras"]  # type: ignore[index]
    cam_o, cam_r = sim[other], sim[ref]
    clock_o = other_stamp_s + origins[other]
    world_s = cam_o.get("start_offset_s", 0.0) + (clock_o - cam_o.get("timestamp_origin_s", 0.0)) / (
        1 + cam_o.get("clock_ppm", 0.0) * 1e-6)
    clock_r = cam_r.get("timestamp_origin_s", 0.0) + (world_s - cam_r.get("start_offset_s", 0.0)) * (
        1 + cam_r.get("clock_ppm", 0.0) * 1e-6)
    return float(clock_r - origins[ref] - other_stamp_s)


@pytest.mark.slow
@pytest.mark.quiet_machine  # at load 10–18 with the lost-frame retries: 1 pass, 1 skip (lab 38 % behind)
def test_rig_syncs_and_sweeps_against_the_lab_on_the_cameras_clocks(tmp_path: Path) -> None:
    """``rig run sweep`` (calibrate, sync, sweep, report) against the lab at 60 fps runs to its certificate;
    the sync's offset and drift between the two cameras' own clocks match the lab world's within 5 standard
    uncertainties of the estimate (its own, from the noise), the line time within 5 of its own, and the
    sweep's measured criteria pass. The timing fiducial dates the sweep: ``controller_clock_u_ms`` is its u,
    the phase restart's bracket (its width/√12) plus the fit's share, and its line-time correction brings the
    timing model's line time to the lab's within 5 u. That u stays above its 0.05-ms limit on a loaded host
    (the restart's round trip, see the README's "The whole lab on mocks"), so the run may end 1 (certificate
    failed) — never 3 (a fault), as it did before the cameras stamped their frames."""
    runs = tmp_path / "runs"
    with running_lab(tmp_path) as lab:
        config = tomllib.loads(lab.config.read_text())
        assert all(cam["timestamps"] == "stream" and cam["source"].endswith(".mkv")
                   for cam in config["cameras"].values())
        result = subprocess.run([sys.executable, "-m", "rig.cli", "run", "sweep", "--config", str(lab.config),
                                 "--runs-dir", str(runs), "--no-dashboard"], check=False, cwd=tmp_path,
                                env=_env(), capture_output=True, text=True, timeout=WAIT_S)
        print(result.stdout[-3000:], result.stderr[-3000:])
        lab.proc.send_signal(signal.SIGTERM)
        out, _ = lab.proc.communicate(timeout=60)
    if result.returncode not in (0, 1):
        _skip_if_the_lab_fell_behind(out)
    assert result.returncode in (0, 1), (result.stdout[-2000:], result.stderr[-2000:])
    (certificate_path,) = runs.glob("*/certificate.json")
    status = {c["id"]: c["status"] for c in json.loads(certificate_path.read_text())["criteria"]}
    print("certificate criteria:", status)
    measured = ("calibration_rms_px", "sync_uncertainty_ms", "amplitude_error_pct", "frequency_error_pct",
                "radius_error_mm", "min_usable_frequency_hz")
    assert all(status[criterion] == "PASS" for criterion in measured), status
    _check_fiducial_dating(certificate_path.parent, config)
    origins = {}
    for name in config["cameras"]:  # each camera's Matroska connections: the client kept one
        one_connection = r"first frames \(index, camera clock s\): \[\(\d+, ([-\d.e]+)\)\]$"
        found = re.search(rf"lab camera {name}: .*{one_connection}", out, re.MULTILINE)
        assert found, out
        origins[name] = float(found.group(1))
    (timing_path,) = runs.glob("*/timing.json")
    timing = json.loads(timing_path.read_text())
    ref = timing["reference_camera"]
    (other,) = (name for name in timing["offset_s"] if name != ref)
    u = timing["uncertainty"]
    truth_s = _truth_offset_s(config, origins, ref, other, timing["epoch_s"][other])
    ppm = {name: cam.get("clock_ppm", 0.0) * 1e-6 for name, cam in config["sim"]["cameras"].items()}
    drift_truth_ppm = ((1 + ppm[ref]) / (1 + ppm[other]) - 1) * 1e6  # the reference's clock against other's
    camera = config["cameras"][other]
    line_truth_s = 0.9 / camera["fps"] / camera["resolution_px"][1]  # the twin's readout: 90 % of a frame
    offset_s, drift_ppm, line_s = (timing[key][other] for key in ("offset_s", "drift_ppm", "line_time_s"))
    print(f"sync vs the lab's truth: offset {offset_s * 1e3:.4f} ms (truth {truth_s * 1e3:.4f}, "
          f"u {u['offset_s'][other] * 1e3:.4f}); drift {drift_ppm:.1f} ppm (truth {drift_truth_ppm:.1f}, "
          f"u {u['drift_ppm'][other]:.1f}); line time {line_s * 1e6:.2f} µs (truth {line_truth_s * 1e6:.2f}, "
          f"u {u['line_time_s'][other] * 1e6:.2f})")
    assert math.isfinite(truth_s)
    assert abs(offset_s - truth_s) <= 5 * u["offset_s"][other]
    assert abs(drift_ppm - drift_truth_ppm) <= 5 * u["drift_ppm"][other]
    assert abs(line_s - line_truth_s) <= 5 * u["line_time_s"][other]


# the share of frames a lab camera may skip (rendering behind real time) for a run's failure to be rig's
LAB_SKIPPED_BOUND = 0.2


def _skip_if_the_lab_fell_behind(lab_output: str) -> None:
    """Skip (stating the figures) when the lab could not render its cameras in real time on this machine: a
    run whose still recordings lost that many frames measures the host's load, not rig (in CI 14, three test
    workers on 2 cores, the lab skipped 41 % and 38 % of its frames and calibrate had 3 frames to average)."""
    counts = re.findall(r"lab camera (\w+): (\d+) frames sent, (\d+) skipped", lab_output)
    behind = {name: int(skipped) / (int(sent) + int(skipped)) for name, sent, skipped in counts
              if int(sent) + int(skipped) > 0}
    if behind and max(behind.values()) > LAB_SKIPPED_BOUND:
        pytest.skip("the lab could not render in real time on this loaded machine (frames skipped: "
                    + ", ".join(f"{name} {share:.0%}" for name, share in behind.items()) + ")")


def _check_fiducial_dating(run_dir: Path, config: dict[str, Any]) -> None:
    """The sweep dated by the fiducial: u from its restart's bracket, the line time corrected to the truth."""
    (clock,) = (c for c in json.loads((run_dir / "certificate.json").read_text())["criteria"]
                if c["id"] == "controller_clock_u_ms")
    print("controller clock:", clock["status"], clock["value"], "ms;", clock["note"])
    assert clock["status"] in ("PASS", "FAIL") and "timing fiducial" in clock["note"], clock
    starts = [json.loads(line)["data"] for line in (run_dir / "record.jsonl").read_text().splitlines()
              if '"stream":"fiducial"' in line and '"action":"start"' in line and '"segment":"sweep"' in line]
    u_bracket_s = (starts[-1]["t_confirmed_s"] - starts[-1]["t_sent_s"]) / math.sqrt(12.0)
    assert u_bracket_s <= clock["value"] * 1e-3 <= u_bracket_s + 1e-5  # the fit's share: a few µs at most
    found = re.search(r"line time corrected by ([-+\d.]+) ± ([\d.]+) ns/row", clock["note"])
    assert found, clock["note"]
    timing = json.loads((run_dir / "timing.json").read_text())
    camera = config["cameras"][timing["reference_camera"]]
    line_truth_s = 0.9 / camera["fps"] / camera["resolution_px"][1]
    corrected_s = timing["line_time_s"][timing["reference_camera"]] + float(found.group(1)) * 1e-9
    print(f"fiducial's line time {corrected_s * 1e6:.4f} µs (truth {line_truth_s * 1e6:.4f})")
    assert abs(corrected_s - line_truth_s) <= 5 * float(found.group(2)) * 1e-9

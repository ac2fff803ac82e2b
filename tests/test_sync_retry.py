"""The sync step's retries when the rotor recording lost frames, end to end on the built-in simulated rig
(``rig run sync``: calibrate → sync, through the real command).

The twin's cameras lose frames by configuration (``[sim.cameras.<name>] drop_probability``, optionally only
for sensor frames starting within ``drop_window_s`` of world time): each lost frame leaves a gap in the
camera's time stamps, as a camera or a loaded host skipping frames does. On the instant virtual clock the
run's world times are fixed by the plan (the first sync recording spans ≈ 9.4–12.4 s, the second — after
the stop, a spin-up and the rotor's ramp — ≈ 22.5–28.5 s), so a window ending at 16 s loses frames in the
first recording only, with seconds of margin either side. Steady loss of a fifth of the frames is bridged
(short gaps); the retries are for heavier loss (45 %, the configuration's largest).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from rig.cli import main
from rig.config.rig_config import load_config
from rig.config.schema import ConfigError
from rig.record.catalogue import run_folders
from rig.record.writer import load_run
from tests.certify_support import true_offset_s, twin_cameras, write_config

STEADY_LOSS = 0.2  # ≈ 20 % of the frames in short gaps: bridged, the sync passes on its first recording
DROP_PROBABILITY = 0.45  # the configuration's largest: ≈ half the frames, too few runs left to bridge
FIRST_ONLY_WINDOW_S = (0.0, 16.0)


def _lossy_config(tmp_path: Path, window_s: tuple[float, float] | None,
                  probability: float = DROP_PROBABILITY) -> Path:
    config = write_config(tmp_path)
    loss = f"drop_probability = {probability}"
    if window_s is not None:
        loss += f"\ndrop_window_s = [{window_s[0]}, {window_s[1]}]"
    text, n = re.subn(r"^(\[sim\.cameras\.(?:left|right)\])$", rf"\1\n{loss}", config.read_text(), flags=re.M)
    assert n == 2
    config.write_text(text)
    return config


def _rotations(run_dir: Path) -> list[tuple[str, float]]:
    rotation = load_run(run_dir).events["rotation"]
    return [(str(s), float(b - a)) for s, a, b in rotation[["segment", "t_start_s", "t_stop_s"]].to_numpy()]


def test_the_drop_window_is_checked_in_the_configuration(tmp_path: Path) -> None:
    config = _lossy_config(tmp_path, (16.0, 2.0))
    with pytest.raises(ConfigError, match=r"drop_window_s.*\[16.0, 2.0\]; allowed: \[start_s, stop_s\] with "
                                          r"start_s < stop_s"):
        load_config(config)


@pytest.mark.slow  # runs the calibration first (≈ 13 CPU-s)
def test_a_first_recording_that_lost_frames_is_followed_by_a_longer_one_that_passes(tmp_path: Path) -> None:
    config = _lossy_config(tmp_path, FIRST_ONLY_WINDOW_S)
    code = main(["run", "sync", "--config", str(config), "--set", "record_s=3.0"])
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert code == 0 and run.stop is not None and run.stop["exit_status"] == "success", run.stop
    rotations = _rotations(run_dir)
    assert [s for s, _ in rotations] == ["sync", "sync-2"], rotations
    assert rotations[0][1] == pytest.approx(3.0, abs=0.1) and rotations[1][1] == pytest.approx(6.0, abs=0.1)
    # the first recording lay inside the lossy window, the second after it
    (first, second) = load_run(run_dir).events["rotation"][["t_start_s", "t_stop_s"]].to_numpy()
    assert first[1] < FIRST_ONLY_WINDOW_S[1] <= second[0], (first, second)
    warnings = [line for line in (run_dir / "rig.log").read_text().splitlines()
                if "sync: the 3.0-s rotor recording lost frames" in line]
    assert len(warnings) == 1 and warnings[0].endswith("; recording again (2 of 3)"), warnings
    assert "camera 'left':" in warnings[0] and "camera 'right':" in warnings[0]
    timing = json.loads((run_dir / "timing.json").read_text())
    assert timing["search"]["attempt"] == 2
    assert "sync" in run.steps_completed


@pytest.mark.slow  # runs the calibration first (≈ 10–30 CPU-s)
def test_every_attempt_losing_frames_ends_in_a_fault_naming_each_cameras_loss(tmp_path: Path) -> None:
    config = _lossy_config(tmp_path, None)
    code = main(["run", "sync", "--config", str(config), "--set", "record_s=1.5", "--set", "attempts=2"])
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert code == 3, run.stop
    stop = run.stop
    assert stop is not None
    assert stop["exit_status"] == "fail" and stop["outcome"] == "fault", stop
    reason = stop["reason"]
    assert reason.startswith("LostFramesError: the 3.0-s rotor recording lost frames"), reason  # the last
    for camera in ("left", "right"):
        found = re.search(rf"camera '{camera}': (\d+) of (\d+) frames missing \((\d+)%\): (\d+) in (\d+) gap",
                          reason)
        assert found is not None, reason
        missing, total, pct, inside, gaps = map(int, found.groups())
        # ≈ 180 frames at 45 %: the binomial's 81 ± 6.7, within 4 σ
        binomial_sd = (total * DROP_PROBABILITY * (1 - DROP_PROBABILITY)) ** 0.5
        assert total == pytest.approx(180, abs=2), reason
        assert abs(missing - DROP_PROBABILITY * total) <= 4 * binomial_sd, reason
        assert inside <= missing and 0 < gaps <= inside and abs(pct - 100 * missing / total) <= 0.5
    assert [s for s, _ in _rotations(run_dir)] == ["sync", "sync-2"]
    assert not (run_dir / "timing.json").exists()
    # every device safe, as read back over its protocol after the runner's safe-state actions
    assert stop["safe_state_failures"] == []
    state = stop["safe_state"]
    for axis in ("exciter", "rotor"):
        assert state[axis]["setpoint_hz"] == 0.0 and abs(state[axis]["frequency_hz"]) <= 0.02, state
        assert state[axis]["status"] in ("stopped", "decelerating"), state
    assert state["robot"]["moved_mm"] == 0.0, state
    assert state["generator"] == {"output_on": False}, state
    assert state["left"] == {"recording": False} and state["right"] == {"recording": False}, state


@pytest.mark.slow  # runs the calibration first (≈ 13 CPU-s)
def test_steady_loss_of_a_fifth_of_the_frames_is_bridged_and_passes_on_the_first_recording(
        tmp_path: Path) -> None:
    """Both cameras lose 20 % of their frames at random in every recording: the joint sync bridges the short
    gaps and passes on the first recording, its offset within the joint fit's k·u of the cameras' hidden
    clocks (k = 10 + 1 µs as in the certify e2e test: the estimator's known row-distortion bias on this rig is
    ≈ 5 u, with or without lost frames)."""
    config = _lossy_config(tmp_path, None, STEADY_LOSS)
    code = main(["run", "sync", "--config", str(config), "--set", "record_s=3.0"])
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert code == 0 and run.stop is not None and run.stop["exit_status"] == "success", run.stop
    assert [s for s, _ in _rotations(run_dir)] == ["sync"]
    timing = json.loads((run_dir / "timing.json").read_text())
    assert timing["search"]["attempt"] == 1
    gaps = timing["details"]["gaps_b"]
    assert gaps["bridged"] >= 10 and gaps["frames_missing"] >= 20, gaps  # ≈ 36 frames lost of 180
    search = timing["search"]
    assert search["frame_gaps"].startswith(f"camera 'right': {gaps['gaps']} gap(s)"), search
    cams = twin_cameras(config)
    ref, other = timing["reference_camera"], "right" if timing["reference_camera"] == "left" else "left"
    truth_s = true_offset_s(cams[ref], cams[other], timing["epoch_s"][other])
    u_s = timing["uncertainty"]["offset_s"][other]
    offset_s = timing["offset_s"][other]
    assert abs(offset_s - truth_s) <= 10 * u_s + 1e-6, (offset_s, truth_s, u_s)


def test_the_dry_run_plan_states_the_recordings_sync_may_repeat(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path)
    assert main(["run", "sync", "--dry-run", "--config", str(config), "--set", "record_s=2.0",
                 "--set", "attempts=4"]) == 0
    (line,) = [x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("sync ")]
    # each recording spins up and stops at the rotor's ramp (2 × 10 Hz / 2 Hz/s = 10 s): 2+4+6+8 + 4 × 10
    assert line.split()[1:3] == ["≈", "12"], line  # the duration stays one recording's
    assert line.endswith("if the cameras lose frames: up to 4 recordings (sync.attempts; the n-th n × 2 s), "
                         "≈ 60 s at most"), line
    assert main(["run", "sync", "--dry-run", "--config", str(config), "--set", "attempts=1"]) == 0
    assert "lose frames" not in capsys.readouterr().out  # one recording: nothing may repeat

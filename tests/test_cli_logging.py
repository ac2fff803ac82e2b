"""Console output of ``rig``: third-party log noise (FFmpeg/OpenCV through their own stderr, pymodbus and
other Python loggers) hidden at the default verbosity and shown with ``-v``; a bad-input message printed once.
Subprocesses where the native libraries read their environment when first loaded."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from rig.cli import main

ROOT = Path(__file__).resolve().parents[1]
TARGET = textwrap.dedent("""\
    [plate]
    rows = 2
    cols = 2

    [[positions]]
    markers_mm = [[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]]

    [[positions]]
    markers_mm = [[0, 0, 5], [10, 0, 5], [0, 10, 5], [10, 10, 5]]
""")


def _rig(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("OPENCV_", "DASK_"))}
    clean["PYTHONPATH"] = str(ROOT)
    return subprocess.run([sys.executable, "-m", "rig.cli", *args], cwd=cwd, env={**clean, **(env or {})},
                          capture_output=True, text=True, timeout=600, check=False)


def _cut_video(path: Path) -> None:
    """An MP4 cut short before its index (``moov``): FFmpeg complains on its own stderr."""
    whole = path.with_name("whole.mp4")
    writer = cv2.VideoWriter(str(whole), cv2.VideoWriter.fourcc(*"mp4v"), 30.0, (64, 48))
    for i in range(30):
        writer.write(np.full((48, 64, 3), 5 * i, np.uint8))
    writer.release()
    data = whole.read_bytes()
    assert b"moov" in data[len(data) // 2:]  # written at the end: cutting the file loses it
    path.write_bytes(data[: len(data) // 2])


@pytest.mark.parametrize("verbose", [False, True])
def test_ffmpeg_and_opencv_noise_only_with_v(tmp_path: Path, verbose: bool) -> None:
    _cut_video(tmp_path / "cut.mp4")
    (tmp_path / "target.toml").write_text(TARGET)
    done = _rig(*(["-v"] if verbose else []), "calibrate", "cut.mp4", "cut.mp4", "--target", "target.toml",
                "--out", "calibration.json", cwd=tmp_path)
    assert done.returncode == 4
    ours = [line for line in done.stderr.splitlines() if line.startswith("rig calibrate: cut.mp4: ")]
    assert len(ours) == 1 and "no decoder can open it" in ours[0]
    if verbose:
        assert "moov atom not found" in done.stderr  # FFmpeg's own line, through OpenCV
    else:
        assert done.stderr.splitlines() == ours


def test_a_variable_the_user_set_is_kept(tmp_path: Path) -> None:
    _cut_video(tmp_path / "cut.mp4")
    (tmp_path / "target.toml").write_text(TARGET)
    done = _rig("calibrate", "cut.mp4", "cut.mp4", "--target", "target.toml", cwd=tmp_path,
                env={"OPENCV_LOG_LEVEL": "WARNING"})
    assert done.returncode == 4 and "[ WARN:" in done.stderr and "moov atom" not in done.stderr


LOGS = textwrap.dedent("""\
    import logging, sys
    from rig.cli_logging import configure_logging
    configure_logging(int(sys.argv[1]), sys.stderr)
    for name in sys.argv[2:]:
        logging.getLogger(name).warning("from %s", name)
        logging.getLogger(name).info("info from %s", name)
""")


LOGGERS = ("pymodbus.logging", "matplotlib.font_manager", "asyncio", "rig.run.runner", "drivers.exciter")


@pytest.mark.parametrize(("verbose", "shown"), [
    (0, ["WARNING rig.run.runner: from rig.run.runner", "WARNING drivers.exciter: from drivers.exciter"]),
    (1, [f"{level} {name}: {text}from {name}" for name in LOGGERS
         for level, text in (("WARNING", ""), ("INFO", "info "))]),
])
def test_python_loggers_of_other_libraries_only_with_v(verbose: int, shown: list[str]) -> None:
    done = subprocess.run([sys.executable, "-c", LOGS, str(verbose), *LOGGERS], capture_output=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, text=True, timeout=120, check=True)
    assert done.stderr.splitlines() == shown


def test_a_bad_parameter_of_a_run_is_printed_once(tmp_path: Path) -> None:
    done = _rig("run", "sync", "--set", "nosuch=1", "--no-dashboard", "--runs-dir", str(tmp_path),
                cwd=tmp_path)
    assert done.returncode == 4
    assert done.stderr.count("sync.nosuch: unknown field") == 1, done.stderr


def test_two_equal_camera_names_are_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", "a.mp4", "b.mp4", "--target", "t.toml", "--names", "cam", "cam"]) == 4
    err = capsys.readouterr().err
    assert err == "rig: bad input: --names: cam cam: give two different camera names\n"


DASK = textwrap.dedent("""\
    import logging, sys
    from rig.cli_logging import configure_logging
    configure_logging(int(sys.argv[1]), sys.stderr)
    import distributed  # its own stderr handler, configured from dask's config when imported
    print(logging.getLevelName(logging.getLogger("distributed").level))
""")


@pytest.mark.parametrize(("verbose", "level"), [(0, "ERROR"), (1, "INFO")])
def test_dask_distributed_logs_errors_only_by_default(verbose: int, level: str) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    done = subprocess.run([sys.executable, "-c", DASK, str(verbose)], env={**env, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=300, check=True)
    assert done.stdout.strip() == level

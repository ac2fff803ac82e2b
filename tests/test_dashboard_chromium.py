"""The live dashboard of ``rig certify`` on the simulated rig, seen in headless Chromium (DevTools protocol):
the page fills in as the run proceeds (steps, plots that grow, camera frames, device states), screenshots
at several phases, and its Abort button stops the run with exit 2 and every device safe.

``RIG_UPDATE_DOCS=1`` also copies the screenshots to ``docs/dashboard/`` (the series the README shows).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rig.record.writer import load_run
from tests.cdp_client import Browser
from tests.certify_support import write_config
from tests.test_reports_html_chromium import _find_chromium

pytestmark = [pytest.mark.chromium, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[1]

# the page's state as the test reads it (the same DOM the operator sees)
PAGE_STATE = """!document.getElementById("step-text") ? "null" : JSON.stringify({
  version: Number(document.body.dataset.version),
  step: document.getElementById('step-text').textContent,
  steps: [...document.querySelectorAll('#steps span')].map(s => s.textContent + ':' + s.className),
  arm: Number(document.getElementById('plot-arm').dataset.points),
  exciter: Number(document.getElementById('plot-exciter').dataset.points),
  rotor: Number(document.getElementById('plot-rotor').dataset.points),
  arm_error: Number(document.getElementById('plot-arm-error').dataset.points),
  exciter_vs_f: Number(document.getElementById('plot-exciter-lag').dataset.points),
  rotor_phase: Number(document.getElementById('plot-rotor-phase').dataset.points),
  rotor_cameras: Number(document.getElementById('plot-rotor-phase-cameras').dataset.points),
  sweep_amplitude: Number(document.getElementById('plot-sweep-amplitude').dataset.points),
  live_stereo: document.getElementById('live-stereo-status').textContent,
  cameras: [...document.querySelectorAll('#cameras img')].filter(i => Number(i.dataset.shown) > 0).length,
  devices: document.getElementById('devices').textContent,
  banner: getComputedStyle(document.getElementById('sim-banner')).display,
  remaining: document.getElementById('remaining').textContent,
  stop: document.getElementById('stop').textContent,
  status: document.getElementById('status').textContent,
})"""


@pytest.fixture(scope="module")
def chromium() -> str:
    path = _find_chromium()
    if not path:
        pytest.skip("no Chromium on PATH; `make browser` installs it as root (Debian package chromium)")
    return path


def _wait(page: Browser, proc: subprocess.Popen, what: str, ok: Callable[[dict[str, Any]], bool],
          timeout_s: float = 400.0) -> dict[str, Any]:
    import json

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        state = json.loads(page.evaluate(PAGE_STATE))  # null until the page has loaded
        if state is not None and ok(state):
            return state
        assert proc.poll() is None, f"the run ended while waiting for {what}"
        time.sleep(0.2)
    raise AssertionError(f"the page never showed {what}")


def _shot(page: Browser, tmp_path: Path, name: str) -> np.ndarray:
    import cv2

    path = tmp_path / f"{name}.png"
    page.screenshot(path)
    if os.environ.get("RIG_UPDATE_DOCS") == "1":
        (ROOT / "docs" / "dashboard").mkdir(exist_ok=True)
        shutil.copy(path, ROOT / "docs" / "dashboard" / path.name)
    image = cv2.imread(str(path))
    assert image is not None and image.std() > 10
    return image


def _has_colour(image: np.ndarray, bgr: tuple[int, int, int], min_pixels: int) -> bool:
    return int(np.all(np.abs(image.astype(int) - bgr) <= 8, axis=2).sum()) >= min_pixels


@pytest.mark.timeout(1500)
def test_dashboard_follows_certify_and_its_abort_stops_it_safely(chromium: str, tmp_path: Path) -> None:
    # patient: at load ≈ 20 a healthy exciter's pty went 2 × 1 s unanswered (an interlock not tested here)
    config = write_config(tmp_path, patient=True)
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "certify", "--config", str(config),
                             "--set", 'preset="fast"', "--set", "sweep_duration_s=240",
                             "--set", "accuracy_grid_points=0", "--set", "accuracy_cycles=0",
                             "--set", "figures=false", "--dashboard-port", "0"],
                            cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err_lines: list[str] = []
    reader = threading.Thread(target=lambda: err_lines.extend(proc.stderr), daemon=True)  # type: ignore[arg-type]
    reader.start()
    try:
        deadline = time.monotonic() + 300
        url = None
        while url is None and time.monotonic() < deadline:
            found = [re.search(r"dashboard at (http://127\.0\.0\.1:\d+/)", ln) for ln in list(err_lines)]
            url = next((m.group(1) for m in found if m), None)
            assert proc.poll() is None or url, "".join(err_lines)
            time.sleep(0.05)
        assert url, "no dashboard URL printed"
        # tall enough for the whole page: the screenshots show every plot the test checks
        with Browser(chromium, url, tmp_path / "profile", window=(1280, 1560)) as page:
            first = _wait(page, proc, "the plan's steps", lambda s: len(s["steps"]) >= 4 and s["version"] > 0)
            assert first["banner"] == "block"  # the simulated rig says so
            assert [s.split(":")[0] for s in first["steps"]][:2] == ["calibrate", "sync"]
            calibrating = _wait(page, proc, "the arm's moves", lambda s: s["arm"] >= 2)
            _shot(page, tmp_path, "1-calibrate")
            assert calibrating["arm_error"] >= 1  # the arm's own position error, per move
            syncing = _wait(page, proc, "the rotor's frequencies, its phase (drive and cameras), a frame",
                            lambda s: s["rotor"] >= 3 and s["rotor_phase"] >= 3 and s["cameras"] >= 1
                            and s["rotor_cameras"] >= 10)
            _shot(page, tmp_path, "2-sync")
            assert "rev/s" in syncing["live_stereo"], syncing["live_stereo"]  # the rotor seen turning
            sweeping = _wait(page, proc, "the sweep", lambda s: s["exciter"] >= 10 and "sweep" in s["step"])
            later = _wait(page, proc, "the sweep's plots growing (the live stereo amplitude error too)",
                          lambda s: s["exciter"] > sweeping["exciter"] + 5
                          and s["exciter_vs_f"] > sweeping["exciter_vs_f"] + 5
                          and s["sweep_amplitude"] > sweeping["sweep_amplitude"] + 2)
            assert "moving markers" in later["live_stereo"], later["live_stereo"]
            image = _shot(page, tmp_path, "3-sweep")
            assert calibrating["arm"] <= syncing["arm"] and later["cameras"] == 2
            assert "exciter" in later["devices"] and "frequency_hz" in later["devices"]
            assert "time remaining" in later["remaining"] and "—" not in later["remaining"]
            assert _has_colour(image, (45, 38, 192), 500)  # the red Abort button (#c0262d) is on screen
            page.evaluate("document.getElementById('abort').click()")
            stopped = _wait(page, proc, "the stop", lambda s: "run ended" in s["stop"], timeout_s=300)
            image = _shot(page, tmp_path, "4-aborted")
            assert "aborted" in stopped["stop"] and "exit 2" in stopped["stop"]
            assert _has_colour(image, (34, 28, 155), 500)  # the stop banner (#9b1c22)
        code = proc.wait(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
        reader.join(timeout=10)
    assert code == 2, "".join(err_lines)
    (run_dir,) = [p for p in (tmp_path / "runs").iterdir() if p.is_dir()]  # and the catalogue's index
    run = load_run(run_dir)
    assert run.stop["exit_status"] == "abort" and run.stop["reason"] == "aborted by the operator (dashboard)"
    assert run.stop["safe_state_failures"] == []
    state = run.stop["safe_state"]
    for axis in ("exciter", "rotor"):
        assert state[axis]["setpoint_hz"] == 0.0 and abs(state[axis]["frequency_hz"]) <= 0.02, state
    assert state["robot"]["moved_mm"] == 0.0, state
    assert state["generator"] == {"output_on": False}, state
    done = [d["name"] for d in run.documents if d["type"] == "step" and d["status"] == "done"]
    assert "sweep" not in done


@pytest.mark.timeout(600)
def test_preview_page_shows_both_cameras_and_the_hints_and_abort_ends_it(chromium: str,
                                                                           tmp_path: Path) -> None:
    import io
    import json

    from rig.config.rig_config import load_config
    from rig.preview import run_preview

    config = load_config(write_config(tmp_path))
    printed = io.StringIO()
    result: dict[str, Any] = {}
    worker = threading.Thread(target=lambda: result.update(state=run_preview(config, interval_s=0.3,
                                                                              stream=printed)), daemon=True)
    worker.start()
    deadline = time.monotonic() + 300
    while "http://" not in printed.getvalue() and time.monotonic() < deadline:
        assert worker.is_alive(), "the preview ended early"
        time.sleep(0.05)
    url = re.search(r"(http://127\.0\.0\.1:\d+/)", printed.getvalue()).group(1)
    hints_js = "JSON.stringify([...document.querySelectorAll('#hints li')].map(li => li.className + ' ' + " \
               "li.textContent).concat([String([...document.querySelectorAll('#cameras img')]" \
               ".filter(i => i.naturalWidth > 0).length)]))"
    with Browser(chromium, url, tmp_path / "profile") as page:
        shown: list[str] = []
        while time.monotonic() < deadline:
            shown = json.loads(page.evaluate(f"document.getElementById('hints') ? {hints_js} : '[]'"))
            if shown and shown[-1] == "2" and len(shown) >= 3:
                break
            time.sleep(0.2)
        else:
            raise AssertionError(f"the preview page never showed both cameras and their hints: {shown}")
        _shot(page, tmp_path, "5-preview")
        assert any(h.startswith("ok left:") and "markers" in h for h in shown), shown
        assert any(h.startswith("ok right:") for h in shown), shown
        page.evaluate("document.getElementById('abort').click()")
        worker.join(timeout=120)
    assert not worker.is_alive() and result["state"].fields["hints"]["cameras"]

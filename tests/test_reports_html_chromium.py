"""report.html opens in headless Chromium without errors, and its screenshot shows the verdict.

``make test`` installs Chromium in its own announced step when it is missing and can be installed (the
Makefile's ``browser`` target); without it the test is skipped with the reason. It installs nothing.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import reports_synth as synth

from reports.build import build_report
from reports.scope import Scope

NO_FIGURES = Scope(figures=False)  # the figures' own tests draw them

pytestmark = pytest.mark.chromium

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
PAGE_ERRORS = ("Failed to load resource", "Uncaught", "net::ERR_", "Not allowed to load local resource")


def _find_chromium() -> str | None:
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope="module")
def chromium() -> str:
    path = _find_chromium()
    if not path:
        pytest.skip(f"no Chromium on PATH (looked for {', '.join(CHROMIUM_NAMES)}); `make browser` installs "
                    "it as root (Debian package chromium)")
    return path


def _screenshot(chromium: str, html: Path, out_dir: Path) -> tuple[np.ndarray, str]:
    png = out_dir / "shot.png"
    cmd = [
        chromium,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--enable-logging=stderr",
        f"--user-data-dir={out_dir / 'profile'}",
        f"--screenshot={png}",
        "--window-size=1280,2000",
        html.resolve().as_uri(),
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    import cv2

    image = cv2.imread(str(png))
    assert image is not None, f"no screenshot written; stderr: {done.stderr[-1000:]}"
    return image, done.stderr


@pytest.mark.timeout(1200)
def test_report_renders_with_the_verdict_on_top(chromium: str, synth_report, tmp_path: Path) -> None:
    # the synthetic run's full report (figures included), built once per session (tests/conftest.py)
    image, log = _screenshot(chromium, synth_report.report_html, tmp_path)
    assert image.shape[:2] == (2000, 1280)
    page_errors = [ln for ln in log.splitlines() if any(e in ln for e in PAGE_ERRORS)]
    assert page_errors == []
    # not blank: many distinct colours and real contrast
    assert image.std() > 10
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 200
    # the PASS banner (#1e7b4a, BGR 74,123,30) fills a block in the first screenful, above everything else
    banner = np.all(np.abs(image.astype(int) - [74, 123, 30]) <= 6, axis=2)
    rows = np.nonzero(banner.sum(axis=1) > 600)[0]
    assert len(rows) > 60, "the verdict banner is not visible at the top of the page"
    assert rows.min() < 300


def test_a_failing_setup_shows_a_red_banner(chromium: str, tmp_path: Path) -> None:
    run = synth.write_run(tmp_path / "run_fail")
    res = build_report(run, sync="linear", analysis=synth.fake_analyse, scope=NO_FIGURES)
    assert res.result == "FAIL"
    image, _ = _screenshot(chromium, res.report_html, tmp_path)
    banner = np.all(np.abs(image.astype(int) - [30, 38, 179]) <= 6, axis=2)  # #b3261e
    assert (banner.sum(axis=1) > 600).sum() > 60

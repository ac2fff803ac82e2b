"""The controller-clock relation of the analysis against the twin's exact exposure instants.

Every observation's analysed time (row-corrected reference-clock time + the segment's controller offset)
is compared with the twin's truth: the middle of the exposure of the marker's image row in world time
(= controller time on the simulated rig), ``SimCamera.row_time_true_s``. The camera ``start`` events are
written as rig/run/acquire.py does (``t_s`` = start, first frame whose row 0 starts at or after it).

Tolerance from the stated uncertainty: every start event bounds the offset to ±T/2, the analysis states the
midpoint of the interval all events allow and u = width/√12, so the truth lies within ±√3·u of it — also
when the start events sit on a controller grid commensurate with the frame period (25 ms = 1.5 frames, as
the simulated rig's procedures start recordings), where averaging the events' offsets is biased by up to
T/2 and a T/√(12n) uncertainty would be far too small; the row-corrected times themselves are exact here
(true timing).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rig.analysis.analyse import Analysis, analyse
from rig.analysis.sync_tracks import row_corrected_times
from rig.record.writer import read_observations
from tests.analysis_twin import twin, write_run

# recordings of 0.3 s at start times whose phase against the 60 fps frame grid is irregular
STARTS_S = [1.0 + 0.731 * k + 0.0137 * (k * k % 11) for k in range(24)]
# recordings started on a 25 ms controller grid: only a few phases against the frame grid
GRID_STARTS_S = [1.0 + 0.725 * k for k in range(24)]


def _run(tmp_path, exposure_s: float, starts_s: list[float] = STARTS_S):
    over = {"exposure_s": exposure_s}
    tw = twin("sweep_column", t_start_s=0.0, t_stop_s=0.0, sigma_px=0.0, left_overrides=over,
              right_overrides=over)
    rig = {"cameras": {c: {"fps": 60.0, "exposure_s": exposure_s} for c in ("left", "right")}}
    segments = [(f"rec{k}", t0, t0 + 0.3) for k, t0 in enumerate(starts_s)]
    return tw, write_run(tmp_path / "runs", tw, segments, rig=rig)


@pytest.fixture(scope="module")
def analysed(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., tuple[Any, Path, Analysis]]:
    """``(exposure_s, starts_s)`` → (twin, run folder, its analysis), each written and analysed once for the
    module: the tests only read them (the exposure test compares the irregular runs the first test checks)."""
    made: dict[tuple[float, tuple[float, ...]], tuple[Any, Path, Analysis]] = {}

    def get(exposure_s: float, starts_s: list[float] = STARTS_S) -> tuple[Any, Path, Analysis]:
        key = (exposure_s, tuple(starts_s))
        if key not in made:
            tw, run_dir = _run(tmp_path_factory.mktemp("clock"), exposure_s, starts_s)
            made[key] = (tw, run_dir, analyse(run_dir))
        return made[key]

    return get


@pytest.mark.parametrize("starts_s", [STARTS_S, GRID_STARTS_S], ids=["irregular", "grid"])
@pytest.mark.parametrize("exposure_s", [1 / 6000, 1 / 120])
def test_observation_times_match_the_twin_within_the_stated_uncertainty(analysed, exposure_s, starts_s):
    tw, run_dir, a = analysed(exposure_s, starts_s)
    assert len(a.clock) == len(starts_s)
    # the truth lies in the events' interval (half-width √3·u_interval) and off the constant by the
    # unresolved drift (≤ √3·u_drift): |bias| ≤ √3·(u_interval + u_drift) ≤ √6·u < 3u
    clock = a.clock.set_index("segment")
    errors = {}
    for cam in (tw.left, tw.right):
        obs = read_observations(run_dir, cam.name)
        offset_s = clock.loc[obs["segment"], "offset_s"].to_numpy()
        t_ctrl = row_corrected_times(obs, tw.timing, cam.name) + offset_s
        truth = np.array([cam.row_time_true_s(int(i), float(v))
                          for i, v in zip(obs["frame_index"], obs["v_px"], strict=True)])
        for seg, e in zip(obs["segment"], t_ctrl - truth, strict=True):
            errors.setdefault(seg, []).append(e)
    assert set(errors) == set(clock.index)
    for seg, e in errors.items():
        # within a 0.3 s recording the error is one constant but for the reference clock's rate error
        # (12 ppm · 0.3 s = 3.6 µs)
        assert np.ptp(e) < 1e-5, (seg, np.ptp(e))
        bias, u = float(np.mean(e)), float(clock.loc[seg, "u_offset_s"])
        assert abs(bias) <= 3 * u, (seg, bias, u)


def test_the_exposure_midpoint_enters_the_offset(analysed):
    """Long exposure, same start events: the offset moves by exactly half the exposure difference."""
    short, long_ = analysed(1 / 6000)[2].clock, analysed(1 / 120)[2].clock
    # the true timing (timing.json) refers to mid-exposure, so the twin's offsets differ by Δe/2 on the
    # reference clock; the events are identical (same frame grid): the estimate must follow that difference
    tw_s, tw_l = (twin("sweep_column", t_start_s=0.0, t_stop_s=0.0, sigma_px=0.0,
                       left_overrides={"exposure_s": e}, right_overrides={"exposure_s": e})
                  for e in (1 / 6000, 1 / 120))
    t_ref = 12.0
    true_shift = float(tw_l.world_time(np.array([t_ref]))[0] - tw_s.world_time(np.array([t_ref]))[0])
    assert true_shift == pytest.approx(0.5 * (1 / 120 - 1 / 6000), rel=1e-9)
    np.testing.assert_allclose(long_["offset_s"] - short["offset_s"], true_shift, rtol=0, atol=1e-9)

"""Row-corrected times: the timing model of rig.stereo.timing gives the twin's exact exposure instants."""

from __future__ import annotations

import numpy as np
import pytest
from analysis_twin import twin

from rig.analysis.errors import AnalysisError
from rig.analysis.sync_tracks import row_corrected_times


def test_row_corrected_times_are_the_exact_exposure_instants():
    """Both cameras' observations, put on the reference clock and mapped to world time, land on the twin's
    own mid-exposure instant of the marker's row (clock error, start offset, drift and line time all in)."""
    tw = twin("rotor", setup=lambda w: w.rotor.set_frequency(0.0, 3.0), t_start_s=5.0, t_stop_s=7.0,
              sigma_px=0.0)
    for cam in ("left", "right"):
        obs = tw.observations[cam]
        t_world = tw.world_time(row_corrected_times(obs, tw.timing, cam))
        assert np.max(np.abs(t_world - obs["t_true_s"].to_numpy())) < 1e-9
    # the dict form of timing.json gives the same instants
    obs = tw.observations["right"]
    assert np.array_equal(row_corrected_times(obs, tw.timing.to_dict(), "right"),
                          row_corrected_times(obs, tw.timing, "right"))


def test_a_camera_missing_from_the_timing_says_what_to_run():
    tw = twin("rotor", t_start_s=1.0, t_stop_s=1.2, sigma_px=0.0)
    with pytest.raises(AnalysisError, match=r"'middle'.*rig run sync"):
        row_corrected_times(tw.observations["left"], tw.timing, "middle")


def test_missing_row_column_is_named():
    tw = twin("rotor", t_start_s=1.0, t_stop_s=1.2, sigma_px=0.0)
    with pytest.raises(AnalysisError, match="v_px"):
        row_corrected_times(tw.observations["left"].drop(columns="v_px"), tw.timing, "left")

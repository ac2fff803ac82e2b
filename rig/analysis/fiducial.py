"""A camera's clock against the controller's from the timing fiducial's recorded rows (``[fiducial]``).

Inputs, as a recording provides them: the ``fiducial`` start event (the controller's clock just before it
sent ``PHASe:SYNChronize`` and just after ``*OPC?`` confirmed it, and the sync frequency), the LED's
rows of one camera (frame index, the frame's time stamp, row, mean brightness of the configured region in
that row), the camera's rolling-shutter line time and exposure, and the start-event relation of the same
recording (controller − camera clock, ±½ frame) as the prior that picks which edge is which.

The sync edges in the controller's clock are those of a square wave from phase 0 at the midpoint of the
command's bracket, each with the bracket's rectangular standard uncertainty (width/√12): the part of the
offset's uncertainty the camera cannot reduce. :func:`rig.stereo.fiducial.fit_fiducial_clock` does the
rest. Without a fiducial the start-event method of :mod:`rig.analysis.analyse` remains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from rig.analysis.errors import AnalysisError
from rig.stereo.errors import StereoError
from rig.stereo.fiducial import FiducialClock, RowSamples, fit_fiducial_clock, square_wave_edges

__all__ = ["ROW_COLUMNS", "FiducialStart", "camera_clock", "clock_row"]

ROW_COLUMNS = ("frame_index", "timestamp_s", "row_px", "brightness_dn")
METHOD = "fiducial"


@dataclass(frozen=True)
class FiducialStart:
    """The fiducial's start as the controller recorded it: ``t_sent_s`` ≤ ``t_confirmed_s`` (controller
    clock, s) bracket the phase restart; ``frequency_hz`` of the sync square wave."""

    t_sent_s: float
    t_confirmed_s: float
    frequency_hz: float

    @classmethod
    def from_event(cls, event: dict[str, Any]) -> FiducialStart:
        """From a ``fiducial`` event of the record (fields as named here); AnalysisError naming a bad one."""
        values = {}
        for name in ("t_sent_s", "t_confirmed_s", "frequency_hz"):
            v = event.get(name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise AnalysisError(f"fiducial event: {name}={v!r} must be a finite number")
            values[name] = float(v)
        start = cls(**values)
        if start.t_confirmed_s < start.t_sent_s or start.frequency_hz <= 0:
            raise AnalysisError(f"fiducial event: need t_sent_s ≤ t_confirmed_s and frequency_hz > 0, got "
                                f"{start}")
        return start

    @property
    def origin_s(self) -> float:
        return 0.5 * (self.t_sent_s + self.t_confirmed_s)

    @property
    def u_origin_s(self) -> float:
        return (self.t_confirmed_s - self.t_sent_s) / math.sqrt(12.0)


def camera_clock(rows: pd.DataFrame, start: FiducialStart, *, line_time_s: float, exposure_s: float,
                 prior_offset_s: float, prior_half_width_s: float, rise_time_s: float) -> FiducialClock:
    """Fit controller − camera clock from one camera's LED rows (``ROW_COLUMNS``) of one recording.

    Raises AnalysisError naming what is missing, or the stereo core's reason (ambiguous prior, no edge
    seen) as an AnalysisError.
    """
    missing = [c for c in ROW_COLUMNS if c not in rows.columns]
    if missing:
        raise AnalysisError(f"fiducial rows: missing column(s) {', '.join(missing)}")
    if rows.empty:
        raise AnalysisError("fiducial rows: none recorded (is the LED region inside the image?)")
    start_s = (rows["timestamp_s"].to_numpy(float) + rows["row_px"].to_numpy(float) * line_time_s)
    order = np.argsort(start_s, kind="stable")
    samples = RowSamples(start_s[order], rows["brightness_dn"].to_numpy(float)[order], exposure_s)
    # edges over the recording mapped to the controller's clock through the prior (± its width and a frame)
    margin_s = prior_half_width_s + exposure_s + 1.0
    t0 = float(samples.start_s[0]) + prior_offset_s - margin_s
    t1 = float(samples.start_s[-1]) + prior_offset_s + margin_s
    try:
        edges = square_wave_edges(start.origin_s, start.frequency_hz, max(t0, start.origin_s), t1,
                                  u_origin_s=start.u_origin_s)
        return fit_fiducial_clock(samples, edges, prior_offset_s=prior_offset_s,
                                  prior_half_width_s=prior_half_width_s, rise_time_s=rise_time_s)
    except StereoError as exc:
        raise AnalysisError(f"fiducial: {exc}") from exc


def clock_row(camera: str, fit: FiducialClock) -> dict[str, Any]:
    """The fit as a row of the analysis's clock table: offset at ``t_ref_s`` and how it was found."""
    drift = f"rate {fit.rate * 1e6:+.3f} ± {fit.u_rate * 1e6:.3f} ppm" if fit.rate_fitted else \
        "rate not resolved (edges seen over too short a span), 0"
    return {"camera": camera, "offset_s": fit.offset_s, "u_offset_s": fit.u_offset_s, "t_ref_s": fit.t_ref_s,
            "rate": fit.rate, "method": METHOD,
            "source": f"timing fiducial: {fit.n_edges_seen} edges in {fit.n_transition_rows} rows lit "
                      f"part-way (fit ±{1e6 * fit.u_fit_s:.2f} µs; LED rise and edge knowledge included; "
                      f"{drift})"}

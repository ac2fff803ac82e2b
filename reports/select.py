"""Selecting the analysis tracks that belong to one truth event (its time window and recording segment)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from reports.errors import ReportError


def track_keys(frame: pd.DataFrame) -> pd.Series:
    """``"<segment>#<track_id>"`` per row (track ids are unique only within a segment)."""
    seg = frame["segment"].astype(str) if "segment" in frame.columns else pd.Series("", index=frame.index)
    return seg + "#" + frame["track_id"].astype(str)


def event_window(tracks: pd.DataFrame, event: dict) -> pd.DataFrame:
    """Rows of ``tracks`` inside the event's [t_start_s, t_stop_s] with a finite position, plus ``track``.

    When the event names its recording ``segment`` (the procedures write it) and the tracks have a
    ``segment`` column, only that segment's tracks are taken.
    """
    for key in ("t_start_s", "t_stop_s"):
        if key not in event or event[key] is None:
            raise ReportError(f"event: missing field '{key}'")
    t = tracks["time_s"].to_numpy(float)
    keep = (t >= float(event["t_start_s"])) & (t <= float(event["t_stop_s"]))
    segment = event.get("segment")
    if isinstance(segment, str) and "segment" in tracks.columns:
        keep &= (tracks["segment"].astype(str) == segment).to_numpy()
    xyz = tracks[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    keep &= np.all(np.isfinite(xyz), axis=1)
    sel = tracks[keep]
    return sel.assign(track=track_keys(sel))

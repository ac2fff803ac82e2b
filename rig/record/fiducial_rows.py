"""The timing fiducial's LED rows in the run folder: ``fiducial/<camera>/<segment>.<n>.parquet``, one row per
frame and image row of the LED's region; written by :mod:`rig.run.fiducial`, read by
:mod:`rig.analysis.fiducial`."""

# frame index, the frame's time stamp (s, camera clock), image row (px), mean brightness of the row (DN)
ROW_COLUMNS = ("frame_index", "timestamp_s", "row_px", "brightness_dn")
ROWS_DIR = "fiducial"  # the folder of the run folder that holds them

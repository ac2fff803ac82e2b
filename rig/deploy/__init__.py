"""Measuring structures from deployed cameras' videos: timing, markers, on-site calibration, measure,
batch."""

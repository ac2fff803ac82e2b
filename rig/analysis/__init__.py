"""Observations of a run → 2-D tracks → pairing → sync → synchronized 3-D tracks."""

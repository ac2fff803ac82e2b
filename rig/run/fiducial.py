"""The timing fiducial during a recording: start its sync square wave, keep the LED's rows, check it held.

Used by :class:`rig.run.acquire.Acquirer` when ``[fiducial]`` is configured. Before the cameras start,
:meth:`FiducialRecording.start` sets the fiducial channel's frequency with that channel's output OFF
(only the Sync connector, and with it the LED, follows its oscillator), points the Sync connector at that
channel (two-channel generator), switches sync on and restarts the phase with ``PHASe:SYNChronize;*OPC?``
(one round trip), bracketed by the controller's clock before the message and as its reply arrives and
retried while that bracket is wider than :data:`BRACKET_TARGET_S`; a ``fiducial`` event (action ``start``)
records the last bracket, the number of tries, the frequency and — when the shaker's channel is another one
and its output is on — the shaker's CW frequency, whose phase restarted at the same instant (the shaker's
phase reference, :mod:`reports.phase`). A fiducial channel whose output is on drives the shaker: its sync
follows the shaker's frequency, so the fiducial is not used for that recording (action ``unavailable``, with
the reason) and the start-event method remains. After the
recording, :meth:`FiducialRecording.finish` checks that the generator still runs the fiducial's
frequency with its output off (else the edges the controller predicts are wrong: action ``invalid``) and
writes the LED's rows of every camera to ``fiducial/<camera>/<segment>.<n>.parquet`` (atomically;
columns :data:`rig.record.fiducial_rows.ROW_COLUMNS`), named in the ``fiducial`` event (action ``rows``).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import numpy as np

from drivers.exciter.generator import ScpiGenerator
from drivers.exciter.shaker import Shaker
from rig.config.fiducial import FiducialConfig
from rig.record.atomic import atomic_path
from rig.record.fiducial_rows import ROW_COLUMNS, ROWS_DIR
from rig.run.procedure import Context

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["BRACKET_TARGET_S", "SYNC_BUDGET_S", "SYNC_TRIES", "FiducialRecording"]

# The restart's bracket (one round trip, ``PHAS:SYNC;*OPC?``) bounds the edges' date: its width/√12 is the
# controller clock's uncertainty floor. A bracket wider than the target (a host or link that stalled for that
# exchange) is retried, up to SYNC_TRIES restarts within SYNC_BUDGET_S (400 tries on `rig mock lab` never
# reached 0.1 ms, and that run's sync failed on unevenly spaced frames), and only while no shaker runs on the
# other channel (each restart jumps its phase too); the last one is recorded, whatever its width.
BRACKET_TARGET_S = 1.5e-4  # u 43 µs; from an idle process the mock's bracket was 0.12–3.9 ms, median 0.27
SYNC_TRIES = 20
SYNC_BUDGET_S = 0.5


class FiducialRecording:
    """One recording's fiducial (see the module docstring); ``regions`` camera → (x0, y0, x1, y1) px."""

    def __init__(self, ctx: Context, config: FiducialConfig) -> None:
        self.ctx, self.config = ctx, config
        self.regions: dict[str, tuple[int, int, int, int]] = {
            name: (int(r[0]), int(r[1]), int(r[2]), int(r[3])) for name, r in config.regions_px.items()}
        device = ctx.station.devices.get(config.device)
        # the generator's device is the shaker it feeds (rig.run.station); its SCPI generator drives the LED
        self.generator: ScpiGenerator | None = device.generator if isinstance(device, Shaker) else None
        gen_config = ctx.config.devices.generator
        self.two_channel = gen_config is not None and gen_config.channels == 2
        self.shaker_channel = gen_config.channel if gen_config is not None else 1
        self.running = False
        self.last_start: tuple[float, float] | None = None  # (t_sent_s, t_confirmed_s) of the last start
        self._count: dict[tuple[str, str], int] = {}

    def start(self, segment: str) -> bool:
        """Start the square wave on the fiducial's channel if that channel is idle; True when the fiducial
        runs for this recording."""
        gen, cfg, clock = self.generator, self.config, self.ctx.clock
        if gen is None:
            return self._unavailable(segment, f"devices.{cfg.device} is not connected")
        if gen.output(channel=cfg.channel):
            return self._unavailable(segment, f"devices.{cfg.device}'s channel {cfg.channel} output is on "
                                              "(it drives the shaker, so its sync follows the shaker)")
        gen.set_frequency_hz(cfg.frequency_hz, channel=cfg.channel)
        if self.two_channel:
            gen.set_sync_source(cfg.channel)
        gen.set_sync(True)
        shaker_hz = self._shaker_frequency_hz()
        most, tries, t_first = (SYNC_TRIES if shaker_hz is None else 1), 0, clock.now_s()
        while True:  # the last restart counts: retried while its bracket is wide
            tries += 1
            t_sent, t_confirmed = gen.synchronize_phase_bracketed(clock.now_s)
            if (t_confirmed - t_sent <= BRACKET_TARGET_S or tries >= most
                    or t_confirmed - t_first > SYNC_BUDGET_S):
                break
        self.ctx.event("fiducial", {"action": "start", "segment": segment, "t_sent_s": t_sent,
                                    "t_confirmed_s": t_confirmed, "tries": tries,
                                    "frequency_hz": cfg.frequency_hz,
                                    "channel": cfg.channel, "rise_time_s": cfg.rise_time_s,
                                    "shaker_channel": self.shaker_channel,
                                    "shaker_frequency_hz": shaker_hz})
        self.running = True
        self.last_start = (t_sent, t_confirmed)
        return True

    def _shaker_frequency_hz(self) -> float | None:
        """Channel 1's CW frequency when its output is on (its phase restarted with the fiducial's)."""
        gen = self.generator
        if gen is None or self.shaker_channel == self.config.channel or not gen.output():
            return None
        return float(gen.frequency_hz())

    def _unavailable(self, segment: str, reason: str) -> bool:
        self.last_start = None
        self.ctx.event("fiducial", {"action": "unavailable", "segment": segment, "reason": reason})
        self.running = False
        return False

    def finish(self, segment: str, rows: dict[str, list[tuple[int, float, np.ndarray, np.ndarray]]]) -> None:
        """Check the square wave held, then write each camera's rows and name them in an event."""
        if not self.running:
            return
        self.running = False
        gen = self.generator
        assert gen is not None
        frequency = gen.frequency_hz(channel=self.config.channel)
        output = gen.output(channel=self.config.channel)
        source_ok = not self.two_channel or gen.sync_source() == self.config.channel
        wanted = self.config.frequency_hz
        if output or not source_ok or abs(frequency - wanted) > 1e-9 * wanted:
            moved = "" if source_ok else " and the Sync connector on another channel"
            self.ctx.event("fiducial", {"action": "invalid", "segment": segment, "reason": (
                f"the generator's channel {self.config.channel} ran at {frequency:g} Hz with its output "
                f"{'on' if output else 'off'}{moved} after the recording: its sync edges were not the "
                "fiducial's")})
            return
        for camera, parts in rows.items():
            frame = _rows_frame(parts)
            n = self._count.get((camera, segment), 0)
            self._count[(camera, segment)] = n + 1
            relative = f"{ROWS_DIR}/{camera}/{_safe(segment)}.{n}.parquet"
            path = self.ctx.run_dir / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp:
                frame.to_parquet(tmp, index=False)
            self.ctx.event("fiducial", {"action": "rows", "segment": segment, "camera": camera,
                                        "file": relative, "n_frames": len(parts)})


def _safe(segment: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", segment) or "segment"


def _rows_frame(parts: list[tuple[int, float, np.ndarray, np.ndarray]]) -> pd.DataFrame:
    import pandas as pd  # here: a dry run loads this module without pandas (tests/test_cli_start.py)

    if not parts:
        return pd.DataFrame({c: pd.Series(dtype=float) for c in ROW_COLUMNS})
    return pd.DataFrame({
        "frame_index": np.concatenate([np.full(p[2].size, p[0], dtype=np.int64) for p in parts]),
        "timestamp_s": np.concatenate([np.full(p[2].size, p[1]) for p in parts]),
        "row_px": np.concatenate([p[2] for p in parts]).astype(np.int64),
        "brightness_dn": np.concatenate([p[3] for p in parts]).astype(float)})

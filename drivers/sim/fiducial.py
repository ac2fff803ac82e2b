"""The timing fiducial of the simulated rig: an LED (or LED bar) on the function generator's sync output.

The generator's sync output is a square wave at the waveform's frequency, high during the first half of
each cycle (phase 0 … π) — the 33500's sync for a continuous waveform ("carrier" sync; in a sweep the
twin keeps following the carrier). The generator's oscillator is a phase-continuous
:class:`~drivers.sim.oscillator.OscillatorBody` (:attr:`SyncLed.waveform`) that the generator mock keeps
at its frequency or sweep whatever its output state (the oscillator runs; OUTPut only connects it);
``PHASe:SYNChronize`` restarts it at phase 0 (:meth:`SyncLed.restart_phase`), and ``OUTPut:SYNC`` switches
the sync output (:meth:`SyncLed.set_enabled`).

The LED is a flat rectangle in the world (centre, two half-side vectors, mm) that emits uniformly. Its
light follows the drive through a first-order response with ``time_constant_s`` (a real LED + driver;
the 10–90 % rise is 2.2 time constants), so a camera row exposed over [a, a + E] sees the closed form
:meth:`SyncLed.mean_levels`: the light's mean over the exposure, 0 (dark) … 1 (fully lit).

The history is bounded as the oscillator's is: at most ``max_changes`` phase restarts and as many sync
switches are kept (a generator retrying ``PHAS:SYNC`` restarts the phase each time); the oldest kept one
starts the history, and asking about a time before it raises :class:`SimCommandError` instead of answering
from a history that is gone. Lookups bisect the kept changes, so a render costs the same however many
restarts came before it.
"""

from __future__ import annotations

import bisect
import itertools
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from drivers.sim.errors import SimCommandError, _finite
from drivers.sim.oscillator import DEFAULT_MAX_SEGMENTS, OscillatorBody

__all__ = ["SyncLed"]

_F = NDArray[np.float64]
_SETTLED_TIME_CONSTANTS = 40.0  # after 40 τ the response to an edge is complete (e^-40 ≈ 4e-18)
V = TypeVar("V")


@dataclass(frozen=True)
class _Changes(Generic[V]):
    """A value that changes at increasing times (world s): the first start may be −inf (always so before)."""

    starts_s: tuple[float, ...]
    values: tuple[V, ...]
    truncated: bool = False  # older changes were dropped: times before starts_s[0] are gone

    def at(self, t_s: float) -> V:
        """The value at ``t_s`` (from the newest change at or before it; ``t_s`` ≥ the history's start)."""
        return self.values[bisect.bisect_right(self.starts_s, t_s) - 1]

    def inside(self, t0_s: float, t1_s: float) -> tuple[float, ...]:
        """Change times strictly inside (t0_s, t1_s)."""
        return self.starts_s[bisect.bisect_right(self.starts_s, t0_s):bisect.bisect_left(self.starts_s, t1_s)]

    def changed(self, t_s: float, value: V, max_kept: int) -> _Changes[V]:
        """Changed to ``value`` at ``t_s``: replaces the changes at or after ``t_s``; keeps the newest
        ``max_kept`` (older ones can no longer decide a value at or after the oldest kept change)."""
        k = bisect.bisect_left(self.starts_s, t_s)
        starts, values = (*self.starts_s[:k], t_s), (*self.values[:k], value)
        drop = max(0, len(starts) - max_kept)
        return _Changes(starts[drop:], values[drop:], self.truncated or drop > 0)

    @property
    def history_start_s(self) -> float:
        return self.starts_s[0] if self.truncated else -math.inf


class SyncLed:
    """An LED in the world lit by the generator's sync output (see the module docstring).

    ``centre_mm``, ``half_u_mm``, ``half_v_mm``: the rectangle's centre and half-side vectors (base frame,
    mm). ``time_constant_s`` (> 0) of the light's first-order response; ``contrast_dn`` the brightness it
    adds to a pixel fully covered when fully lit (8-bit DN). ``max_changes`` (≥ 2) bounds the kept phase
    restarts and sync switches each.
    """

    def __init__(self, name: str, centre_mm: Sequence[float], half_u_mm: Sequence[float],
                 half_v_mm: Sequence[float], *, time_constant_s: float = 5e-6, contrast_dn: float = 180.0,
                 t_origin_s: float = 0.0, max_changes: int = DEFAULT_MAX_SEGMENTS) -> None:
        self.name = str(name)
        self.centre_mm = np.asarray(centre_mm, dtype=float).reshape(3)
        self.half_u_mm = np.asarray(half_u_mm, dtype=float).reshape(3)
        self.half_v_mm = np.asarray(half_v_mm, dtype=float).reshape(3)
        for label, v in (("centre_mm", self.centre_mm), ("half_u_mm", self.half_u_mm),
                         ("half_v_mm", self.half_v_mm)):
            if not np.all(np.isfinite(v)):
                raise SimCommandError(f"{label} must be 3 finite numbers, got {v.tolist()!r}")
        if np.linalg.norm(np.cross(self.half_u_mm, self.half_v_mm)) <= 0:
            raise SimCommandError("half_u_mm and half_v_mm must span a rectangle (not parallel, not zero)")
        self.time_constant_s = _finite(time_constant_s, "time_constant_s", positive=True)
        self.contrast_dn = _finite(contrast_dn, "contrast_dn", positive=True)
        if int(max_changes) < 2:
            raise SimCommandError(f"max_changes must be >= 2, got {max_changes!r}")
        self.max_changes = int(max_changes)
        self._lock = threading.Lock()
        # the oscillator from each start time: a phase restart begins a new oscillator at phase 0
        self._phases: _Changes[OscillatorBody] = _Changes(
            (-math.inf,), (OscillatorBody(f"{name}-waveform", t_origin_s=t_origin_s),))
        self._enabled: _Changes[bool] = _Changes((-math.inf,), (False,))

    # -- commands (the generator mock) -----------------------------------------------------------------
    @property
    def waveform(self) -> OscillatorBody:
        """The generator's oscillator now (the mock sets its frequency or sweep)."""
        return self._phases.values[-1]

    def restart_phase(self, t_s: float) -> None:
        """The oscillator restarts at phase 0 at ``t_s`` with its frequency then (``PHASe:SYNChronize``)."""
        t = _finite(t_s, "t_s")
        with self._lock:
            f = float(self._phases.values[-1].frequency_hz(t))
            body = OscillatorBody(f"{self.name}-waveform", initial_hz=f, t_origin_s=t)
            self._phases = self._phases.changed(t, body, self.max_changes)

    def set_enabled(self, t_s: float, enabled: bool) -> None:
        """Switch the sync output (and with it the LED's drive) on or off from ``t_s``."""
        t = _finite(t_s, "t_s")
        with self._lock:
            self._enabled = self._enabled.changed(t, bool(enabled), self.max_changes)

    # -- the drive ---------------------------------------------------------------------------------------
    def corners_mm(self) -> _F:
        """The rectangle's 4 corners (4, 3) in order around it (base frame, mm)."""
        c, u, v = self.centre_mm, self.half_u_mm, self.half_v_mm
        return np.stack([c - u - v, c + u - v, c + u + v, c - u + v])

    def _pieces(self, t0: float, t1: float) -> list[tuple[float, float, OscillatorBody, bool]]:
        """[a, b) pieces of [t0, t1) with one oscillator and one sync state each."""
        history_start_s = max(self._phases.history_start_s, self._enabled.history_start_s)
        if t0 < history_start_s:
            raise SimCommandError(f"{self.name}: t_s={t0!r} is before the kept history (from "
                                  f"{history_start_s!r} s; at most {self.max_changes} phase restarts and "
                                  "as many sync switches)")
        cuts = sorted({t0, t1, *self._phases.inside(t0, t1), *self._enabled.inside(t0, t1)})
        return [(a, b, self._phases.at(a), self._enabled.at(a)) for a, b in itertools.pairwise(cuts)]

    @staticmethod
    def _half_cycles(body: OscillatorBody, t: _F) -> _F:
        return np.asarray(body.phase_rad(t), dtype=float) / math.pi

    @classmethod
    def _crossings(cls, body: OscillatorBody, a: float, b: float) -> _F:
        """Times in (a, b] where the phase crosses a multiple of π (Newton on φ/π from a linear guess)."""
        psi_a, psi_b = cls._half_cycles(body, np.array([a, b]))
        ks = np.arange(math.floor(psi_a) + 1, math.floor(psi_b) + 1, dtype=float)
        if ks.size == 0:
            return np.zeros(0)
        t = a + (ks - psi_a) / (psi_b - psi_a) * (b - a)
        for _ in range(6):
            f_hz, phase_rad = body.frequency_and_phase(t)
            f = np.maximum(np.asarray(f_hz, dtype=float), 1e-12)
            t = np.clip(t - (np.asarray(phase_rad, dtype=float) / math.pi - ks) / (2.0 * f), a, b)
        return np.asarray(t, dtype=np.float64)

    def drive_edges(self, t0_s: float, t1_s: float) -> tuple[_F, NDArray[np.bool_], bool]:
        """(edge times, rising?, drive high just before t0_s) of the sync drive on [t0_s, t1_s] (world s)."""
        with self._lock:
            pieces = self._pieces(float(t0_s), float(t1_s))
        times: list[float] = []
        rising: list[bool] = []
        state = initial = False
        for i, (a, b, body, on) in enumerate(pieces):
            high = on and math.floor(float(self._half_cycles(body, np.array([a]))[0])) % 2 == 0
            if i == 0:
                state = initial = high
            elif high != state:
                times.append(a)
                rising.append(high)
                state = high
            if not on:
                continue
            for t in self._crossings(body, a, b):
                if t >= b:
                    continue
                state = not state
                times.append(float(t))
                rising.append(state)
        return np.array(times, dtype=float), np.array(rising, dtype=bool), initial

    def mean_levels(self, window_start_s: _F, exposure_s: float) -> _F:
        """Mean light (0..1) over each exposure window [a, a + exposure_s] (world time, s)."""
        a = np.asarray(window_start_s, dtype=float)
        if a.size == 0:
            return np.zeros(0)
        tc = self.time_constant_s
        t0 = float(a.min()) - _SETTLED_TIME_CONSTANTS * tc
        edges, rising, initial = self.drive_edges(t0, float(a.max()) + exposure_s)

        def light(x: _F) -> _F:  # ∫0^x (1 − e^(−u/τ)) du, 0 before the edge
            xp = np.maximum(x, 0.0)
            return np.where(x > 0, xp + tc * np.expm1(-xp / tc), 0.0)

        level = np.full(a.shape, 1.0 if initial else 0.0)
        for e, up in zip(edges, rising, strict=True):
            level += (1.0 if up else -1.0) * (light(a + exposure_s - e) - light(a - e)) / exposure_s
        return np.asarray(np.clip(level, 0.0, 1.0), dtype=np.float64)

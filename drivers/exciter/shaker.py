"""An electrodynamic shaker fed by the SCPI generator through a power amplifier.

The generator sets volts; what reaches the table is displacement. ``SensitivityTable`` holds the
measured displacement sensitivity of amplifier + shaker + payload in **mm (peak) per volt (peak) at the
generator output** versus frequency, interpolated linearly (never extrapolated). Generator amplitudes
are in volts peak-to-peak, so ``x_mm = s(f) · Vpp / 2``.

Every operating point — and every frequency a sweep will pass through — is checked against the limits
(frequency, displacement, acceleration (2πf)²·x, velocity, ramp rate) **before anything is sent**;
the maximum of each quantity over a sweep is found exactly on each linear piece of the table.

Safe sequence (notes §2.4): output OFF → ``*CLS`` → sine, high-Z load, Vpp, offset 0, minimum
amplitude → errors drained → output ON → amplitude raised in steps → … → amplitude lowered in steps →
output OFF. On any failure the abort path (minimum amplitude, output OFF) is attempted.
"""

from __future__ import annotations

import bisect
import contextlib
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any, TypeVar

from drivers.clock import Clock
from drivers.exciter.generator import GeneratorError, SafeOffOutcome, ScpiGenerator, SweepSettings
from drivers.exciter.limits import LimitError, MotionLimits
from drivers.heartbeat import Heartbeat
from drivers.roles import Generator

__all__ = ["GeneratorSample", "SensitivityTable", "Shaker", "ShakerLimits", "ShakerSweep"]

_R = TypeVar("_R")


class SensitivityTable:
    """Displacement sensitivity s(f) in mm (peak) per V (peak), from ``[(f_hz, mm_per_v), ...]`` with
    strictly increasing frequencies and positive sensitivities; linear between points."""

    def __init__(self, points: Sequence[Sequence[float]]) -> None:
        pts: list[tuple[float, float]] = []
        for i, p in enumerate(points):
            if len(p) != 2:
                raise ValueError(f"sensitivity[{i}]={p!r}: must be a (f_hz, mm_per_v) pair")
            f, s = float(p[0]), float(p[1])
            if not (math.isfinite(f) and f >= 0):
                raise ValueError(f"sensitivity[{i}].f_hz={p[0]!r}: must be a finite frequency >= 0")
            if not (math.isfinite(s) and s > 0):
                raise ValueError(f"sensitivity[{i}].mm_per_v={p[1]!r}: must be > 0")
            if pts and f <= pts[-1][0]:
                raise ValueError(f"sensitivity[{i}].f_hz={p[0]!r}: frequencies must increase strictly")
            pts.append((f, s))
        if not pts:
            raise ValueError("sensitivity table is empty")
        self.points = tuple(pts)
        self.f_min_hz, self.f_max_hz = pts[0][0], pts[-1][0]

    def _check_range(self, f_hz: float) -> None:
        if not self.f_min_hz <= f_hz <= self.f_max_hz:
            raise ValueError(f"frequency {f_hz:g} Hz is outside the sensitivity table "
                             f"{self.f_min_hz:g}..{self.f_max_hz:g} Hz (no extrapolation)")

    def mm_per_v(self, f_hz: float) -> float:
        self._check_range(f_hz)
        freqs = [p[0] for p in self.points]
        i = bisect.bisect_right(freqs, f_hz) - 1
        if i >= len(self.points) - 1:
            return self.points[-1][1]
        (f0, s0), (f1, s1) = self.points[i], self.points[i + 1]
        return s0 + (s1 - s0) * (f_hz - f0) / (f1 - f0)

    def pieces(self, f_lo: float, f_hi: float) -> list[tuple[float, float, float, float]]:
        """Linear pieces ``(fa, fb, a, b)`` with s(f) = a + b·f on [fa, fb], covering [f_lo, f_hi]."""
        self._check_range(f_lo)
        self._check_range(f_hi)
        knots = sorted({f_lo, f_hi, *(p[0] for p in self.points if f_lo < p[0] < f_hi)})
        out = []
        for fa, fb in itertools.pairwise(knots):
            sa, sb = self.mm_per_v(fa), self.mm_per_v(fb)
            b = (sb - sa) / (fb - fa)
            out.append((fa, fb, sa - b * fa, b))
        if not out:
            out.append((f_lo, f_hi, self.mm_per_v(f_lo), 0.0))
        return out


@dataclass(frozen=True)
class ShakerSweep:
    """A sweep as carried out: rig-clock start/stop, frequencies, spacing, volts, and the commanded
    profile ``[(t_s, f_hz), ...]`` (what a ``sweep`` record event holds)."""

    t_start_s: float
    t_stop_s: float
    start_hz: float
    stop_hz: float
    spacing: str
    amplitude_vpp: float
    profile: list[tuple[float, float]]


@dataclass(frozen=True)
class GeneratorSample:
    """What the generator reports when polled (the ``generator`` event stream), rig time ``t_s``.

    ``frequency_hz`` is its CW frequency setting (``FREQ?``): the output frequency when no sweep runs.
    During a sweep a generator does not report its instantaneous frequency; ``sweep`` then holds the
    sweep settings it reports (``start_hz``, ``stop_hz``, ``time_s``, ``spacing``). ``displacement_mm`` is
    s(f)·Vpp/2 (the sensitivity table) at ``frequency_hz``, or at the sweep's start frequency during a sweep
    (constant volts: the same at every frequency only where the table is flat); 0 with the output OFF, NaN
    outside the table."""

    t_s: float
    frequency_hz: float
    amplitude_vpp: float
    output_on: bool
    sweep_on: bool
    displacement_mm: float
    sweep: SweepSettings | None = None

    def as_event(self) -> dict[str, Any]:
        """The ``generator`` event payload (``sweep`` as a table; None fields left out)."""
        return {k: v for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class ShakerLimits:
    """The shaker's limits without a generator: mechanical ``limits``, the ``sensitivity`` table and the
    amplifier's input limit ``max_amplitude_vpp`` (V peak-to-peak). Checks send nothing; the whole-plan
    validation uses them before any device is connected."""

    limits: MotionLimits
    sensitivity: SensitivityTable
    max_amplitude_vpp: float

    def displacement_mm(self, frequency_hz: float, amplitude_vpp: float) -> float:
        return self.sensitivity.mm_per_v(frequency_hz) * amplitude_vpp / 2.0

    def amplitude_vpp_for(self, frequency_hz: float, amplitude_mm: float) -> float:
        """Generator Vpp giving peak displacement ``amplitude_mm`` at ``frequency_hz``."""
        return 2.0 * amplitude_mm / self.sensitivity.mm_per_v(frequency_hz)

    def check_volts(self, amplitude_vpp: float) -> None:
        if not 0 <= amplitude_vpp <= self.max_amplitude_vpp:
            raise LimitError("generator amplitude", amplitude_vpp, self.max_amplitude_vpp, "Vpp",
                             "amplifier input limit", field="max_amplitude_vpp")

    def check_point(self, frequency_hz: float, amplitude_vpp: float) -> None:
        """Mechanical limits at (f, volts), then the amplifier's input limit."""
        self.limits.check_point(frequency_hz, self.displacement_mm(frequency_hz, amplitude_vpp),
                                f"shaker at {amplitude_vpp:.4g} Vpp")
        self.check_volts(amplitude_vpp)

    def check_sweep(self, start_hz: float, stop_hz: float, duration_s: float, spacing: str,
                    amplitude_vpp: float) -> None:
        """Every limit at every frequency of the sweep (exact maxima per linear piece of the table)."""
        if spacing not in ("linear", "log"):
            raise ValueError(f"spacing={spacing!r}: must be 'linear' or 'log'")
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s={duration_s!r}: must be > 0 s")
        if spacing == "log" and min(start_hz, stop_hz) <= 0:
            raise ValueError(f"a log sweep needs start_hz and stop_hz > 0, got {start_hz!r}, {stop_hz!r}")
        self.check_volts(amplitude_vpp)
        lo, hi = min(start_hz, stop_hz), max(start_hz, stop_hz)
        for fa, fb, a, b in self.sensitivity.pieces(lo, hi):
            candidates = {fa, fb}
            if b != 0:  # stationary points of velocity f·(a+bf) and acceleration f²·(a+bf)
                candidates |= {f for f in (-a / (2 * b), -2 * a / (3 * b)) if fa < f < fb}
            for f in sorted(candidates):
                self.check_point(f, amplitude_vpp)
        slope = abs(stop_hz - start_hz) / duration_s if spacing == "linear" else \
            hi * abs(math.log(stop_hz / start_hz)) / duration_s
        if slope > 0:
            self.limits.check_ramp_rate(slope, "shaker sweep")


class Shaker(Generator):
    """Shaker + amplifier + generator.

    generator: the SCPI generator. clock: rig clock. limits: shaker limits. sensitivity: the table.
    max_amplitude_vpp: the amplifier's input limit (V peak-to-peak). min_amplitude_vpp: the level used
    while switching the output. amplitude_step_vpp / step_interval_s: amplitude ramp (strict steps).
    heartbeat_timeout_s: wall seconds without a reply line from the generator after which
    :meth:`heartbeat` reports it lost. safe_deadline_s: wall seconds the abort path keeps trying (on fresh
    links) to confirm the output OFF.
    """

    def __init__(self, generator: ScpiGenerator, *, clock: Clock, limits: MotionLimits,
                 sensitivity: SensitivityTable, max_amplitude_vpp: float = 10.0,
                 min_amplitude_vpp: float = 0.01,
                 amplitude_step_vpp: float = 0.5, step_interval_s: float = 0.1,
                 heartbeat_timeout_s: float = 2.0, safe_deadline_s: float = 3.0) -> None:
        for name, value in (("max_amplitude_vpp", max_amplitude_vpp), ("safe_deadline_s", safe_deadline_s),
                            ("min_amplitude_vpp", min_amplitude_vpp),
                            ("amplitude_step_vpp", amplitude_step_vpp), ("step_interval_s", step_interval_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}={value!r}: must be a finite number > 0")
        if min_amplitude_vpp >= max_amplitude_vpp:
            raise ValueError(f"min_amplitude_vpp={min_amplitude_vpp!r} must be below max_amplitude_vpp")
        self.generator = generator
        self.clock = clock
        self.limits = limits
        self.sensitivity = sensitivity
        self.max_amplitude_vpp = max_amplitude_vpp
        self.min_amplitude_vpp = min_amplitude_vpp
        self.amplitude_step_vpp = amplitude_step_vpp
        self.step_interval_s = step_interval_s
        self.safe_deadline_s = safe_deadline_s
        self.last_safe_outcome: SafeOffOutcome | None = None
        self._amplitude_vpp = 0.0
        self._output_on = False
        self.heartbeat_monitor = Heartbeat("generator", generator.contact, self._probe,
                                           timeout_s=heartbeat_timeout_s)

    # conversions and checks (no I/O): :class:`ShakerLimits` ------------------------------------------------
    @property
    def checks(self) -> ShakerLimits:
        return ShakerLimits(self.limits, self.sensitivity, self.max_amplitude_vpp)

    def displacement_mm(self, frequency_hz: float, amplitude_vpp: float) -> float:
        return self.checks.displacement_mm(frequency_hz, amplitude_vpp)

    def amplitude_vpp_for(self, frequency_hz: float, amplitude_mm: float) -> float:
        """Generator Vpp giving peak displacement ``amplitude_mm`` at ``frequency_hz``."""
        return self.checks.amplitude_vpp_for(frequency_hz, amplitude_mm)

    def check_point(self, frequency_hz: float, amplitude_vpp: float) -> None:
        """Mechanical limits at (f, volts), then the amplifier's input limit."""
        self.checks.check_point(frequency_hz, amplitude_vpp)

    def check_sweep(self, start_hz: float, stop_hz: float, duration_s: float, spacing: str,
                    amplitude_vpp: float) -> None:
        """Every limit at every frequency of the sweep (:meth:`ShakerLimits.check_sweep`)."""
        self.checks.check_sweep(start_hz, stop_hz, duration_s, spacing, amplitude_vpp)

    # operations ---------------------------------------------------------------------------------------------
    def _guarded(self, fn: Callable[[], _R]) -> _R:
        """``fn()``; a generator failure aborts the output first and says so in the error."""
        try:
            return fn()
        except GeneratorError as exc:
            note = self._abort_note()
            exc.args = (f"{exc.args[0]}; {note}",)
            raise

    def _abort_note(self) -> str:
        try:
            self.abort()
        except GeneratorError as abort_exc:
            return f"abort (minimum amplitude, output OFF) attempted but failed: {abort_exc}"
        assert self.last_safe_outcome is not None
        return f"abort: minimum amplitude, {self.last_safe_outcome.describe()}"

    def prepare(self) -> None:
        """Output OFF, clear errors, sine into a high-Z amplifier at minimum amplitude (no motion)."""
        def run() -> None:
            g = self.generator
            if self._output_on:
                self._ramp_amplitude(self.min_amplitude_vpp)
            g.set_output(False)
            self._output_on = False
            g.clear_status()
            g.set_sine()
            g.set_load_high_z()
            g.configure_units()
            g.set_amplitude_vpp(self.min_amplitude_vpp)
            self._amplitude_vpp = self.min_amplitude_vpp
        self._guarded(run)

    def _ramp_amplitude(self, target_vpp: float) -> None:
        """Move the amplitude to ``target_vpp`` in steps of at most ``amplitude_step_vpp``, waiting
        ``step_interval_s`` between steps; the last step lands exactly on the target."""
        g = self.generator
        start = self._amplitude_vpp
        n = max(1, math.ceil(abs(target_vpp - start) / self.amplitude_step_vpp - 1e-9))
        for i in range(1, n + 1):
            value = target_vpp if i == n else start + (target_vpp - start) * i / n
            g.set_amplitude_vpp(value)
            self._amplitude_vpp = value
            if i < n:
                self.clock.sleep_s(self.step_interval_s)

    def start(self, frequency_hz: float, amplitude_mm: float) -> float:
        """Vibrate at ``frequency_hz`` with peak displacement ``amplitude_mm``; returns the Vpp used."""
        vpp = self.amplitude_vpp_for(frequency_hz, amplitude_mm)
        self.check_point(frequency_hz, vpp)

        def run() -> None:
            self.prepare()
            self.generator.set_frequency_hz(frequency_hz)
            self.generator.set_output(True)
            self._output_on = True
            self._ramp_amplitude(vpp)
        self._guarded(run)
        return vpp

    def retune(self, frequency_hz: float, amplitude_mm: float, *,
               frequency_set: Callable[[], None] | None = None) -> float:
        """While running: CW frequency to ``frequency_hz`` (phase-continuous on the instrument), then the
        volts for ``amplitude_mm`` there (in amplitude steps); limits checked first. Returns the Vpp.
        ``frequency_set()`` is called as soon as the frequency command returned (before the volts: the
        caller brackets the frequency change's instant with it)."""
        vpp = self.amplitude_vpp_for(frequency_hz, amplitude_mm)
        self.check_point(frequency_hz, vpp)
        if not self._output_on:
            raise GeneratorError("retune: the output is OFF (call start first); nothing was sent")

        def run() -> None:
            self.generator.set_frequency_hz(frequency_hz)
            if frequency_set is not None:
                frequency_set()
            if vpp != self._amplitude_vpp:
                self._ramp_amplitude(vpp)
        self._guarded(run)
        return vpp

    def read_state(self) -> GeneratorSample:
        """Poll the generator: output state, CW frequency, Vpp, sweep state (and its settings when on)."""
        g = self.generator
        t_before = self.clock.now_s()
        output_on, frequency_hz, vpp = g.output(), g.frequency_hz(), g.amplitude_vpp()
        sweep_on = g.sweep_enabled()
        sweep = g.sweep_settings() if sweep_on else None
        t_after = self.clock.now_s()
        f_ref = sweep.start_hz if sweep is not None else frequency_hz  # what the volts were set for
        inside = self.sensitivity.f_min_hz <= f_ref <= self.sensitivity.f_max_hz
        disp = self.displacement_mm(f_ref, vpp) if output_on and inside else (
            0.0 if not output_on else math.nan)
        return GeneratorSample(0.5 * (t_before + t_after), frequency_hz, vpp, output_on, sweep_on, disp,
                               sweep)

    def _wait_until(self, t_end_s: float, poll_interval_s: float | None,
                    on_poll: Callable[[], None] | None) -> None:
        while (remaining := t_end_s - self.clock.now_s()) > 0:
            step = remaining if on_poll is None or poll_interval_s is None else \
                min(poll_interval_s, remaining)
            self.clock.sleep_s(step)
            if on_poll is not None and t_end_s - self.clock.now_s() > 0:
                on_poll()

    def sweep(self, start_hz: float, stop_hz: float, duration_s: float, *, spacing: str = "linear",
              amplitude_mm: float, reference_hz: float | None = None, hold_s: float = 0.0,
              poll_interval_s: float | None = None, on_poll: Callable[[], None] | None = None) -> ShakerSweep:
        """One generator sweep at constant volts (giving ``amplitude_mm`` at ``reference_hz``, default the
        start frequency), then ``hold_s`` s at ``stop_hz`` (sweep OFF, CW), then ramp down and output OFF.
        Waits through the injected clock; ``on_poll()`` is called every ``poll_interval_s`` s of the sweep
        and the hold (e.g. to record :meth:`read_state`). The returned profile covers sweep and hold."""
        ref = start_hz if reference_hz is None else reference_hz
        vpp = self.amplitude_vpp_for(ref, amplitude_mm)
        self.check_sweep(start_hz, stop_hz, duration_s, spacing, vpp)
        if not (math.isfinite(hold_s) and hold_s >= 0):
            raise ValueError(f"hold_s={hold_s!r}: must be a finite number >= 0 s")
        if poll_interval_s is not None and not (math.isfinite(poll_interval_s) and poll_interval_s > 0):
            raise ValueError(f"poll_interval_s={poll_interval_s!r}: must be > 0 s")

        def run() -> ShakerSweep:
            g = self.generator
            self.prepare()
            g.set_frequency_hz(start_hz)
            g.configure_sweep(start_hz, stop_hz, duration_s, spacing)
            g.set_output(True)
            self._output_on = True
            self._ramp_amplitude(vpp)
            t0 = self.clock.now_s()
            g.set_sweep(True)
            if on_poll is not None:
                on_poll()
            self._wait_until(t0 + duration_s, poll_interval_s, on_poll)
            t1 = self.clock.now_s()
            g.set_frequency_hz(stop_hz)
            g.set_sweep(False)
            hold: list[tuple[float, float]] = []
            if hold_s > 0:
                t_hold = self.clock.now_s()
                if on_poll is not None:
                    on_poll()
                self._wait_until(t_hold + hold_s, poll_interval_s, on_poll)
                t1 = self.clock.now_s()
                hold = [(t_hold, stop_hz), (t1, stop_hz)]
            n = 50
            if spacing == "linear":
                freqs = [start_hz + (stop_hz - start_hz) * i / n for i in range(n + 1)]
            else:
                freqs = [start_hz * (stop_hz / start_hz) ** (i / n) for i in range(n + 1)]
            prof = [(t0 + duration_s * i / n, f) for i, f in enumerate(freqs)] + hold
            return ShakerSweep(t0, t1, start_hz, stop_hz, spacing, vpp, prof)
        result: ShakerSweep = self._guarded(run)
        self.stop()
        return result

    def arm_sweep(self, start_hz: float, stop_hz: float, duration_s: float, *, spacing: str = "linear",
                  amplitude_mm: float) -> float:
        """Configure the generator's own sweep and start it with the output OFF (its phase generator sweeps,
        nothing moves), so that a later ``PHASe:SYNChronize`` restarts it at phase 0 on the instrument's
        timebase; returns the volts (constant) that give ``amplitude_mm`` at ``start_hz``.
        :meth:`drive_armed` then connects the output."""
        vpp = self.amplitude_vpp_for(start_hz, amplitude_mm)
        self.check_sweep(start_hz, stop_hz, duration_s, spacing, vpp)

        def run() -> None:
            g = self.generator
            self.prepare()
            g.set_frequency_hz(start_hz)
            g.configure_sweep(start_hz, stop_hz, duration_s, spacing)
            g.set_sweep(True)
        self._guarded(run)
        return vpp

    def drive_armed(self, amplitude_vpp: float, until_s: float, *, poll_interval_s: float | None = None,
                    on_poll: Callable[[], None] | None = None) -> tuple[float, float]:
        """Output ON with the amplitude ramped up to ``amplitude_vpp`` (an armed sweep keeps running), hold
        until ``until_s`` (injected clock), then ramp down, output OFF and sweep OFF. Returns (the instant
        the amplitude was reached, the instant the hold ended)."""
        self.checks.check_volts(amplitude_vpp)

        def run() -> tuple[float, float]:
            g = self.generator
            g.set_output(True)
            self._output_on = True
            self._ramp_amplitude(amplitude_vpp)
            t_steady = self.clock.now_s()
            if on_poll is not None:
                on_poll()
            self._wait_until(until_s, poll_interval_s, on_poll)
            return t_steady, self.clock.now_s()
        times: tuple[float, float] = self._guarded(run)
        self.stop()
        self._guarded(lambda: self.generator.set_sweep(False))
        return times

    def stop(self) -> None:
        """Ramp the amplitude down in steps, then output OFF."""
        def run() -> None:
            if self._output_on:
                self._ramp_amplitude(self.min_amplitude_vpp)
            self.generator.set_output(False)
            self._output_on = False
        self._guarded(run)

    def safe_state(self) -> None:
        """The runner's "make safe": ramp down and output OFF; a failure runs the abort path (once).
        Raises :class:`GeneratorError` only when the output could not be confirmed OFF."""
        self.last_safe_outcome = None
        try:
            self.stop()
        except GeneratorError:
            if self.last_safe_outcome is None or not self.last_safe_outcome.output_off:
                raise

    def read_back(self) -> dict[str, Any]:
        """The generator's own report (:class:`drivers.roles.Generator`): is its output on?"""
        return {"output_on": bool(self.generator.output())}

    def snapshot(self) -> dict[str, Any]:
        """Configuration for the run record (no I/O)."""
        return {"driver": "scpi-generator", "channel": self.generator.channel,
                "max_amplitude_vpp": self.max_amplitude_vpp, "output_on": self._output_on}

    def heartbeat(self, *, wait: bool = False) -> bool:
        """Watchdog probe (thread-safe, no I/O in the caller's thread, returns at once; ``wait=True``
        probes now in the caller's thread instead, for ``rig check``).

        Raises :class:`~drivers.heartbeat.DeviceLostError` naming the device, the age of the generator's
        last reply line and the limit when the link closed or nothing came back for
        ``heartbeat_timeout_s`` (every reply to the procedure's commands counts). After a quarter of
        that without traffic, one ``*OPC?`` is sent from a helper thread under the generator's lock."""
        return self.heartbeat_monitor.verify() if wait else self.heartbeat_monitor.check()

    def _probe(self) -> None:
        self.generator.probe(min(self.generator.timeout_s, self.heartbeat_monitor.timeout_s / 2.0))

    def abort(self, deadline_s: float | None = None) -> None:
        """Abort path: minimum amplitude at once, output OFF, read back OFF; repeated on a fresh link until
        ``deadline_s`` (default ``safe_deadline_s``; see :meth:`ScpiGenerator.output_off`). The outcome is
        kept in :attr:`last_safe_outcome`; :class:`GeneratorError` describing it if OFF was not confirmed."""
        outcome = self.generator.output_off(
            min_amplitude_vpp=self.min_amplitude_vpp,
            deadline_s=self.safe_deadline_s if deadline_s is None else deadline_s)
        self.last_safe_outcome = outcome
        self._output_on = False
        self._amplitude_vpp = self.min_amplitude_vpp
        if not outcome.output_off:
            raise GeneratorError(f"make safe: {outcome.describe()}")

    def close(self) -> None:
        """Abort without raising (cleanup path). When a make-safe already ran out of its deadline, one
        more round is tried, not another deadline's worth."""
        failed_before = self.last_safe_outcome is not None and not self.last_safe_outcome.output_off
        with contextlib.suppress(GeneratorError):
            self.abort(deadline_s=0.0 if failed_before else None)

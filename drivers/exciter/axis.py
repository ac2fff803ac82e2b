"""A mechanism driven by a VFD through a gear: what the exciter and the rotor have in common.

Mechanical frequency (vibration or rotation, Hz) = drive output frequency / ``gear_ratio``. Every
command is checked against the configured :class:`~drivers.exciter.limits.MotionLimits` (frequency,
displacement, acceleration (2πf)²·x, velocity, ramp rate) **before any byte is sent**; a violation
raises :class:`~drivers.exciter.limits.LimitError`. All waiting goes through the injected clock.

Start sequence (docs/exciter.md): read the fault register (reset it if allowed) → ramp time → setpoint
→ read back the frequency command → run → poll the actual frequency until it is within
``tolerance_hz`` on two consecutive polls. Stop: stop command → poll until the output is 0 Hz.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from typing import Any, TypedDict

from drivers.clock import Clock
from drivers.exciter.limits import MotionLimits
from drivers.exciter.sweep import FrequencySample, SweepProfile, SweepResult, run_sweep
from drivers.exciter.vfd import VfdDriver, VfdError
from drivers.heartbeat import Heartbeat
from drivers.roles import VibrationSource

__all__ = ["AxisOptions", "VfdAxis", "VfdTimeoutError"]


class VfdTimeoutError(VfdError):
    """The drive did not reach the commanded frequency (or standstill) in the expected time."""


class AxisOptions(TypedDict, total=False):
    """The optional keywords of :class:`VfdAxis` that the exciter and the rotor pass through."""

    direction: str
    tolerance_hz: float
    poll_interval_s: float
    settle_margin_s: float
    fixed_drive_ramp_rate_hz_per_s: float | None
    reset_faults: bool
    heartbeat_timeout_s: float


class VfdAxis(VibrationSource):
    """A VFD-driven mechanism (base of :class:`~drivers.exciter.exciter.Exciter` and
    :class:`~drivers.exciter.rotor.Rotor`).

    vfd: the drive. clock: the rig clock (``now_s``, ``sleep_s``). limits: mechanical limits.
    gear_ratio: drive Hz per mechanical Hz (> 0). amplitude_mm: peak displacement used for the
    acceleration/velocity limits (crank radius, marker radius). ramp_rate_hz_per_s: default mechanical
    ramp rate (Hz/s) for set_frequency and stop. direction: "forward" | "reverse".
    tolerance_hz: |actual − setpoint| accepted as "reached" (mechanical Hz). poll_interval_s: time
    between polls. settle_margin_s: extra time allowed beyond the ideal ramp time.
    fixed_drive_ramp_rate_hz_per_s: for a map without ramp-time registers, the drive's own fixed ramp
    rate in drive Hz/s (it must then be given). reset_faults: reset a latched fault before starting.
    heartbeat_timeout_s: wall seconds without a reply from the drive after which :meth:`heartbeat`
    reports it lost.
    """

    kind = "axis"

    def __init__(self, vfd: VfdDriver, *, clock: Clock, limits: MotionLimits, gear_ratio: float = 1.0,
                 amplitude_mm: float, ramp_rate_hz_per_s: float, direction: str = "forward",
                 tolerance_hz: float = 0.02, poll_interval_s: float = 0.05, settle_margin_s: float = 2.0,
                 fixed_drive_ramp_rate_hz_per_s: float | None = None, reset_faults: bool = False,
                 heartbeat_timeout_s: float = 2.0) -> None:
        if not (math.isfinite(gear_ratio) and gear_ratio > 0):
            raise ValueError(f"gear_ratio={gear_ratio!r}: must be a finite number > 0 "
                             f"(drive Hz per {self.kind} Hz)")
        if direction not in ("forward", "reverse"):
            raise ValueError(f"direction={direction!r}: must be 'forward' or 'reverse'")
        for name, value in (("tolerance_hz", tolerance_hz), ("poll_interval_s", poll_interval_s),
                            ("settle_margin_s", settle_margin_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}={value!r}: must be a finite number > 0")
        limits.check_displacement(amplitude_mm, f"{self.kind} amplitude")
        limits.check_ramp_rate(ramp_rate_hz_per_s, f"{self.kind} default ramp")
        if not vfd.map.has_ramp_registers and fixed_drive_ramp_rate_hz_per_s is None:
            raise ValueError(f"register map {vfd.map.model!r} has no ramp-time registers: "
                             "give fixed_drive_ramp_rate_hz_per_s (the drive's own ramp rate)")
        if fixed_drive_ramp_rate_hz_per_s is not None:
            limits.check_ramp_rate(fixed_drive_ramp_rate_hz_per_s / gear_ratio,
                                   f"{self.kind} drive's fixed ramp")
        self.vfd = vfd
        self.clock = clock
        self.limits = limits
        self.gear_ratio = float(gear_ratio)
        self.amplitude_mm = float(amplitude_mm)
        self.ramp_rate_hz_per_s = float(ramp_rate_hz_per_s)
        self.direction = direction
        # never tighter than the drive's own resolution (half a register step, in mechanical Hz)
        self.tolerance_hz = max(float(tolerance_hz), 0.5001 * vfd.map.freq_unit_hz / gear_ratio)
        self.poll_interval_s = float(poll_interval_s)
        self.settle_margin_s = float(settle_margin_s)
        self.fixed_drive_ramp_rate = fixed_drive_ramp_rate_hz_per_s
        self.reset_faults = reset_faults
        self.heartbeat_monitor = Heartbeat(self.kind, vfd.contact, vfd.probe, timeout_s=heartbeat_timeout_s)
        self._rate_written: float | None = None  # mechanical Hz/s the drive ramps at (after rounding)
        self._rate_requested: float | None = None  # what was asked for it
        self._setpoint_hz = 0.0

    # checks (no I/O) --------------------------------------------------------------------------------
    def check_frequency(self, frequency_hz: float, context: str = "") -> None:
        """Every limit for running at ``frequency_hz`` (mechanical), and the drive's own range."""
        self.limits.check_point(frequency_hz, self.amplitude_mm, context or f"{self.kind} setpoint")
        self.vfd.check_frequency_hz(frequency_hz * self.gear_ratio)

    def _current_rate(self) -> float:
        if self.fixed_drive_ramp_rate is not None:
            return self.fixed_drive_ramp_rate / self.gear_ratio
        return self._rate_written if self._rate_written is not None else self.ramp_rate_hz_per_s

    # FrequencyActuator (used by run_sweep) -------------------------------------------------------------
    def fixed_ramp_rate_hz_per_s(self) -> float | None:
        return None if self.fixed_drive_ramp_rate is None else self.fixed_drive_ramp_rate / self.gear_ratio

    def write_ramp_rate_hz_per_s(self, rate_hz_per_s: float) -> None:
        self.limits.check_ramp_rate(rate_hz_per_s, f"{self.kind} ramp")
        obtained = self.vfd.set_ramp_rate_hz_per_s(
            rate_hz_per_s * self.gear_ratio,
            max_rate_hz_per_s=self.limits.max_ramp_rate_hz_per_s * self.gear_ratio)
        self._rate_written = obtained / self.gear_ratio
        self._rate_requested = rate_hz_per_s

    def write_setpoint_hz(self, frequency_hz: float) -> None:
        self.check_frequency(frequency_hz)
        self.vfd.set_frequency_hz(frequency_hz * self.gear_ratio, verify=False)
        self._setpoint_hz = frequency_hz

    def read_sample(self, *, fault_is_error: bool = True) -> FrequencySample:
        """Poll the drive: time-stamped actual frequency (mechanical Hz); raises on a drive fault
        unless ``fault_is_error`` is False (then the status reads ``"fault N"``)."""
        t_before = self.clock.now_s()
        status = self.vfd.read_status()
        t_after = self.clock.now_s()
        if fault_is_error:
            self.vfd.raise_if_faulted(status, f"{self.kind} poll")
        state = f"fault {status.fault_code}" if status.fault_code else status.state
        return FrequencySample(t_s=0.5 * (t_before + t_after),
                               frequency_hz=status.freq_out_hz / self.gear_ratio,
                               setpoint_hz=status.freq_cmd_hz / self.gear_ratio, status=state)

    # operations ------------------------------------------------------------------------------------------
    def frequency_hz(self) -> float:
        """Actual mechanical frequency (Hz), as the drive reports it."""
        return self.read_sample().frequency_hz

    def _prepare(self) -> None:
        status = self.vfd.read_status()
        if status.fault_code and self.reset_faults:
            self.vfd.reset_fault()
            status = self.vfd.read_status()
        self.vfd.raise_if_faulted(status, f"{self.kind} start")

    def set_frequency(self, frequency_hz: float, *, wait: bool = True,
                      ramp_rate_hz_per_s: float | None = None) -> FrequencySample | None:
        """Run at ``frequency_hz`` (mechanical Hz), ramping at ``ramp_rate_hz_per_s`` (default: the
        configured rate). With ``wait``, returns the first sample within tolerance."""
        rate = self.ramp_rate_hz_per_s if ramp_rate_hz_per_s is None else ramp_rate_hz_per_s
        self.check_frequency(frequency_hz)
        self.limits.check_ramp_rate(rate, f"{self.kind} ramp")
        self._prepare()
        if self.fixed_drive_ramp_rate is None and self._rate_requested != rate:
            self.write_ramp_rate_hz_per_s(rate)
        self.vfd.set_frequency_hz(frequency_hz * self.gear_ratio, verify=True)
        self._setpoint_hz = frequency_hz
        self.vfd.run(self.direction)
        return self.wait_until_reached(frequency_hz) if wait else None

    def wait_until_reached(self, frequency_hz: float, *, fault_is_error: bool = True,
                           on_sample: Callable[[FrequencySample], None] | None = None) -> FrequencySample:
        """Poll until the actual frequency is within tolerance twice in a row; raises
        :class:`VfdTimeoutError` (after a stop attempt) when a sample past the expected ramp time + margin
        is out of tolerance. A first in-tolerance sample that comes late (a slow link, a loaded machine)
        gets its confirming poll: the drive has reached the setpoint, so it is not a time-out."""
        first = self.read_sample(fault_is_error=fault_is_error)
        ramp_s = abs(frequency_hz - first.frequency_hz) / self._current_rate()
        deadline = first.t_s + ramp_s + self.settle_margin_s
        sample, hits = first, 0
        while True:
            if on_sample is not None:
                on_sample(sample)
            hits = hits + 1 if abs(sample.frequency_hz - frequency_hz) <= self.tolerance_hz else 0
            if hits >= 2:
                return sample
            if sample.t_s > deadline and hits == 0:
                raise self.vfd._fail(VfdTimeoutError(
                    f"{self.kind}: actual frequency {sample.frequency_hz:.4g} Hz did not reach "
                    f"{frequency_hz:.4g} Hz ± {self.tolerance_hz:g} Hz by t = {deadline:.3f} s"))
            self.clock.sleep_s(self.poll_interval_s)
            sample = self.read_sample(fault_is_error=fault_is_error)

    def sweep(self, profile: SweepProfile, *, update_interval_s: float = 0.5,
              on_sample: Callable[[FrequencySample], None] | None = None) -> SweepResult:
        """Ramp to the profile's start, then carry the profile out (see :func:`run_sweep`). Every
        profile point and its slope are checked against the limits before anything is sent."""
        for t_s, f_hz in profile.points(update_interval_s):
            self.check_frequency(f_hz, f"{self.kind} sweep at t = {t_s:g} s")
        slope = profile.max_slope_hz_per_s()
        if slope > 0:
            self.limits.check_ramp_rate(slope, f"{self.kind} sweep slope")
        fixed = self.fixed_ramp_rate_hz_per_s()
        if fixed is not None and slope > fixed * (1 + 1e-9):
            raise ValueError(f"{self.kind} sweep slope {slope:.6g} Hz/s exceeds the drive's fixed ramp rate "
                             f"{fixed:.6g} Hz/s (its register map has no ramp-time registers); "
                             "nothing was sent")
        self.set_frequency(profile.start_hz, wait=True)
        try:
            return run_sweep(self, profile, update_interval_s=update_interval_s,
                             poll_interval_s=self.poll_interval_s,
                             max_ramp_rate_hz_per_s=self.limits.max_ramp_rate_hz_per_s, on_sample=on_sample)
        except VfdError:
            raise  # the driver already attempted a stop
        except Exception:
            self._stop_quietly()
            raise

    def stop(self, *, wait: bool = True) -> FrequencySample | None:
        """Command a stop; with ``wait``, poll until the output frequency is 0 (within tolerance)."""
        self.vfd.stop()
        self._setpoint_hz = 0.0
        # a tripped drive is already coasting down: still wait for rest, do not fail on its fault code
        return self.wait_until_reached(0.0, fault_is_error=False) if wait else None

    def safe_state(self) -> None:
        """The runner's "make safe": stop command, setpoint 0 Hz, wait until the output is at rest.
        Raises (after the driver's own stop attempt) if the drive cannot be reached."""
        self.vfd.stop()
        self.vfd.set_frequency_hz(0.0, verify=False)
        self._setpoint_hz = 0.0
        self.wait_until_reached(0.0, fault_is_error=False)

    def read_back(self) -> dict[str, Any]:
        """The drive's own report (:class:`drivers.roles.VibrationSource`): output frequency and setpoint
        (mechanical Hz) and status, a drive fault included as ``"fault N"``."""
        sample = self.read_sample(fault_is_error=False)
        return {"frequency_hz": float(sample.frequency_hz), "setpoint_hz": float(sample.setpoint_hz),
                "status": str(sample.status)}

    def snapshot(self) -> dict[str, Any]:
        """Configuration for the run record (no I/O)."""
        return {"driver": "modbus-vfd", "kind": self.kind, "register_map": self.vfd.map.model,
                "unit_id": self.vfd.map.unit_id, "gear_ratio": self.gear_ratio,
                "amplitude_mm": self.amplitude_mm, "ramp_rate_hz_per_s": self.ramp_rate_hz_per_s,
                "max_output_hz": self.vfd.max_output_hz, "setpoint_hz": self._setpoint_hz}

    def heartbeat(self, *, wait: bool = False) -> bool:
        """Watchdog probe (thread-safe, no I/O in the caller's thread, returns at once; ``wait=True``
        probes now in the caller's thread instead, for ``rig check``).

        Raises :class:`~drivers.heartbeat.DeviceLostError` naming the device, the age of the drive's last
        reply and the limit when nothing came back for ``heartbeat_timeout_s`` (every reply to the
        procedure's own polls counts), and :class:`~drivers.heartbeat.HeartbeatError` when the last
        probe found a drive fault. After a quarter of the timeout without traffic, one STATUS read
        (FAULT + STATUS, 0x2100..0x2101 on Delta) is sent from a helper thread under the line lock.
        The stop after a loss is the runner's (it makes every device safe at once)."""
        return self.heartbeat_monitor.verify() if wait else self.heartbeat_monitor.check()

    def _stop_quietly(self) -> None:
        with contextlib.suppress(VfdError):
            self.vfd.stop()

    def close(self) -> None:
        """Stop (without waiting); never raises for a lost link — always safe in cleanup."""
        self._stop_quietly()

    @property
    def setpoint_hz(self) -> float:
        return self._setpoint_hz

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(unit={self.vfd.map.unit_id}, gear_ratio={self.gear_ratio:g}, "
                f"amplitude_mm={self.amplitude_mm:g})")


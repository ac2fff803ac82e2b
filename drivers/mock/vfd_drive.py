"""The simulated drive behind the mock VFD server: register semantics, ramp, faults, watchdog.

:class:`DriveModel` implements the register map of :mod:`drivers.exciter.register_map`: the Modbus
slave (:mod:`drivers.mock.vfd_server`) hands it every read (:meth:`DriveModel.read`) and write
(:meth:`DriveModel.write`); it validates writes, updates the drive state and computes the monitor
registers **at the moment of the request** from the world clock. The physics lives in the twin: the
drive commands the body (``body.ramp_to(t, target_hz / gear_ratio, rate / gear_ratio)``) and reads
its output frequency back as ``body.frequency_hz(clock.now_s()) · gear_ratio``, so the drive and the
twin cannot disagree.

Behaviour (docs/exciter.md, "Mock drive"):

* ramp: the output frequency moves linearly toward the command at ``max_output_hz / accel_time_s``
  (accelerating) or ``max_output_hz / decel_time_s`` (decelerating); ramp times are registers;
* FREQ_SET above ``max_output_hz`` → exception 03 and the value is unchanged; an unknown command code
  → exception 03; an unmapped address anywhere in the requested range → 02; write to a monitor
  register → 02;
* load model ``I = I0 + (I_max − I0)·(f/f_max)²`` (eccentric force ∝ ω²); **overload** trips when the
  current exceeds ``overload_current_a``; **overspeed** trips when the output exceeds ``overspeed_hz``;
  **watchdog**: no request for ``watchdog_s`` while running trips; a trip latches the fault code, drops
  the run command and decelerates the body to rest. ``watchdog_s`` is also set over Modbus, as on the
  drive: the communication time-out register (Delta 09-03, 0 = off) with the fault treatment register
  (09-02) at 1 or 2 (ramp / coast to stop; 0 and 3 keep running: no trip). The fault reset (AUX bit 1)
  clears the code only once the output is at 0 Hz (the cause is gone);
* events between requests (a trip while nobody asks) are applied at the exact virtual time they
  happen, by the next request or by the server's housekeeping tick.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import TYPE_CHECKING

from drivers.exciter.register_map import DELTA_MAP, RegisterMap
from drivers.modbus import ExceptionCode

if TYPE_CHECKING:
    from drivers.clock import Clock
    from drivers.sim.oscillator import OscillatorBody

__all__ = ["FAULT_OVERLOAD", "FAULT_OVERSPEED", "FAULT_WATCHDOG", "DriveModel"]

log = logging.getLogger(__name__)

FAULT_OVERLOAD = 5        # "oL" drive overload
FAULT_OVERSPEED = 0x41    # "oSPd" overspeed (mock-defined)
FAULT_WATCHDOG = 0x42     # "CE10" Modbus communication time-out (mock-defined)


class DriveModel:
    """A VFD driving a twin body through a gear.

    body: the twin body (``ramp_to``, ``frequency_hz``). clock: the world clock (``now_s``).
    register_map: the drive's map. gear_ratio: drive Hz per body Hz. max_output_hz: drive maximum
    output frequency (Hz). accel_time_s / decel_time_s: initial ramp times (0 → max_output_hz).
    watchdog_s: communication time-out while running (None: off). overspeed_hz: output frequency that
    trips overspeed (None: off). no_load_current_a / current_at_max_a: load model. overload_current_a:
    current that trips overload (None: off).
    """

    def __init__(self, body: OscillatorBody, clock: Clock, *, register_map: RegisterMap = DELTA_MAP,
                 gear_ratio: float = 1.0, max_output_hz: float = 50.0, accel_time_s: float = 10.0,
                 decel_time_s: float = 10.0, watchdog_s: float | None = None,
                 overspeed_hz: float | None = None, no_load_current_a: float = 0.8,
                 current_at_max_a: float = 4.0, overload_current_a: float | None = None) -> None:
        if not gear_ratio > 0 or not max_output_hz > 0:
            raise ValueError(f"gear_ratio={gear_ratio!r} and max_output_hz={max_output_hz!r} must be > 0")
        if watchdog_s is not None and not watchdog_s > 0:
            raise ValueError(f"watchdog_s={watchdog_s!r}: must be > 0 s or None")
        self.body = body
        self.clock = clock
        self.map = register_map
        self.gear_ratio = float(gear_ratio)
        self.max_output_hz = float(max_output_hz)
        self.watchdog_s = watchdog_s
        self.overspeed_hz = overspeed_hz
        self.no_load_current_a = no_load_current_a
        self.current_at_max_a = current_at_max_a
        self.overload_current_a = overload_current_a
        m = register_map
        self.regs: dict[int, int] = {m.command: m.cmd_stop, m.freq_set: 0}
        if m.aux_command is not None:
            self.regs[m.aux_command] = 0
        if m.accel_time is not None and m.decel_time is not None:
            self.regs[m.accel_time] = m.ramp_time_to_register(accel_time_s)
            self.regs[m.decel_time] = m.ramp_time_to_register(decel_time_s)
        if m.comm_timeout is not None and m.comm_fault_treatment is not None:
            self.regs[m.comm_fault_treatment] = 0
            self.regs[m.comm_timeout] = 0
        self._accel_s = float(accel_time_s)
        self._decel_s = float(decel_time_s)
        self.running = False
        self.reverse = False
        self.fault_code = 0
        self.fault_time_s: float | None = None
        self.request_count = 0
        self.forced_exception: int | None = None  # fault injection: refuse every request with this code
        self._last_request_s = clock.now_s()
        # the ramp the drive is carrying out: (t0, f0, target, rate) in drive Hz
        self._plan = (self._last_request_s, self._output_hz(self._last_request_s), 0.0, 1.0)
        self._lock = threading.RLock()

    # Modbus requests -------------------------------------------------------------------------------------
    def address_sets(self) -> tuple[set[int], set[int]]:
        """(read/write addresses, read-only monitor addresses) of this drive."""
        m = self.map
        optional = (m.aux_command, m.accel_time, m.decel_time, m.comm_fault_treatment,
                    m.comm_timeout)
        rw = {m.command, m.freq_set} | {a for a in optional if a is not None}
        ro = {a for a in (m.fault, m.status, m.freq_cmd, m.freq_out, m.current) if a is not None}
        return rw, ro

    def _begin_request(self) -> float:
        now = self.clock.now_s()
        self.advance(now)
        self.request_count += 1
        self._last_request_s = now
        return now

    def read(self, address: int, count: int) -> list[int] | ExceptionCode:
        """FC03: ``count`` registers from ``address`` computed now, or the exception code."""
        rw, ro = self.address_sets()
        with self._lock:
            now = self._begin_request()
            if self.forced_exception is not None:
                return ExceptionCode(self.forced_exception)
            wanted = range(address, address + count)
            if any(a not in rw and a not in ro for a in wanted):
                return ExceptionCode.ILLEGAL_DATA_ADDRESS
            registers = [0] * count
            self._publish(address, registers, now)
            return registers

    def write(self, address: int, values: list[int]) -> ExceptionCode | None:
        """FC06/FC16: validate every value, then apply them all (or none); None when accepted."""
        rw, _ = self.address_sets()
        with self._lock:
            now = self._begin_request()
            if self.forced_exception is not None:
                return ExceptionCode(self.forced_exception)
            if any(address + i not in rw for i in range(len(values))):
                return ExceptionCode.ILLEGAL_DATA_ADDRESS
            for i, value in enumerate(values):
                if (exc := self._validate(address + i, value)) is not None:
                    return exc
            for i, value in enumerate(values):
                self._apply(address + i, value, now)
            return None

    # state ---------------------------------------------------------------------------------------------
    def _output_hz(self, t_s: float) -> float:
        return float(self.body.frequency_hz(t_s)) * self.gear_ratio

    def output_hz(self) -> float:
        """Actual output frequency (drive Hz) now."""
        return self._output_hz(self.clock.now_s())

    def current_a(self, output_hz: float) -> float:
        u = output_hz / self.max_output_hz
        return self.no_load_current_a + (self.current_at_max_a - self.no_load_current_a) * u * u

    def _rate(self, accelerating: bool) -> float:
        return self.max_output_hz / (self._accel_s if accelerating else self._decel_s)

    def _retarget(self, t_s: float) -> None:
        """Command the body toward the drive's present target from ``t_s``."""
        target = 0.0
        if self.running and not self.fault_code:
            target = self.regs[self.map.freq_set] * self.map.freq_unit_hz
        f_now = self._output_hz(t_s)
        rate = self._rate(target > f_now)
        self.body.ramp_to(t_s, target / self.gear_ratio, rate / self.gear_ratio)
        self._plan = (t_s, f_now, target, rate)

    def _trip_frequency_hz(self) -> tuple[float, int] | None:
        """Lowest output frequency that trips a protection, with its fault code."""
        trips = []
        if self.overspeed_hz is not None:
            trips.append((self.overspeed_hz, FAULT_OVERSPEED))
        if self.overload_current_a is not None:
            span = self.current_at_max_a - self.no_load_current_a
            if self.overload_current_a <= self.no_load_current_a:
                trips.append((0.0, FAULT_OVERLOAD))
            elif span > 0:
                excess = (self.overload_current_a - self.no_load_current_a) / span
                trips.append((self.max_output_hz * math.sqrt(excess), FAULT_OVERLOAD))
        return min(trips) if trips else None

    def _next_event(self) -> tuple[float, int] | None:
        """(time, fault code) of the next protection trip the present plan leads to, if any."""
        if self.fault_code:
            return None
        events = []
        if self.watchdog_s is not None and self.running:
            events.append((self._last_request_s + self.watchdog_s, FAULT_WATCHDOG))
        trip = self._trip_frequency_hz()
        if trip is not None:
            t0, f0, target, rate = self._plan
            f_trip, code = trip
            if f0 > f_trip:
                events.append((t0, code))
            elif target > f_trip:
                events.append((t0 + (f_trip - f0) / rate, code))
        return min(events) if events else None

    def advance(self, now_s: float) -> None:
        """Apply every protection trip due at or before ``now_s``, at its own time."""
        with self._lock:
            while (event := self._next_event()) is not None and event[0] <= now_s:
                self.trip(event[1], max(event[0], self._plan[0]))

    def trip(self, fault_code: int, t_s: float | None = None) -> None:
        """Latch ``fault_code`` at ``t_s`` (default now): the run command drops, the output ramps to 0."""
        with self._lock:
            t = self.clock.now_s() if t_s is None else t_s
            self.fault_code = fault_code
            self.fault_time_s = t
            self.running = False
            self._retarget(t)
            _t0, f_hz, _target, rate = self._plan
            log.warning("drive fault 0x%02X at t = %.3f s (last request t = %.3f s): output %.2f Hz ramps to "
                        "0 at %.3g Hz/s, at rest by t = %.3f s", fault_code, t, self._last_request_s, f_hz,
                        rate, t + f_hz / rate)

    def _validate(self, address: int, value: int) -> ExceptionCode | None:
        m = self.map
        if address == m.command and value not in (m.cmd_stop, m.cmd_run_forward, m.cmd_run_reverse):
            return ExceptionCode.ILLEGAL_DATA_VALUE
        if address == m.freq_set and value * m.freq_unit_hz > self.max_output_hz + 1e-9:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        if address in (m.accel_time, m.decel_time) and value < 1:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        return None

    def _apply(self, address: int, value: int, now: float) -> None:
        m = self.map
        self.regs[address] = value
        if address == m.command:
            if value == m.cmd_stop:
                self.running = False
            elif not self.fault_code:  # a faulted drive ignores run commands until reset
                self.running = True
                self.reverse = value == m.cmd_run_reverse
            self._retarget(now)
        elif address == m.freq_set:
            self._retarget(now)
        elif address in (m.accel_time, m.decel_time):
            if address == m.accel_time:
                self._accel_s = value * m.ramp_time_unit_s
            else:
                self._decel_s = value * m.ramp_time_unit_s
            self._retarget(now)
        elif address in (m.comm_timeout, m.comm_fault_treatment):
            self._set_comm_watchdog()
        elif (address == m.aux_command and value & m.aux_fault_reset and self.fault_code
              and self._output_hz(now) <= 0.0):
            self.fault_code = 0
            self.fault_time_s = None

    def _set_comm_watchdog(self) -> None:
        """``watchdog_s`` from the communication time-out registers (09-03 × unit; off unless 09-02 stops)."""
        m = self.map
        assert m.comm_timeout is not None and m.comm_fault_treatment is not None
        timeout = self.regs[m.comm_timeout] * m.comm_timeout_unit_s
        stops = self.regs[m.comm_fault_treatment] in (1, 2)
        self.watchdog_s = timeout if timeout > 0 and stops else None

    def status_word(self, now: float) -> int:
        m = self.map
        moving = self._output_hz(now) > 0.0
        if self.running:
            run = m.status_running if self.regs[m.freq_set] > 0 or moving else m.status_standby
        else:
            run = m.status_decelerating if moving else m.status_stopped
        direction = m.status_dir_reverse if self.reverse else m.status_dir_forward
        return (run & m.status_run_mask) | (direction & m.status_dir_mask)

    def _publish(self, start: int, registers: list[int], now: float) -> None:
        m = self.map
        f_out = self._output_hz(now)
        values = {m.fault: self.fault_code & 0xFFFF, m.status: self.status_word(now),
                  m.freq_cmd: self.regs[m.freq_set], m.freq_out: m.freq_to_register(f_out)}
        if m.current is not None:
            values[m.current] = min(0xFFFF, round(self.current_a(f_out) / m.current_unit_a))
        values.update(self.regs)
        for address, value in values.items():
            index = address - start
            if 0 <= index < len(registers):
                registers[index] = value

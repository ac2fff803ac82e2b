"""The runner: owns a procedure's lifecycle, its safety and its record.

``Runner(module, config=..., station_factory=...).run(overrides, resume=None) -> RunOutcome``:

1. **validate** the parameters (defaults + ``--set`` overrides; nothing is built or moved on bad input →
   exit 4, no run folder);
2. build the **station** (``station_factory(config, clock)``, a context manager yielding an object with
   ``devices: dict[str, device]`` and optionally ``snapshot() -> dict`` and
   ``check_interlocks() -> [(device, reason)]``); a failure to connect → exit 3, no run folder;
3. **snapshot** and write **start** (``rig`` = the configuration snapshot, ``devices`` = the station's
   snapshot): a new run folder, or the same folder with a ``resume`` start when ``resume=RUN_DIR``
   (completed steps are then skipped, see :class:`rig.procedure.Step`);
4. run ``module.run(ctx, params)`` with a watchdog thread polling every device's ``heartbeat()`` and the
   station's interlock checks, and SIGINT handled (first Ctrl-C: abort at the next checkpoint; second:
   ``KeyboardInterrupt`` at once);
5. **always**, whatever happened: put every device in its safe state (vibration sources, then the arm,
   then the rest; each attempted; each failure recorded), then write **stop** (``exit_status`` success /
   abort / fail, ``reason``, ``outcome``, ``exit_code``, ``verdict``) and close the record and station.

Heartbeats and the station's interlock checks run at every checkpoint and in the watchdog. An
interlock trip (watchdog, checkpoint, or a driver refusing a command beyond a limit) writes an ``interlock``
document, interrupts the procedure at once (SIGUSR1 → :class:`InterlockTripped` in the main thread when
the runner runs there; else at the next checkpoint) and ends the run with exit code 3. Motion is never
resumed after a trip. Logs go to ``<run_dir>/rig.log``.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading
import types
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.clock import make_clock
from rig.config_schema import ConfigError, to_dict
from rig.jsonenc import dumps
from rig.procedure import Abort, Context, InterlockTripped, ParameterError, validate_parameters
from rig.record import RecordError, RunRecord, parse_record
from rig.safety import (
    EXIT_ABORTED,
    EXIT_BAD_INPUT,
    EXIT_FAULT,
    Watchdog,
    check_heartbeats,
    classify,
    format_exception,
    make_safe,
)

__all__ = ["RunOutcome", "Runner"]

log = logging.getLogger("rig.runner")


@dataclass
class RunOutcome:
    """How a run ended. ``run_dir`` is None when it ended before a run folder was created."""

    exit_code: int
    exit_status: str | None
    outcome: str
    reason: str
    run_dir: Path | None = None
    result: Any = None


class _Control:
    """Abort/interlock flags shared by the signal handlers, the watchdog and the checkpoints."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.abort_reason: str | None = None
        self.interlock: tuple[str, str] | None = None
        self.sigints = 0
        self.in_cleanup = False


class Runner:
    """Run one procedure module safely (see the module docstring).

    Args:
        module: the procedure module (``NAME``, ``Parameters``, ``run``).
        config: the validated :class:`rig.config.RigConfig`.
        station_factory: ``(config, clock) -> context manager`` yielding the station.
        runs_dir: where run folders go (default: ``config.station.runs_dir``).
        progress: ``(fraction | None, message) -> None`` renderer (the CLI's progress bar).
        handle_signals: install the SIGINT/SIGUSR1 handlers (only possible in the main thread).
        watchdog_period_s: wall seconds between watchdog rounds.
        log_level: level of the ``rig.log`` file handler.
    """

    def __init__(self, module: types.ModuleType, *, config: Any, station_factory: Callable[[Any, Any], Any],
                 runs_dir: str | Path | None = None,
                 progress: Callable[[float | None, str], None] | None = None, handle_signals: bool = True,
                 watchdog_period_s: float = 0.25, log_level: int = logging.INFO) -> None:
        self.module = module
        self.config = config
        self.station_factory = station_factory
        self.runs_dir = Path(runs_dir if runs_dir is not None else config.station.runs_dir)
        self.progress = progress or (lambda fraction, message: None)
        self.handle_signals = handle_signals and threading.current_thread() is threading.main_thread()
        self.watchdog_period_s = watchdog_period_s
        self.log_level = log_level
        self._control = _Control()
        self._record: RunRecord | None = None

    # ------------------------------------------------------------------ control (thread-safe)
    def request_abort(self, reason: str = "abort requested") -> None:
        """Ask the procedure to abort at its next checkpoint (what the first Ctrl-C does)."""
        with self._control.lock:
            if self._control.abort_reason is None:
                self._control.abort_reason = reason

    def trip(self, device: str, reason: str) -> None:
        """Trip the interlock: record it, latch it, and interrupt the procedure."""
        with self._control.lock:
            if self._control.interlock is not None:
                return
            self._control.interlock = (device, reason)
        log.error("INTERLOCK on %s: %s", device, reason)
        if self._record is not None:
            with contextlib.suppress(Exception):
                self._record.interlock(device, reason)
        main_thread = threading.main_thread()
        from_other_thread = threading.current_thread() is not main_thread
        if self.handle_signals and not self._control.in_cleanup and from_other_thread:
            with contextlib.suppress(Exception):
                signal.pthread_kill(main_thread.ident, signal.SIGUSR1)  # type: ignore[arg-type]

    def _checkpoint(self, station: Any) -> None:
        c = self._control
        if c.interlock is not None:
            raise InterlockTripped(*c.interlock)
        lost = check_heartbeats(dict(getattr(station, "devices", {})))
        if lost is not None:
            self.trip(*lost)
            raise InterlockTripped(*lost)
        check = getattr(station, "check_interlocks", None)
        if callable(check):
            trips = check()
            if trips:
                self.trip(*trips[0])
                raise InterlockTripped(*trips[0])
        if c.abort_reason is not None:
            raise Abort(c.abort_reason)

    # ------------------------------------------------------------------ signals
    def _on_sigint(self, signum: int, frame: Any) -> None:
        c = self._control
        c.sigints += 1
        if c.in_cleanup:
            print("rig: putting devices in their safe state; please wait", file=sys.stderr, flush=True)
            return
        if c.sigints == 1:
            self.request_abort("aborted by the operator (Ctrl-C)")
            print("rig: abort requested; stopping at the next checkpoint (Ctrl-C again to abort at once)",
                  file=sys.stderr, flush=True)
            return
        raise KeyboardInterrupt

    def _on_sigusr1(self, signum: int, frame: Any) -> None:
        c = self._control
        if c.interlock is not None and not c.in_cleanup:
            raise InterlockTripped(*c.interlock)

    @contextlib.contextmanager
    def _signals(self) -> Iterator[None]:
        if not self.handle_signals:
            yield
            return
        old_int = signal.signal(signal.SIGINT, self._on_sigint)
        old_usr1 = signal.signal(signal.SIGUSR1, self._on_sigusr1)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, old_int)
            signal.signal(signal.SIGUSR1, old_usr1)

    # ------------------------------------------------------------------ the run
    def run(self, overrides: dict[str, Any] | None = None, *, resume: str | Path | None = None) -> RunOutcome:
        """Validate, build, record, run, make safe, stop. Returns the :class:`RunOutcome` (never raises for
        a procedure failure; the exit code says what happened)."""
        try:
            params, resume_dir = self._validate(overrides, resume)
        except (ConfigError, RecordError) as exc:
            log.error("%s", exc)
            return RunOutcome(EXIT_BAD_INPUT, None, "bad_input", str(exc))
        clock = make_clock(self.config.station.clock == "virtual",
                           rate=self.config.sim.rate if self.config.sim is not None else None)
        with self._signals():
            try:
                station_cm = self.station_factory(self.config, clock)
                station = station_cm.__enter__()
            except KeyboardInterrupt:
                return RunOutcome(EXIT_ABORTED, None, "aborted", "aborted while building the station")
            except Exception as exc:
                log.error("could not build the station: %s", exc, exc_info=True)
                code = EXIT_BAD_INPUT if isinstance(exc, ConfigError) else EXIT_FAULT
                return RunOutcome(code, None, "bad_input" if code == EXIT_BAD_INPUT else "fault",
                                  f"could not build the station: {type(exc).__name__}: {exc}")
            try:
                return self._run_with_station(station, clock, params, resume_dir)
            finally:
                self._control.in_cleanup = True
                try:
                    station_cm.__exit__(None, None, None)
                except Exception as exc:
                    log.error("closing the station failed: %s", exc, exc_info=True)

    def _validate(self, overrides: dict[str, Any] | None,
                  resume: str | Path | None) -> tuple[Any, Path | None]:
        if resume is None:
            return validate_parameters(self.module, overrides), None
        resume_dir = Path(resume)
        if overrides:
            raise ParameterError("--set", "parameters cannot be changed on --resume; the run keeps its own")
        docs = parse_record(resume_dir / "record.jsonl").documents
        start = next((d for d in docs if d.get("type") == "start"), None)
        if start is None:
            raise RecordError(f"{resume_dir}: no start document; cannot resume")
        if start.get("procedure") != self.module.NAME:
            raise RecordError(f"{resume_dir} is a {start.get('procedure')!r} run, not {self.module.NAME!r}")
        return validate_parameters(self.module, start.get("parameters") or {}), resume_dir

    def _run_with_station(self, station: Any, clock: Any, params: Any, resume_dir: Path | None) -> RunOutcome:
        snapshot = self.config.snapshot()
        station_snapshot: dict[str, Any] = {}
        snap = getattr(station, "snapshot", None)
        if callable(snap):
            try:  # a snapshot failure must not prevent making safe
                station_snapshot = snap()
            except Exception as exc:
                station_snapshot = {"error": f"{type(exc).__name__}: {exc}"}
        devices: dict[str, Any] = dict(getattr(station, "devices", {}))
        try:
            if resume_dir is None:
                record = RunRecord.create(self.runs_dir, self.module.NAME, to_dict(params), snapshot, clock,
                                          devices=station_snapshot)
            else:
                record = RunRecord.resume(resume_dir, clock, rig_snapshot=snapshot, devices=station_snapshot)
        except Exception as exc:
            results = make_safe(devices)
            return RunOutcome(EXIT_FAULT, None, "fault", f"could not create the run record: {exc}; "
                              f"safe state: {[r.device for r in results if r.error is None]}")
        self._record = record
        handler = logging.FileHandler(record.run_dir / "rig.log", encoding="utf-8")
        handler.setLevel(self.log_level)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        root = logging.getLogger()
        old_level = root.level
        root.addHandler(handler)
        root.setLevel(min(old_level or logging.WARNING, self.log_level))
        log.info("run %s: procedure %s, session %d", record.run_id, self.module.NAME, record.session)
        watchdog = Watchdog(devices, self.trip, period_s=self.watchdog_period_s,
                            extra_checks=getattr(station, "check_interlocks", None))
        ctx = Context(station=station, config=self.config, clock=clock, record=record, params=params,
                      log=logging.getLogger(f"procedures.{self.module.NAME}"),
                      checkpoint=lambda: self._checkpoint(station), progress=self.progress)
        error: BaseException | None = None
        result: Any = None
        try:
            try:
                watchdog.start()
                self._checkpoint(station)
                result = self.module.run(ctx, params)
            except BaseException as exc:
                error = exc
            finally:
                self._control.in_cleanup = True
                watchdog.stop()
            error = self._lost_device_check(watchdog, error)
            if error is not None and not isinstance(error, Abort | KeyboardInterrupt):
                log.error("procedure raised:\n%s", format_exception(error))
            return self._finish(record, devices, error, result)
        finally:
            root.removeHandler(handler)
            root.setLevel(old_level)
            handler.close()
            self._record = None

    def _lost_device_check(self, watchdog: Watchdog, error: BaseException | None) -> BaseException | None:
        """A procedure that failed on a device error before the watchdog's next round: if a heartbeat now
        says a device is lost (its link closed, or silent past the limit), that is the interlock."""
        if error is None or isinstance(error, Abort | KeyboardInterrupt):
            return error
        if self._control.interlock is not None:
            return error
        try:
            lost = watchdog.poll_once()
        except Exception as exc:
            log.error("final heartbeat check failed: %s", exc)
            return error
        if lost is None:
            return error
        self.trip(*lost)
        tripped = InterlockTripped(*lost)
        tripped.__cause__ = error
        log.error("procedure error caused by the lost device:\n%s", format_exception(error))
        return tripped

    def _finish(self, record: RunRecord, devices: dict[str, Any], error: BaseException | None,
                result: Any) -> RunOutcome:
        # a late interlock (tripped after the procedure returned) still counts
        if error is None and self._control.interlock is not None:
            error = InterlockTripped(*self._control.interlock)
        passed, summary = _verdict(result)
        verdict = classify(error, passed, summary)
        if verdict.outcome == "interlock" and not isinstance(error, InterlockTripped):
            record.interlock(verdict.interlock_device or "limits", str(error))  # a driver refused a command
        safe = make_safe(devices)
        failures = [{"device": r.device, "action": r.action, "error": r.error} for r in safe if r.error]
        for r in safe:
            if r.error:
                record.log("error", f"safe state of {r.device} ({r.action}) failed: {r.error}")
            elif r.action != "none":
                record.log("info", f"{r.device}: {r.action}() done")
        exit_code, status = verdict.exit_code, verdict.exit_status
        outcome, reason = verdict.outcome, verdict.reason
        if failures and exit_code in (0, 1, EXIT_ABORTED):
            exit_code, status, outcome = EXIT_FAULT, "fail", "fault"
            reason = f"{reason}; then making a device safe failed: " + "; ".join(
                f"{f['device']}: {f['error']}" for f in failures)
        stop_fields = {"outcome": outcome, "exit_code": exit_code, "safe_state_failures": failures,
                       "verdict": None if passed is None else ("pass" if passed else "fail")}
        try:
            dumps({"result": result})
            stop_fields["result"] = result if isinstance(result, dict) else None
        except (TypeError, ValueError) as exc:
            record.log("warning", f"procedure result not recordable as JSON: {exc}")
        record.stop(status, reason, **stop_fields)
        record.close()
        log.info("run %s ended: %s (exit %d): %s", record.run_id, outcome, exit_code, reason)
        return RunOutcome(exit_code, status, outcome, reason, record.run_dir, result)


def _verdict(result: Any) -> tuple[bool | None, str]:
    if result is None:
        return None, ""
    if isinstance(result, bool):
        return result, ""
    if isinstance(result, dict):
        passed = result.get("passed")
        return (None if passed is None else bool(passed)), str(result.get("summary", ""))
    passed = getattr(result, "passed", None)
    return (None if passed is None else bool(passed)), str(getattr(result, "summary", ""))

"""The runner: owns a procedure's lifecycle, its safety and its record.

``Runner(module, config=..., station_factory=...).run(overrides, resume=None) -> RunOutcome``:

1. **validate** the parameters (defaults + ``--set`` overrides) and the procedure's whole plan against the
   limits (:func:`rig.run.plan.validate_procedure`; nothing is built or moved on bad input →
   exit 4, no run folder);
2. write **start** before any device is reached (``rig`` = the configuration snapshot, the parameters,
   the versions; ``devices`` = ``{"connected": false}``): a new run folder, or the same folder with a
   ``resume`` start when ``resume=RUN_DIR`` (completed steps are then skipped, see
   :class:`rig.run.procedure.Step`); ``rig.log`` in the run folder from here on;
3. build the **station** (``station_factory(config, clock)``, a context manager yielding a
   :class:`rig.run.safety.StationLike`: ``devices``, ``roster()`` — every device with its declared role —,
   ``snapshot()`` and ``check_interlocks()``) and record its snapshot as the ``devices`` event. When it
   cannot be built: a **stop** ``fail`` with the reason (exit 3; 4 for a configuration error; a stop
   signal: ``abort``, exit 2), the traceback in ``rig.log`` only;
4. run ``module.run(ctx, params)`` with a watchdog thread polling every device's ``heartbeat()`` and the
   station's interlock checks, and the stop signals handled alike (SIGINT, SIGTERM, SIGHUP, SIGQUIT;
   first: abort at the next checkpoint — or, in a step without checkpoints, at its end (the report step
   checkpoints before each analysis and before it issues the certificate); second:
   :class:`rig.run.safety.Interrupted` at once); either way the run ends ``abort``, exit 2;
5. **always**, whatever happened: put every device in its safe state in the order of its role
   (:data:`drivers.roles.SHUTDOWN_ORDER`: generator, exciter and rotor, then the arm, then the cameras;
   each attempted; each failure recorded), read back what the devices then report
   (:mod:`rig.run.readback`) and whether each still answers (``heartbeats``: answering / recovered /
   lost, :func:`rig.run.safety.heartbeat_states`), and write **stop** (``exit_status`` success / abort /
   fail, ``reason``, ``outcome``, ``exit_code``, ``verdict``, ``safe_state``, ``heartbeats``, ``signal``
   when a signal ended the run) and
   close the record and station. An I/O error closing the record after the stop turns a pass or a fail
   into the fault exit 3 (an abort or a fault stands).

Heartbeats and the station's interlock checks run at every checkpoint and in the watchdog. An
interlock trip (watchdog, checkpoint, or a driver refusing a command beyond a limit) writes an ``interlock``
document, interrupts the procedure at once (SIGUSR1 → :class:`InterlockTripped` in the main thread when
the runner runs there; else at the next checkpoint) and ends the run with exit code 3. Motion is never
resumed after a trip. Logs go to ``<run_dir>/rig.log``; the console gets each error once (the CLI's exit
line): an interlock, a fault's traceback and a failed close of the record go to ``rig.log`` only.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading
import types
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from drivers.clock import Clock
from drivers.roles import Assignment
from rig.config.rig_config import RigConfig
from rig.config.schema import ConfigError, to_dict
from rig.record.jsonenc import dumps
from rig.record.writer import RecordError, RunRecord, parse_record
from rig.run.clock import make_clock
from rig.run.plan import validate_procedure
from rig.run.procedure import Abort, Context, InterlockTripped, ParameterError, validate_parameters
from rig.run.readback import read_back
from rig.run.safety import (
    EXIT_ABORTED,
    EXIT_BAD_INPUT,
    EXIT_FAULT,
    INTERLOCK_ERROR_TYPES,
    STOP_SIGNALS,
    Interrupted,
    StationLike,
    Watchdog,
    abort_reason,
    check_heartbeats,
    classify,
    format_exception,
    heartbeat_states,
    make_safe,
)

__all__ = ["RunOutcome", "Runner"]

log = logging.getLogger("rig.run.runner")


@dataclass
class RunOutcome:
    """How a run ended. ``run_dir`` is None when it ended before a run folder was created."""

    exit_code: int
    exit_status: str | None
    outcome: str
    reason: str
    run_dir: Path | None = None
    result: object = None


class _Control:
    """Abort/interlock flags shared by the signal handlers, the watchdog and the checkpoints."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.abort_reason: str | None = None
        self.interlock: tuple[str, str] | None = None
        self.signals: list[str] = []  # names of the stop signals received, in order
        self.in_cleanup = False


class Runner:
    """Run one procedure module safely (see the module docstring).

    Args:
        module: the procedure module (``NAME``, ``Parameters``, ``run``).
        config: the validated :class:`rig.config.rig_config.RigConfig`.
        station_factory: ``(config, clock) -> context manager`` yielding the station.
        runs_dir: where run folders go (default: ``config.station.runs_dir``).
        progress: ``(fraction | None, message) -> None`` renderer (the CLI's progress bar).
        handle_signals: install the SIGINT/SIGUSR1 handlers (only possible in the main thread).
        watchdog_period_s: wall seconds between watchdog rounds (at most ``station.heartbeat_timeout_s / 4``).
        log_level: level of the ``rig.log`` file handler.
        observers: ``(document) -> None`` offered every record document (:meth:`RunRecord.add_observer`).
    """

    def __init__(self, module: types.ModuleType, *, config: RigConfig,
                 station_factory: Callable[[RigConfig, Clock], AbstractContextManager[StationLike]],
                 runs_dir: str | Path | None = None,
                 progress: Callable[[float | None, str], None] | None = None, handle_signals: bool = True,
                 watchdog_period_s: float = 0.25, log_level: int = logging.INFO,
                 observers: tuple[Callable[[dict[str, Any]], None], ...] = ()) -> None:
        self.module = module
        self.config = config
        self.station_factory = station_factory
        self.runs_dir = Path(runs_dir if runs_dir is not None else config.station.runs_dir)
        self.progress = progress or (lambda fraction, message: None)
        self.handle_signals = handle_signals and threading.current_thread() is threading.main_thread()
        self.watchdog_period_s = watchdog_period_s
        self.log_level = log_level
        self.observers = observers
        self._control = _Control()
        self._record: RunRecord | None = None
        self._record_close_tried = False  # a failed close is not repeated (it would fail, and say so, again)
        # rig.log only, while a run lasts
        self._file_only: Callable[[str, BaseException | None], None] | None = None

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
        # rig.log only: the console gets the interlock once, in the exit line (rig.cli)
        self._log_file_only(f"INTERLOCK on {device}: {reason}")
        if self._record is not None:
            with contextlib.suppress(Exception):
                self._record.interlock(device, reason)
        main_thread = threading.main_thread()
        from_other_thread = threading.current_thread() is not main_thread
        if self.handle_signals and not self._control.in_cleanup and from_other_thread:
            with contextlib.suppress(Exception):
                signal.pthread_kill(main_thread.ident, signal.SIGUSR1)  # type: ignore[arg-type]

    def _log_file_only(self, message: str, exc: BaseException | None = None) -> None:
        """An error (with ``exc``'s traceback) for ``rig.log`` only while a run lasts — what the exit line
        says once on the console must not be printed before it too; outside a run, the usual log."""
        file_only = self._file_only
        if file_only is not None:
            file_only(message, exc)
        elif exc is not None:
            log.error("%s:\n%s", message, format_exception(exc))
        else:
            log.error("%s", message)

    def _checkpoint(self, station: StationLike, roster: list[Assignment]) -> None:
        c = self._control
        if c.interlock is not None:
            raise InterlockTripped(*c.interlock)
        lost = check_heartbeats(roster)
        if lost is not None:
            self.trip(*lost)
            raise InterlockTripped(*lost)
        trips = station.check_interlocks()
        if trips:
            self.trip(*trips[0])
            raise InterlockTripped(*trips[0])
        if c.abort_reason is not None:
            raise Abort(c.abort_reason)

    # ------------------------------------------------------------------ signals
    def _on_stop_signal(self, signum: int, frame: FrameType | None) -> None:
        """SIGINT, SIGTERM, SIGHUP, SIGQUIT alike: the first asks for an abort at the next checkpoint, the
        second aborts at once (:class:`Interrupted`); during cleanup they only say to wait."""
        c = self._control
        name = signal.Signals(signum).name
        c.signals.append(name)
        if c.in_cleanup:
            print(f"rig: {name}: putting devices in their safe state; please wait", file=sys.stderr,
                  flush=True)
            return
        if len(c.signals) == 1:
            self.request_abort(abort_reason(name))
            again = "Ctrl-C again" if name == "SIGINT" else "a second signal"
            print(f"rig: {name}: abort requested; stopping at the next checkpoint ({again} to abort at once)",
                  file=sys.stderr, flush=True)
            return
        raise Interrupted(name)

    def _on_sigusr1(self, signum: int, frame: FrameType | None) -> None:
        c = self._control
        if c.interlock is not None and not c.in_cleanup:
            raise InterlockTripped(*c.interlock)

    @contextlib.contextmanager
    def _signals(self) -> Iterator[None]:
        if not self.handle_signals:
            yield
            return
        old = {sig: signal.signal(sig, self._on_stop_signal) for sig in STOP_SIGNALS}
        old[signal.SIGUSR1] = signal.signal(signal.SIGUSR1, self._on_sigusr1)
        try:
            yield
        finally:
            for sig, handler in old.items():
                signal.signal(sig, handler)

    # ------------------------------------------------------------------ the run
    def run(self, overrides: dict[str, Any] | None = None, *, resume: str | Path | None = None) -> RunOutcome:
        """Validate, build, record, run, make safe, stop. Returns the :class:`RunOutcome` (never raises for
        a procedure failure; the exit code says what happened)."""
        try:
            params, resume_dir = self._validate(overrides, resume)
        except (ConfigError, RecordError) as exc:  # the outcome's reason says it (rig prints it once)
            return RunOutcome(EXIT_BAD_INPUT, None, "bad_input", str(exc))
        clock = make_clock(self.config.station.clock == "virtual",
                           rate=self.config.sim.rate if self.config.sim is not None else None)
        with self._signals():
            try:
                record = self._open_record(clock, params, resume_dir)
            except KeyboardInterrupt:
                return RunOutcome(EXIT_ABORTED, None, "aborted", "aborted before the run folder was created")
            except RecordError as exc:  # e.g. --resume of a run that already completed
                return RunOutcome(EXIT_BAD_INPUT, None, "bad_input", str(exc))
            except Exception as exc:
                return RunOutcome(EXIT_FAULT, None, "fault",
                                  f"could not create the run record: {type(exc).__name__}: {exc}")
            self._record, self._record_close_tried = record, False
            outcome: RunOutcome | None = None
            for observer in self.observers:  # live views (the dashboard): every document, start first
                record.add_observer(observer)
            try:
                with _run_log(record, self.log_level) as file_only:
                    self._file_only = file_only
                    log.info("run %s: procedure %s, session %d", record.run_id, self.module.NAME,
                             record.session)
                    try:
                        outcome = self._run_and_close_station(record, clock, params, file_only)
                    finally:
                        self._record, self._file_only = None, None
                        if not self._record_close_tried:  # _finish closes it first (reporting a failure)
                            record.close()
            except OSError as exc:
                if outcome is None:
                    raise  # the devices were made safe; the CLI reports the I/O fault (exit 3)
                return self._io_fault_after_stop(outcome, exc)
            return outcome

    def _run_and_close_station(self, record: RunRecord, clock: Clock, params: object,
                               file_only: Callable[[str, BaseException | None], None]) -> RunOutcome:
        try:
            station_cm = self.station_factory(self.config, clock)
            station = station_cm.__enter__()
        except (KeyboardInterrupt, Exception) as exc:
            return self._station_failed(record, exc, file_only)
        try:
            return self._run_with_station(record, station, clock, params)
        finally:
            self._control.in_cleanup = True
            try:
                station_cm.__exit__(None, None, None)
            except Exception as exc:
                log.error("closing the station failed: %s", exc, exc_info=True)

    def _open_record(self, clock: Clock, params: object, resume_dir: Path | None) -> RunRecord:
        """The run folder and its start document, written before any device is reached."""
        snapshot = self.config.snapshot()
        devices = {"connected": False}  # the station's snapshot follows as the ``devices`` event
        if resume_dir is None:
            return RunRecord.create(self.runs_dir, self.module.NAME, to_dict(params), snapshot, clock,
                                    devices=devices)
        return RunRecord.resume(resume_dir, clock, rig_snapshot=snapshot, devices=devices)

    def _station_failed(self, record: RunRecord, exc: BaseException,
                        file_only: Callable[[str, BaseException | None], None]) -> RunOutcome:
        """The station could not be built (nothing moved): stop ``fail`` (``abort`` on Ctrl-C) and why."""
        self._control.in_cleanup = True
        if isinstance(exc, KeyboardInterrupt):
            code, status, outcome = EXIT_ABORTED, "abort", "aborted"
            signame = self._control.signals[-1] if self._control.signals else "SIGINT"
            reason = f"{abort_reason(signame)} while connecting to the devices"
        else:
            code = EXIT_BAD_INPUT if isinstance(exc, ConfigError) else EXIT_FAULT
            status, outcome = "fail", "bad_input" if code == EXIT_BAD_INPUT else "fault"
            reason = f"could not build the station: {type(exc).__name__}: {exc}"
            file_only(reason, exc)  # the traceback goes to rig.log, not to the console
        record.stop(status, reason, outcome=outcome, exit_code=code, safe_state_failures=[], verdict=None,
                    **self._signal_field())
        log.info("run %s ended: %s (exit %d): %s", record.run_id, outcome, code, reason)
        return RunOutcome(code, status, outcome, reason, record.run_dir)

    def _signal_field(self) -> dict[str, str]:
        """``{"signal": NAME}`` for the stop document when a stop signal ended the run."""
        return {"signal": self._control.signals[0]} if self._control.signals else {}

    def _validate(self, overrides: dict[str, Any] | None,
                  resume: str | Path | None) -> tuple[Any, Path | None]:
        params, resume_dir = self._parameters(overrides, resume)
        validate_procedure(self.module, params, self.config)  # the whole plan, before any device (exit 4)
        return params, resume_dir

    def _parameters(self, overrides: dict[str, Any] | None,
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

    def _run_with_station(self, record: RunRecord, station: StationLike, clock: Clock,
                          params: object) -> RunOutcome:
        roster = station.roster()  # every device with its declared role, fixed for the run
        try:  # a snapshot failure must not prevent making safe
            station_snapshot: dict[str, Any] = station.snapshot()
        except Exception as exc:
            station_snapshot = {"error": f"{type(exc).__name__}: {exc}"}
        try:
            record.event("devices", station_snapshot)
        except Exception as exc:  # e.g. a snapshot not recordable as JSON: say so, carry on
            record.log("warning", f"station snapshot not recordable: {type(exc).__name__}: {exc}")
        # at least one round per heartbeat probe interval: a heartbeat counts the time between its checks
        # up to that interval (drivers/heartbeat.py), so rounds as frequent keep its count = wall time
        period_s = min(self.watchdog_period_s, self.config.station.heartbeat_timeout_s / 4.0)
        watchdog = Watchdog(roster, self.trip, period_s=period_s,
                            extra_checks=station.check_interlocks)
        ctx = Context(station=station, config=self.config, clock=clock, record=record, params=params,
                      log=logging.getLogger(f"procedures.{self.module.NAME}"),
                      checkpoint=lambda: self._checkpoint(station, roster), progress=self.progress)
        error: BaseException | None = None
        result: object = None
        try:
            watchdog.start()
            self._checkpoint(station, roster)
            result = self.module.run(ctx, params)
        except BaseException as exc:
            error = exc
        finally:
            self._control.in_cleanup = True
            watchdog.quiet()  # its probes keep idle drives' communication-loss stops from firing
        try:
            error = self._lost_device_check(watchdog, roster, error)
            if isinstance(error, (OSError, *INTERLOCK_ERROR_TYPES)):
                # an I/O or link fault (full disk, read-only folder, a device's socket) or an interlock (a
                # trip, a driver refusing a command beyond a limit): the exit line says what happened,
                # once; the traceback goes to rig.log only
                self._log_file_only(f"procedure raised {type(error).__name__}: {error}", error)
            elif error is not None and not isinstance(error, Abort | KeyboardInterrupt):
                log.error("procedure raised:\n%s", format_exception(error))
            return self._finish(record, roster, error, result)
        finally:
            watchdog.stop()

    def _lost_device_check(self, watchdog: Watchdog, roster: list[Assignment],
                           error: BaseException | None) -> BaseException | None:
        """A procedure that failed on a device error before the watchdog's next round: if a heartbeat now
        says a device is lost (its link closed, or silent past the limit) — or, failing that, a probe of
        each device now does (the procedure has ended: the links are free; a drive that stopped
        answering mid-poll may not yet be silent past the heartbeat limit) — that is the interlock."""
        if error is None or isinstance(error, Abort | KeyboardInterrupt):
            return error
        if self._control.interlock is not None:  # tripped already (its document is written): the cause
            tripped = InterlockTripped(*self._control.interlock)
            tripped.__cause__ = error
            self._log_file_only("procedure error after the interlock tripped", error)
            return tripped
        try:
            lost = watchdog.poll_once() or check_heartbeats(roster, wait=True)
        except Exception as exc:
            log.error("final heartbeat check failed: %s", exc)
            return error
        if lost is None:
            return error
        self.trip(*lost)
        tripped = InterlockTripped(*lost)
        tripped.__cause__ = error
        self._log_file_only("procedure error caused by the lost device", error)
        return tripped

    def _finish(self, record: RunRecord, roster: list[Assignment], error: BaseException | None,
                result: object) -> RunOutcome:
        # a late interlock (tripped after the procedure returned) still counts, and so does an abort
        # requested during a step without checkpoints (or after the last): the run did not finish as asked
        if error is None and self._control.interlock is not None:
            error = InterlockTripped(*self._control.interlock)
        elif error is None and self._control.abort_reason is not None:
            error = Abort(self._control.abort_reason)
        passed, summary = _verdict(result)
        certificate = result.get("certificate_result") if isinstance(result, dict) else None
        verdict = classify(error, passed, summary, certificate)
        safe = make_safe(roster)  # first: nothing written to disk (which may be full) comes before it
        if verdict.outcome == "interlock" and not isinstance(error, InterlockTripped):
            record.interlock(verdict.interlock_device or "limits", str(error))  # a driver refused a command
        failures = [{"device": r.device, "role": r.role, "error": r.error} for r in safe if r.error]
        for r in safe:
            if r.error:
                record.log("error", f"safe state of {r.device} ({r.role}) failed: {r.error}")
            else:
                record.log("info", f"{r.device}: safe_state() done")
        exit_code, status = verdict.exit_code, verdict.exit_status
        outcome, reason = verdict.outcome, verdict.reason
        if failures and exit_code in (0, 1, EXIT_ABORTED):
            exit_code, status, outcome = EXIT_FAULT, "fail", "fault"
            reason = f"{reason}; then making a device safe failed: " + "; ".join(
                f"{f['device']}: {f['error']}" for f in failures)
        heartbeats = heartbeat_states(roster, safe, self._control.interlock)
        for name, state in heartbeats.items():
            if state == "recovered":
                record.log("warning", f"{name} answers again after it was lost (the interlock stands)")
        stop_fields = {"outcome": outcome, "exit_code": exit_code, "safe_state_failures": failures,
                       "safe_state": read_back(roster, safe),  # what the devices now report
                       "heartbeats": heartbeats,
                       "verdict": _verdict_word(passed, certificate),
                       **self._signal_field()}
        try:
            dumps({"result": result})
            stop_fields["result"] = result if isinstance(result, dict) else None
        except (TypeError, ValueError) as exc:
            record.log("warning", f"procedure result not recordable as JSON: {exc}")
        record.stop(status, reason, **stop_fields)
        log.info("run %s ended: %s (exit %d): %s", record.run_id, outcome, exit_code, reason)
        ended = RunOutcome(exit_code, status, outcome, reason, record.run_dir, result)
        self._record_close_tried = True
        try:
            record.close()  # durable before the station closes (which may hang on a dead device)
        except OSError as exc:
            return self._io_fault_after_stop(ended, exc)
        return ended

    def _io_fault_after_stop(self, outcome: RunOutcome, exc: OSError) -> RunOutcome:
        """Closing the record or the log failed after the stop document (e.g. ENOSPC): the run cannot count
        as passed or failed on an incomplete record, so 0/1 become the I/O fault (3); 2, 3 and 4 stand.
        The reason says it (the exit line prints it once); the traceback goes to ``rig.log`` if still open."""
        if self._file_only is not None:
            self._file_only("closing the record failed", exc)
        return _after_close_failure(outcome, exc)


def _after_close_failure(outcome: RunOutcome, exc: OSError) -> RunOutcome:
    what = f"closing the record failed: {type(exc).__name__}: {exc}"
    if outcome.exit_code in (0, 1):
        return RunOutcome(EXIT_FAULT, outcome.exit_status, "fault", f"{outcome.reason}; then {what}",
                          outcome.run_dir, outcome.result)
    return RunOutcome(outcome.exit_code, outcome.exit_status, outcome.outcome,
                      f"{outcome.reason}; then {what}", outcome.run_dir, outcome.result)


class _LogFile(logging.FileHandler):
    """``rig.log``: a write failure (full disk) is noted once in ``failed`` instead of a traceback per
    message on the console (the run's own I/O failures are reported by the runner)."""

    failed: str | None = None

    def handleError(self, record: logging.LogRecord) -> None:  # noqa: N802 — logging's name
        if self.failed is None:
            self.failed = str(sys.exc_info()[1])


class _RecordLog(logging.Handler):
    """The procedures' warnings and errors (logger ``procedures``) as the record's ``log`` documents: the
    evidence itself, not only ``rig.log``, says what a run warned about (a sync recorded again, a calibrate
    position re-recorded). A document that cannot be written is dropped here: the run's own I/O failures
    are reported by the runner."""

    def __init__(self, record: RunRecord) -> None:
        super().__init__(logging.WARNING)
        self.record = record

    def emit(self, entry: logging.LogRecord) -> None:
        self.record.log(entry.levelname.lower(), f"{entry.name}: {entry.getMessage()}")

    def handleError(self, record: logging.LogRecord) -> None:  # noqa: N802 — logging's name
        pass


@contextlib.contextmanager
def _run_log(record: RunRecord, level: int) -> Iterator[Callable[[str, BaseException | None], None]]:
    """Log to ``<run_dir>/rig.log`` while the run lasts, and the procedures' warnings into the record too;
    yields ``file_only(message, exc)``, which writes an error with its traceback to that file and not to the
    console."""
    handler = _LogFile(record.run_dir / "rig.log", encoding="utf-8")
    handler.setLevel(level)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    old_level = root.level
    root.addHandler(handler)
    root.setLevel(min(old_level or logging.WARNING, level))
    procedures, to_record = logging.getLogger("procedures"), _RecordLog(record)
    procedures.addHandler(to_record)

    def file_only(message: str, exc: BaseException | None) -> None:
        exc_info = None if exc is None else (type(exc), exc, exc.__traceback__)
        handler.handle(log.makeRecord(log.name, logging.ERROR, __file__, 0, "%s", (message,), exc_info))

    try:
        yield file_only
    finally:
        procedures.removeHandler(to_record)
        root.removeHandler(handler)
        root.setLevel(old_level)
        handler.close()


def _verdict_word(passed: bool | None, certificate: str | None) -> str | None:
    """The stop document's ``verdict``: pass / fail / incomplete (None: the procedure gave none)."""
    if certificate == "INCOMPLETE":
        return "incomplete"
    return None if passed is None else ("pass" if passed else "fail")


def _verdict(result: object) -> tuple[bool | None, str]:
    """(passed, summary) of a procedure's result: a dict (``passed``, ``summary``), a bool, or None (no
    verdict; so is any other value)."""
    if isinstance(result, bool):
        return result, ""
    if isinstance(result, dict):
        passed = result.get("passed")
        return (None if passed is None else bool(passed)), str(result.get("summary", ""))
    return None, ""

"""The ``rig`` command: certify a stereo-camera measurement setup on a robot/exciter rig.

Commands (``rig COMMAND --help`` for each):
  certify   the whole certification (calibrate → sync → accuracy → sweep → report → certificate)
  run       one scripted procedure (``rig list`` shows them), or a procedure file
  report    report a run folder without hardware (issues its certificate, or writes a revision)
  check     validate a rig.toml and reach every device
  mock      a mock device (robot, exciter, rotor, generator) as a standalone server on 127.0.0.1
  list      the procedures and their parameters
  calibrate on-site calibration from a video pair of the slid plate (target.toml)
  measure   displacement and spectra from a video pair and a calibration
  preview   the cameras' live view with markers and aiming/focus hints (a local web page)

Without ``--config`` the built-in simulated rig is used. Exit codes (one meaning each): 0 pass,
1 certificate failed (FAIL or INCOMPLETE), 2 aborted (SIGINT/Ctrl-C, SIGTERM, SIGHUP, SIGQUIT),
3 interlock, hardware or I/O fault, 4 bad input (command line included).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import os
import pkgutil
import signal
import sys
import threading
import types
from collections.abc import Callable, MutableMapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

# only light modules here (tests/test_cli_start.py): the heavy ones are imported by the commands that use them
from rig.cli_logging import configure_logging
from rig.config.schema import ConfigError
from rig.run.exit_codes import EXIT_ABORTED, EXIT_BAD_INPUT, EXIT_FAULT, STOP_SIGNALS, Interrupted

if TYPE_CHECKING:
    from rig.config.rig_config import RigConfig

log = logging.getLogger("rig.cli")
MOCK_MODULES = {"robot": ("drivers.mock.bcap_server", []),
                "exciter": ("drivers.mock.vfd_server", ["--body", "exciter"]),
                "rotor": ("drivers.mock.vfd_server", ["--body", "rotor"]),
                "generator": ("drivers.mock.generator_server", []),
                "lab": ("rig.run.lab", [])}  # every device and the cameras on one world


def load_config(path: str | None) -> RigConfig:
    """:func:`rig.config.rig_config.load_config`, imported when a command needs the configuration (some of its
    sections import numpy)."""
    from rig.config.rig_config import load_config as load

    return load(path)


def _bad_input(field: str, message: str) -> Exception:
    """A :class:`rig.run.procedure.ParameterError` (exit 4), its module imported only when one is raised: it
    imports the drivers and the record writer, which ``rig --help`` does without."""
    from rig.run.procedure import ParameterError

    return ParameterError(field, message)


# ---------------------------------------------------------------------------- procedures
def discover_procedures(*, declarations: bool = False) -> dict[str, types.ModuleType]:
    """Every module of the ``procedures`` package that defines ``NAME``, ``Parameters`` and ``run``. With
    ``declarations`` (``rig list``), a procedure's light declaration ``procedures/params/<module>.py``
    (``NAME``, ``DESCRIPTION``, ``Parameters``, no numpy) stands in for the module where there is one."""
    import procedures
    from rig.run.procedure import check_declaration, check_procedure_module

    found: dict[str, types.ModuleType] = {}
    for info in pkgutil.iter_modules(procedures.__path__):
        if info.name.startswith("_") or info.ispkg:
            continue
        light = f"procedures.params.{info.name}"
        if declarations and importlib.util.find_spec(light) is not None:
            module, check = importlib.import_module(light), check_declaration
        else:
            module, check = importlib.import_module(f"procedures.{info.name}"), check_procedure_module
        try:
            check(module)
        except TypeError:
            continue  # a helper module of the package, not a procedure
        found[module.NAME] = module
    return dict(sorted(found.items()))


def load_procedure(name_or_path: str) -> types.ModuleType:
    """A procedure by name (``rig list``) or from a ``.py`` file; ParameterError if there is none."""
    from rig.run.procedure import check_procedure_module

    if name_or_path.endswith(".py"):
        path = Path(name_or_path)
        if not path.is_file():
            raise _bad_input("PROCEDURE", f"{name_or_path!r}: no such file")
        spec = importlib.util.spec_from_file_location(f"rig_user_procedure_{path.stem}", path)
        module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        sys.modules[module.__name__] = module  # dataclasses resolve string annotations through it
        spec.loader.exec_module(module)  # type: ignore[union-attr]
        try:
            check_procedure_module(module)
        except TypeError as exc:
            raise _bad_input("PROCEDURE", str(exc)) from exc
        return module
    available = discover_procedures()
    if name_or_path not in available:
        raise _bad_input("PROCEDURE", f"{name_or_path!r} is not a procedure; allowed: "
                                          f"{', '.join(available) or '(none installed)'} or a .py file")
    return available[name_or_path]


# ---------------------------------------------------------------------------- commands
def _run_procedure(module: types.ModuleType, args: argparse.Namespace) -> int:
    from rig.run.procedure import parse_set

    config = load_config(args.config)
    overrides = parse_set(args.set or [])
    if args.dry_run:  # before the runner's modules: a dry run does without pandas (tests/test_cli_start.py)
        return _dry_run(module, config, overrides, resume=args.resume)
    from rig.dashboard.live_run import run_state
    from rig.dashboard.terminal import TerminalProgress
    from rig.run.runner import Runner
    from rig.run.station import open_station

    live = _live_dashboard(module, config, args)
    state = live.state if live else run_state(module, config)
    terminal = TerminalProgress(state)
    runner = Runner(module, config=config, station_factory=open_station, runs_dir=args.runs_dir,
                    progress=live.progress(terminal.progress) if live else _then(state.on_progress,
                                                                                 terminal.progress),
                    observers=(live.observe if live else state.on_document, terminal.observe))
    if live:
        live.attach(runner)
    try:
        outcome = runner.run(overrides, resume=args.resume)
    finally:
        terminal.close()
        if live:
            live.close()
    if outcome.run_dir:
        _index_in_catalogue(Path(outcome.run_dir))
        _print_summary(Path(outcome.run_dir))
    where = f" — {outcome.run_dir}" if outcome.run_dir else ""
    print(f"rig: {module.NAME}: {outcome.outcome} (exit {outcome.exit_code}): {outcome.reason}{where}",
          file=sys.stderr if outcome.exit_code else sys.stdout, flush=True)
    return outcome.exit_code


def _then(first: Callable[[float | None, str], None],
          second: Callable[[float | None, str], None]) -> Callable[[float | None, str], None]:
    """A progress callback calling ``first`` then ``second``."""
    def both(fraction: float | None, message: str) -> None:
        first(fraction, message)
        second(fraction, message)
    return both


def _print_summary(run_dir: Path) -> None:
    """The closing table of a run that issued a certificate: each criterion (value, U, limit, decision), then
    the folder."""
    from rig.record.catalogue import read_entry
    from rig.record.reader import RecordError

    try:
        entry = read_entry(run_dir)
    except (RecordError, OSError) as exc:
        log.warning("no summary of %s: %s", run_dir, exc)
        return
    if not entry.criteria:  # no certificate: the outcome line names the folder and the reason
        return
    print(f"certificate: {entry.result}" + (" (simulated rig — not a certificate of hardware)"
                                             if entry.simulated else ""))
    print(criteria_table(entry.criteria))
    print(f"run folder: {run_dir}")


def criteria_table(criteria: Sequence[Any]) -> str:
    """Criteria (:class:`rig.record.catalogue.Criterion`) as an aligned text table: value, expanded
    uncertainty U, limit, decision."""
    rows = [("criterion", "value", "U", "unit", "limit", "decision")]
    for c in criteria:
        rows.append((c.criterion, "-" if c.value is None else f"{c.value:.4g}",
                     "-" if c.expanded_uncertainty is None else f"{c.expanded_uncertainty:.2g}", c.unit or "",
                     "-" if c.limit_value is None else f"{c.comparison} {c.limit_value:g}", c.status))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    right = {1, 2}  # numbers right-aligned
    return "\n".join("  " + "  ".join(cell.rjust(w) if i in right else cell.ljust(w)
                                       for i, (cell, w) in enumerate(zip(row, widths, strict=True))).rstrip()
                     for row in rows)


def _live_dashboard(module: types.ModuleType, config: Any, args: argparse.Namespace) -> Any:
    """The run's dashboard (rig.dashboard.live_run.LiveDashboard), or None with --no-dashboard."""
    if args.no_dashboard:
        return None
    from rig.dashboard.live_run import LiveDashboard
    from rig.dashboard.server import DashboardError

    host = args.dashboard_host or "127.0.0.1"
    try:
        return LiveDashboard(module, config, host=host, port=args.dashboard_port,
                             allow_remote=args.dashboard_host is not None)
    except DashboardError as exc:
        raise _bad_input("--dashboard-port", str(exc)) from exc


def _index_in_catalogue(run_dir: Path) -> None:
    """Add the finished run to its runs folder's catalogue; a failure only warns (the folder is the record,
    and `rig runs` indexes it later)."""
    import sqlite3

    from rig.record.catalogue import index_run
    from rig.record.reader import RecordError

    try:
        index_run(run_dir)
    except (RecordError, OSError, sqlite3.Error) as exc:
        log.warning("the run was not added to the catalogue of runs (rig runs will add it): %s", exc)


def _dry_run(module: types.ModuleType, config: Any, overrides: dict[str, Any], *, resume: str | None) -> int:
    """Print the procedure's plan and every limit check without connecting anything: 0 all pass, 4 not."""
    from rig.run.plan import PlanRefused, check_plan, format_plan, plan_of
    from rig.run.procedure import validate_parameters

    if resume:
        raise _bad_input("--dry-run", "not with --resume (a resumed run keeps its checked plan)")
    plan = plan_of(module, validate_parameters(module, overrides), config)
    if plan is None:
        print(f"rig: {module.NAME} declares no plan (no plan(params, config) in its module): nothing to "
              "check before connecting; its drivers check every command before sending it")
        return 0
    checks = check_plan(plan, config)
    print(format_plan(plan, checks))
    if any(not c.passed for c in checks):
        print(f"rig: dry run of {module.NAME}: refused (exit {EXIT_BAD_INPUT}): {PlanRefused(plan, checks)}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"rig: dry run of {module.NAME}: all {len(checks)} checks pass; nothing was connected")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    name = args.procedure
    if name is None:
        if not args.resume:
            raise _bad_input("PROCEDURE", "missing; give a procedure name or file (or --resume RUN)")
        from rig.record.writer import parse_record

        docs = parse_record(Path(args.resume) / "record.jsonl").documents
        name = next((d.get("procedure") for d in docs if d.get("type") == "start"), None)
        if not isinstance(name, str):
            raise _bad_input("--resume", f"{args.resume!r} has no start document naming its procedure")
    return _run_procedure(load_procedure(name), args)


def cmd_certify(args: argparse.Namespace) -> int:
    return _run_procedure(load_procedure("certify"), args)


def cmd_report(args: argparse.Namespace) -> int:
    """Issue the run's certificate, or — when it was issued — write a revision beside it and say so."""
    run_dir = Path(args.run)
    if not (run_dir / "record.jsonl").is_file():
        raise _bad_input("RUN", f"{args.run!r} is not a run folder (no record.jsonl)")
    from rig.record.writer import record_is_open

    if record_is_open(run_dir):  # its own report step issues the certificate from the complete record
        raise _bad_input("RUN", f"{args.run!r} is still running (a rig process has its record open): a "
                         "certificate is issued only from a finished record, by the run's own report step; "
                         "`rig report` it after the run has ended")
    from reports.build import build_report
    from reports.errors import ReportError

    try:
        result = build_report(run_dir, sync=args.sync)
    except ReportError as exc:
        print(f"rig: report of {run_dir} failed: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if result.revision is None:
        print(f"rig: report of {run_dir}: {result.result} — certificate issued: {result.certificate_json}; "
              f"{result.report_html}")
    else:
        changes = result.changes or {}
        print(f"rig: {run_dir} already has an issued certificate ({changes.get('issued_result')}); it is not "
              f"rewritten. Revision {changes.get('revision')} (sync {changes.get('sync_method')}): "
              f"{result.result} — {result.revision}")
        for line in changes.get("summary", []):
            print(f"  changed: {line}" if "→" in line else f"  {line}")
    return 1 if result.result in ("FAIL", "INCOMPLETE") else 0


def cmd_check(args: argparse.Namespace) -> int:
    if args.schema:
        from rig.config.rig_config import RigConfig
        from rig.config.schema import describe

        for row in describe(RigConfig):
            allowed = f"  [{row['allowed']}]" if row["allowed"] else ""
            print(f"{row['field']}: {row['type']} = {row['default']!r}{allowed}")
            if row["doc"]:
                print(f"    {row['doc']}")
        return 0
    config = load_config(args.config)
    devices = list(config.devices.configured())
    print(f"configuration {config.source}: valid ({config.station.name}; cameras "
          f"{', '.join(config.camera_names())}; devices {', '.join(devices)})")
    if args.no_devices:
        return 0
    from rig.run.clock import make_clock
    from rig.run.station import open_station

    clock = make_clock(config.station.clock == "virtual", rate=config.sim.rate if config.sim else None)
    failures = 0
    with open_station(config, clock, keep_going=True) as station:  # each device tried on its own
        for name in [*devices, *(n for n in station.unreachable if n not in devices)]:
            if name in station.unreachable:
                print(f"  {name:10s} NOT REACHABLE: {station.unreachable[name]}")
                failures += 1
                continue
            try:
                ok = station.devices[name].heartbeat(wait=True)  # probes now (plain heartbeat() only reports)
                print(f"  {name:10s} {'reachable' if ok is not False else 'NOT REACHABLE'}")
                failures += ok is False
            except Exception as exc:
                print(f"  {name:10s} NOT REACHABLE: {type(exc).__name__}: {exc}")
                failures += 1
    return EXIT_FAULT if failures else 0


def cmd_mock(args: argparse.Namespace) -> int:
    module_name, fixed = MOCK_MODULES[args.device]
    module = importlib.import_module(module_name)
    # the mock's own --help/usage/errors name it as typed here (``rig mock robot``)
    return int(module.main([*fixed, *args.options], prog=f"rig mock {args.device}") or 0)


def cmd_demo(args: argparse.Namespace) -> int:
    """Write the twin's sample videos and print the commands that calibrate and measure them."""
    from rig.demo import next_commands, write_demo

    folder = Path(args.dir)
    if folder.exists() and any(folder.iterdir()):
        raise _bad_input("DIR", f"{args.dir!r} is not empty; give a new or empty folder for the demo")
    files = write_demo(folder)
    print(f"rig demo: sample videos from the digital twin in {folder} (what they show: {files.truth_txt})")
    print("calibrate the camera pair from the plate videos, then measure the vibrating column:")
    for command in next_commands(files, folder):
        print(f"  {command}")
    return 0


def cmd_preview(args: argparse.Namespace) -> int:
    """The cameras' live view with markers and aiming/focus hints, until Ctrl-C or the page's Abort."""
    from rig.dashboard.server import DashboardError
    from rig.preview import run_preview

    try:
        state = run_preview(load_config(args.config), calibration=args.calibration,
                            host=args.dashboard_host or "127.0.0.1", port=args.dashboard_port,
                            allow_remote=args.dashboard_host is not None, interval_s=args.interval_s,
                            max_updates=args.updates)
    except DashboardError as exc:
        raise _bad_input("--dashboard-host", str(exc)) from exc
    except KeyboardInterrupt:
        print("rig preview: stopped", file=sys.stderr)
        return 0
    for item in (state.fields["hints"] or {}).get("items", []):
        print(f"  {item['level']:4s} {item['text']}")
    return 0


def _runs_dir(args: argparse.Namespace) -> Path:
    return Path(args.runs_dir or load_config(args.config).station.runs_dir)


def cmd_runs(args: argparse.Namespace) -> int:
    """List the run folders (catalogue synced with them first), show one run, or a setup's trend."""
    from rig.record import catalogue

    if args.action in ("show", "trend") and not args.target:
        raise _bad_input("RUN|SETUP", f"`rig runs {args.action}` needs "
                                          f"{'a run' if args.action == 'show' else 'a setup name'}")
    runs_dir = _runs_dir(args)
    synced = catalogue.sync(runs_dir)
    for run_id, why in sorted(synced.unreadable.items()):
        print(f"rig runs: {run_id} not indexed: {why}", file=sys.stderr)
    if args.action == "show":
        return _show_run(runs_dir, args.target)
    if args.action == "trend":
        return _show_trend(runs_dir, args.target, Path(args.out) if args.out else runs_dir)
    entries = catalogue.list_runs(runs_dir, setup=args.setup)
    if not entries:
        print(f"no runs in {runs_dir}" + (f" of setup {args.setup!r}" if args.setup else ""))
        return 0
    print(f"{'run':44s} {'setup':18s} {'procedure':10s} {'started (UTC)':20s} {'exit':8s} {'result':10s} "
          "criteria passed")
    for e in entries:
        passed = sum(c.status == "PASS" for c in e.criteria)
        result = (e.result or "-") + (" (sim)" if e.simulated and e.result else "")
        print(f"{e.run_id:44s} {(e.setup or '-')[:18]:18s} {(e.procedure or '-')[:10]:10s} "
              f"{(e.started_utc or '-')[:19]:20s} {e.exit_status or 'running?':8s} {result:10s} "
              f"{f'{passed}/{len(e.criteria)}' if e.criteria else '-'}")
    return 0


def _show_run(runs_dir: Path, run: str) -> int:
    from rig.record.catalogue import find_run

    entry = find_run(runs_dir, run)
    if entry is None:
        raise _bad_input("RUN", f"{run!r} is not a run folder in {runs_dir} (see `rig runs`)")
    print(f"run {entry.run_id} — {entry.folder}")
    print(f"  setup {entry.setup!r}, procedure {entry.procedure}, simulated {entry.simulated}")
    print(f"  started {entry.started_utc}, stopped {entry.stopped_utc or '(no stop document)'}: "
          f"{entry.exit_status or '-'} {entry.stop_reason or ''}".rstrip())
    print(f"  certificate: {entry.result or 'none issued'}")
    if entry.criteria:
        print(criteria_table(entry.criteria))
    return 0


def _show_trend(runs_dir: Path, setup: str, out_dir: Path) -> int:
    from reports.trend import trend_frame, write_trend
    from rig.record.catalogue import list_runs

    frame = trend_frame(list_runs(runs_dir, setup=setup))
    if frame.empty:
        raise _bad_input("SETUP", f"no certificate of setup {setup!r} in {runs_dir} (see `rig runs`)")
    table = frame.pivot_table(index=["started_utc", "run_id"], columns="criterion", values="value",
                              aggfunc="first", sort=False)
    print(table.to_string(float_format=lambda v: f"{v:.4g}"))
    csv_path, png_path = write_trend(frame, setup, out_dir)
    print(f"rig runs trend: {csv_path}" + (f", {png_path}" if png_path else ""))
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    """Run (or resume) the measurement of a monitoring archive on Dask."""
    from reports.figures import save_png
    from reports.trend import archive_trend_figure
    from rig.deploy.batch import run_batch, target_trend
    from rig.deploy.batch_manifest import ManifestError, load_manifest

    try:
        manifest = load_manifest(args.manifest)
    except ManifestError as exc:
        raise _bad_input(f"MANIFEST {exc.field}", str(exc).split(": ", 1)[-1]) from exc
    out = Path(args.out)
    report = run_batch(manifest, out, scheduler=args.scheduler, n_workers=args.workers,
                       show_progress=sys.stderr.isatty())
    figure = archive_trend_figure(target_trend(out))
    if figure is not None:
        save_png(figure, out / "trend.png")
    rate = report.video_seconds / report.seconds if report.seconds > 0 else float("nan")
    print(f"rig batch: {len(report.done)} tasks done ({report.video_seconds:.0f} s of video, {rate:.2f}× "
          f"real time), {len(report.skipped)} skipped as done before, {len(report.failed)} failed, "
          f"{len(report.unmatched)} unmatched segments — {out}")
    for text in report.jumps:
        print(f"  timing: {text}")
    for task, error in report.failed.items():
        print(f"  failed {task}: {error}", file=sys.stderr)
    return EXIT_BAD_INPUT if report.failed else 0


def cmd_list(args: argparse.Namespace) -> int:
    from rig.run.procedure import parameter_table

    procedures = discover_procedures(declarations=True)
    if not procedures:
        print("no procedures installed (the procedures/ package is empty)")
    for name, module in procedures.items():
        doc = getattr(module, "DESCRIPTION", None) or (module.__doc__ or "").strip().splitlines()[0:1]
        print(f"{name}: {doc if isinstance(doc, str) else ''.join(doc)}")
        for row in parameter_table(module):
            allowed = f" ({row['allowed']})" if row["allowed"] else ""
            doc_text = f" — {row['doc']}" if row["doc"] else ""
            print(f"    {row['name']} = {row['default']!r}{allowed}{doc_text}")
    return 0


# ---------------------------------------------------------------------------- parser
def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="RIG.TOML",
                   help="rig configuration (default: the built-in simulated rig)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a procedure parameter "
                   "(repeatable; values are TOML literals: 30, 2.5, true, [1, 2], \"text\")")
    p.add_argument("--resume", metavar="RUN",
                   help="continue the run folder RUN after its last completed step")
    p.add_argument("--runs-dir", metavar="DIR", help="where run folders go (default: station.runs_dir)")
    p.add_argument("--dry-run", action="store_true", help="print the plan (steps, poses, frequencies, "
                   "durations) and its limit checks without connecting any device; exit 0 if all pass, "
                   "4 if not")
    _add_dashboard_options(p)


def _add_dashboard_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-dashboard", action="store_true", help="do not serve the live dashboard")
    p.add_argument("--dashboard-port", type=int, default=0, metavar="PORT",
                   help="the live dashboard's port on 127.0.0.1 (default 0: chosen automatically; the URL is "
                   "printed at start)")
    p.add_argument("--dashboard-host", metavar="HOST",
                   help="serve the dashboard on this interface instead of 127.0.0.1 (e.g. 0.0.0.0); "
                   "the URL then carries a random token, required by every request")


class _Parser(argparse.ArgumentParser):
    """argparse with the usage error exiting 4 (bad input), not argparse's 2 (which means aborted)."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level argument parser with one sub-command per verb (sub-parsers are
    :class:`_Parser` too: argparse makes them of the parent's class)."""
    parser = _Parser(prog="rig", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output, third-party "
                        "libraries' (FFmpeg, OpenCV, pymodbus, Dask) included (-vv: debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("certify", help="run the whole certification", description=cmd_certify.__doc__ or
                       "Run the certify procedure: calibrate, sync, accuracy, sweep, report, certificate.")
    _add_run_options(p)
    p = sub.add_parser("run", help="run one procedure", description="Run one scripted procedure.")
    p.add_argument("procedure", metavar="PROCEDURE", nargs="?",
                   help="a procedure name (see `rig list`) or a .py file (with --resume: the run's)")
    _add_run_options(p)
    p = sub.add_parser("report", help="report a run folder (a revision when its certificate was issued)",
                       description="Build tables/, figures/, report.html and certificate.json from a run "
                                   "folder's record, without hardware. A run whose certificate was issued "
                                   "is never rewritten: the report goes to RUN/revisions/<n>-<sync>/, with "
                                   "changes.json saying what differs from the issued certificate. A run "
                                   "still going (a rig process has its record open) is refused (exit 4): "
                                   "its own report step issues the certificate.")
    p.add_argument("run", metavar="RUN", help="the run folder")
    p.add_argument("--sync", metavar="METHOD", help="synchronization method: trajectory (default), "
                   "bandlimited, cubic, or linear (the paper's)")
    p = sub.add_parser("check", help="validate a rig.toml and reach its devices",
                       description="Validate the configuration and ping every device.")
    p.add_argument("--config", metavar="RIG.TOML", help="rig configuration (default: the simulated rig)")
    p.add_argument("--no-devices", action="store_true", help="only validate the configuration")
    p.add_argument("--schema", action="store_true",
                   help="print every rig.toml field with its type, default and allowed values")
    p = sub.add_parser("mock", help="run a mock device server on 127.0.0.1",
                       description="Start a mock device as a standalone server on 127.0.0.1, backed by a "
                                   "simulated world, for trying a real configuration without hardware. "
                                   "Options after the device name go to the mock "
                                   "(try `rig mock robot --help`).")
    p.add_argument("device", choices=sorted(MOCK_MODULES), help="which device")
    p.add_argument("options", nargs=argparse.REMAINDER, help="options of the mock server")
    sub.add_parser("list", help="list the procedures and their parameters",
                   description="List the procedures with their parameters, defaults and ranges.")
    p = sub.add_parser("batch", help="measure a monitoring archive on Dask (resumable)",
                       description="Measure every segment pair of a manifest's camera pairs (the same code "
                                   "as rig measure) as Dask tasks; results as a partitioned Parquet dataset.")
    p.add_argument("manifest", metavar="MANIFEST.TOML", help="sites, camera pairs, calibrations and videos")
    p.add_argument("--out", required=True, metavar="DIR", help="the batch's output folder (rerun to resume)")
    p.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="an existing Dask scheduler (default: a LocalCluster on this machine)")
    p.add_argument("--workers", type=int, metavar="N", help="LocalCluster worker processes (default: the "
                   "cores this process may use, a container's CPU quota included)")
    p = sub.add_parser("runs", help="the catalogue of runs: list, show one, a setup's trend",
                       description="List the run folders (from an SQLite index synced with the folders "
                                   "first), show one run's certificate, or a setup's criteria over time.")
    p.add_argument("action", nargs="?", choices=("list", "show", "trend"), default="list",
                   help="list (default), show RUN, or trend SETUP")
    p.add_argument("target", nargs="?", metavar="RUN|SETUP", help="the run (show) or the setup name (trend)")
    p.add_argument("--setup", help="list only the runs of this setup (station.name)")
    p.add_argument("--out", metavar="DIR", help="trend: where the CSV and PNG go (default: the runs folder)")
    p.add_argument("--runs-dir", metavar="DIR", help="the runs folder (default: station.runs_dir)")
    p.add_argument("--config", metavar="RIG.TOML", help="rig configuration naming station.runs_dir")
    p = sub.add_parser("preview", help="live view of the cameras for aiming and focusing",
                       description="Serve the cameras' latest frames with the markers found and hints "
                                   "(saturation, marker size, blur, count per camera, the epipolar check "
                                   "with --calibration) on a local page, until Ctrl-C.")
    p.add_argument("--config", metavar="RIG.TOML", help="rig configuration (default: the simulated rig)")
    p.add_argument("--calibration", metavar="CALIBRATION.JSON", help="check the found markers against its "
                   "epipolar geometry")
    p.add_argument("--interval-s", type=float, default=0.5, metavar="S", help="seconds between views")
    p.add_argument("--updates", type=int, metavar="N", help="stop after N views (default: until Ctrl-C)")
    p.add_argument("--dashboard-port", type=int, default=0, metavar="PORT",
                   help="the page's port on 127.0.0.1 (default 0: chosen automatically)")
    p.add_argument("--dashboard-host", metavar="HOST", help="serve on this interface instead (a token then "
                   "required in the URL)")
    p = sub.add_parser("demo", help="write sample stereo videos to try calibrate and measure",
                       description="Write a short stereo video pair of the slid calibration plate, its "
                                   "target.toml, and a pair of a vibrating marker column, all rendered by "
                                   "the digital twin; print the commands that calibrate and measure them.")
    p.add_argument("dir", metavar="DIR", help="a new or empty folder for the demo files")
    from rig.cli_measure import add_parsers

    add_parsers(sub)  # calibrate (on site, from videos) and measure
    return parser


def _interrupted(signum: int, frame: object) -> None:
    raise Interrupted(signal.Signals(signum).name)


# what OpenBLAS (numpy's and scipy's wheels), MKL and BLIS read, once, when they are loaded
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def single_threaded_blas_by_default(environ: MutableMapping[str, str]) -> None:
    """One BLAS thread for every BLAS library the process loads later, unless ``environ`` (the process's
    ``os.environ``) already sets its variable: its idle threads only spin through our small solves
    (:mod:`rig.stereo.blas`). Called by :func:`main` as the process's command, before numpy is imported."""
    for name in BLAS_THREAD_VARIABLES:
        environ.setdefault(name, "1")


def main(argv: list[str] | None = None) -> int:
    """Run the ``rig`` command; return its exit code (the one place that maps outcomes to exit codes:
    see :mod:`rig.run.safety`). Outside a run (whose runner handles them itself) a stop signal ends the
    command as an abort (2); an I/O error (full disk, read-only folder) that escapes a command is a
    fault (3) with a one-line message — a run has made its devices safe before it gets here.

    As the process's command (``argv`` None) the outcome is final when this returns: stop signals are then
    ignored, so a second Ctrl-C arriving while the process exits cannot turn exit 2 into a death by
    SIGINT. An in-process caller (``argv`` given) gets its own handlers back."""
    if argv is None:
        single_threaded_blas_by_default(os.environ)
    in_main = threading.current_thread() is threading.main_thread()
    old = {sig: signal.signal(sig, _interrupted) for sig in STOP_SIGNALS if in_main}
    try:
        return _main(argv)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, signal.SIG_IGN if argv is None else handler)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    configure_logging(args.verbose, sys.stderr)
    if args.command is None:
        parser.print_help()
        return 0
    from rig.cli_measure import COMMANDS as DEPLOYMENT_COMMANDS

    commands = {"run": cmd_run, "certify": cmd_certify, "report": cmd_report, "check": cmd_check,
                "list": cmd_list, "mock": cmd_mock, "demo": cmd_demo, "runs": cmd_runs, "batch": cmd_batch,
                "preview": cmd_preview,
                **DEPLOYMENT_COMMANDS}
    try:
        return commands[args.command](args)
    except ConfigError as exc:  # ParameterError is one
        print(f"rig: bad input: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        name = exc.signal_name if isinstance(exc, Interrupted) else "SIGINT"
        print(f"rig: interrupted ({name})", file=sys.stderr)
        return EXIT_ABORTED
    except OSError as exc:
        print(f"rig: I/O fault: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAULT
    except Exception as exc:
        from rig.record.reader import RecordError  # here, not at the top: it imports numpy

        if not isinstance(exc, RecordError):
            raise
        print(f"rig: bad input: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


def _one_line(exc: OSError) -> str:
    """``[Errno 28] No space left on device: runs/…/record.jsonl`` as one line, naming the file."""
    if exc.errno is None:
        return " ".join((str(exc) or type(exc).__name__).split())
    text = f"[Errno {exc.errno}] {exc.strerror}" + (f": {exc.filename}" if exc.filename is not None else "")
    return " ".join(text.split())


if __name__ == "__main__":
    raise SystemExit(main())

"""``python -m reports RUN [--sync METHOD] [--no-figures]``: rebuild a run folder's report.

The ``rig report`` command is meant to call :func:`main` (or :func:`reports.build.build_report`).
Exit status: 0 PASS, 1 FAIL, 2 INCOMPLETE, 3 the report could not be built (the message says why).
"""

from __future__ import annotations

import argparse
import sys

from reports.build import build_report
from reports.errors import ReportError
from rig.config.analysis import SYNC_METHODS

EXIT_CODES = {"PASS": 0, "FAIL": 1, "INCOMPLETE": 2}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rig report",
        description="Build tables, figures, report.html and certificate.json from a run folder (no "
        "hardware); a run whose certificate was issued gets a revision in revisions/<n>-<sync>/ instead.",
    )
    parser.add_argument("run", help="the run folder")
    parser.add_argument(
        "--sync",
        choices=SYNC_METHODS,
        default=None,
        help="primary synchronization method (default: the rig's, else trajectory); the run's [report] "
        "comparison methods (by default 'linear', the paper's) are shown beside it",
    )
    parser.add_argument("--no-figures", action="store_true",
                        help="skip the figures (faster; default: the run's [report] figures)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        res = build_report(args.run, sync=args.sync,
                           no_figures_why="--no-figures" if args.no_figures else None)
    except (ReportError, OSError) as exc:  # OSError: a full disk, a read-only run folder
        print(f"rig report: {exc}", file=sys.stderr)
        return 3
    print(f"{res.result}  {res.report_html}")
    if res.revision is not None and res.changes is not None:
        print(f"  revision {res.changes['revision']} of the issued certificate "
              f"({res.changes['issued_result']}, unchanged): " + "; ".join(res.changes["summary"]))
    for c in res.certificate["criteria"]:
        value = "—" if c["value"] is None else f"{c['value']:.4g}"
        print(f"  {c['status']:<13} {c['id']:<26} {value:>10} {c['comparison']} {c['limit']:g} {c['unit']}")
    for note in res.notes:
        print(f"  note: {note}")
    return EXIT_CODES[res.result]


if __name__ == "__main__":
    raise SystemExit(main())

"""The ``rig`` command: parses arguments, builds a station, runs procedures and reports."""

from __future__ import annotations

import argparse


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level argument parser with one sub-command per verb."""
    parser = argparse.ArgumentParser(prog="rig", description=__doc__)
    parser.add_subparsers(dest="command", metavar="COMMAND")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the ``rig`` command; return its exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

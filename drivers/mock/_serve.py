"""Scaffolding shared by the mock servers: the TCP accept loop and the stand-alone command line.

* :func:`accept_loop` — accept connections on a listening socket until a stop event is set, handing
  each to a callback (the b-CAP, SCPI and VFD mocks);
* :func:`require_loopback` — every mock binds a loopback address only: it speaks a real controller's
  protocol with no authentication and moves nothing real, so it must never be reachable from the network
  (where a program looking for the real device could find it);
* :func:`standalone_parser`, :func:`start_standalone`, :func:`wait_for_interrupt` — what every
  ``python -m drivers.mock.<server>`` needs: ``--port``/``--rate`` options, logging, its own simulated
  world on a paced virtual clock, and serving until Ctrl-C or ``kill`` (SIGTERM), both a clean stop.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import logging
import signal
import socket
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    from drivers.sim.world import World

log = logging.getLogger("drivers.mock")

__all__ = ["accept_loop", "loopback_host", "require_loopback", "standalone_parser", "start_standalone",
           "wait_for_interrupt"]


def require_loopback(host: str, what: str = "host") -> str:
    """``host`` if it is an IPv4 loopback address (127.0.0.0/8; ``"localhost"`` → ``"127.0.0.1"``), else
    ``ValueError`` naming it: mock servers bind 127.0.0.1 only, never an address reachable from outside."""
    text = str(host).strip()
    if text.lower() == "localhost":
        return "127.0.0.1"
    try:
        address = ipaddress.ip_address(text)
    except ValueError:
        address = None
    if address is None or address.version != 4 or not address.is_loopback:
        raise ValueError(f"{what}={host!r} is not allowed: a mock server binds a loopback address only "
                         "(127.0.0.1, or 127.x.y.z), so that it is never reachable from the network")
    return text


def loopback_host(text: str) -> str:
    """argparse ``type`` for ``--host``: :func:`require_loopback` with argparse's error."""
    try:
        return require_loopback(text, "--host")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def accept_loop(listener: socket.socket, stopped: threading.Event,
                on_connection: Callable[[socket.socket], None], *, poll_s: float = 0.05) -> None:
    """Accept connections on ``listener`` and pass each to ``on_connection`` until ``stopped`` is set or
    the listener is closed; ``poll_s`` (s) is how often ``stopped`` is looked at."""
    try:
        listener.settimeout(poll_s)
    except OSError:  # closed before this thread got to run: nothing to serve
        return
    while not stopped.is_set():
        try:
            conn, _ = listener.accept()
        except TimeoutError:
            continue
        except OSError:  # the listener was closed
            return
        try:
            on_connection(conn)
        except Exception:  # one client's failure (e.g. reset before it was served) must not stop the server
            log.warning("mock server: a connection could not be served; accepting the next", exc_info=True)
            with contextlib.suppress(OSError):
                conn.close()


EXIT_BAD_INPUT = 4  # rig's exit code for bad input (rig.run.exit_codes; drivers sit below rig's layers)


class _BadInputParser(argparse.ArgumentParser):
    """argparse with ``rig``'s exit code for a usage error: 4 (bad input), not argparse's 2, which ``rig``
    keeps for a stop signal."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def standalone_parser(module: str, description: str, *, default_port: int,
                      prog: str | None = None) -> argparse.ArgumentParser:
    """Command line of ``python -m drivers.mock.<module>`` (or ``prog``, e.g. ``rig mock robot``) with
    ``--port`` (TCP on 127.0.0.1; 0 = any free port) and ``--rate`` (virtual seconds per wall second);
    callers add their own options."""
    parser = _BadInputParser(prog=prog or f"python -m drivers.mock.{module}", description=description)
    parser.add_argument("--port", type=int, default=default_port,
                        help=f"TCP port (default {default_port}; 0 = any free port)")
    parser.add_argument("--rate", type=float, default=1.0, help="virtual seconds per wall second")
    return parser


def start_standalone(parser: argparse.ArgumentParser,
                     argv: list[str] | None) -> tuple[argparse.Namespace, World]:
    """Parse ``argv``, log INFO to stderr, and build the server's own simulated world (seed 0) on a virtual
    clock paced at ``--rate``; return (options, world)."""
    from drivers.sim.clock import VirtualClock
    from drivers.sim.world import World

    options = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    return options, World(VirtualClock(rate=options.rate), seed=0)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def wait_for_interrupt() -> None:
    """Block until Ctrl-C or SIGTERM (``kill`` stops a server as cleanly as Ctrl-C) and return."""
    signal.signal(signal.SIGTERM, _interrupt)
    with contextlib.suppress(KeyboardInterrupt):
        threading.Event().wait()

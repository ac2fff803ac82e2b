"""The live dashboard's web server: one page, a server-sent-event stream, frames, and Abort.

``DashboardServer(state, host="127.0.0.1", port=0, on_abort=runner.request_abort).start()`` serves, from a
daemon thread (:class:`http.server.ThreadingHTTPServer`, one thread per client):

- ``GET /`` the page (``rig/data/dashboard.html``: vanilla JS and canvas, nothing fetched from elsewhere);
- ``GET /events`` a ``text/event-stream``: ``event: state`` messages whose ``data`` is one JSON object
  (:meth:`rig.dashboard.state.DashboardState.patch`: the fields, the plots' new rows, ``frames`` = the
  latest frame number per camera); at most one message per ``min_interval_s`` per client, changes in
  between coalesced (a slow client gets fewer, larger messages; nothing queues), ``: keepalive`` comments
  when idle;
- ``GET /state`` the whole state as JSON (what the page shows; tests poll it);
- ``GET /frame/CAMERA.jpg`` the camera's latest frame, downscaled and annotated (:mod:`rig.run.frame_tap`);
- ``POST /abort`` the operator's abort: ``on_abort(reason)`` (the runner's ``request_abort``, the same
  safe stop as a first Ctrl-C); 202, or 404 when there is nothing to abort. The request must carry the
  header ``X-Rig-Dashboard: abort`` (403 otherwise), which another site's page cannot send.

Bound to 127.0.0.1 by default. Any other ``host`` is refused unless ``allow_remote=True`` (the CLI's
``--dashboard-host``), and then every request needs ``?token=…``: a random token, printed in the URL
(403 without it). A failure in a client's thread is logged and ends that client only.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import secrets
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from rig.dashboard.state import DashboardState
from rig.run.frame_tap import FRAMES, FrameTap

__all__ = ["DashboardError", "DashboardServer", "is_loopback", "sse_message"]

log = logging.getLogger("rig.dashboard.server")
ABORT_HEADER = "X-Rig-Dashboard"
PAGE = Path(__file__).parents[1] / "data" / "dashboard.html"


class DashboardError(ValueError):
    """The dashboard cannot be served as asked (a non-loopback host without the explicit flag)."""


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def sse_message(event: str, data: dict[str, Any], event_id: int | None = None) -> bytes:
    """One server-sent event: ``event:``, optional ``id:``, one ``data:`` line of compact JSON, blank line."""
    text = json.dumps(data, separators=(",", ":"), allow_nan=False)
    head = f"event: {event}\n" + (f"id: {event_id}\n" if event_id is not None else "")
    return (head + f"data: {text}\n\n").encode("utf-8")


class DashboardServer:
    """The dashboard's HTTP server (see the module docstring). ``url`` is known after :meth:`start`."""

    def __init__(self, state: DashboardState, *, host: str = "127.0.0.1", port: int = 0,
                 on_abort: Callable[[str], None] | None = None, allow_remote: bool = False,
                 frames: FrameTap = FRAMES, min_interval_s: float = 0.1, keepalive_s: float = 10.0) -> None:
        if not is_loopback(host) and not allow_remote:
            raise DashboardError(f"dashboard host {host!r} is not a loopback address; serving on another "
                                 "interface needs --dashboard-host (and then a token in the URL)")
        if not 0 <= int(port) <= 65535:
            raise DashboardError(f"dashboard port {port!r} not allowed; allowed: 0 (automatic) to 65535")
        self.state, self.host, self.port = state, host, int(port)
        self.on_abort, self.frames = on_abort, frames
        self.token = None if is_loopback(host) else secrets.token_urlsafe(16)
        self.min_interval_s, self.keepalive_s = min_interval_s, keepalive_s
        self.closing = threading.Event()
        self.sent_versions: dict[int, int] = {}  # client id → the last state version sent
        self._httpd: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    def start(self) -> DashboardServer:
        handler = type("Handler", (_Handler,), {"dashboard": self})
        self._httpd = ThreadingHTTPServer((self.host, self.port), handler)
        self._httpd.daemon_threads = True
        self.port = self._httpd.server_address[1]
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="dashboard", daemon=True)
        self._thread.start()
        return self

    def close(self, linger_s: float = 1.0) -> None:
        """Give connected clients up to ``linger_s`` to receive the last state, then stop serving."""
        deadline = time.monotonic() + linger_s
        behind = lambda: any(v < self.state.version for v in list(self.sent_versions.values()))  # noqa: E731
        while time.monotonic() < deadline and behind():
            time.sleep(0.05)
        self.closing.set()
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()

    def __enter__(self) -> DashboardServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close(linger_s=0.0)


class _Handler(BaseHTTPRequestHandler):
    dashboard: DashboardServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("%s " + format, self.address_string(), *args)

    def _authorised(self) -> bool:
        token = self.dashboard.token
        if token is None:
            return True
        given = parse_qs(urlsplit(self.path).query).get("token", [""])[0]
        if secrets.compare_digest(given.encode(), token.encode()):
            return True
        self._send(403, "text/plain; charset=utf-8", b"a valid ?token= is required\n")
        return False

    def _send(self, code: int, content_type: str, body: bytes) -> None:
        self.send_response(code)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self) -> None:
        try:
            if not self._authorised():
                return
            path = urlsplit(self.path).path
            if path == "/":
                self._send(200, "text/html; charset=utf-8", PAGE.read_bytes())
            elif path == "/events":
                self._events()
            elif path == "/state":
                data, _ = self.dashboard.state.patch({})
                data["frames"] = self.dashboard.frames.seqs()
                self._send(200, "application/json", json.dumps(data, allow_nan=False).encode())
            elif path.startswith("/frame/") and path.endswith(".jpg"):
                jpeg = self.dashboard.frames.jpeg(path[len("/frame/"):-len(".jpg")])
                if jpeg is None:
                    self._send(404, "text/plain; charset=utf-8", b"no frame from this camera yet\n")
                else:
                    self._send(200, "image/jpeg", jpeg)
            else:
                self._send(404, "text/plain; charset=utf-8", b"not found\n")
        except (BrokenPipeError, ConnectionResetError):
            pass
        except Exception:
            log.warning("dashboard request %s failed", self.path, exc_info=True)

    def do_POST(self) -> None:
        try:
            if not self._authorised():
                return
            if urlsplit(self.path).path != "/abort":
                self._send(404, "text/plain; charset=utf-8", b"not found\n")
            elif self.headers.get(ABORT_HEADER) != "abort":
                # a page of another site can post a form here but cannot add this header without a CORS
                # preflight, which this server never approves: only the dashboard's own page can abort
                self._send(403, "text/plain; charset=utf-8", f"the {ABORT_HEADER}: abort header is required\n"
                           .encode())
            elif self.dashboard.on_abort is None:
                self._send(404, "application/json", b'{"abort":"nothing to abort"}')
            else:
                self.dashboard.on_abort("aborted by the operator (dashboard)")
                log.warning("abort requested from the dashboard (%s)", self.address_string())
                self._send(202, "application/json", b'{"abort":"requested"}')
        except (BrokenPipeError, ConnectionResetError):
            pass
        except Exception:
            log.warning("dashboard request %s failed", self.path, exc_info=True)

    def _events(self) -> None:
        """The SSE stream: a state patch whenever the state changed (coalesced, throttled)."""
        d = self.dashboard
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        client = id(self)
        cursors: dict[str, int] = {}
        seen, idle_s = -1, 0.0
        seen_frames: dict[str, int] = {}
        d.sent_versions[client] = -1
        try:
            while not d.closing.is_set():
                version = d.state.wait_change(seen, timeout_s=0.5)  # frames are polled twice a second
                frames = d.frames.seqs()
                if version == seen and frames == seen_frames:
                    idle_s += 0.5
                    if idle_s >= d.keepalive_s:
                        self.wfile.write(b": keepalive\n\n")
                        self.wfile.flush()
                        idle_s = 0.0
                    continue
                data, cursors = d.state.patch(cursors)
                data["frames"] = frames
                self.wfile.write(sse_message("state", data, data["version"]))
                self.wfile.flush()
                seen, seen_frames, idle_s = data["version"], frames, 0.0
                d.sent_versions[client] = seen
                time.sleep(d.min_interval_s)
        finally:
            d.sent_versions.pop(client, None)

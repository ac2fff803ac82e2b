"""A null-modem cable in software: two pseudo-terminals joined by a byte-copying thread.

A mock device opens :attr:`PtyLink.device_port` (for example the mock VFD's Modbus RTU slave), the
driver under test opens :attr:`PtyLink.client_port`; both are ordinary tty device names (``/dev/pts/N``)
that pyserial opens like a USB-RS485 adapter. Every byte written on one side arrives on the other.

Why two pty pairs and not one: a single pair gives one slave name and one master *file descriptor*, and
a master cannot be opened by name, so libraries that insist on a port name (pymodbus opens its ports
with ``exclusive=True``) cannot sit on both ends. Two pairs give two names.

The link keeps its own descriptor on each slave (in raw mode) so that a peer closing and reopening its
port never makes the master read fail with ``EIO`` (the Linux behaviour once every slave descriptor is
closed), and so that bytes are never cooked (``\\n`` → ``\\r\\n``, echo) before pyserial sets raw mode.

Fault injection for cable-level problems (shared with the b-CAP mock):

* :meth:`unplug` / :meth:`plug` — bytes are silently discarded while unplugged (a pulled cable);
* ``filter_to_client`` / ``filter_to_device`` — a callable ``bytes -> bytes`` applied to each chunk on
  its way across (drop, corrupt or delay bytes); ``None`` means pass through.

POSIX only (``os.openpty``).
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty
from collections.abc import Callable
from types import TracebackType

ByteFilter = Callable[[bytes], bytes]


class PtyLink:
    """Two pty pairs whose masters are joined by a daemon thread.

    Use as a context manager or call :meth:`close`. ``device_port`` and ``client_port`` are symmetric;
    the names only say which end a mock is expected to take.
    """

    def __init__(self) -> None:
        self._dev_master, self._dev_slave = os.openpty()
        self._cli_master, self._cli_slave = os.openpty()
        for fd in (self._dev_slave, self._cli_slave):
            tty.setraw(fd)
        self.device_port: str = os.ttyname(self._dev_slave)
        self.client_port: str = os.ttyname(self._cli_slave)
        self.filter_to_client: ByteFilter | None = None
        self.filter_to_device: ByteFilter | None = None
        self.bytes_to_client = 0
        self.bytes_to_device = 0
        self._plugged = threading.Event()
        self._plugged.set()
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"pty-link {self.client_port}", daemon=True)
        self._thread.start()

    # control ------------------------------------------------------------------------------------
    def unplug(self) -> None:
        """Simulate a pulled cable: from now on every byte in either direction is discarded."""
        self._plugged.clear()

    def plug(self) -> None:
        """Reconnect the cable (bytes sent while unplugged stay lost)."""
        self._plugged.set()

    @property
    def plugged(self) -> bool:
        return self._plugged.is_set()

    def close(self) -> None:
        """Stop the bridge thread and close every descriptor; idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._thread.join(timeout=2.0)
        for fd in (self._dev_master, self._cli_master, self._dev_slave, self._cli_slave,
                   self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> PtyLink:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"PtyLink(device_port={self.device_port!r}, client_port={self.client_port!r})"

    # bridge -------------------------------------------------------------------------------------
    def _forward(self, src: int, dst: int, to_client: bool) -> None:
        try:
            data = os.read(src, 4096)
        except OSError:  # EIO: no slave descriptor open on that side (cannot happen while we hold one)
            return
        if not data or not self._plugged.is_set():
            return
        fn = self.filter_to_client if to_client else self.filter_to_device
        if fn is not None:
            data = fn(data)
        if to_client:
            self.bytes_to_client += len(data)
        else:
            self.bytes_to_device += len(data)
        view = memoryview(data)
        while view and not self._stop.is_set():
            try:
                written = os.write(dst, view)
            except BlockingIOError:
                select.select([], [dst], [], 0.05)
                continue
            except OSError:
                return
            view = view[written:]

    def _run(self) -> None:
        fds = [self._dev_master, self._cli_master, self._wake_r]
        while not self._stop.is_set():
            try:
                readable, _, _ = select.select(fds, [], [], 0.5)
            except (OSError, ValueError):
                return
            if self._stop.is_set():
                return
            if self._dev_master in readable:
                self._forward(self._dev_master, self._cli_master, to_client=True)
            if self._cli_master in readable:
                self._forward(self._cli_master, self._dev_master, to_client=False)

"""Test helper shared by the b-CAP tests: a real transport wrapped to keep what the driver wrote."""

from __future__ import annotations

from drivers.denso.bcap import PacketDecoder


class RecordingTransport:
    """Wraps a real transport and keeps every write (one bytes object per write), to see what left the
    driver; :meth:`functions` decodes them into the function IDs of the packets sent."""

    def __init__(self, inner, serial_line: bool = False) -> None:
        self.inner, self.url, self.serial_line = inner, inner.url, serial_line
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.written.append(bytes(data))
        self.inner.write(data)

    def functions(self) -> list[int]:
        decoder = PacketDecoder(serial_line=self.serial_line)
        decoder.feed(b"".join(self.written))
        return [p.code for p in decoder.packets()]

    def read_exact(self, n, timeout_s=None):
        return self.inner.read_exact(n, timeout_s)

    def read_until(self, terminator, timeout_s=None, max_bytes=65536):
        return self.inner.read_until(terminator, timeout_s, max_bytes)

    def read_available(self):
        return self.inner.read_available()

    def close(self) -> None:
        self.inner.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

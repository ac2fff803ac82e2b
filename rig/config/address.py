"""Device addresses of ``rig.toml`` (``tcp://``, ``serial://``, ``mock://``) and the endpoint they lead to."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rig.config.schema import ConfigError

BUILTIN_REGISTER_MAPS = ("delta",)
BAUD_RATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)


def parse_address(address: str, path: str = "address") -> dict[str, Any]:
    """Split a device address into ``{"scheme", "host", "port"}`` / ``{"scheme", "device", "baud"}`` /
    ``{"scheme": "mock", "link": "tcp"|"pty"}``; raise ConfigError naming ``path`` when malformed."""
    from urllib.parse import parse_qs, urlsplit

    allowed = "tcp://HOST:PORT, serial:///dev/DEVICE?baud=N, mock://tcp or mock://pty"
    parts = urlsplit(address)
    if parts.scheme == "tcp":
        try:
            port = parts.port
        except ValueError:
            port = None
        if not parts.hostname or port is None or not 1 <= port <= 65535:
            raise ConfigError(path, f"{address!r} needs a host and a port 1-65535; allowed: {allowed}")
        return {"scheme": "tcp", "host": parts.hostname, "port": port}
    if parts.scheme == "serial":
        device = parts.netloc + parts.path
        if not device:
            raise ConfigError(path, f"{address!r} names no serial device; allowed: {allowed}")
        query = parse_qs(parts.query)
        unknown = sorted(set(query) - {"baud", "parity", "stopbits", "bytesize"})
        if unknown:
            raise ConfigError(path, f"{address!r}: unknown option {unknown[0]!r}; allowed: baud, parity, "
                                    "stopbits, bytesize")
        baud = query.get("baud", ["38400"])[-1]
        if not baud.isdigit() or int(baud) not in BAUD_RATES:
            raise ConfigError(path, f"{address!r}: baud {baud!r} not allowed; allowed: "
                                    f"{', '.join(map(str, BAUD_RATES))}")
        return {"scheme": "serial", "device": device, "baud": int(baud)}
    if parts.scheme == "mock":
        if parts.netloc not in ("tcp", "pty") or parts.path:
            raise ConfigError(path, f"{address!r} not allowed; allowed: mock://tcp or mock://pty")
        return {"scheme": "mock", "link": parts.netloc}
    raise ConfigError(path, f"{address!r} has an unknown scheme; allowed: {allowed}")


def check_address(value: str, path: str) -> None:
    parse_address(value, path)


def check_register_map(value: str, path: str) -> None:
    if value in BUILTIN_REGISTER_MAPS:
        return
    if not Path(value).is_file():
        raise ConfigError(path, f"{value!r} is neither a built-in register map nor a TOML file; allowed: "
                                f"{', '.join(BUILTIN_REGISTER_MAPS)} or the path of a register-map TOML file")


def endpoint(address: str) -> tuple[str, ...] | None:
    """Where an address leads, normalised so that two spellings of one endpoint compare equal:
    ``("tcp", host, port)`` (``localhost`` and ``::1`` → ``127.0.0.1``, IP addresses in canonical form, names
    lower-cased), ``("serial", device)`` (symbolic links resolved: ``/dev/serial/by-id/…`` is the tty it
    names); None for a ``mock://`` address (the station starts one server per device)."""
    import ipaddress
    import os

    parts = parse_address(address)
    if parts["scheme"] == "serial":
        return ("serial", os.path.realpath(parts["device"]))
    if parts["scheme"] != "tcp":
        return None
    host = parts["host"].lower().rstrip(".")
    try:
        ip = ipaddress.ip_address(host)
        host = "127.0.0.1" if ip.is_loopback and (ip.version == 6 or host == "127.0.0.1") else ip.compressed
    except ValueError:
        host = "127.0.0.1" if host == "localhost" else host
    return ("tcp", host, str(parts["port"]))

"""Atomic file writes: a result carries its final name only once it is complete and on disk.

Every writer of results (calibration.json, timing.json, certificate.json, report.html, tables, figures,
``rig measure`` outputs) writes a temporary file in the destination folder, fsyncs it, renames it over
the final name (``os.replace``, atomic on POSIX within one file system) and fsyncs the folder, so a crash,
a full disk or a read-only folder never leaves a 0-byte or half-written file under the final name — the
old file, if any, stays whole. On an error the temporary file is removed and the ``OSError`` propagates
(``rig`` maps it to exit 3).

The append-only ``record.jsonl`` and the Parquet part files keep their own crash-safe schemes
(:mod:`rig.record.writer`, :mod:`rig.record.observations`).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["atomic_path", "fsync_dir", "write_bytes", "write_json", "write_text"]


def fsync_dir(folder: str | os.PathLike[str]) -> None:
    """fsync a folder so a rename inside it survives a power loss (no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return  # e.g. Windows: folders cannot be opened; the rename is still atomic
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP):  # file systems that cannot sync a folder
            raise
    finally:
        os.close(fd)


def _temporary_name(path: Path) -> Path:
    """A hidden name beside ``path`` that keeps its suffix (writers such as pandas infer the format)."""
    return path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{path.suffix}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for a writer that wants a file name (matplotlib ``savefig``,
    pandas ``to_csv``); when the block ends without an error the file is fsync'ed and renamed to ``path``
    and the folder fsync'ed. On an error the temporary file is removed and the error propagates (an
    ``OSError`` naming ``path``, of the same errno and subclass)."""
    final = Path(path)
    tmp = _temporary_name(final)
    try:
        yield tmp
        with open(tmp, "rb") as fh:  # the writer closed it; make its bytes durable before the rename
            os.fsync(fh.fileno())
        os.replace(tmp, final)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and exc.errno is not None:  # name the file meant, not the temporary one
            raise OSError(exc.errno, exc.strerror, str(final)) from exc
        raise
    fsync_dir(final.parent)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return ``path``."""
    final = Path(path)
    with atomic_path(final) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return final


def write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (``\\n`` line ends kept as given); return ``path``."""
    return write_bytes(path, text.encode(encoding))


def write_json(path: str | os.PathLike[str], obj: Any, *, indent: int | None = 1,
               **dumps_kwargs: Any) -> Path:
    """Write ``obj`` as JSON (a trailing newline) to ``path`` atomically; return ``path``.
    ``dumps_kwargs`` go to :func:`json.dumps` (``sort_keys``, ``ensure_ascii``, ``default``, ...)."""
    return write_text(path, json.dumps(obj, indent=indent, **dumps_kwargs) + "\n")

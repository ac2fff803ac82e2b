"""A DataFrame as CSV text identical to ``DataFrame.to_csv(index=False)``, in a third less time.

``rig measure`` writes its tables (tens of thousands of floats per second of video) as CSV; pandas formats
each float column with numpy's ``astype(str)`` and feeds the rows to :mod:`csv`. Python's ``repr`` gives
the same shortest round-trip text for a float64 (both print the fewest digits that read back to the same
number, switching to exponent notation below 1e-4 and from 1e16) in about half numpy's time, and the rows
are joined directly with pandas' conventions: minimal quoting (only text cells can need it), ``os.linesep``,
NaN and missing values as empty fields. Frames with a column of any other kind than float64, integer,
boolean or text (all ``str`` or missing), or with a single column, are left to pandas, so the text never
differs.

Long float columns are formatted by Arrow's float → string cast, about 4× faster than ``repr`` and the same
text wherever 1e-4 ≤ |x| < 1e9 and x is not a whole number (both print the shortest round-trip digits in
positional notation there; outside, Arrow's exponent and integer styles differ: ``0.00001``, ``5``): those
values keep ``repr``. The agreement is checked once per process on probe values (:func:`arrow_agrees`);
a pyarrow whose text differs is not used.
"""

from __future__ import annotations

import csv
import functools
import io
import math
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["arrow_agrees", "csv_text", "float_texts", "write_csv"]


ARROW_LOW, ARROW_HIGH = 1e-4, 1e9  # where Arrow's text of a non-integral float64 is repr's
ARROW_MIN_VALUES = 64  # shorter columns: repr (Arrow's per-call cost is not repaid)


def arrow_agrees(cast: Callable[[np.ndarray], list[str]]) -> bool:
    """Whether ``cast`` writes ``repr``'s text for probe values spanning [ARROW_LOW, ARROW_HIGH): random bit
    patterns there and decimals of 0–16 digits (the shortest-digit cases), both signs."""
    rng = np.random.default_rng(20261203)
    low_bits, high_bits = np.array([ARROW_LOW, ARROW_HIGH]).view(np.int64)
    probe = np.concatenate([rng.integers(low_bits, high_bits, 2000).view(np.float64),
                            *(np.round(rng.uniform(0.0, 1.0, 200) * 10.0 ** rng.uniform(-3.0, 9.0, 200), k)
                              for k in range(17))])
    probe = np.concatenate([probe, -probe])
    probe = probe[(np.abs(probe) >= ARROW_LOW) & (np.abs(probe) < ARROW_HIGH) & (probe != np.floor(probe))]
    return cast(probe) == [repr(x) for x in probe.tolist()]


@functools.cache
def _arrow_cast() -> Callable[[np.ndarray], list[str]] | None:
    """Arrow's float64 → string cast when it agrees with ``repr`` (:func:`arrow_agrees`), else None."""
    try:
        import pyarrow as pa
        import pyarrow.compute as pc
    except ImportError:  # a dependency; without it, repr
        return None

    def cast(values: np.ndarray) -> list[str]:
        return list(pc.cast(pa.array(np.ascontiguousarray(values, np.float64)), pa.string()).to_pylist())

    return cast if arrow_agrees(cast) else None


def float_texts(values: np.ndarray) -> list[str]:
    """``repr`` of each float64, NaN as "" (±inf as ``inf``/``-inf``); through Arrow where its text is the
    same (module docstring)."""
    cast = _arrow_cast() if len(values) >= ARROW_MIN_VALUES else None
    if cast is None:
        return [repr(x) if not math.isnan(x) else "" for x in values.tolist()]
    texts = cast(values)
    magnitude = np.abs(values)
    with np.errstate(invalid="ignore"):  # NaN compares False: left to repr (as "")
        arrow = (magnitude >= ARROW_LOW) & (magnitude < ARROW_HIGH) & (values != np.floor(values))
    for i in np.flatnonzero(~arrow).tolist():
        x = float(values[i])
        texts[i] = repr(x) if not math.isnan(x) else ""
    return texts


def _float_cells(values: np.ndarray) -> list[str]:
    """float64 values as pandas writes them: ``repr``, NaN empty (±inf as ``inf``/``-inf``). A value
    repeated on consecutive rows (bit for bit: −0.0 is not 0.0), e.g. a frame's time stamp on each of its
    markers' rows, is formatted once."""
    bits = values.view(np.int64)
    starts = np.flatnonzero(np.r_[True, bits[1:] != bits[:-1]])
    if 2 * len(starts) > len(values):  # mostly distinct: each formatted
        return float_texts(values)
    text = float_texts(values[starts])
    return [text[i] for i in np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(values)])).tolist()]


def _csv_cell(text: str) -> str:
    """One non-empty text cell as :mod:`csv` writes it with pandas' settings (minimal quoting)."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator=os.linesep).writerow([text])
    return buffer.getvalue()[:-len(os.linesep)]


def _quoted(cells: list[str]) -> list[str]:
    """Text cells as :mod:`csv` writes them: those holding a delimiter, quote or line-break character (which
    ones csv quotes depends on the Python version and the line terminator) formatted by csv itself."""
    special = {x: _csv_cell(x) for x in set(cells) if any(c in x for c in ',"\r\n')}  # each value once
    return [special.get(x, x) for x in cells] if special else cells


def _cells(column: pd.Series) -> list[str] | None:
    """The column's cells as pandas' CSV writer formats them, or None for a kind left to pandas."""
    dtype = column.dtype
    if dtype == np.float64:
        return _float_cells(column.to_numpy())
    if isinstance(dtype, np.dtype) and dtype.kind in "iub":  # numpy's own (not pandas' nullable Int64 …)
        return [str(x) for x in column.to_numpy().tolist()]
    if dtype == np.dtype(object) or isinstance(dtype, pd.StringDtype):
        cells = column.to_numpy(dtype=object, na_value=None)
        if all(isinstance(x, str) or x is None for x in cells):
            return _quoted(["" if x is None else x for x in cells])
    return None


def csv_text(frame: pd.DataFrame) -> str:
    """The text of ``frame.to_csv(index=False)``."""
    # one column: csv writes an empty cell as "" there (a row, not a blank line): left to pandas
    plain = (frame.shape[1] > 1 and frame.columns.is_unique and not isinstance(frame.columns, pd.MultiIndex))
    columns = [_cells(frame.iloc[:, i]) for i in range(frame.shape[1])] if plain else []
    if not plain or any(c is None for c in columns):
        return str(frame.to_csv(index=False))
    end = os.linesep
    header = ",".join(_quoted([str(name) for name in frame.columns]))
    return end.join([header, *map(",".join, zip(*columns, strict=True))]) + end


def write_csv(frame: pd.DataFrame, path: Path) -> None:
    """``frame`` as CSV at ``path`` (UTF-8), the text of ``frame.to_csv(path, index=False)``."""
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(csv_text(frame))

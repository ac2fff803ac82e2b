"""rig measure's CSV writer gives the text of pandas' ``to_csv(index=False)`` character for character."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.deploy import csv_table
from rig.deploy.csv_table import csv_text, write_csv

_TEXT = st.text(alphabet=st.sampled_from(list('ab ,"\n\r;é0.-')), max_size=6)


@st.composite
def frames(draw: st.DrawFn) -> pd.DataFrame:
    rows = draw(st.integers(0, 12))
    out: dict[str, object] = {}
    for i in range(draw(st.integers(1, 5))):
        kind = draw(st.sampled_from(["float", "bits", "runs", "int", "uint8", "bool", "str", "object",
                                     "float32"]))
        if kind == "float":
            out[f"c{i}_mm"] = np.array(draw(st.lists(st.floats(allow_nan=True, allow_infinity=True),
                                                     min_size=rows, max_size=rows)), dtype=np.float64)
        elif kind == "bits":  # any bit pattern: subnormals, every exponent, NaN payloads
            seed = draw(st.integers(0, 2**32 - 1))
            bits = np.random.default_rng(seed).integers(0, 2**63, rows, dtype=np.uint64)
            out[f"c{i}"] = bits.view(np.float64)
        elif kind == "runs":  # values repeated on consecutive rows (formatted once): ±0, NaN, inf among them
            pool = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1.5, 1e-5, 0.1, 1e16])
            picks = draw(st.lists(st.integers(0, len(pool) - 1), min_size=rows, max_size=rows))
            out[f"c{i}_s"] = pool[np.sort(np.array(picks, dtype=np.int64))]
        elif kind == "int":
            out[f"c{i}"] = np.array(draw(st.lists(st.integers(-2**62, 2**62), min_size=rows, max_size=rows)),
                                    dtype=np.int64)
        elif kind == "uint8":
            out[f"c{i}"] = np.arange(rows, dtype=np.uint8)
        elif kind == "bool":
            out[f"c{i}"] = np.array(draw(st.lists(st.booleans(), min_size=rows, max_size=rows)), dtype=bool)
        elif kind == "str":
            out[f"c{i}"] = pd.array(draw(st.lists(st.one_of(_TEXT, st.none()), min_size=rows, max_size=rows)),
                                    dtype="string")
        elif kind == "object":  # text with missing values, or mixed (left to pandas)
            out[f"c{i}"] = pd.Series(draw(st.lists(st.one_of(_TEXT, st.none(), st.just(np.nan),
                                                             st.just(1.5)), min_size=rows, max_size=rows)),
                                     dtype=object)
        else:
            out[f"c{i}"] = np.linspace(0, 1, rows, dtype=np.float32)
    return pd.DataFrame(out)


@settings(max_examples=300, deadline=None)
@given(frames())
def test_the_text_is_pandas_to_csv(frame: pd.DataFrame) -> None:
    assert csv_text(frame) == frame.to_csv(index=False)


def test_the_file_is_pandas_file_and_odd_frames_are_left_to_pandas(tmp_path: Path) -> None:
    frame = pd.DataFrame({"time_s": [0.1, 1e-5, 1e16, -0.0, np.nan, np.inf],
                          "track_id": ["T1", "a,b", 'q"', "", None, "x\ny"]})
    write_csv(frame, tmp_path / "ours.csv")
    frame.to_csv(tmp_path / "pandas.csv", index=False)
    assert (tmp_path / "ours.csv").read_bytes() == (tmp_path / "pandas.csv").read_bytes()
    for odd in (pd.DataFrame(), pd.DataFrame({"t": pd.to_datetime(["2026-01-01"])}),
                pd.DataFrame([[1, 2]], columns=["a", "a"]), pd.DataFrame({"n": pd.array([1, None], "Int64")}),
                pd.DataFrame({"c": pd.Categorical(["x", None])})):
        assert csv_text(odd) == odd.to_csv(index=False)


def _long_columns(seed: int) -> pd.DataFrame:
    """Columns long enough for Arrow's cast: measurement-like values (px, mm, s, Hz) of every digit count,
    with whole numbers, ±0, tiny and huge values, NaN and ±inf mixed in, and random bit patterns."""
    rng = np.random.default_rng(seed)
    n = 4000
    scale = 10.0 ** rng.uniform(-6.0, 12.0, n)
    decimals = np.round(rng.normal(size=n) * scale, rng.integers(0, 17))
    specials = rng.choice(np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 5.0, 1e-5, 1e9, 1e16, 1e-4, 12.0]), n)
    mixed = np.where(rng.random(n) < 0.1, specials, decimals)
    return pd.DataFrame({"u_px": rng.uniform(0, 1920, n), "x_mm": mixed,
                         "bits": rng.integers(0, 2**63, n, dtype=np.uint64).view(np.float64),
                         "time_s": np.repeat(np.arange(n // 4) / 60.0, 4)})  # runs: each formatted once


@pytest.mark.parametrize("seed", range(8))
def test_long_columns_through_arrow_are_still_pandas_text(seed: int) -> None:
    frame = _long_columns(seed)
    assert csv_table._arrow_cast() is not None  # the pinned pyarrow agrees with repr on the probe values
    assert csv_text(frame) == frame.to_csv(index=False)


def test_a_cast_that_writes_other_text_is_not_used() -> None:
    """Arrow's text differs from repr outside the range (``0.00001``, ``5``): a cast writing any such style
    inside it fails the check, and the values are then formatted by repr."""
    assert csv_table.arrow_agrees(lambda values: [repr(x) for x in values.tolist()])
    assert not csv_table.arrow_agrees(lambda values: [f"{x:.15g}" for x in values.tolist()])
    assert not csv_table.arrow_agrees(lambda values: [*[repr(x) for x in values.tolist()][:-1], "0"])

"""reports.measurement: the report of a `rig measure` folder, rendered from the files it holds."""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.backend_bases import RendererBase
from matplotlib.figure import Figure

from reports.errors import RunFolderError
from reports.html import CSS
from reports.measurement import load_measurement, write_measurement_report

FREQUENCY_HZ = 5.0
AMPLITUDE_MM = 4.0
EVIDENCE = "sensor noise not renewed: median block change 0.0 DN < 0.3 × typical 1.4 DN"


def _frame_report(duplicated: list[int], *, truncated: bool = False) -> dict:
    return {"frames_read": 150, "missing_frames": 0, "truncated": truncated, "duration_s": 2.5,
            "undecided": [], "dropped": [],
            "duplicated": [{"index": i, "pts_s": i / 60, "evidence": EVIDENCE} for i in duplicated]}


def _write_folder(out: Path, *, problems: tuple[str, ...] = (), n_duplicates: int = 2) -> Path:
    """A measurement folder as `rig measure` writes it: one reference and two target tracks."""
    (out / "tables").mkdir(parents=True)
    t = np.arange(0, 2.0, 1 / 60)
    rows = []
    for track_id in (1, 2):
        rows += [{"track_id": track_id, "time_s": ti, "dx_mm": 0.0, "dy_mm": 0.0,
                  "dz_mm": AMPLITUDE_MM * np.sin(2 * np.pi * FREQUENCY_HZ * ti)} for ti in t]
    pd.DataFrame(rows).to_csv(out / "tables" / "displacement.csv", index=False)
    pd.DataFrame({"track_id": [0, 1, 2], "role": ["reference", "target", "target"],
                  "x_mm": [0.0, 100.0, 200.0], "y_mm": 0.0, "z_mm": 500.0, "n_samples": len(t),
                  "direction_x": [np.nan, 0.0, 0.0], "direction_y": [np.nan, 0.0, 0.0],
                  "direction_z": [np.nan, 1.0, 1.0], "frequency_hz": [np.nan, 5.0001, 4.9999],
                  "amplitude_mm": [np.nan, 3.9991, 4.0012]}).to_csv(out / "tables" / "summary.csv",
                                                                      index=False)
    f = np.linspace(0, 30, 31)
    pd.DataFrame([{"track_id": k, "frequency_hz": fi, "amplitude_mm": AMPLITUDE_MM * (fi == FREQUENCY_HZ)}
                  for k in (1, 2) for fi in f]).to_csv(out / "tables" / "spectra.csv", index=False)
    pd.DataFrame({"track_id": [1, 2], "frequency_hz": [5.0001, 4.9999], "amplitude_mm": [3.9991, 4.0012],
                  "welch_amplitude_mm": [3.9, 3.9], "method": "4-parameter fit"}).to_csv(
        out / "tables" / "peaks.csv", index=False)
    (out / "frames.json").write_text(json.dumps({"left": _frame_report(list(range(10, 10 + n_duplicates))),
                                                 "right": _frame_report([], truncated=bool(problems))}))
    (out / "timing.json").write_text(json.dumps({
        "reference_camera": "left", "method": "twin truth", "offset_s": {"left": 0.0, "right": 0.15},
        "line_time_s": {"left": 2.8e-5, "right": 2.8e-5}, "uncertainty": {"offset_s": {"right": 2e-4}}}))
    (out / "measure.json").write_text(json.dumps({
        "videos": {"left": "left.mkv", "right": "right.mkv"}, "calibration": "calibration.json",
        "notes": ["reference markers (auto): tracks [0]"], "problems": list(problems)}))
    return out


def test_the_report_shows_the_folder_with_the_certification_reports_stylesheet(tmp_path: Path) -> None:
    out = _write_folder(tmp_path / "out")
    files = write_measurement_report(out)
    assert files == {"figure_displacement": out / "figures" / "displacement.svg",
                     "figure_spectrum": out / "figures" / "spectrum.svg", "report": out / "report.html"}
    page = (out / "report.html").read_text()
    assert f"<style>{CSS}</style>" in page  # one stylesheet for every report
    assert page.count("data:image/svg+xml;base64,") == 2
    for text in ("Summary per track", "Significant tones per target track",
                 "Duplicated frames and their evidence", html.escape(EVIDENCE),
                 "reference markers (auto): tracks [0]", "left = left.mkv"):
        assert text in page
    assert ">0.15</td>" in page and ">0.0002</td>" in page  # timing.json's offset and its u
    assert "welch_amplitude_mm" not in page and "Problems with the inputs" not in page
    assert "3.9991" in page and "4.0012" in page  # the measured amplitudes, 5 significant digits


def test_the_report_is_deterministic(tmp_path: Path) -> None:
    a, b = _write_folder(tmp_path / "a"), _write_folder(tmp_path / "b")
    write_measurement_report(a)
    write_measurement_report(b)
    for name in ("report.html", "figures/displacement.svg", "figures/spectrum.svg"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    for name in ("displacement", "spectrum"):  # nothing that changes with the day or the matplotlib version
        svg = (a / "figures" / f"{name}.svg").read_text()
        assert "<dc:date>" not in svg and "<dc:creator>" not in svg and "Matplotlib v" not in svg
        assert "<text" not in svg  # text drawn as paths: the same look whatever fonts the reader has


def test_each_figure_is_drawn_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The figures place their axes themselves: no layout engine, so ``savefig`` draws each figure once
    (with one, even a placeholder left by turning constrained layout off, it draws a layout pass first)."""
    out = _write_folder(tmp_path / "out")
    drawn: list[Figure] = []
    draw = Figure.draw

    def counted(fig: Figure, renderer: RendererBase) -> None:
        drawn.append(fig)
        draw(fig, renderer)

    monkeypatch.setattr(Figure, "draw", counted)
    files = write_measurement_report(out)
    assert len(drawn) == 2 == len([k for k in files if k.startswith("figure_")])
    assert len(set(map(id, drawn))) == 2

def test_input_problems_come_first_and_duplicates_are_capped(tmp_path: Path) -> None:
    out = _write_folder(tmp_path / "out", problems=("right.mkv: truncated after frame 147",), n_duplicates=45)
    write_measurement_report(out)
    page = (out / "report.html").read_text()
    assert page.index("Problems with the inputs") < page.index("Summary per track")
    assert "right.mkv: truncated after frame 147" in page
    assert "40 of 45; all of them in frames.json" in page


def test_a_folder_without_targets_or_tones_has_no_figures(tmp_path: Path) -> None:
    out = _write_folder(tmp_path / "out")
    summary = pd.read_csv(out / "tables" / "summary.csv").assign(role="reference")
    summary.to_csv(out / "tables" / "summary.csv", index=False)
    (out / "tables" / "peaks.csv").write_text("\n")  # pandas writes an empty frame as one empty line
    files = write_measurement_report(out)
    assert set(files) == {"report"}
    page = (out / "report.html").read_text()
    assert "data:image/png" not in page and "Significant tones" not in page
    assert load_measurement(out).peaks.empty


@pytest.mark.parametrize("name", ["measure.json", "frames.json", "timing.json", "tables/summary.csv"])
def test_a_missing_file_is_named(tmp_path: Path, name: str) -> None:
    out = _write_folder(tmp_path / "out")
    (out / name).unlink()
    with pytest.raises(RunFolderError, match=rf"{name}: missing"):
        write_measurement_report(out)
    assert not (out / "report.html").exists()

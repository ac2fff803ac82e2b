"""``report.html`` and ``figures/*.svg`` of a ``rig measure`` folder, from the files the measurement wrote.

The measurement (:mod:`rig.deploy.measure`) writes its tables, ``frames.json``, ``timing.json`` and
``measure.json``; this renders them with the certification report's page, stylesheet and figure style
(:mod:`reports.html`, :mod:`reports.figures`): summary per track, significant tones, displacement and
spectrum figures, frame reports, timing, notes. The folder is only read, except for the two outputs, so
the report can be rebuilt from it. Deterministic: the same folder gives byte-identical files.
"""

from __future__ import annotations

import html
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from reports import figures
from reports.errors import RunFolderError
from reports.html import figure, page, table
from reports.summaries import timing_frame
from rig.record.atomic import write_text
from rig.stereo.errors import StereoError
from rig.stereo.timing import TimingResult

__all__ = ["Measurement", "load_measurement", "write_measurement_report"]

SUMMARY_COLUMNS = ("track_id", "role", "x_mm", "y_mm", "z_mm", "n_samples", "dominant_frequency_hz",
                   "frequency_hz", "frequency_std_hz", "amplitude_mm", "amplitude_std_mm",
                   "half_peak_to_peak_mm", "rms_mm")
MAX_DUPLICATES_SHOWN = 40  # the rest are in frames.json
CAPTIONS = {"displacement": "Displacement relative to the reference markers",
            "spectrum": "Amplitude spectrum along each track's principal direction"}


@dataclass(frozen=True)
class Measurement:
    """What the report shows of a measurement folder. Times in s on the reference video's clock."""

    out_dir: Path
    videos: dict[str, str]  # camera name → video path
    calibration: str
    notes: list[str]
    problems: list[str]  # unreadable or truncated inputs: the results use the frames that could be read
    summary: pd.DataFrame  # one row per 3-D track (tables/summary.csv)
    displacement: pd.DataFrame  # tables/displacement.csv
    spectra: pd.DataFrame  # tables/spectra.csv
    peaks: pd.DataFrame  # significant tones per target track (tables/peaks.csv)
    frame_reports: dict[str, dict[str, Any]]  # frames.json: per camera
    timing: TimingResult  # timing.json, decoded

    @property
    def targets(self) -> pd.DataFrame:
        """The summary rows of the moving (target) tracks."""
        return self.summary[self.summary["role"] == "target"]


def _json(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise RunFolderError(f"{path}: missing; is {path.parent} the --out folder of `rig measure`?") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RunFolderError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(doc, dict):
        raise RunFolderError(f"{path}: the top level must be a JSON object")
    return doc


def _timing(path: Path) -> TimingResult:
    try:
        return TimingResult.from_dict(_json(path))
    except StereoError as exc:
        raise RunFolderError(f"{path}: {exc}") from exc


def _csv(path: Path) -> pd.DataFrame:
    """A table of the folder; a table without rows or columns (no tones found) is empty."""
    if not path.is_file():
        raise RunFolderError(f"{path}: missing; is {path.parent.parent} the --out folder of `rig measure`?")
    try:
        return pd.read_csv(path)
    except pd.errors.EmptyDataError:
        return pd.DataFrame()


def load_measurement(out_dir: str | Path) -> Measurement:
    """Read the measurement folder ``out_dir`` (the ``--out`` of ``rig measure``)."""
    out = Path(out_dir)
    meta = _json(out / "measure.json")
    tables = out / "tables"
    return Measurement(
        out_dir=out,
        videos={str(k): str(v) for k, v in (meta.get("videos") or {}).items()},
        calibration=str(meta.get("calibration")),
        notes=[str(n) for n in meta.get("notes") or []],
        problems=[str(p) for p in meta.get("problems") or []],
        summary=_csv(tables / "summary.csv"),
        displacement=_csv(tables / "displacement.csv"),
        spectra=_csv(tables / "spectra.csv"),
        peaks=_csv(tables / "peaks.csv"),
        frame_reports=_json(out / "frames.json"),
        timing=_timing(out / "timing.json"),
    )


def write_measurement_report(out_dir: str | Path) -> dict[str, Path]:
    """Write ``figures/<name>.svg`` and ``report.html`` into the measurement folder ``out_dir`` (each file
    atomically); return {``figure_<name>``: path, ``report``: path}."""
    m = load_measurement(out_dir)
    figures_dir = m.out_dir / "figures"
    figures_dir.mkdir(exist_ok=True)
    files: dict[str, Path] = {}
    svgs: dict[str, bytes] = {}
    for name, fig in (("displacement", fig_displacement(m)), ("spectrum", fig_spectrum(m))):
        if fig is not None:  # vector figures: sharp at any zoom, in less than half a PNG's drawing time
            files[f"figure_{name}"] = figures_dir / f"{name}.svg"
            figures.save_svg(fig, files[f"figure_{name}"])
            svgs[name] = files[f"figure_{name}"].read_bytes()
    files["report"] = write_text(m.out_dir / "report.html", render(m, svgs))
    return files


# ------------------------------------------------------------------------------------------------ figures
def fig_displacement(m: Measurement) -> Figure | None:
    """Each target's displacement along its principal direction over time."""
    targets = m.targets.dropna(subset=["direction_x"]) if "direction_x" in m.summary else m.targets.iloc[:0]
    if targets.empty:
        return None
    fig, axes = figures.new_figure(size=(10.0, 4.0), layout=None)
    ax = axes[0, 0]
    for r in targets.itertuples():
        g = m.displacement[m.displacement["track_id"] == r.track_id]
        d = g["dx_mm"] * r.direction_x + g["dy_mm"] * r.direction_y + g["dz_mm"] * r.direction_z
        ax.plot(g["time_s"], d, lw=0.9, label=f"track {r.track_id}")
    ax.set_xlabel("time (s, reference video clock)")
    ax.set_ylabel("displacement along its principal direction (mm)")
    _legend_above(ax)
    return fig


def fig_spectrum(m: Measurement) -> Figure | None:
    """Each target's amplitude spectrum along its principal direction."""
    sel = m.spectra[m.spectra["track_id"].isin(set(m.targets["track_id"]))] if len(m.spectra) else m.spectra
    if sel.empty:
        return None
    fig, axes = figures.new_figure(size=(10.0, 4.0), layout=None)
    ax = axes[0, 0]
    for track_id, g in sel.groupby("track_id"):
        ax.plot(g["frequency_hz"], g["amplitude_mm"], lw=0.9, label=f"track {track_id}")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude (mm)")
    _legend_above(ax)
    return fig


LEGEND_COLUMNS = 6
LEGEND_ROW = 0.06  # height of a legend row, fraction of a 4-inch-high figure


def _legend_above(ax: Axes) -> None:
    """The legend in a row above the axes and fixed margins (a figure without a layout engine): no search
    of a place among the data points and no layout pass (together half the report's drawing time)."""
    rows = math.ceil(len(ax.get_lines()) / LEGEND_COLUMNS)
    top = 0.96 - LEGEND_ROW * max(rows, 1)
    ax.set_position((0.075, 0.12, 0.915, top - 0.12))  # figure fractions: left, bottom, width, height
    ax.legend(ncols=LEGEND_COLUMNS, loc="lower left", bbox_to_anchor=(0.0, 1.0), borderaxespad=0.2)


# ---------------------------------------------------------------------------------------------------- page
def render(m: Measurement, svgs: dict[str, bytes]) -> str:
    """The whole page as a string (deterministic for the same folder); ``svgs``: the figures' SVG files."""
    shown = "".join(figure(svgs, name, caption, "image/svg+xml") for name, caption in CAPTIONS.items())
    parts = [_header(m), _problems_section(m), _summary_section(m), _peaks_section(m),
             f"<section><h2>Displacement and spectrum</h2>{shown}</section>" if shown else "",
             _frames_section(m), _timing_section(m), _notes_section(m)]
    return page("rig measure — displacement measurement", [p for p in parts if p])


def _header(m: Measurement) -> str:
    videos = ", ".join(f"{html.escape(n)} = {html.escape(p)}" for n, p in m.videos.items())
    return (f"<header><h1>Displacement measurement</h1><div class='sub'>videos: {videos}; calibration: "
            f"{html.escape(m.calibration)}</div></header>")


def _problems_section(m: Measurement) -> str:
    if not m.problems:
        return ""
    lines = "".join(f"<p><span class='badge FAIL'>problem</span> {html.escape(p)}</p>" for p in m.problems)
    return (f"<section><h2>Problems with the inputs</h2>{lines}"
            "<p class='note'>The results below use the frames that could be read.</p></section>")


def _summary_section(m: Measurement) -> str:
    cols = [c for c in SUMMARY_COLUMNS if c in m.summary.columns]
    return "<section><h2>Summary per track</h2>" + table(m.summary[cols], digits=5, text_cols=("role",)) \
        + "</section>"


def _peaks_section(m: Measurement) -> str:
    if m.peaks.empty:
        return ""
    peaks = m.peaks.drop(columns=["welch_amplitude_mm"], errors="ignore")
    return ("<section><h2>Significant tones per target track</h2><p class='note'>Sine fit over each tone's "
            "active interval (from the STFT), the other tones subtracted; significant above the Welch noise "
            "floor (false-alarm probability per spectrum in the notes)</p>"
            + table(peaks, digits=5) + "</section>")


def _frames_section(m: Measurement) -> str:
    """Frames read, duplicated, undecided and dropped per camera; the first duplicates with their evidence."""
    frames = pd.DataFrame([{"camera": n, "frames_read": r.get("frames_read"),
                            "duplicated": len(r.get("duplicated") or []),
                            "undecided": len(r.get("undecided") or []), "dropped": r.get("missing_frames"),
                            "truncated": str(r.get("truncated")), "duration_s": r.get("duration_s")}
                           for n, r in m.frame_reports.items()])
    evidence = pd.DataFrame([{"camera": n, "index": d.get("index"), "pts_s": d.get("pts_s"),
                              "evidence": d.get("evidence")}
                             for n, r in m.frame_reports.items() for d in r.get("duplicated") or []],
                            columns=["camera", "index", "pts_s", "evidence"])
    shown = evidence.head(MAX_DUPLICATES_SHOWN)
    duplicates = ("" if shown.empty else "<h3>Duplicated frames and their evidence</h3>"
                  + table(shown, digits=5, text_cols=("camera", "evidence"))
                  + f"<p class='note'>{len(shown)} of {len(evidence)}; all of them in frames.json</p>")
    return ("<section><h2>Frames</h2>" + table(frames, digits=5, text_cols=("camera", "truncated"))
            + duplicates + "</section>")


def _timing_section(m: Measurement) -> str:
    t = m.timing
    return ("<section><h2>Timing</h2>" + table(timing_frame(t), digits=6, text_cols=("camera",))
            + f"<p class='note'>method: {html.escape(t.method)}; reference camera: "
            f"{html.escape(t.reference_camera)}; u_…: standard uncertainties.</p></section>")


def _notes_section(m: Measurement) -> str:
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in m.notes)
    return f"<section><h2>Notes</h2><ul class='note'>{notes}</ul></section>" if notes else ""

"""Figures and the self-contained ``report.html`` of ``rig measure`` (PNG figures embedded as base64).

``rig`` may not import ``reports/`` (layers, DESIGN.md), so this is a small page of its own in the same
offline style: summary table, displacement and spectrum figures, frame reports, timing, notes.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pandas as pd

from rig.record.atomic import write_bytes, write_text

__all__ = ["write_report"]

CSS = """body{margin:0;background:#f5f7fa;color:#1d2733;font:15px/1.5 -apple-system,"Segoe UI",Roboto,Arial,
sans-serif}main{max-width:1120px;margin:0 auto;padding:24px}section{background:#fff;border:1px solid #dde3ea;
border-radius:10px;padding:16px 20px;margin:16px 0}h1{font-size:22px}h2{font-size:18px;margin:0 0 10px}
table{border-collapse:collapse;font-size:13px;width:100%}
th,td{border-bottom:1px solid #dde3ea;padding:4px 8px;text-align:right}th{background:#f0f3f7}
td.t,th.t{text-align:left}img{max-width:100%}.warn{color:#b3261e;font-weight:700}.muted{color:#5b6775;font-size:13px}"""


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _fig_displacement(disp: pd.DataFrame, summary: pd.DataFrame) -> bytes | None:
    targets = summary[summary["role"] == "target"]
    if targets.empty or "direction_x" not in targets.columns:
        return None
    fig, ax = plt.subplots(figsize=(10, 4))
    for r in targets.itertuples():
        g = disp[disp["track_id"] == r.track_id]
        if pd.isna(r.direction_x):
            continue
        d = g["dx_mm"] * r.direction_x + g["dy_mm"] * r.direction_y + g["dz_mm"] * r.direction_z
        ax.plot(g["time_s"], d, lw=0.9, label=f"track {r.track_id}")
    ax.set_xlabel("time (s, reference video clock)")
    ax.set_ylabel("displacement along its principal direction (mm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=4)
    return _png(fig)


def _fig_spectrum(spectra: pd.DataFrame, summary: pd.DataFrame) -> bytes | None:
    targets = set(summary.loc[summary["role"] == "target", "track_id"])
    sel = spectra[spectra["track_id"].isin(targets)]
    if sel.empty:
        return None
    fig, ax = plt.subplots(figsize=(10, 4))
    for tid, g in sel.groupby("track_id"):
        ax.plot(g["frequency_hz"], g["amplitude_mm"], lw=0.9, label=f"track {tid}")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude (mm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=4)
    return _png(fig)


def _table(df: pd.DataFrame) -> str:
    head = "".join(f"<th class='t'>{html.escape(str(c))}</th>" if df[c].dtype == object else
                   f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    body = []
    for row in df.itertuples(index=False):
        cells = []
        for v in row:
            if isinstance(v, float):
                cells.append(f"<td>{v:.5g}</td>")
            else:
                cells.append(f"<td class='t'>{html.escape(str(v))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def write_report(result: Any, videos: dict[str, str], calibration: str) -> dict[str, Path]:
    """Write ``figures/*.png`` and ``report.html`` into ``result.out_dir``; return {name: path}."""
    out = Path(result.out_dir)
    figs_dir = out / "figures"
    figs_dir.mkdir(exist_ok=True)
    files: dict[str, Path] = {}
    pngs = {"displacement": _fig_displacement(result.displacement, result.summary),
            "spectrum": _fig_spectrum(result.spectra, result.summary)}
    for name, data in pngs.items():
        if data is not None:
            files[f"figure_{name}"] = figs_dir / f"{name}.png"
            write_bytes(files[f"figure_{name}"], data)
    cols = [c for c in ("track_id", "role", "x_mm", "y_mm", "z_mm", "n_samples", "dominant_frequency_hz",
                        "frequency_hz", "frequency_std_hz", "amplitude_mm", "amplitude_std_mm",
                        "half_peak_to_peak_mm", "rms_mm") if c in result.summary.columns]
    parts = ["<h1>Displacement measurement</h1><p class='muted'>videos: "
             + ", ".join(f"{html.escape(n)} = {html.escape(p)}" for n, p in videos.items())
             + f"; calibration: {html.escape(calibration)}</p>"]
    if result.problems:
        parts.append("<section><h2>Problems with the inputs</h2>" + "".join(
            f"<p class='warn'>{html.escape(p)}</p>" for p in result.problems)
            + "<p>The results below use the frames that could be read.</p></section>")
    parts.append("<section><h2>Summary per track</h2>" + _table(result.summary[cols]) + "</section>")
    if len(result.peaks):
        parts.append("<section><h2>Significant tones per target track</h2><p class='muted'>Sine fit over "
                     "each tone's active interval (from the STFT), the other tones subtracted; significant "
                     "above the Welch noise floor (false-alarm probability per spectrum in the notes)</p>"
                     + _table(result.peaks.drop(columns=["welch_amplitude_mm"])) + "</section>")
    for name, caption in (("displacement", "Displacement relative to the reference markers"),
                          ("spectrum", "Amplitude spectrum along each track's principal direction")):
        if pngs[name] is not None:
            b64 = base64.b64encode(pngs[name]).decode("ascii")
            parts.append(f"<section><h2>{caption}</h2><img alt='{name}' src='data:image/png;base64,{b64}'>"
                         "</section>")
    frames = pd.DataFrame([{"camera": n, "frames_read": r["frames_read"], "duplicated": len(r["duplicated"]),
                            "undecided": len(r["undecided"]),
                            "dropped": r["missing_frames"], "truncated": str(r["truncated"]),
                            "duration_s": r["duration_s"]} for n, r in result.frame_reports.items()])
    parts.append("<section><h2>Frames</h2>" + _table(frames) + "</section>")
    evidence = pd.DataFrame([{"camera": n, "index": d["index"], "pts_s": d["pts_s"],
                              "evidence": d["evidence"]}
                             for n, r in result.frame_reports.items() for d in r["duplicated"]][:40])
    if len(evidence):
        parts.append("<section><h2>Duplicated frames and their evidence</h2>" + _table(evidence)
                     + "<p class='muted'>all of them in frames.json</p></section>")
    timing = result.timing
    parts.append("<section><h2>Timing</h2><p>" + html.escape(
        f"reference camera {timing['reference_camera']}; method {timing['method']}; offset_s "
        f"{timing['offset_s']}; line_time_s {timing.get('line_time_s')}; uncertainty "
        f"{timing.get('uncertainty')}") + "</p></section>")
    parts.append("<section><h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in result.notes)
                 + "</ul></section>")
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>rig measure</title><style>" + CSS
            + "</style></head><body><main>" + "".join(parts) + "</main></body></html>")
    files["report"] = write_text(out / "report.html", page)
    return files

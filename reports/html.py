"""The self-contained ``report.html``: summary first, then the sections; figures embedded as base64 images
(PNG; SVG in ``rig measure``'s report).

No external assets (no fonts, scripts or stylesheets from the network): the page opens offline and can
be mailed as one file.
"""

from __future__ import annotations

import base64
import html
import json
import math
from typing import Any

import pandas as pd

from reports.tables import ReportTables

CSS = """
:root{--ink:#1d2733;--muted:#5b6775;--line:#dde3ea;--bg:#f5f7fa;--pass:#1e7b4a;--fail:#b3261e;--inc:#9a6700}
*{box-sizing:border-box}body{margin:0;background:var(--bg);color:var(--ink);
font:15px/1.5 -apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif}
main{max-width:1120px;margin:0 auto;padding:28px 28px 60px}
header h1{font-size:22px;margin:0 0 4px}header .sub{color:var(--muted);font-size:13.5px}
section{background:#fff;border:1px solid var(--line);border-radius:10px;padding:18px 22px;margin:18px 0}
h2{font-size:18px;margin:0 0 12px;padding-bottom:6px;border-bottom:1px solid var(--line)}
h3{font-size:15px;margin:18px 0 8px}
.verdict{display:flex;gap:22px;align-items:center;border-radius:10px;padding:18px 22px;margin:18px 0;
color:#fff}
.verdict.PASS{background:var(--pass)}.verdict.FAIL{background:var(--fail)}.verdict.INCOMPLETE{background:var(--inc)}
.verdict .big{font-size:40px;font-weight:800;letter-spacing:1px;min-width:210px}
.verdict .why{font-size:15px}.verdict .why b{font-weight:700}
.verdict ul{margin:6px 0 0;padding-left:18px}
.cards{display:grid;grid-template-columns:repeat(auto-fill,minmax(200px,1fr));gap:12px}
.card{border:1px solid var(--line);border-radius:8px;padding:10px 14px;background:#fff}
.card .k{color:var(--muted);font-size:12.5px}.card .v{font-size:21px;font-weight:700}
.card .l{font-size:12px;color:var(--muted)}
.card.PASS{border-left:5px solid var(--pass)}.card.FAIL{border-left:5px solid var(--fail)}
.card.NA{border-left:5px solid #b8c0ca}
.tw{overflow-x:auto}table{border-collapse:collapse;width:100%;font-size:13px;margin:6px 0 10px}
th,td{padding:5px 8px;border-bottom:1px solid var(--line);text-align:right;white-space:nowrap}
th{background:#eef2f6;font-weight:600}td.t,th.t{text-align:left;white-space:normal}
tr:hover td{background:#fafbfc}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-size:12px;font-weight:700;color:#fff}
.badge.PASS{background:var(--pass)}.badge.FAIL{background:var(--fail)}.badge.NOT{background:#8a94a0}
figure{margin:12px 0}figure img{max-width:100%;height:auto;display:block;margin:0 auto}
figcaption{color:var(--muted);font-size:13px;text-align:center}
.note{color:var(--muted);font-size:13.5px}details summary{cursor:pointer;color:var(--muted)}
pre{background:#f0f3f6;padding:10px;border-radius:6px;overflow:auto;font-size:12px}
.budget{font-size:12px;color:#7a8591}
nav a{margin-right:14px;color:#1f5fa8;text-decoration:none;font-size:13.5px}
.simulated{background:repeating-linear-gradient(135deg,#fff4d6 0 14px,#ffe9ad 14px 28px);
border:2px solid var(--inc);border-radius:10px;padding:10px 18px;margin:14px 0;font-weight:700;color:#5c3d00}
"""


_SYMBOL = {"<=": "≤", ">=": "≥"}


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "—"
        return f"{value:.{digits}g}"
    return html.escape(str(value))


def table(df: pd.DataFrame, *, digits: int = 4, text_cols: tuple[str, ...] = ()) -> str:
    """A DataFrame as an HTML table; text columns left-aligned, numbers to ``digits`` significant digits."""
    if df is None or df.empty:
        return '<p class="note">No data.</p>'
    head = "".join(
        f'<th class="{"t" if c in text_cols else ""}">{html.escape(str(c))}</th>' for c in df.columns
    )
    rows = []
    for rec in df.itertuples(index=False):
        cells = "".join(
            f'<td class="{"t" if c in text_cols else ""}">{_fmt(v, digits)}</td>'
            for c, v in zip(df.columns, rec, strict=True)
        )
        rows.append(f"<tr>{cells}</tr>")
    return (
        f"<div class='tw'><table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table></div>"
    )


def _length_line(lengths: pd.DataFrame) -> str:
    """One sentence on the test lengths: how many, their range, mean and worst ΔL."""
    if lengths is None or lengths.empty:
        return "<p class='note'>No marker pairs measured in one pose.</p>"
    dl = lengths["length_error_mm"]
    worst = lengths.iloc[int(dl.abs().to_numpy().argmax())]
    return (
        f"<p>{len(lengths)} test lengths of {_fmt(float(lengths['length_cal_mm'].min()))}–"
        f"{_fmt(float(lengths['length_cal_mm'].max()))} mm: mean ΔL {_fmt(float(dl.mean()))} mm, "
        f"RMS {_fmt(float((dl**2).mean() ** 0.5))} mm, worst {_fmt(float(worst['length_error_mm']))} mm "
        f"({html.escape(str(worst['marker_a']))}–{html.escape(str(worst['marker_b']))}, "
        f"L = {_fmt(float(worst['length_cal_mm']))} mm).</p>"
    )


def _timing_details(details: dict[str, Any]) -> str:
    """The scalar diagnostics of the sync fit (``details`` of timing.json), as one short line."""
    items = [
        f"{html.escape(str(k))} = {_fmt(v)}"
        for k, v in sorted(details.items())
        if isinstance(v, (int, float)) and not isinstance(v, bool)
    ]
    return ("Fit: " + ", ".join(items) + ".") if items else ""


def _vertical(values: dict[str, Any]) -> str:
    """A one-row summary as a two-column table (quantity, value): readable without scrolling."""
    frame = pd.DataFrame({"quantity": list(values), "value": [_fmt(v, 6) for v in values.values()]})
    return table(frame, text_cols=("quantity",))


def figure(images: dict[str, bytes], name: str, caption: str, media_type: str = "image/png") -> str:
    """The image ``images[name]`` (a file of ``media_type``: PNG, or ``image/svg+xml``) embedded as base64
    with its caption; empty when there is no such figure."""
    if name not in images:
        return ""
    data = base64.b64encode(images[name]).decode("ascii")
    return (
        f'<figure><img alt="{html.escape(caption)}" src="data:{media_type};base64,{data}">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


def _limit_text(lim: Any) -> str:
    if lim.reached:
        return f"{lim.limit_hz:.1f} Hz"
    return f"at least {lim.limit_hz:.1f} Hz (the highest tested)"


def _verdict(cert: dict[str, Any], t: ReportTables, tolerance_pct: float) -> str:
    result = cert["result"]
    crit = cert["criteria"]
    failed = [c for c in crit if c["status"] == "FAIL"]
    missing = [c for c in crit if c["status"] == "NOT EVALUATED"]
    lines = []
    lim = t.limits.get(t.primary_sync)
    if lim is not None:
        required = cert.get("criteria_settings", {}).get("min_usable_frequency_hz")
        req = f"; required {required:g} Hz" if isinstance(required, (int, float)) else ""
        lines.append(
            f"<b>Trusted up to {_limit_text(lim)}</b> "
            f"(amplitude error within ±{tolerance_pct:g} %, sync '{html.escape(t.primary_sync)}'{req})"
        )
        for m, other in t.limits.items():
            if m != t.primary_sync:
                lines.append(f"with sync '{html.escape(m)}': up to {_limit_text(other)}")
    else:
        lines.append("<b>No usable frequency limit</b>: the run has no sweep that could be fitted")
    reasons = [
        f"<li>{html.escape(c['description'])}: {_fmt(c['value'], 3)} {html.escape(c['unit'])} "
        f"(U = {_fmt(c['expanded_uncertainty'], 2)} {html.escape(c['unit'])}); required "
        f"{_SYMBOL[c['comparison']]} {_fmt(c['limit'])} {html.escape(c['unit'])} — "
        f"{html.escape(c['zone'])}</li>"
        for c in failed
    ]
    if missing:
        reasons.append(
            f"<li>Not evaluated (no data): {html.escape(', '.join(c['id'] for c in missing))}</li>"
        )
    if not failed and not missing:
        reasons.append(
            f"<li>All {len(crit)} criteria met with their expanded uncertainty (k = 2) inside the limits</li>"
        )
    if cert["conditions"].get("exit_status") not in ("success", None):
        reasons.append(
            f"<li>The run stopped with status '{html.escape(str(cert['conditions'].get('exit_status')))}'"
            "</li>"
        )
    return (
        f'<div class="verdict {result}"><div class="big">{result}</div><div class="why">'
        f"{'<br>'.join(lines)}<ul>{''.join(reasons)}</ul></div></div>"
    )


def _simulated_banner(cert: dict[str, Any]) -> str:
    """The banner over the verdict of a run on the simulated rig: its PASS says nothing of hardware."""
    note = html.escape(str(cert.get("simulated_note", "simulated rig")))
    return (f"<div class='simulated' id='simulated'>{note[0].upper() + note[1:]}: every device was a mock "
            "server and every camera frame was rendered by the digital twin.</div>")


def _cards(cert: dict[str, Any]) -> str:
    cards = []
    for c in cert["criteria"]:
        state = c["status"] if c["status"] in ("PASS", "FAIL") else "NA"
        unit = "" if c["unit"] == "1" else f" {c['unit']}"
        big_u = c["expanded_uncertainty"]
        shown = (
            c["status"] != "NOT EVALUATED" and isinstance(big_u, float) and math.isfinite(big_u) and big_u > 0
        )
        u = f" ± {_fmt(big_u, 2)}" if shown else ""
        cards.append(
            f'<div class="card {state}"><div class="k">{html.escape(c["description"])}</div>'
            f'<div class="v">{_fmt(c["value"], 3)}{html.escape(unit)}</div>'
            f'<div class="l">limit {_SYMBOL[c["comparison"]]} {_fmt(c["limit"])}{html.escape(unit)}{u}'
            "</div></div>"
        )
    return f'<div class="cards">{"".join(cards)}</div>'


def _budget(c: dict[str, Any]) -> str:
    """The uncertainty budget of a criterion as a short line: component (type) standard uncertainty."""
    items = [f"{html.escape(b['component'])} ({b['type']}) {_fmt(b['u'], 2)}" for b in c.get("budget") or []]
    if not items:
        return ""
    unit = "" if c["unit"] == "1" else f" {html.escape(c['unit'])}"
    return f"<br><span class='budget'>u: {'; '.join(items)}{unit}</span>"


def _criteria_table(cert: dict[str, Any]) -> str:
    rows = []
    for c in cert["criteria"]:
        badge = c["status"].split()[0]
        rows.append(
            f'<tr><td class="t">{html.escape(c["description"])}<br><span class="note">{html.escape(c["id"])}'
            f"</span></td><td>{_fmt(c['value'])}</td><td>{_fmt(c['expanded_uncertainty'], 2)}</td>"
            f"<td>{_fmt(c['coverage_factor'], 3)}</td><td>{_SYMBOL[c['comparison']]} {_fmt(c['limit'])}</td>"
            f'<td class="t">{html.escape(c["unit"])}</td><td class="t">{html.escape(c["zone"])}</td>'
            f'<td><span class="badge {badge}">{html.escape(c["status"])}</span></td>'
            f'<td class="t note">{html.escape(c["note"])}{_budget(c)}</td></tr>'
        )
    head = (
        "<tr><th class='t'>criterion</th><th>measured</th><th>U</th><th>k</th><th>limit</th>"
        "<th class='t'>unit</th>"
        "<th class='t'>zone</th><th>decision</th><th class='t'>note</th></tr>"
    )
    return f"<div class='tw'><table><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table></div>"


def render(
    cert: dict[str, Any],
    t: ReportTables,
    pngs: dict[str, bytes],
    acceptance: dict[str, Any],
    tables_html: dict[str, pd.DataFrame],
    *,
    figures_note: str | None = None,
) -> str:
    """The whole page as a string (deterministic for the same inputs). ``figures_note``: why the page has no
    figure (e.g. "figures not drawn: [report] figures = false"), said under the verdict."""
    simulated = bool(cert.get("simulated"))
    parts = [
        _header(cert, t, simulated=simulated),
        NAV,
        _simulated_banner(cert) if simulated else "",
        _verdict(cert, t, float(acceptance["amplitude_error_pct"])),
        f"<p class='note'>{html.escape(figures_note)}</p>" if figures_note else "",
        "<section>" + _cards(cert) + "</section>",
        _certificate_section(cert),
        _position_section(t, pngs, tables_html),
        _frequency_section(t, pngs, tables_html, bin_hz=float(acceptance["frequency_bin_hz"])),
        _band_section(t),
        _phase_section(t, pngs),
        _extended_band_section(t, pngs),
        _steps_section(t),
        _motion_section(t, pngs, tables_html),
        _calibration_section(t, tables_html),
        _conditions_section(cert["conditions"]),
    ]
    return page(f"{cert['result']} — {cert['conditions'].get('run_id')}", parts)


def page(title: str, parts: list[str]) -> str:
    """A self-contained HTML page of the company's stylesheet: ``parts`` (HTML) one per line in ``<main>``."""
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body><main>"
        + "\n".join(parts)
        + "</main></body></html>\n"
    )


NAV = (
    "<nav><a href='#cert'>Certificate</a><a href='#pos'>Position</a><a href='#freq'>Frequency</a>"
    "<a href='#band'>Band</a><a href='#phase'>Phase</a>"
    "<a href='#motion'>Steady motion</a><a href='#cal'>Calibration &amp; sync</a>"
    "<a href='#cond'>Conditions</a></nav>"
)


def _header(cert: dict[str, Any], t: ReportTables, *, simulated: bool) -> str:
    cond = cert["conditions"]
    title = "Certification report (simulated rig)" if simulated else "Certification report"
    return (
        f"<header><h1>{title} — {html.escape(str(cond.get('run_id')))}</h1>"
        f"<div class='sub'>procedure {html.escape(str(cond.get('procedure')))} · run started "
        f"{html.escape(str(cond.get('date_utc')))} · sync method '{html.escape(t.primary_sync)}' · "
        f"software {html.escape(str(cond.get('report_software')))}</div></header>"
    )


def _certificate_section(cert: dict[str, Any]) -> str:
    return (
        f"<section id='cert'><h2>Certificate</h2>{_criteria_table(cert)}<p class='note'><b>Decision rule."
        f"</b> {html.escape(cert['decision_rule']['text'])} U is the expanded uncertainty, k its coverage "
        "factor (2, or Student's t for fitted values with few degrees of freedom).</p></section>"
    )


def _position_section(t: ReportTables, pngs: dict[str, bytes], tables_html: dict[str, pd.DataFrame]) -> str:
    s = t.position_summary
    return (
        "<section id='pos'><h2>Error versus position</h2>"
        f"<p>{s['n_matched']} of {s['n_commanded']} commanded marker poses measured. "
        f"|error|: mean {_fmt(s['mean_mm'])} mm, "
        f"RMS {_fmt(s['rms_mm'])} mm, 95th percentile {_fmt(s['p95_mm'])} mm, max {_fmt(s['max_mm'])} mm.</p>"
        + figure(pngs, "error_vectors", "Error vectors at the commanded positions (scaled up)")
        + figure(
            pngs,
            "error_vs_position",
            "|error| against the distance from the cameras and off the viewing axis",
        )
        + "<h3>ISO 9283 pose accuracy (AP) and repeatability (RP) per target</h3>"
        + "<p class='note'>Targets visited in at least two cycles; poses visited once are in the pose table "
        "and in the figures above.</p>"
        + table(tables_html["iso9283"], text_cols=("target", "marker_id"))
        + "<h3>VDI/VDE 2634-1 length measurement error ΔL between marker pairs</h3>"
        + _length_line(t.lengths)
        + "<details><summary>Per marker pair</summary>"
        + table(tables_html["length_summary"], text_cols=("marker_a", "marker_b"))
        + "</details>"
        + "<details><summary>All poses</summary>"
        + table(tables_html["poses"], text_cols=("target", "marker_id"))
        + "</details></section>"
    )


def _frequency_section(
    t: ReportTables, pngs: dict[str, bytes], tables_html: dict[str, pd.DataFrame], *, bin_hz: float
) -> str:
    fit_rows = tables_html["fits"]
    return (
        "<section id='freq'><h2>Error versus frequency</h2>"
        f"<p>The sweep is cut into {bin_hz:g} Hz bins; in each, the measured "
        "displacement along the exciter axis is fitted with the reference phase (three-parameter sine fit). "
        "The relative amplitude error is fitted by weighted least squares with e(f) = c0 + c2·f² "
        f"over bins up to {t.fit_max_hz:.1f} Hz (default fs/3, away from Nyquist; fs = {t.fs_hz:g} fps). "
        "The dashed and dotted "
        "curves are the exact amplitude loss of linear interpolation of one camera's image coordinates; "
        "in 3D only a geometry-weighted share of it appears — about half for a symmetric pair and motion "
        "across the lines of sight (dash-dotted).</p>"
        + figure(
            pngs,
            "amplitude_error_vs_frequency",
            "Amplitude error and phase versus frequency, per sync method",
        )
        + table(
            fit_rows, digits=4, text_cols=tuple(c for c in fit_rows.columns if fit_rows[c].dtype == object)
        )
        + "<p class='note'>The phase of every bin is taken relative to the track's first bin: it grows as "
        "−360°·f·τ when the tracks' time stamps are offset by τ from the rig clock (the camera-to-controller "
        "clock mapping); 'track delay' is that τ from the slope. It shifts the motion in time and does not "
        "change the amplitude. The reference phase is the crank's polled actual frequency (the drive ramps "
        "ahead of the commanded profile); the notes say when only the commanded profile was available.</p>"
        + "<p class='note'>± on c0 and c2: 95 % confidence half-widths (Student's t); on the limit: its"
        " expanded uncertainty from the fit covariance.</p>"
        + figure(pngs, "sweep_time_frequency", "Frequency of the sweep over time (paper Fig. 17)")
        + "<details><summary>Per-bin values (mean over markers)</summary>"
        + table(tables_html["sweep_means"], text_cols=("sync_method",))
        + "</details></section>"
    )


def _band_section(t: ReportTables) -> str:
    """The band: one camera's Nyquist, the pair's combined rate at the measured offset, each method's
    usable band and ceiling, the certified edge and why it ends there (reports.band)."""
    b = t.band
    if b is None:
        return ""
    rows = pd.DataFrame([{"method": m, "usable to (Hz)": v.get("usable_to_hz"),
                          "ceiling (Hz)": v["ceiling_hz"], "why": v.get("why_it_ends") or v["why_ceiling"]}
                         for m, v in b["methods"].items()])
    alpha = "—" if b["offset_frames"] is None else f"{b['offset_frames']:.3f}"
    separation = "—" if b["alias_separation"] is None else f"{b['alias_separation']:.3f}"
    rate = "—" if b["combined_rate_hz"] is None else f"{b['combined_rate_hz']:g} Hz"
    edge = ("no method has a usable band" if b["certified_to_hz"] is None else
            f"certified to <b>{b['certified_to_hz']:g} Hz</b> by '{b['certified_by']}'")
    means = pd.DataFrame()
    if t.band_bins is not None and len(t.band_bins):
        means = t.band_bins.groupby("bin", sort=True).agg(
            frequency_hz=("frequency_hz", "mean"), n_tracks=("track", "size"),
            amplitude_error_pct=("amplitude_error_pct", "mean"),
            u_amplitude_error_pct=("u_amplitude_error_pct", "mean"),
            refused=("refused", lambda r: next((x for x in r if x), ""))).reset_index()
    return (
        "<section id='band'><h2>Band beyond one camera's Nyquist limit</h2>"
        f"<p>One camera samples at {t.fs_hz:g} fps (Nyquist {b['single_camera_nyquist_hz']:g} Hz). "
        f"The pair's instants fall α = {alpha} of a frame apart (measured on the sweep's markers, "
        f"rolling-shutter rows included; |sin πα| = {separation}): "
        f"combined rate {rate}. The 'interleaved' fit uses every camera's observations at their own instants "
        "along the marker's line of motion; bins whose frequency the pair cannot tell from its alias are "
        f"refused. Tolerance {b['tolerance_pct']:g} %: {edge} — {html.escape(str(b['why_it_ends']))}.</p>"
        + table(rows, digits=4, text_cols=("method", "why"))
        + ("<details><summary>Interleaved per-bin values (mean over markers)</summary>"
           + table(means, digits=4, text_cols=("refused",)) + "</details>" if len(means) else "")
        + "</section>"
    )


def _extended_band_section(t: ReportTables, pngs: dict[str, bytes]) -> str:
    """Certify's shaker band beyond the crank sweep: amplitude and phase per bin (reports.band_phase)."""
    ext = t.extended
    if ext is None:
        return ""
    s = ext.sweep
    edge = ("no bin passes" if not math.isfinite(ext.edge_hz) else
            f"certified from {ext.start_hz:g} to <b>{ext.edge_hz:g} Hz</b>")
    return (
        "<section id='extended-band'><h2>Band beyond the crank sweep (shaker)</h2>"
        f"<p>The sweep column on the shaker, the generator's linear sweep {s['profile'][0][1]:g} → "
        f"{s['profile'][-1][1]:g} Hz at {s['amplitude_mm']:g} mm, analysed with the interleaved fit. "
        "Reference: the generator's own waveform — its sweep law is exact from its phase restart "
        f"(PHASe:SYNChronize); {html.escape(str(s.get('phase_origin', '')))}. Controller↔camera clock: "
        f"{html.escape(ext.clock_source)} (u = {1e6 * ext.u_clock_s:.3g} µs). {edge} — "
        f"{html.escape(ext.why_it_ends)}.</p>"
        + figure(pngs, "extended_band", "Amplitude error and phase per bin over the shaker's band")
        + table(ext.bins, digits=4, text_cols=("refused",))
        + "</section>"
    )


def _steps_section(t: ReportTables) -> str:
    """The sweep's steady steps: amplitude, frequency, phase and delay per step (reports.step_phase)."""
    sp = t.steps
    if sp is None:
        return ""
    notes = "".join(f"<p class='note'>{html.escape(n)}</p>" for n in sp.notes)
    return (
        "<section id='steps'><h2>Phase per steady step</h2>"
        f"<p>Every flat stretch of the sweep's reference profile, from {sp.settle_s:g} s after it begins "
        f"(settle time) to its end, fitted per marker (sync '{sp.sync_method}', four-parameter sine fit); "
        f"mean over the markers. Reference: {html.escape(sp.reference)}. Controller↔camera clock: "
        f"{html.escape(sp.clock_source)} (u = {1e6 * sp.u_clock_s:.3g} µs). Phase budget per step: fit (A), "
        "reference phase law (B), clock (B); delay = −phase/(360°·f).</p>" + notes
        + (table(sp.bins, digits=4) if len(sp.bins) else "")
        + "</section>"
    )


def _phase_section(t: ReportTables, pngs: dict[str, bytes]) -> str:
    """The sweep's delay against the excitation, its budget and the phase per bin (reports.phase)."""
    ph = t.phase
    if ph is None:
        return ""
    budget = pd.DataFrame([{"component": c[0], "type": c[1], "u (ms)": c[2]} for c in ph.budget])
    p10, u10 = ph.phase_at_deg(10.0)
    return (
        "<section id='phase'><h2>Phase against the excitation</h2>"
        f"<p>Delay of the measured motion (sync '{ph.sync_method}') against the excitation's phase: "
        f"τ = {ph.delay_ms:+.4f} ms, U = {2 * ph.u_delay_ms:.4f} ms (k = 2); at 10 Hz that is "
        f"{p10:+.3f}° ± {2 * u10:.3f}°. The drive reports its frequency, not the crank's angle, so the phase "
        "is known up to a constant: each bin's phase is taken against the line's intercept, and its "
        "delay is −phase/(360°·f). Controller↔camera clock: "
        f"{html.escape(ph.clock_source)}. Reference: {html.escape(ph.reference.source)}.</p>"
        + table(budget, digits=4, text_cols=("component", "type"))
        + figure(pngs, "phase_vs_frequency", "Phase of the measured motion against the excitation, per bin")
        + "<details><summary>Phase and delay per bin</summary>" + table(ph.bins, digits=4)
        + "</details></section>"
    )


def _motion_section(t: ReportTables, pngs: dict[str, bytes], tables_html: dict[str, pd.DataFrame]) -> str:
    motion = []
    plate = tables_html.get("plate")
    if plate is not None and not plate.empty:
        motion.append("<h3>Oscillating plate</h3>" + table(plate, text_cols=("track",)))
    if t.rotation_summary:
        motion.append("<h3>Rotor</h3>" + _vertical(t.rotation_summary))
    return (
        "<section id='motion'><h2>Steady motion: plate and rotor</h2>"
        + "".join(motion)
        + figure(
            pngs, "trajectory", "Trajectory X(t), Y(t), Z(t) and an enlarged 5 s segment (paper Figs. 5–8)"
        )
        + figure(pngs, "rotation_radius", "Measured radius of rotation (paper Fig. 14)")
        + figure(pngs, "spectrum", "Spectrum of the rotor marker's height (paper Fig. 15)")
        + ("" if motion or "trajectory" in pngs else "<p class='note'>No steady-motion data in this run.</p>")
        + "</section>"
    )


def _calibration_section(t: ReportTables, tables_html: dict[str, pd.DataFrame]) -> str:
    timing = t.timing
    return (
        "<section id='cal'><h2>Calibration and synchronization</h2><h3>Calibration residuals per camera</h3>"
        + table(tables_html["calibration"], text_cols=("camera",))
        + "<h3>Synchronization</h3>"
        + table(tables_html["timing"], digits=6, text_cols=("camera",))
        + f"<p class='note'>method: {html.escape(timing.method if timing else '—')}; reference camera: "
        f"{html.escape(timing.reference_camera if timing else '—')}; u_…: standard uncertainties. "
        f"{_timing_details(timing.details if timing else {})}</p></section>"
    )


def _conditions_section(cond: dict[str, Any]) -> str:
    """The run's conditions (scalar fields), notes, measurands and the rig snapshot with versions."""
    fields = {
        k: ", ".join(map(str, v)) if isinstance(v, list) else v
        for k, v in cond.items()
        if not isinstance(v, dict) and k != "notes"
    }
    measurands = pd.DataFrame(
        [
            {"item": k, "value": json.dumps(v, sort_keys=True, ensure_ascii=False, default=str)}
            for k, v in (cond.get("measurands") or {}).items()
        ],
        columns=["item", "value"],
    )
    snapshot = json.dumps(
        {"rig": cond.get("rig"), "versions": cond.get("versions")}, indent=2, sort_keys=True, default=str
    )
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in cond.get("notes", []))
    return (
        "<section id='cond'><h2>Conditions</h2>"
        + table(
            pd.DataFrame([fields]).T.reset_index().set_axis(["field", "value"], axis=1),
            text_cols=("field", "value"),
        )
        + (f"<ul class='note'>{notes}</ul>" if notes else "")
        + "<h3>Measurands and conditions</h3>"
        + table(measurands, text_cols=("item", "value"))
        + "<details><summary>Rig snapshot and software versions</summary><pre>"
        + html.escape(snapshot)
        + "</pre></details></section>"
    )

"""Report figures (matplotlib, Agg backend, no display). Each ``fig_*`` returns a Figure or None (no data).

:func:`save_png` and :func:`save_svg` write with fixed metadata (no software/date stamp), so the same tables
give byte-identical files.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from reports import frequency
from reports.tables import ReportTables
from rig.record.atomic import atomic_path

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

DPI = 110
COLORS = {"primary": "#1f5fa8", "linear": "#c0392b", "theory": "#6c6c6c", "ok": "#2e8b57", "tol": "#d4a017"}
STYLE: dict[RcKeyType, Any] = {
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "font.size": 9.5,
    "axes.titlesize": 10.5,
    "axes.titleweight": "bold",
    "legend.fontsize": 8.5,
    "legend.frameon": False,
    "svg.hashsalt": "rig",
    "path.simplify": False,
}


def new_figure(
    nrows: int = 1, ncols: int = 1, size: tuple[float, float] = (7.5, 4.0),
    layout: Literal["constrained", "compressed", "tight"] | None = "constrained", **kw
) -> tuple[Figure, np.ndarray]:
    """A figure in the reports' style with an (nrows, ncols) array of axes; ``size`` in inches. ``layout``:
    matplotlib's layout engine, or None for axes placed by the caller (no layout engine: ``savefig`` then
    draws the figure once, not a layout pass first)."""
    with plt.rc_context(STYLE):
        fig = Figure(figsize=size, layout=layout)
        axes = fig.subplots(nrows, ncols, squeeze=False, **kw)
        for ax in axes.ravel():
            ax.grid(True, alpha=0.3)
            ax.spines[["top", "right"]].set_visible(False)
    return fig, axes


def save_png(fig: Figure, path: Path) -> None:
    """Write ``fig`` as PNG without a Software tag, so identical figures give identical bytes (atomically:
    :func:`rig.record.atomic.atomic_path`)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, format="png", metadata={"Software": None})


def save_svg(fig: Figure, path: Path) -> None:
    """Write ``fig`` as SVG, text drawn as paths (it looks the same whatever fonts the reader has), without
    date or creator stamp and with fixed element ids, so identical figures give identical bytes
    (atomically). A line figure of thousands of points draws in less than half the CPU time of its PNG (no
    rasterising, no compression: ``rig measure``'s two figures of a 20-s pair 0.07 against 0.16 s) and is
    smaller."""
    svg_style: dict[RcKeyType, Any] = {"svg.fonttype": "path", "svg.hashsalt": STYLE["svg.hashsalt"]}
    with plt.rc_context(svg_style), atomic_path(path) as tmp:
        fig.savefig(tmp, format="svg", metadata={"Date": None, "Creator": None})


def _method_color(method: str, primary: str) -> str:
    return COLORS["primary"] if method == primary else COLORS["linear"] if method == "linear" else "#7d3c98"


def fig_error_vectors(t: ReportTables) -> Figure | None:
    """Error vectors at the commanded positions in the volume (arrows scaled up), with the cameras."""
    p = t.poses.dropna(subset=["error_mm"])
    if p.empty:
        return None
    with plt.rc_context(STYLE):
        fig = Figure(figsize=(7.5, 5.6), layout="constrained")
        ax = fig.add_subplot(projection="3d")
    cmd = p[["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"]].to_numpy(float)
    err = p[["ex_mm", "ey_mm", "ez_mm"]].to_numpy(float)
    extent = float(np.ptp(cmd, axis=0).max()) or 100.0
    scale = 0.15 * extent / max(float(np.linalg.norm(err, axis=1).max()), 1e-12)
    sc = ax.scatter(*cmd.T, c=p["error_mm"], cmap="viridis", s=18, depthshade=False)
    ax.quiver(*cmd.T, *(err * scale).T, color="#c0392b", linewidth=1.0, arrow_length_ratio=0.25)
    ends = [cmd, cmd + err * scale]
    if len(t.centres_mm) >= 2:  # the cameras are far away: show the direction towards them
        mid = cmd.mean(axis=0)
        cams = np.mean(np.stack(list(t.centres_mm.values())), axis=0)
        v = (cams - mid) / np.linalg.norm(cams - mid)
        ax.quiver(*mid, *(v * 0.3 * extent), color="#333333", linewidth=1.5, arrow_length_ratio=0.15)
        ax.text(
            *(mid + v * 0.33 * extent),
            f"to the cameras ({np.linalg.norm(cams - mid) / 1000:.2f} m)",
            fontsize=8,
        )
        ends.append((mid + v * 0.36 * extent)[None, :])
    pts = np.concatenate(ends)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * extent
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_zlim(lo[2] - pad, hi[2] + pad)
    ax.set_box_aspect(np.maximum(hi - lo + 2 * pad, 0.2 * extent))
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title(f"Position error vectors (arrows ×{scale:.0f})")
    fig.colorbar(sc, ax=ax, shrink=0.6, label="|error| (mm)")
    return fig


MAX_DISTINCT_COLOURS = 10  # matplotlib's default cycle: an 11th series would repeat a colour


def _legend_groups(targets: pd.Series) -> tuple[pd.Series, str]:
    """One legend entry per target when the colours can tell them apart, else per kind of target.

    A kind is the target's name without a trailing index (``frame_3`` → ``frame``); when even the kinds
    are too many, every pose shares one colour. Returns the group of each row and the legend's title.
    """
    names = targets.astype(str)
    if names.nunique() <= MAX_DISTINCT_COLOURS:
        return names, "target"
    kinds = names.str.replace(r"[_\-\s]*\d+$", "", regex=True)
    if kinds.nunique() <= MAX_DISTINCT_COLOURS:
        per_kind = names.groupby(kinds).nunique()
        labels = {kind: f"{kind} ({n} target{'s' * (n > 1)})" for kind, n in per_kind.items()}
        return kinds.map(labels), "kind of target"
    return pd.Series(f"all {names.nunique()} targets", index=names.index), "targets"


def fig_error_vs_position(t: ReportTables, limit_mm: float | None = None) -> Figure | None:
    """|error| against distance from the cameras and distance off the viewing axis, per target.

    Every colour has a legend entry: per target, or per kind of target when there are more targets
    than distinct colours (:func:`_legend_groups`).
    """
    p = t.poses.dropna(subset=["error_mm"])
    if p.empty:
        return None
    groups, legend_title = _legend_groups(p["target"])
    fig, axes = new_figure(1, 2, size=(8.5, 3.6), sharey=True)
    for ax, col, label in (
        (axes[0, 0], "distance_mm", "distance from the cameras (mm)"),
        (axes[0, 1], "off_axis_mm", "distance off the viewing axis (mm)"),
    ):
        for group, g in p.groupby(groups, sort=True):
            ax.errorbar(
                g[col],
                g["error_mm"],
                yerr=2 * g["u_error_mm"].fillna(0),
                fmt="o",
                ms=4,
                capsize=2,
                label=str(group),
            )
        ax.set_xlabel(label)
    top = 1.15 * float((p["error_mm"] + 2 * p["u_error_mm"].fillna(0)).max())
    if limit_mm is not None and limit_mm <= 3 * top:  # show the limit when it does not squash the data
        for ax in axes[0]:
            ax.axhline(limit_mm, color=COLORS["linear"], ls="--", lw=1)
        axes[0, 0].annotate(
            f"limit {limit_mm:g} mm",
            (0.01, limit_mm),
            xycoords=("axes fraction", "data"),
            xytext=(0, 3),
            textcoords="offset points",
            color=COLORS["linear"],
            fontsize=8.5,
        )
        top = max(top, 1.15 * limit_mm)
    elif limit_mm is not None:
        axes[0, 0].text(
            0.01,
            0.97,
            f"limit {limit_mm:g} mm: far above",
            transform=axes[0, 0].transAxes,
            va="top",
            color=COLORS["linear"],
            fontsize=8.5,
        )
    axes[0, 0].set_ylim(0, top)
    axes[0, 0].set_ylabel("|error| (mm), bars ±2u")
    axes[0, 1].legend(title=legend_title, ncols=2 if groups.nunique() > 5 else 1)
    fig.suptitle("Error versus position", fontweight="bold", fontsize=10.5)
    return fig


def fig_amplitude_error(t: ReportTables, tolerance_pct: float) -> Figure | None:
    """Amplitude error and phase versus frequency per sync method, with the quadratic fit and the theory."""
    if t.sweep_bins.empty:
        return None
    fig, axes = new_figure(2, 1, size=(10.0, 6.2), sharex=True, height_ratios=[2.2, 1])
    ax, axp = axes[0, 0], axes[1, 0]
    f_max = float(t.sweep_bins["frequency_hz"].max())
    _plot_tolerance_and_theory(ax, t, tolerance_pct, np.linspace(0, f_max, 300))
    for method in t.sync_methods:
        _plot_method_bins(ax, axp, t, method, tolerance_pct=tolerance_pct, f_max_hz=f_max)
    _plot_interleaved(ax, t)
    lo = min(-2 * tolerance_pct, float(t.sweep_bins["amplitude_error_pct"].min()) - tolerance_pct)
    ax.set_ylim(max(lo, -105), max(2 * tolerance_pct, float(t.sweep_bins["amplitude_error_pct"].max()) + 1))
    ax.set_xlim(0, f_max * 1.03)
    ax.set_ylabel("amplitude error (%)")
    fig.suptitle(
        "Amplitude error versus frequency (bars ±2u; band: 95 % confidence of the fit)",
        fontweight="bold",
        fontsize=10.5,
    )
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    axp.set_ylabel("phase (deg)\nrel. first bin")
    axp.set_xlabel("frequency (Hz)")
    return fig


def _plot_tolerance_and_theory(ax: Axes, t: ReportTables, tolerance_pct: float, f_hz: np.ndarray) -> None:
    """The tolerance band and the amplitude loss of linear interpolation (paper's theory) over ``f_hz``."""
    ax.axhspan(
        -tolerance_pct,
        tolerance_pct,
        color=COLORS["tol"],
        alpha=0.10,
        lw=0,
        label=f"tolerance ±{tolerance_pct:g} %",
    )
    if t.alpha is not None:
        ax.plot(
            f_hz,
            frequency.theory_linear_pct(f_hz, t.fs_hz, t.alpha),
            ls="--",
            color=COLORS["theory"],
            lw=1.2,
            label=f"theory, one camera interpolated, α = {t.alpha:.2f}",
        )
        ax.plot(
            f_hz,
            0.5 * frequency.theory_linear_pct(f_hz, t.fs_hz, t.alpha),
            ls="-.",
            color=COLORS["theory"],
            lw=1.0,
            label="theory in 3D, cameras weighted equally",
        )
    ax.plot(
        f_hz,
        frequency.theory_linear_pct(f_hz, t.fs_hz),
        ls=":",
        color=COLORS["theory"],
        lw=1.2,
        label="theory, one camera interpolated, mean over α",
    )


def _plot_interleaved(ax: Axes, t: ReportTables) -> None:
    """The interleaved per-bin errors (±2u; refused bins as crosses at 0) and one camera's Nyquist limit."""
    if t.band_bins is None or t.band_bins.empty:
        return
    g = t.band_bins.groupby("bin", sort=True)
    m = g.agg(f=("frequency_hz", "mean"), e=("amplitude_error_pct", "mean"),
              u=("u_amplitude_error_pct", "mean"))
    refused = g["refused"].agg(lambda r: any(bool(x) for x in r))
    ok = ~refused
    ax.errorbar(m["f"][ok], m["e"][ok], yerr=2 * m["u"][ok], fmt="s", ms=3, color="0.15", capsize=1.5,
                label="measured, interleaved (both cameras' instants)")
    if refused.any():
        ax.plot(m["f"][refused], np.zeros(int(refused.sum())), "x", color="0.15",
                label="refused (see report)")
    ax.axvline(t.fs_hz / 2, color="0.4", lw=1, ls=":", label=f"one camera's Nyquist {t.fs_hz / 2:g} Hz")


def _plot_method_bins(
    ax: Axes, axp: Axes, t: ReportTables, method: str, *, tolerance_pct: float, f_max_hz: float
) -> None:
    """One sync method: per-bin error (±2u) and phase, its quadratic fit with the 95 % band, its limit."""
    color = _method_color(method, t.primary_sync)
    g = t.sweep_bins[t.sweep_bins["sync_method"] == method]
    m = g.groupby("bin", sort=True).agg(
        f=("frequency_hz", "mean"),
        e=("amplitude_error_pct", "mean"),
        u=("u_amplitude_error_pct", "mean"),
        ph=("phase_deg", "mean"),
    )
    ax.errorbar(
        m["f"], m["e"], yerr=2 * m["u"], fmt="o", ms=3.5, color=color, capsize=1.5,
        label=f"measured, sync '{method}'",
    )
    axp.plot(m["f"], m["ph"], "o-", ms=3, lw=1, color=color, label=method)
    fit = t.fits.get(method)
    if fit is not None:
        ff = np.linspace(0, fit.f_max_hz, 200)
        band = fit.t_factor * fit.u_predict(ff)
        ax.plot(
            ff,
            fit.predict(ff),
            color=color,
            lw=1.6,
            label=f"fit e = {fit.c0:.3f} {fit.c2:+.4g}·f²  (R² = {fit.r2:.3f})",
        )
        ax.fill_between(ff, fit.predict(ff) - band, fit.predict(ff) + band, color=color, alpha=0.15, lw=0)
    lim = t.limits.get(method)
    if lim is not None and lim.reached:
        ax.axvline(lim.limit_hz, color=color, lw=1, ls="-.")
        near_right = lim.limit_hz > 0.8 * f_max_hz
        ax.annotate(
            f"{lim.limit_hz:.1f} Hz",
            (lim.limit_hz, tolerance_pct),
            xytext=(-3 if near_right else 3, 4),
            textcoords="offset points",
            ha="right" if near_right else "left",
            color=color,
            fontsize=8.5,
        )


def fig_time_frequency(t: ReportTables) -> Figure | None:
    """The sweep's frequency over time: the commanded profile and the measured frequency per bin (Fig. 17)."""
    if t.sweep is None:
        return None
    fig, axes = new_figure(size=(7.5, 3.4))
    ax = axes[0, 0]
    prof = np.asarray(t.sweep["profile"], float)
    ax.plot(prof[:, 0] - prof[0, 0], prof[:, 1], color="#333333", lw=1.4, label="commanded profile")
    m = t.sweep_means[t.sweep_means["sync_method"] == t.primary_sync] if not t.sweep_means.empty else None
    if m is not None and len(m):
        ax.plot(
            m["t_mid_s"] - prof[0, 0],
            m["measured_frequency_hz"],
            "o",
            ms=4,
            color=COLORS["primary"],
            label=f"measured (sync '{t.primary_sync}')",
        )
    ax.set_xlabel("time since sweep start (s)")
    ax.set_ylabel("frequency (Hz)")
    ax.set_title("Sweep: frequency over time")
    ax.legend()
    return fig


def fig_phase(t: ReportTables) -> Figure | None:
    """The measured motion's phase against the excitation per bin (± 2u) and the line −360°·f·τ."""
    ph = t.phase
    if ph is None:
        return None
    fig, axes = new_figure(size=(7.5, 3.4))
    ax = axes[0, 0]
    b = ph.bins
    ax.errorbar(b["frequency_hz"], b["phase_deg"], yerr=2 * b["u_phase_deg"], fmt="o", ms=4, capsize=2,
                color=COLORS["primary"], label=f"bins (sync '{ph.sync_method}', ± U, k = 2)")
    f = np.linspace(0.0, float(b["frequency_hz"].max()), 50)
    ax.plot(f, -360.0 * f * ph.delay_ms / 1000.0, color="#333333", lw=1.2,
            label=f"τ = {ph.delay_ms:+.3f} ± {2 * ph.u_delay_ms:.3f} ms")
    ax.axhline(0.0, color="#999999", lw=0.8)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("phase against the excitation (°)")
    ax.set_title("Phase of the measured motion")
    ax.legend()
    return fig


def fig_extended_band(t: ReportTables) -> Figure | None:
    """The shaker's band step: amplitude error and phase per bin against the generator's waveform (± 2u)."""
    ext = t.extended
    if ext is None or ext.bins.empty:
        return None
    fig, axes = new_figure(2, 1, size=(7.5, 5.2))
    b = ext.bins
    ok = b["refused"] == ""
    panels = ((axes[0, 0], "amplitude_error_pct", "u_amplitude_error_pct", "amplitude error (%)"),
              (axes[1, 0], "phase_deg", "u_phase_deg", "phase against the generator (°)"))
    for ax, col, u, label in panels:
        ax.errorbar(b["frequency_hz"][ok], b[col][ok], yerr=2 * b[u][ok], fmt="s", ms=3, capsize=1.5,
                    color=COLORS["primary"], label="interleaved fit, mean over markers (± U, k = 2)")
        if (~ok).any():
            ax.plot(b["frequency_hz"][~ok], np.zeros(int((~ok).sum())), "x", color="0.15", label="refused")
        ax.axhline(0.0, color="#999999", lw=0.8)
        ax.axvline(t.fs_hz / 2, color="0.4", lw=1, ls=":", label=f"one camera's Nyquist {t.fs_hz / 2:g} Hz")
        ax.set_ylabel(label)
    axes[0, 0].set_title("Band beyond the crank sweep (shaker): amplitude and phase per bin")
    axes[0, 0].legend()
    axes[1, 0].set_xlabel("frequency (Hz)")
    return fig


def fig_trajectory(t: ReportTables) -> Figure | None:
    """X(t), Y(t), Z(t) of one marker and an enlarged 5 s segment of its most moving axis (Figs. 5–8)."""
    tr = t.trajectory
    if tr is None or tr.empty:
        return None
    fig, axes = new_figure(4, 1, size=(8.0, 7.6))
    time = tr["time_s"].to_numpy(float) - float(tr["time_s"].iloc[0])
    for ax, col in zip(axes[:3, 0], ("x_mm", "y_mm", "z_mm"), strict=True):
        ax.plot(time, tr[col], lw=0.7, color=COLORS["primary"])
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_ylabel(col.replace("_mm", " (mm)").upper().replace("(MM)", "(mm)"))
    main = max(("x_mm", "y_mm", "z_mm"), key=lambda c: float(np.ptp(tr[c])))
    mid = 0.5 * (time[0] + time[-1])
    sel = (time >= mid - 2.5) & (time <= mid + 2.5)
    axes[3, 0].plot(time[sel], tr[main].to_numpy(float)[sel], ".-", ms=3, lw=0.7, color=COLORS["primary"])
    axes[3, 0].set_ylabel(main.replace("_mm", "").upper() + " (mm), zoom")
    axes[3, 0].set_xlabel("time (s)")
    axes[0, 0].set_title(f"Trajectory of the {t.trajectory_source}")
    return fig


def fig_spectrum(t: ReportTables) -> Figure | None:
    """Amplitude spectrum of the rotor marker's height (Fig. 15)."""
    if t.spectrum is None or t.spectrum.empty:
        return None
    fig, axes = new_figure(size=(7.5, 3.2))
    ax = axes[0, 0]
    ax.plot(t.spectrum["frequency_hz"], t.spectrum["amplitude_mm"], lw=1, color=COLORS["primary"])
    if t.rotation is not None:
        ax.axvline(
            float(t.rotation["frequency_hz"]), color=COLORS["theory"], ls="--", lw=1, label="commanded"
        )
        ax.legend()
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude (mm)")
    ax.set_title("Spectrum of the rotor marker's height z(t) (flat-top window: peak heights are amplitudes)")
    return fig


def fig_rotation_radius(t: ReportTables) -> Figure | None:
    """Measured radius of rotation over time against the reference radius (Fig. 14)."""
    rs = t.rotation_samples
    if rs is None or rs.empty or t.rotation is None:
        return None
    fig, axes = new_figure(size=(7.5, 3.2))
    ax = axes[0, 0]
    time = rs["time_s"].to_numpy(float) - float(rs["time_s"].iloc[0])
    ax.plot(time, rs["radius_mm"], lw=0.8, color=COLORS["primary"], label="measured")
    ax.axhline(float(t.rotation["radius_mm"]), color=COLORS["theory"], ls="--", lw=1.2, label="reference")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("radius (mm)")
    ax.set_title("Radius of rotation")
    ax.legend()
    return fig


def all_figures(
    t: ReportTables, tolerance_pct: float, position_limit_mm: float | None = None
) -> dict[str, Figure]:
    """Every figure with data, by file stem, in report order."""
    made = {
        "error_vectors": fig_error_vectors(t),
        "error_vs_position": fig_error_vs_position(t, position_limit_mm),
        "amplitude_error_vs_frequency": fig_amplitude_error(t, tolerance_pct),
        "sweep_time_frequency": fig_time_frequency(t),
        "phase_vs_frequency": fig_phase(t),
        "extended_band": fig_extended_band(t),
        "trajectory": fig_trajectory(t),
        "rotation_radius": fig_rotation_radius(t),
        "spectrum": fig_spectrum(t),
    }
    return {k: v for k, v in made.items() if v is not None}

"""The shaker's band beyond the crank sweep (certify's ``band`` step): amplitude and phase per bin against
the generator's own waveform, the certified band edge, and the certificate's ``extended_band`` section.

Reference: the generator's linear sweep from its phase restart (``PHASe:SYNChronize``, the
``band_sweep`` event's first profile time). Its frequency law is exact (the instrument's synthesiser), and
with the timing fiducial on the generator's other channel the LED's edges that date the cameras share the
same phase origin — an error in the controller's estimate of that instant moves the cameras' dates and the
reference alike. The interleaved fit (:func:`reports.band.interleaved_bins`) gives each marker's motion
along the sweep axis as A·sin(φ + phase) against that reference; per frequency bin (mean over the markers):

* amplitude error e = (A − A_ref)/A_ref (%) with its fit uncertainty (Type A);
* phase (°) with the budget: the fit (Type A, u_A/A rad) and the controller↔camera clock of the segment
  (Type B, 360°·f·u_clock: the reference camera's fiducial fit, taken whole although the fit averages
  both cameras' own fiducial dates, each of that size; it includes the command bracket's width, which
  cancels for this reference — so it is an upper bound); the delay −phase/(360°·f) (ms) likewise. Not
  included: the channels' skew after ``PHASe:SYNChronize`` (the instrument's data sheet) and, on a real
  bench, the shaker and amplifier's own phase response (the certificate then states the phase of the
  motion against the drive; a lab corrects it with the shaker's calibration or a reference accelerometer).

The certified edge: from the lowest bin, the last bin of the unbroken run where no marker's fit is refused
and |e| + k·u and |phase| + k·u are within the limits (k = 2 under the guarded rule, else 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from reports.certificate import Measured

EXTENDED_COLUMNS = ["frequency_lo_hz", "frequency_hi_hz", "frequency_hz", "n_tracks", "amplitude_error_pct",
                    "u_amplitude_error_pct", "phase_deg", "u_phase_fit_deg", "u_phase_deg", "delay_ms",
                    "u_delay_ms", "refused"]


@dataclass
class ExtendedBand:
    """The band step's per-bin table (:data:`EXTENDED_COLUMNS`), its reference and clock, and its edge."""

    sweep: dict[str, Any]
    bins: pd.DataFrame
    u_clock_s: float
    clock_source: str
    start_hz: float = float("nan")
    edge_hz: float = float("nan")
    why_it_ends: str = ""
    notes: list[str] = field(default_factory=list)


def per_bin(bins: pd.DataFrame, u_clock_s: float) -> pd.DataFrame:
    """Means over the markers per bin of the interleaved fits (:data:`reports.band.BAND_COLUMNS`) with the
    phase budget and the delay (:data:`EXTENDED_COLUMNS`)."""
    if bins.empty:
        return pd.DataFrame(columns=EXTENDED_COLUMNS)
    g = bins.groupby("bin", sort=True)
    out = g[["frequency_lo_hz", "frequency_hi_hz", "frequency_hz", "amplitude_error_pct",
             "u_amplitude_error_pct"]].mean()
    # the markers' phases are averaged on the circle (each within ±180°)
    z = bins.assign(z=np.exp(1j * np.deg2rad(bins["phase_deg"].to_numpy(float)))).groupby("bin")["z"].mean()
    out["phase_deg"] = np.rad2deg(np.angle(z.to_numpy()))
    out["u_phase_fit_deg"] = g["u_phase_deg"].mean()
    out["n_tracks"] = g.size()
    out["refused"] = g["refused"].agg(lambda s: next((r for r in s if r), ""))
    f = out["frequency_hz"].to_numpy(float)
    out["u_phase_deg"] = np.hypot(out["u_phase_fit_deg"].to_numpy(float), 360.0 * f * u_clock_s)
    out["delay_ms"] = -out["phase_deg"] / (360.0 * f) * 1000.0
    out["u_delay_ms"] = out["u_phase_deg"] / (360.0 * f) * 1000.0
    return out.reset_index(drop=True)[EXTENDED_COLUMNS]


def band_edge(table: pd.DataFrame, amplitude_pct: float | None, phase_deg: float | None,
              guard_k: float) -> tuple[float, float, str]:
    """(lowest bin's lower edge, upper edge of the unbroken passing run from it, why it ends there); a
    limit None is not applied. NaN edges when no bin passes."""
    if table.empty:
        return float("nan"), float("nan"), "no interleaved bin in the band step"
    start, edge = float(table["frequency_lo_hz"].iloc[0]), float("nan")
    for r in table.itertuples():
        f = f"{r.frequency_hz:.1f} Hz"
        if r.refused:
            return start, edge, f"the bin at {f} is refused: {r.refused}"
        worst_e = abs(r.amplitude_error_pct) + guard_k * r.u_amplitude_error_pct
        if amplitude_pct is not None and worst_e > amplitude_pct:
            return start, edge, (f"at {f} |e| = {abs(r.amplitude_error_pct):.2f} % (+{guard_k:g}u = "
                                 f"{worst_e:.2f} %) exceeds the {amplitude_pct:g} % limit")
        worst_p = abs(r.phase_deg) + guard_k * r.u_phase_deg
        if phase_deg is not None and worst_p > phase_deg:
            return start, edge, (f"at {f} |phase| = {abs(r.phase_deg):.2f}° (+{guard_k:g}u = {worst_p:.2f}°) "
                                 f"exceeds the {phase_deg:g}° limit")
        edge = float(r.frequency_hi_hz)
    return start, edge, "the highest frequency swept (a lower bound: the band step ends there)"


def extended_band(bins: pd.DataFrame, sweep: dict[str, Any], *, u_clock_s: float, clock_source: str,
                  acceptance: dict[str, Any]) -> ExtendedBand:
    """The band step's table and edge from its interleaved bins (``bins``: BAND_COLUMNS)."""
    table = per_bin(bins, u_clock_s)
    guard_k = 2.0 if acceptance.get("decision_rule", "guarded") == "guarded" else 0.0
    start, edge, why = band_edge(table, acceptance.get("band_amplitude_error_pct"),
                                 acceptance.get("band_phase_deg"), guard_k)
    return ExtendedBand(sweep, table, u_clock_s, clock_source, start, edge, why)


def measured_values(ext: ExtendedBand | None) -> dict[str, Measured]:
    """The band criteria: the worst bin's |e| and |phase| (not refused bins) and the certified edge."""
    if ext is None or ext.bins.empty:
        return {}
    t = ext.bins[ext.bins["refused"] == ""]
    out: dict[str, Measured] = {}
    fiducial = ext.clock_source.startswith("timing fiducial")
    clock = "timing fiducial" if fiducial else "start events (±½ frame: no timing fiducial in this segment)"
    if len(t):
        i = int(np.argmax(np.abs(t["amplitude_error_pct"].to_numpy(float))))
        r = t.iloc[i]
        out["band_amplitude_error_pct"] = Measured.from_budget(
            abs(float(r["amplitude_error_pct"])),
            [("interleaved fit", "A", float(r["u_amplitude_error_pct"]))],
            note=f"worst of {len(t)} bins {t['frequency_hz'].min():.3g}–{t['frequency_hz'].max():.3g} Hz: "
                 f"{r['frequency_hz']:.3g} Hz (mean of {int(r['n_tracks'])} markers)")
        j = int(np.argmax(np.abs(t["phase_deg"].to_numpy(float))))
        q = t.iloc[j]
        out["band_phase_deg"] = Measured.from_budget(
            abs(float(q["phase_deg"])),
            [("interleaved fit", "A", float(q["u_phase_fit_deg"])),
             ("controller↔camera clock", "B", 360.0 * float(q["frequency_hz"]) * ext.u_clock_s)],
            note=f"worst bin {q['frequency_hz']:.3g} Hz: delay {q['delay_ms']:+.4g} ± "
                 f"{2 * q['u_delay_ms']:.2g} ms (k = 2); reference: the generator's sweep from its phase "
                 f"restart; clock: {clock}")
    if math.isfinite(ext.edge_hz):
        out["band_min_hz"] = Measured(ext.edge_hz, 0.0,
                                      note=f"from {ext.start_hz:g} Hz; ends: {ext.why_it_ends}")
    return out


def section(ext: ExtendedBand | None) -> dict[str, Any] | None:
    """The certificate's ``extended_band`` section (plain JSON types)."""
    if ext is None:
        return None
    s = ext.sweep
    return {
        "body": s.get("body"),
        "sweep_hz": [float(s["profile"][0][1]), float(s["profile"][-1][1])],
        "amplitude_mm": float(s["amplitude_mm"]),
        "steady_window_s": [float(s["t_start_s"]), float(s["t_stop_s"])],
        "reference": "the generator's own linear sweep, exact law from its phase restart (PHASe:SYNChronize) "
                     "at the first profile time; x = A·sin(φ + phase) along the sweep axis",
        "phase_origin": s.get("phase_origin", ""),
        "phase_origin_bracket_s": s.get("phase_origin_s"),
        "clock_source": ext.clock_source,
        "u_clock_ms": 1000.0 * ext.u_clock_s,
        "not_in_budget": "the channels' skew after PHASe:SYNChronize (instrument data sheet); on a real "
                         "bench the shaker's and amplifier's own phase response",
        "usable_from_hz": ext.start_hz if math.isfinite(ext.start_hz) else None,
        "certified_to_hz": ext.edge_hz if math.isfinite(ext.edge_hz) else None,
        "why_it_ends": ext.why_it_ends,
        "bins": ext.bins.to_dict("records"),
        "notes": list(ext.notes),
    }


__all__ = ["EXTENDED_COLUMNS", "ExtendedBand", "band_edge", "extended_band", "measured_values", "per_bin",
           "section"]

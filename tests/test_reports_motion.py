"""Steady motions: the plate (per-marker cantilever amplitudes), the rotor (radius, frequency), spectra."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from reports import motion
from reports.errors import ReportError

FS_HZ = 60.0
GEOMETRY = {
    "root_mm": [500.0, -100.0, 300.0],
    "length_mm": 250.0,
    "cols": 4,
    "rows": 2,
    "pitch_mm": 50.0,
    "row_pitch_mm": 60.0,
    "length_direction": [0.0, 1.0, 0.0],
    "width_direction": [0.0, 0.0, 1.0],
}
TIP_MM = 8.0
F_PLATE_HZ = 3.5


def _shape(xi: float) -> float:
    return 0.5 * (3 * xi**2 - xi**3)


def _plate_event() -> dict:
    amps = {f"plate_r{r}c{c}": TIP_MM * _shape((c + 1) * 50.0 / 250.0) for r in range(2) for c in range(4)}
    return {
        "t_start_s": 10.0,
        "t_stop_s": 16.0,
        "frequency_hz": F_PLATE_HZ,
        "amplitude_mm": TIP_MM,
        "axis": [1.0, 0.0, 0.0],
        "marker_ids": list(amps),
        "marker_amplitudes_mm": amps,
        "segment": "plate",
    }


def _plate_tracks(gain: dict[str, float]) -> pd.DataFrame:
    """Every marker at its rest position, moving along x by its amplitude × gain[marker] (default 1)."""
    ev = _plate_event()
    rest = motion.plate_rest_positions_mm(GEOMETRY)
    t = np.arange(int(10.0 * FS_HZ), int(16.0 * FS_HZ) + 1) / FS_HZ
    frames = []
    for i, (mid, amp) in enumerate(sorted(ev["marker_amplitudes_mm"].items())):
        d = amp * gain.get(mid, 1.0) * np.sin(2 * np.pi * F_PLATE_HZ * t + 0.3 * i)
        p = rest[mid]
        frames.append(
            pd.DataFrame(
                {
                    "segment": "plate",
                    "time_s": t,
                    "track_id": 10 + i,
                    "x_mm": p[0] + d,
                    "y_mm": p[1],
                    "z_mm": p[2],
                }
            )
        )
    frames.append(
        pd.DataFrame({"segment": "plate", "time_s": t, "track_id": 99, "x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0})
    )  # a static reference marker
    return pd.concat(frames, ignore_index=True)


def test_rest_positions_follow_the_geometry() -> None:
    rest = motion.plate_rest_positions_mm(GEOMETRY)
    np.testing.assert_allclose(rest["plate_r0c0"], [500.0, -50.0, 330.0])
    np.testing.assert_allclose(rest["plate_r1c3"], [500.0, 100.0, 270.0])
    with pytest.raises(ReportError, match=r"targets\.plate"):
        motion.plate_rest_positions_mm({"root_mm": [0, 0, 0]})


def test_each_plate_marker_is_compared_with_its_own_amplitude() -> None:
    gain = {"plate_r0c2": 0.97, "plate_r1c0": 1.05}  # injected amplitude errors −3 % and +5 %
    table = motion.plate_table(_plate_tracks(gain), _plate_event(), GEOMETRY).set_index("marker_id")
    assert len(table) == 8  # the static reference is not a plate marker
    for mid, row in table.iterrows():
        expected = 100 * (gain.get(mid, 1.0) - 1)
        assert row["amplitude_error_pct"] == pytest.approx(expected, abs=1e-8), mid
        assert row["amplitude_ref_mm"] == pytest.approx(_plate_event()["marker_amplitudes_mm"][mid])
        assert row["frequency_error_pct"] == pytest.approx(0.0, abs=1e-8)


def test_without_geometry_per_marker_amplitudes_are_not_guessed() -> None:
    table = motion.plate_table(_plate_tracks({}), _plate_event(), None)
    assert len(table) == 8
    assert table["amplitude_ref_mm"].isna().all() and (table["marker_id"] == "").all()
    # a uniform plate (no per-marker amplitudes) uses the event's amplitude for every track
    ev = _plate_event()
    del ev["marker_amplitudes_mm"]
    uniform = motion.plate_table(_plate_tracks({}), ev, None)
    assert (uniform["amplitude_ref_mm"] == TIP_MM).all()


def test_rotor_radius_and_frequency() -> None:
    f_true, r_meas = 10.02, 60.25
    rot = {
        "t_start_s": 0.0,
        "t_stop_s": 4.0,
        "frequency_hz": 10.0,
        "radius_mm": 60.0,
        "centre_mm": [400.0, 0.0, 300.0],
        "axis": [1.0, 0.0, 0.0],
        "segment": "sync",
    }
    t = np.arange(0, 241) / FS_HZ
    ang = 2 * np.pi * f_true * t
    rng = np.random.default_rng(4)
    sigma = 0.02
    tracks = pd.DataFrame(
        {
            "segment": "sync",
            "time_s": t,
            "track_id": 3,
            "x_mm": 400.0,
            "y_mm": r_meas * np.cos(ang) + rng.normal(0, sigma, len(t)),
            "z_mm": 300.0 + r_meas * np.sin(ang) + rng.normal(0, sigma, len(t)),
        }
    )
    samples = motion.rotation_samples(tracks, rot)
    s = motion.rotation_summary(samples, rot)
    assert s["radius_error_mm"] == pytest.approx(r_meas - 60.0, abs=4 * sigma / np.sqrt(len(t)) + 1e-4)
    assert s["frequency_meas_hz"] == pytest.approx(f_true, abs=4 * s["u_frequency_hz"])
    # the four-parameter fit attains the Cramér–Rao bound of a real sinusoid: σ·√24 / (2π·A·T·√N)
    crb = sigma * np.sqrt(24) / (2 * np.pi * r_meas * 4.0 * np.sqrt(len(t)))
    assert s["u_frequency_hz"] == pytest.approx(crb, rel=0.15)
    assert s["frequency_error_pct"] == pytest.approx(100 * (f_true - 10.0) / 10.0, abs=4e-3)


def test_rotor_of_another_segment_is_not_taken() -> None:
    rot = {
        "t_start_s": 0.0,
        "t_stop_s": 1.0,
        "frequency_hz": 2.0,
        "radius_mm": 50.0,
        "centre_mm": [0, 0, 0],
        "axis": [0, 0, 1],
        "segment": "sync",
    }
    t = np.arange(0, 61) / FS_HZ
    tracks = pd.DataFrame(
        {
            "segment": "other",
            "time_s": t,
            "track_id": 0,
            "x_mm": 50 * np.cos(t),
            "y_mm": 50 * np.sin(t),
            "z_mm": 0.0,
        }
    )
    assert motion.rotation_samples(tracks, rot).empty
    assert np.isnan(motion.rotation_summary(motion.rotation_samples(tracks, rot), rot)["radius_error_mm"])


@pytest.mark.parametrize("bin_offset", [0.0, 0.25, 0.5])
def test_amplitude_spectrum_reads_the_amplitude_on_and_between_bins(bin_offset: float) -> None:
    t = np.arange(600) / FS_HZ  # 10 s: bins every 0.1 Hz, 2 Hz sits exactly on one
    f_hz = 2.0 + 0.1 * bin_offset
    spec = motion.amplitude_spectrum(t, 3.0 * np.sin(2 * np.pi * f_hz * t) + 7.0)
    peak = spec.iloc[int(spec["amplitude_mm"].idxmax())]
    assert peak["frequency_hz"] == pytest.approx(f_hz, abs=0.05 + 1e-9)  # the nearest bin
    # flat-top window: scalloping loss ≤ 0.12 % (0.11 % at half a bin); a Hann window would lose 15 %
    assert peak["amplitude_mm"] == pytest.approx(3.0, rel=1.2e-3)
    with pytest.raises(ReportError, match="≥ 8 samples"):
        motion.amplitude_spectrum(t[:5], t[:5])


def test_plate_frequency_criterion_counts_identified_plate_markers_only() -> None:
    """A still reference marker that slipped into the plate table (tiny amplitude, noise frequency) must not
    make the steady-frequency criterion fail; without any identification every track still counts."""
    from types import SimpleNamespace

    from reports.tables import _frequency_errors

    rows = pd.DataFrame({
        "track": ["t0", "t1", "t2"], "marker_id": ["plate_r0c5", "plate_r0c4", ""],
        "frequency_ref_hz": 3.5, "frequency_meas_hz": [3.5001, 3.4999, 5.0], "u_frequency_hz": 1e-4,
        "frequency_error_pct": [100 * 1e-4 / 3.5, -100 * 1e-4 / 3.5, 100 * 1.5 / 3.5],
    })
    errors = _frequency_errors(SimpleNamespace(plate=rows, rotation_summary=None))
    assert [what for what, _, _ in errors] == ["plate t0", "plate t1"]
    unidentified = rows.assign(marker_id="")
    assert len(_frequency_errors(SimpleNamespace(plate=unidentified, rotation_summary=None))) == 3

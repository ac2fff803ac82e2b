"""Helpers of the certify end-to-end tests: a rig.toml in a temporary folder and the twin's truth."""

from __future__ import annotations

import json
import re
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from rig.config.rig_config import load_config

SIM_TOML = resources.files("rig").joinpath("data/sim.toml").read_text()


# (s) bounds of a patient station: for tests about something else than how long a device may stay silent,
# whose healthy mocks a loaded machine leaves unanswered for 2 × 1 s (the defaults' heartbeat loss)
PATIENT_HEARTBEAT_S, PATIENT_REPLY_S = 10.0, 3.0


def write_config(tmp_path: Path, *, patient: bool = False, comparison: tuple[str, ...] = (),
                 figures: bool = False) -> Path:
    """The built-in simulated rig with runs in ``tmp_path/runs``; ``patient``: the station's heartbeat
    timeout and the drives' and generator's reply timeouts raised (:data:`PATIENT_HEARTBEAT_S`, ...).
    ``comparison``, ``figures``: its ``[report]`` — by default the certificate only (no second analysis, no
    figure; the tests of those outputs and the full certification ask for them)."""
    text = re.sub(r'^runs_dir = .*$', f'runs_dir = "{(tmp_path / "runs").as_posix()}"', SIM_TOML, flags=re.M)
    text = with_report(text, comparison=comparison, figures=figures)
    if patient:
        text = re.sub(r'^\[station\]$', f"[station]\nheartbeat_timeout_s = {PATIENT_HEARTBEAT_S}", text,
                      flags=re.M)
        text = re.sub(r'^(\[devices\.(?:exciter|rotor|generator)\].*)$',
                      rf"\1\ntimeout_s = {PATIENT_REPLY_S}", text, flags=re.M)
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def with_report(rig_toml: str, *, comparison: tuple[str, ...] = (), figures: bool = False) -> str:
    """``rig_toml`` (text with a two-line ``[report]`` table, as sim.toml) with that table's ``comparison``
    and ``figures`` (the defaults: the certificate only, no second analysis, no figure)."""
    methods = ", ".join(f'"{m}"' for m in comparison)
    text, n = re.subn(r'^\[report\]\ncomparison = .*\nfigures = .*$',
                      f"[report]\ncomparison = [{methods}]\nfigures = {str(figures).lower()}", rig_toml,
                      flags=re.M)
    assert n == 1, "the configuration has no [report] table of two lines"
    return text


def twin_cameras(config_path: Path) -> dict[str, Any]:
    """The simulated cameras of the configuration (their hidden truth), on a fresh world."""
    from drivers.sim.clock import VirtualClock
    from drivers.sim.stereo_rig import make_camera
    from drivers.sim.world import World
    from rig.run.station import camera_specs

    cfg = load_config(config_path)
    world = World(VirtualClock())
    return {s.name: make_camera(s, world) for s in camera_specs(cfg)}


def true_offset_s(ref: Any, other: Any, tau_other_s: float) -> float:
    """τ_ref − τ_other at the world instant when ``other``'s frame stamped ``tau_other_s`` starts (row 0)."""
    k = (tau_other_s - other.timestamp_origin_s) * other.fps
    t_world = other.start_offset_s + k / (other.fps * (1 + other.clock_ppm * 1e-6))
    k_ref = (t_world - ref.start_offset_s) * ref.fps * (1 + ref.clock_ppm * 1e-6)
    return ref.timestamp_origin_s + k_ref / ref.fps - tau_other_s


def still_pixel_noise_px(observations: Any) -> float:
    """Single-frame centroid noise (px): median over still markers of the per-axis std across frames."""
    g = observations.groupby(["segment", "track_2d"]).agg(su=("u_px", "std"), sv=("v_px", "std"),
                                                          n=("u_px", "size"))
    g = g[g["n"] >= 4]
    return float(np.median(np.r_[g["su"].to_numpy(), g["sv"].to_numpy()]))


def depth_scale(calibration: dict[str, Any], point_mm: Any) -> tuple[float, float]:
    """(mm per px at ``point_mm``, depth / baseline) of the calibrated pair (Z/f and Z/B)."""
    cams = list(calibration["cameras"].values())
    centres = [np.asarray(c["centre_mm"], float) for c in cams]
    f_px = np.mean([c["intrinsics_px"]["fx_px"] for c in cams])
    z_mm = float(np.mean([np.linalg.norm(np.asarray(point_mm, float) - c) for c in centres]))
    return z_mm / f_px, z_mm / float(np.linalg.norm(centres[0] - centres[1]))


def read_json(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8"))


ROTATION_HZ, ROTATION_RECORD_S = 10.0, 1.5


def rotation_run(folder: Path) -> dict[str, Any]:
    """``rig run rotation`` (``record_s`` = :data:`ROTATION_RECORD_S` s at :data:`ROTATION_HZ` rev/s) on the
    simulated rig of :func:`write_config` in ``folder``: calibrate, sync, rotation and the report (its
    certificate issued). {"config": rig.toml, "run_dir": the run folder, "code": rig's exit code}."""
    from rig.cli import main
    from rig.record.catalogue import run_folders

    config = write_config(folder)
    code = main(["run", "rotation", "--config", str(config), "--set", f"record_s={ROTATION_RECORD_S}",
                 "--set", f"rotation_hz={ROTATION_HZ}"])
    (run_dir,) = run_folders(folder / "runs")
    return {"config": config, "run_dir": run_dir, "code": code}

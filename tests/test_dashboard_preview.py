"""``rig preview``'s findings and hints: saturation, marker size, blur, counts per camera, the epipolar check
(known truth: synthetic frames and the twin's true cameras), and a round on the simulated rig."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from drivers.sim.stereo_rig import default_camera_specs, make_camera
from drivers.sim.world import World
from rig.config.rig_config import load_config
from rig.preview import CameraView, HintLimits, edge_width_px, preview_hints, run_preview, view_of
from rig.run.frame_tap import FRAMES
from rig.stereo import DLTCamera
from tests.analysis_twin import projection
from tests.certify_support import write_config

ROOT = Path(__file__).resolve().parents[1]


def _frame(centres: list[tuple[int, int]], radius_px: int, grey: int,
           blur_sigma_px: float = 0.0) -> np.ndarray:
    """Bright discs on a dark background, drawn 8× larger and shrunk (antialiased edges), maybe blurred."""
    big = np.full((480 * 8, 640 * 8), 30, np.uint8)
    for u, v in centres:
        cv2.circle(big, (u * 8, v * 8), radius_px * 8, grey, -1)
    image = cv2.resize(big, (640, 480), interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(image, (0, 0), blur_sigma_px) if blur_sigma_px else image


CENTRES = [(100, 100), (300, 120), (500, 300), (200, 400)]


def _warnings(hints: dict) -> list[str]:
    return [h["text"] for h in hints["items"] if h["level"] == "warn"]


def test_a_sharp_well_exposed_pair_gets_no_warning() -> None:
    views = [view_of(name, _frame(CENTRES, 8, 200)) for name in ("left", "right")]
    hints = preview_hints(views)
    assert _warnings(hints) == []
    assert hints["cameras"]["left"]["markers"] == 4 and hints["cameras"]["left"]["saturated"] == 0
    assert abs(hints["cameras"]["left"]["median_diameter_px"] - 16.0) < 1.0


def test_saturated_small_blurred_and_missing_markers_are_named() -> None:
    saturated = view_of("left", _frame(CENTRES, 8, 255))
    assert saturated.saturated == 4
    small = view_of("left", _frame(CENTRES, 4, 200))
    blurred = view_of("right", _frame(CENTRES[:3], 8, 200, blur_sigma_px=3.0))
    sharp = view_of("right", _frame(CENTRES[:3], 8, 200))
    # a Gaussian blur of σ widens a 10–90 % edge to ≈ 2.56 σ; the contrast/steepest-slope width is √(2π) σ
    assert sharp.edge_px < 2.0 < 3.0 * 2.0 < blurred.edge_px < 3.0 * 3.0
    text = " | ".join(_warnings(preview_hints([saturated, blurred])))
    assert "left: 4 of 4 markers saturated" in text
    assert "right: blurred" in text
    assert "marker count differs between the cameras: left 4, right 3" in text
    text = " | ".join(_warnings(preview_hints([small, sharp], limits=HintLimits(min_diameter_px=10.0))))
    assert "left: 4 of 4 markers smaller than 10 px" in text and "right" not in text.split("count")[0]
    empty = CameraView("right", np.zeros((0, 2)), np.zeros(0), 0, float("nan"))
    assert "right: no marker found" in " ".join(_warnings(preview_hints([sharp, empty])))


def test_edge_width_of_an_ideal_ramp_is_its_length() -> None:
    ramp = np.tile(np.clip((np.arange(64) - 28) * 40 + 40, 40, 200), (64, 1)).astype(np.uint8)  # 4 px ramp
    assert abs(edge_width_px(ramp, 32, 32, 10) - 4.0) < 0.5


def test_epipolar_check_passes_the_true_calibration_and_flags_a_moved_camera() -> None:
    world = World(seed=0)
    cams = [make_camera(spec, world) for spec in default_camera_specs()]
    true = {c.name: DLTCamera(projection(c), (c.width_px, c.height_px)) for c in cams}
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(250, 550, 12), rng.uniform(-100, 100, 12),
                              rng.uniform(250, 450, 12)])
    views = [CameraView(name, cam.project(points), np.full(12, 12.0), 0, 1.5)
             for name, cam in true.items()]
    hints = preview_hints(views, true)
    assert hints["epipolar_px"] < 1e-6 and _warnings(hints) == []
    # the right camera moved 20 mm (its own y) after the calibration: its markers no longer lie on the
    # calibration's epipolar lines
    shift = cams[1].camera_matrix @ [0.0, 20.0, 0.0]
    moved_P = projection(cams[1]) + np.column_stack([np.zeros((3, 3)), shift])
    moved_uv = DLTCamera(moved_P, (cams[1].width_px, cams[1].height_px)).project(points)
    views = [views[0], CameraView(cams[1].name, moved_uv, np.full(12, 12.0), 0, 1.5)]
    hints = preview_hints(views, true)
    assert hints["epipolar_px"] > 2.0
    assert any("epipolar check" in w and "moved" in w for w in _warnings(hints))


def test_preview_round_on_the_simulated_rig(tmp_path: Path) -> None:
    config = load_config(write_config(tmp_path))
    state = run_preview(config, max_updates=1, interval_s=0.0, stream=open("/dev/null", "w"))  # noqa: SIM115
    hints = state.fields["hints"]
    assert sorted(hints["cameras"]) == sorted(config.camera_names())
    counts = {h["markers"] for h in hints["cameras"].values()}
    assert len(counts) == 1 and counts.pop() > 0, hints
    assert state.fields["simulated"] is True and not FRAMES.enabled
    for name in config.camera_names():
        jpeg = FRAMES.jpeg(name)
        assert jpeg is not None and cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR) is not None


def test_rig_preview_command_prints_its_url_and_hints(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    calibration = tmp_path / "calibration.json"
    world = World(seed=0)
    cams = [make_camera(spec, world) for spec in default_camera_specs()]
    calibration.write_text(json.dumps({"cameras": {c.name: DLTCamera(projection(c), (c.width_px, c.height_px))
                                                   .to_dict() for c in cams}}))
    done = subprocess.run([sys.executable, "-m", "rig.cli", "preview", "--config", str(config),
                           "--updates", "1", "--calibration", str(calibration)],
                          cwd=tmp_path, capture_output=True, text=True,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    assert "rig preview: live view at http://127.0.0.1:" in done.stderr
    assert "epipolar check: median distance" in done.stdout, done.stdout


def test_a_blob_in_the_fiducials_region_is_the_led_not_a_marker() -> None:
    image = np.full((200, 300), 30, np.uint8)
    cv2.circle(image, (60, 100), 9, 230, -1)  # a marker
    cv2.circle(image, (220, 100), 9, 230, -1)  # the LED, lit in this frame
    assert len(view_of("left", image).uv_px) == 2
    kept = view_of("left", image, (200, 80, 240, 120)).uv_px
    assert len(kept) == 1 and abs(kept[0, 0] - 60) < 1

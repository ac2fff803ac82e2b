"""The dashboard's live stereo preview (rig.dashboard.live_stereo, rig.analysis.live_estimate) on synthetic
tracks: two unsynchronized 60 fps cameras projected with OpenCV (tests/stereo_scene.py, not our DLT), the
preview fed the frames as the frame tap would queue them, one tick at a time (no thread, no clock)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from stereo_scene import TARGET, TrueCamera, stereo_pair

from rig.dashboard.live_stereo import LiveStereo, SegmentPlan, segments_of
from rig.dashboard.state import DashboardState
from rig.run.frame_tap import FrameTap, MarkerFrame
from rig.stereo import DLTCamera, TimingResult

FPS = 60.0
DELAY_S = 0.0041  # the right camera exposes this much after the left (unsynchronized)
STAMP_ORIGIN_S = {"left": 100.0, "right": 7.0}  # each camera's own clock at world time 0
NOISE_PX = 0.05


def _projection(camera: TrueCamera) -> np.ndarray:
    return camera.K @ np.hstack([cv2.Rodrigues(camera.rvec)[0], camera.tvec.reshape(3, 1)])


@pytest.fixture
def scene(tmp_path: Path) -> tuple[dict[str, TrueCamera], Path]:
    """The true cameras and a run folder holding their calibration (P = K[R|t])."""
    true = dict(zip(("left", "right"), stereo_pair(), strict=True))
    calibration = {"cameras": {name: DLTCamera(_projection(c)).to_dict() for name, c in true.items()}}
    (tmp_path / "calibration.json").write_text(json.dumps(calibration))
    return true, tmp_path


def _write_timing(run_dir: Path, line_time_s: dict[str, float]) -> None:
    """timing.json relating both clocks exactly (what sync writes): τ + offset + v·line time on the left's
    clock."""
    offset = {"left": 0.0, "right": STAMP_ORIGIN_S["left"] - STAMP_ORIGIN_S["right"]}
    timing = TimingResult("left", offset, line_time_s, {"left": 0.0, "right": 0.0}, "test")
    (run_dir / "timing.json").write_text(json.dumps(timing.to_dict()))


def _frames(true: dict[str, TrueCamera], positions: Callable[[np.ndarray], np.ndarray], duration_s: float,
            segment: str, *, seed: int = 1, line_time_s: dict[str, float] | None = None) -> list[MarkerFrame]:
    """Both cameras' frames in the order two reader threads would queue them (rolling shutters: a marker
    on row v is exposed v·``line_time_s[camera]`` after the frame's stamp); the right camera numbers the
    markers in reverse (its own track ids)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(duration_s * FPS)):
        for name, delay in (("left", 0.0), ("right", DELAY_S)):
            t_world = k / FPS + delay
            uv = true[name].project(positions(np.array([t_world]))[:, :, 0])  # (markers, 2)
            for _ in range(2):  # each marker where it is when its row is exposed
                exposed = t_world + uv[:, 1] * (line_time_s or {}).get(name, 0.0)
                uv = np.array([true[name].project(positions(np.array([t]))[m:m + 1, :, 0])[0]
                               for m, t in enumerate(exposed)])
            uv = uv + rng.normal(0, NOISE_PX, uv.shape)
            ids = np.arange(len(uv)) if name == "left" else 10 + np.arange(len(uv))[::-1]
            order = np.argsort(ids)
            out.append(MarkerFrame(name, segment, k, STAMP_ORIGIN_S[name] + t_world, uv[order], ids[order]))
    return out


def _run(preview: LiveStereo, frames: list[MarkerFrame], chunk: int = 20) -> None:
    """Feed ``frames`` in chunks, one tick each, then tick until every complete window is done."""
    for i in range(0, len(frames), chunk):
        preview.step(frames[i:i + chunk])
    for _ in range(200):
        before = preview.state.version
        preview.step([])
        if preview.state.version == before:
            return
    raise AssertionError("the preview never settled")


def _rows(state: DashboardState, plot: str) -> list[list[float | None]]:
    return state.patch({})[0]["plots"][plot]["rows"]


# a sweep: two markers of a column move together along x at AMPLITUDE_MM, the frequency rising linearly;
# a third marker stands still beside them
AMPLITUDE_MM = 4.0
F0_HZ, RATE_HZ_S = 2.0, 1.0


def _sweep_positions(t: np.ndarray) -> np.ndarray:
    displacement = AMPLITUDE_MM * np.sin(2 * np.pi * (F0_HZ * t + 0.5 * RATE_HZ_S * t**2))
    base = TARGET + np.array([[0.0, -60.0, 0.0], [0.0, 60.0, 0.0], [150.0, 0.0, 40.0]])
    moving = np.array([1.0, 1.0, 0.0])[:, None]
    return base[:, :, None] + moving[:, :, None] * np.array([1.0, 0.0, 0.0])[None, :, None] * displacement


def test_the_sweep_window_amplitude_and_frequency_match_the_truth(scene: tuple) -> None:
    true, run_dir = scene
    # two camera models' rolling shutters: ≈ 10 ms apart at the markers' rows, which without each
    # marker's row time would show as an amplitude error of several % at 10 Hz
    line_time_s = {"left": 15e-6, "right": 30e-6}
    _write_timing(run_dir, line_time_s)
    state = DashboardState("sweep")
    preview = LiveStereo(state, run_dir, {"sweep": SegmentPlan("sweep", AMPLITUDE_MM)}, tap=FrameTap())
    _run(preview, _frames(true, _sweep_positions, 8.0, "sweep", line_time_s=line_time_s))
    rows = _rows(state, "sweep_amplitude")
    assert len(rows) >= 6
    for t_mid, f_hz, amplitude_mm, error_mm in rows:
        true_f = F0_HZ + RATE_HZ_S * (t_mid - STAMP_ORIGIN_S["left"])  # on the left camera's clock
        assert f_hz == pytest.approx(true_f, abs=0.05)
        # triangulation noise (0.05 px at 1.5 m, ≈ 0.03 mm a sample) averages to ≈ 0.005 mm over a window;
        # the spline's interpolation of the right camera at ≤ 10 Hz of 60 fps costs ≤ 1 % of the amplitude
        assert error_mm == pytest.approx(amplitude_mm - AMPLITUDE_MM)
        # ≈ 3σ of the noise of the median of two markers over ≥ 24 samples (the window's error spreads
        # ≈ 0.004 mm); without each marker's row time the errors reach 0.6 mm by 10 Hz
        assert abs(error_mm) < 0.02
    assert "moving markers" in state.fields["live_stereo"]["status"]  # two of the three


def test_the_rotor_phase_is_counted_in_turns_across_windows(scene: tuple) -> None:
    """Before sync there is no timing.json: the clocks are related by the first frames (4 ms off here)."""
    true, run_dir = scene
    rotor_hz, radius_mm = 10.0, 60.0

    def positions(t: np.ndarray) -> np.ndarray:
        angle = 2 * np.pi * rotor_hz * t
        marker = TARGET[:, None] + radius_mm * np.stack([np.cos(angle), np.sin(angle), 0 * angle])
        still = np.broadcast_to((TARGET + np.array([0.0, 150.0, 0.0]))[:, None], marker.shape)
        return np.stack([marker, still])

    state = DashboardState("sync")
    preview = LiveStereo(state, run_dir, {"sync": SegmentPlan("rotor", radius_mm)}, tap=FrameTap())
    _run(preview, _frames(true, positions, 3.0, "sync"))
    rows = _rows(state, "rotor_phase_cameras")
    gaps = [r for r in rows if r[1] is None]
    assert len(gaps) == 1 and rows[0] is gaps[0]  # one line: each window goes on from the last one
    t = np.array([r[0] for r in rows[1:]])
    turns = np.array([r[1] for r in rows[1:]])
    assert np.all(np.diff(turns) > 0)
    # 10 turns a second, counted from the first sample; pairing by the first frames views the rotor
    # f·δ = 0.041 turn apart, which moves the triangulated angle by about half that, not the count
    np.testing.assert_allclose(turns, rotor_hz * (t - t[0]), atol=0.03)
    assert t[-1] - t[0] > 2.0
    assert "10.00 rev/s" in state.fields["live_stereo"]["status"]


def test_an_error_is_shown_not_raised_and_the_next_recording_is_followed(scene: tuple) -> None:
    true, run_dir = scene
    (run_dir / "calibration.json").write_text(json.dumps({"cameras": {"left": {"P": [[1, 2]]},
                                                                      "right": {"P": [[1, 2]]}}}))
    state = DashboardState("certify")
    preview = LiveStereo(state, run_dir, {"sweep": SegmentPlan("sweep", AMPLITUDE_MM)}, tap=FrameTap())
    preview.step(_frames(true, _sweep_positions, 0.5, "sweep"))
    shown = state.fields["live_stereo"]
    assert shown["status"] == "error" and "image_size" in shown["error"]
    assert _rows(state, "sweep_amplitude") == []


def test_without_a_calibration_it_says_so_and_recordings_not_planned_are_ignored(scene: tuple) -> None:
    true, run_dir = scene
    (run_dir / "calibration.json").unlink()
    state = DashboardState("certify")
    preview = LiveStereo(state, run_dir, {"sweep": SegmentPlan("sweep", AMPLITUDE_MM)}, tap=FrameTap())
    preview.step(_frames(true, _sweep_positions, 0.5, "accuracy_grid"))
    assert state.fields["live_stereo"] is None  # nothing planned for that recording
    _run(preview, _frames(true, _sweep_positions, 3.0, "sweep"))
    assert "no calibration.json" in state.fields["live_stereo"]["status"]
    assert _rows(state, "sweep_amplitude") == []


def test_the_tap_queues_markers_only_when_asked_and_bounded() -> None:
    tap = FrameTap(min_interval_s=1e9, max_marker_frames=3)
    image, uv, ids = np.zeros((4, 4), np.uint8), np.zeros((1, 2)), np.array([0])
    tap.offer("left", 0, image, uv, ids, timestamp_s=0.0, segment="sync")  # disabled: nothing
    tap.enabled = True
    tap.offer("left", 1, image, uv, ids, timestamp_s=0.1, segment="sync")  # no markers kept yet
    tap.keep_markers = True
    for k in range(2, 7):  # every frame, not only the one per min_interval_s the view keeps
        tap.offer("left", k, image, uv, ids, timestamp_s=k / 10, segment="sync")
    assert [f.frame_index for f in tap.drain_markers()] == [4, 5, 6]  # the oldest dropped
    assert tap.drain_markers() == []
    assert tap.latest("left").frame_index == 1


def test_the_certify_plan_names_the_rotor_and_sweep_recordings() -> None:
    from rig.cli import load_config, load_procedure
    from rig.run.plan import plan_of
    from rig.run.procedure import validate_parameters

    module, config = load_procedure("certify"), load_config(None)
    plan = plan_of(module, validate_parameters(module, {"preset": "fast"}), config)
    assert plan is not None
    segments = segments_of(plan)
    assert sorted(segments) == ["sweep", "sync"]
    assert segments["sync"] == SegmentPlan("rotor", plan.vibration("sync").amplitude_mm)
    assert segments["sweep"] == SegmentPlan("sweep", plan.vibration("sweep").amplitude_mm)


def test_a_preview_far_behind_keeps_a_bounded_number_of_frames(scene: tuple,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    from rig.dashboard import live_stereo

    monkeypatch.setattr(live_stereo, "MAX_KEPT_FRAMES", 100)
    true, run_dir = scene
    state = DashboardState("sync")
    preview = LiveStereo(state, run_dir, {"sync": SegmentPlan("rotor", 60.0)}, tap=FrameTap())
    preview.feed(_frames(true, _sweep_positions, 4.0, "sync"))  # 240 frames a camera, no window computed
    recording = preview._recording
    assert recording is not None and all(len(f) <= 100 for f in recording.frames.values())
    assert min(f[0][0] for f in recording.frames.values()) > 2.0  # the newest kept, the oldest dropped

"""`rig calibrate` and `rig measure` on bad inputs and bad output folders: each an exit 4 with a message
that names the file and what to do — never a traceback — and a run folder is never written to."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import measure_twin as mt
import numpy as np
import pytest

from rig.cli import main
from rig.deploy.onsite_calibration import OnsiteCalibrationError, load_target
from rig.deploy.video_markers import ExtractOptions, extract_video
from rig.record.writer import RunRecord


def _reencode(src: Path, dst: Path, *, fps: float, every: int = 1, scale: float = 1.0) -> Path:
    """Every ``every``-th frame of ``src`` at ``fps``, resized by ``scale`` (MJPG AVI)."""
    cap, writer, i = cv2.VideoCapture(str(src)), None, 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        if i % every == 0:
            img = cv2.resize(img, None, fx=scale, fy=scale) if scale != 1 else img
            if writer is None:
                writer = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"MJPG"), fps,
                                         (img.shape[1], img.shape[0]))
            writer.write(img)
        i += 1
    cap.release()
    writer.release()
    return dst


def _hide_one_marker(src: Path, dst: Path) -> Path:
    """``src`` with the plate marker nearest the image centre painted over in every frame."""
    obs = extract_video(src, "cam", ExtractOptions(mode="detect")).observations
    cap = cv2.VideoCapture(str(src))
    fps, size = cap.get(cv2.CAP_PROP_FPS), (int(cap.get(3)), int(cap.get(4)))
    writer = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    at = np.array(size, float) / 2
    for _index, group in obs.groupby("frame_index"):
        ok, img = cap.read()
        assert ok
        uv = group[["u_px", "v_px"]].to_numpy()
        k = int(np.argmin(np.linalg.norm(uv - at, axis=1)))
        at = uv[k]
        radius = int(3 * np.sqrt(group["area_px"].to_numpy()[k] / np.pi)) + 2
        cv2.circle(img, (int(at[0]), int(at[1])), radius, tuple(int(v) for v in np.median(img, axis=(0, 1))),
                   -1)
        writer.write(img)
    cap.release()
    writer.release()
    return dst


@pytest.fixture(scope="module")
def site(mjpg_site: dict) -> dict:
    return mjpg_site  # built once per session (tests/conftest.py)


def _calibrate(site: dict, left: Path, right: Path, out: Path, *more: str) -> int:
    return main(["calibrate", str(left), str(right), "--target", str(site["target"]), "--out", str(out),
                 *more])


def _measure(site: dict, left: Path, right: Path, out: Path, *more: str) -> int:
    return main(["measure", str(left), str(right), "--calibration", str(site["calibration"]), "--out",
                 str(out), *more])


def _error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return err


# ------------------------------------------------------------------------------------ calibrate
def test_videos_without_markers_are_a_clear_error(site: dict, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    blank = tmp_path / "blank.avi"
    writer = cv2.VideoWriter(str(blank), cv2.VideoWriter_fourcc(*"MJPG"), 60, (960, 540), False)
    for _ in range(90):
        writer.write(np.full((540, 960), 40, np.uint8))
    writer.release()
    assert _calibrate(site, blank, blank, tmp_path / "c.json") == 4
    assert f"camera 'left' ({blank}): no marker found in any of its 90 frames" in _error(capsys)
    assert not (tmp_path / "c.json").exists()


def test_a_truncated_calibration_video_says_where_it_ends(site: dict, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.avi"
    data = (site["folder"] / "cal_right.avi").read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    assert _calibrate(site, site["folder"] / "cal_left.avi", cut, tmp_path / "c.json") == 4
    err = _error(capsys)
    assert f"camera 'right' ({cut}): the video is truncated or corrupt: decoding stopped after" in err
    assert "the last frame read is frame" in err and "copy or export it again" in err


def test_a_corrupt_calibration_video_names_the_file(site: dict, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    corrupt = tmp_path / "corrupt.avi"
    corrupt.write_bytes(np.random.default_rng(0).integers(0, 256, 200_000, dtype=np.uint8).tobytes())
    assert _calibrate(site, site["folder"] / "cal_left.avi", corrupt, tmp_path / "c.json") == 4
    err = _error(capsys)
    assert err.startswith(f"rig calibrate: {corrupt}: ") and not (tmp_path / "c.json").exists()


def test_a_hidden_marker_names_the_count_and_the_position(site: dict, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    hidden = _hide_one_marker(site["folder"] / "cal_right.avi", tmp_path / "hidden.avi")
    assert _calibrate(site, site["folder"] / "cal_left.avi", hidden, tmp_path / "c.json") == 4
    err = _error(capsys)
    assert "camera 'right', position 0" in err
    assert "found 34 plate markers; the plate has rows × cols = 5 × 7 = 35" in err


def test_coplanar_control_points_are_refused_naming_the_target(site: dict, tmp_path: Path) -> None:
    flat = mt.write_target(tmp_path / "flat.toml", [site["truth"][0]] * 3)  # the plate never slid
    with pytest.raises(OnsiteCalibrationError, match=r"flat\.toml: the control points of all positions lie "
                                                     r"in one plane .* slide the plate along its normal"):
        load_target(flat)
    assert len(load_target(site["target"]).positions_mm) == len(site["truth"])


# ------------------------------------------------------------------------------------ measure
def test_a_frame_rate_mismatch_names_both_videos(site: dict, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    slow = _reencode(site["right"], tmp_path / "right30.avi", fps=30, every=2)
    assert _measure(site, site["left"], slow, tmp_path / "o") == 4
    err = _error(capsys)
    assert (f"the videos' frame rates differ: left 60 fps 960×540 px ({site['left']}) vs right 30 fps "
            f"960×540 px ({slow})") in err


@pytest.mark.parametrize("case", [("--max-offset-s", "0", "> 0 s, finite"),
                                  ("--clock-agreement-s", "-1", "≥ 0 s, finite"),
                                  ("--prior-offset-s", "nan", "a finite number")])
def test_offset_window_options_are_checked_before_decoding(site: dict, tmp_path: Path, case: tuple[str, ...],
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    option, value, allowed = case
    assert _measure(site, site["left"], site["right"], tmp_path / "o", option, value) == 4
    err = _error(capsys)
    assert f"{option[2:].replace('-', '_')}=" in err and allowed in err
    assert not (tmp_path / "o").exists()


def test_a_resolution_mismatch_names_both_videos(site: dict, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    small = _reencode(site["right"], tmp_path / "small.avi", fps=60, scale=0.5)
    assert _measure(site, site["left"], small, tmp_path / "o") == 4
    err = _error(capsys)
    assert (f"camera 'right': the video is 480×270 px but {site['calibration']} calibrated it at 960×540 "
            "px") in err
    assert f"left 60 fps 960×540 px ({site['left']}) vs right 60 fps 480×270 px ({small})" in err


def test_a_truncated_video_is_blamed_before_the_timing_it_spoils(site: dict, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.avi"
    cut.write_bytes(site["right"].read_bytes()[:250_000])
    assert _measure(site, site["left"], cut, tmp_path / "o") == 4  # timing estimated from the videos
    err = _error(capsys)
    first = err.strip().splitlines()[0]
    assert first.startswith(f"rig measure: camera right: {cut}: the video is truncated or corrupt"), first
    assert first.index("truncated") < first.index("with the frames that could be read: estimating the timing")


# ------------------------------------------------------------------------------------ --out and --force
@pytest.fixture
def run_folder(tmp_path: Path) -> Path:
    from drivers.sim.clock import VirtualClock

    rec = RunRecord.create(tmp_path / "runs", "plate", {}, {}, VirtualClock())
    rec.stop("success", "done")
    rec.close()
    (rec.run_dir / "timing.json").write_text('{"issued": true}\n')
    (rec.run_dir / "calibration.json").write_text('{"issued": true}\n')
    return rec.run_dir


def _tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_measure_never_writes_into_a_run_folder(site: dict, run_folder: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    before = _tree(run_folder)
    for out, force in ((run_folder, ()), (run_folder, ("--force",)), (run_folder / "measure", ("--force",))):
        assert _measure(site, site["left"], site["right"], out, "--timing", str(site["timing"]), *force) == 4
        err = _error(capsys)
        assert err.startswith(f"rig measure: --out {out}: ") and "--force included" in err
        assert ("is a run folder" if out == run_folder else f"lies in the run folder {run_folder}") in err
    assert _tree(run_folder) == before


def test_calibrate_never_writes_into_a_run_folder(site: dict, run_folder: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    before = _tree(run_folder)
    out = run_folder / "calibration.json"
    assert _calibrate(site, site["folder"] / "cal_left.avi", site["folder"] / "cal_right.avi", out,
                      "--force") == 4
    assert _error(capsys).startswith(f"rig calibrate: --out {out}: lies in the run folder {run_folder}")
    assert _tree(run_folder) == before


def test_earlier_results_are_replaced_only_with_force(site: dict, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    args = (site["left"], site["right"], out, "--timing", str(site["timing"]))
    assert _measure(site, *args) == 0
    first = _tree(out)
    (out / "clock.json").write_text("{}")  # an earlier measurement's clock must not survive a --force
    assert _measure(site, *args) == 4
    err = _error(capsys)
    assert f"--out {out}: already holds results (clock.json, figures, frames.json, measure.json" in err
    assert "--force to replace them" in err
    assert _measure(site, *args, "--force") == 0
    assert _tree(out) == first  # the same measurement again, the stale clock.json gone
    cal = tmp_path / "calibration.json"
    cal.write_text("{}")
    cal_args = (site["folder"] / "cal_left.avi", site["folder"] / "cal_right.avi", cal)
    assert _calibrate(site, *cal_args) == 4
    assert f"--out {cal}: already exists; give another file name, or --force" in _error(capsys)
    assert cal.read_text() == "{}"
    assert _calibrate(site, *cal_args, "--force") == 0
    assert json.loads(cal.read_text())["cameras"].keys() == {"left", "right"}

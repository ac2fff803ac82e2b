"""One frame's marker work split over threads (rig.stereo.markers_threads): the results of one thread, bit
for bit — markers on the binarization's band edges included — and a clear error for a bad ``threads``."""

from __future__ import annotations

import itertools
import multiprocessing
import threading
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from marker_images import Disc, render

from rig.stereo import InputArrayError, detect_markers, track_markers
from rig.stereo.markers_binarize import BAND_ROWS
from rig.stereo.markers_label import reduced_shape
from rig.stereo.markers_threads import run_parts, split

SHAPE = (512, 640)


def _edge_rows(factor: int, threads: int) -> list[int]:
    """Full-resolution rows where the binarization's bands of ``threads`` threads meet."""
    bands = split(reduced_shape(SHAPE, factor)[0], threads, BAND_ROWS)
    return [factor // 2 + y0 * factor for y0, _ in bands[1:]]


def _edge_scene(seed: int) -> tuple[np.ndarray, list[Disc]]:
    """Markers centred on (and a few pixels off) the band edges of 2 and 3 threads at reductions 2 and 4,
    and scattered elsewhere."""
    rng = np.random.default_rng(seed)
    rows = sorted({r for f in (2, 4) for t in (2, 3) for r in _edge_rows(f, t)})
    assert rows == [170, 171, 257, 258, 341, 342]  # three groups of two
    discs = []
    for row in rows[::2]:
        for j, shift in enumerate((-3.5, -0.5, 0.0, 0.5, 1.0, 1.5, 3.0)):
            u = 40.0 + 90.0 * j + rng.uniform(-0.5, 0.5)
            discs.append(Disc(u, row + shift + rng.uniform(-0.3, 0.3), rng.uniform(6.0, 9.0)))
    discs += [Disc(rng.uniform(20, 620), rng.uniform(20, 60), rng.uniform(6.0, 9.0)) for _ in range(4)]
    return render(SHAPE, discs, seed=seed), discs


@pytest.mark.parametrize("min_area_px", [20.0, 80.0])  # the frame reduced ×2 and ×4
@pytest.mark.parametrize("centre", ["centroid", "ellipse"])
def test_detection_on_threads_is_that_of_one_thread(min_area_px: float, centre: str) -> None:
    img, discs = _edge_scene(7)
    one = detect_markers(img, min_area_px=min_area_px, centre=centre)
    assert len(one) == len(discs)  # every marker on a band edge found once
    for threads in (2, 3, 8):
        assert detect_markers(img, min_area_px=min_area_px, centre=centre, threads=threads).tobytes() \
            == one.tobytes()


def test_tracking_on_threads_is_that_of_one_thread() -> None:
    img, discs = _edge_scene(8)
    rng = np.random.default_rng(8)
    truth = np.array([[d.u_px, d.v_px] for d in discs])
    pred = truth + rng.uniform(-3, 3, truth.shape)
    pred[3] = np.nan  # lost: NaN, outside the frame, nothing in the window
    pred[7] = (-5.0, 100.0)
    pred[11] = (300.0, 120.0)
    for centre in ("centroid", "ellipse"):
        one = track_markers(img, pred, window_px=31, centre=centre)
        assert np.isnan(one["u_px"][[3, 7, 11]]).all()
        assert np.isfinite(np.delete(one["u_px"], [3, 7, 11])).all()
        for threads in (2, 3, 64):
            many = track_markers(img, pred, window_px=31, centre=centre, threads=threads)
            assert many.tobytes() == one.tobytes()


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**16), n_markers=st.integers(0, 25), threads=st.integers(2, 4))
def test_random_layouts_on_threads_are_those_of_one_thread(seed: int, n_markers: int, threads: int) -> None:
    """Markers anywhere (touching, overlapping, cut by the frame's edge, of 2–12 px radius, either
    polarity): detection and tracking on ``threads`` threads give one thread's rows."""
    rng = np.random.default_rng(seed)
    discs = [Disc(rng.uniform(-5, SHAPE[1] + 5), rng.uniform(-5, SHAPE[0] + 5), rng.uniform(2.0, 12.0),
                  contrast_dn=rng.uniform(40, 200)) for _ in range(n_markers)]
    dark = bool(seed % 2)
    img = render(SHAPE, discs, seed=seed, dark=dark, background_dn=235.0 if dark else 20.0)
    polarity = "dark" if dark else "bright"
    one = detect_markers(img, polarity=polarity, min_area_px=20.0 * (1 + seed % 4))
    many = detect_markers(img, polarity=polarity, min_area_px=20.0 * (1 + seed % 4), threads=threads)
    assert many.tobytes() == one.tobytes()
    pred = np.array([[d.u_px, d.v_px] for d in discs]).reshape(-1, 2) + rng.normal(0, 2, (n_markers, 2))
    assert track_markers(img, pred, polarity=polarity, threads=threads).tobytes() \
        == track_markers(img, pred, polarity=polarity).tobytes()


@pytest.mark.parametrize("threads", [0, -1, 65, 1.5, "2", True, None])
def test_a_bad_threads_option_is_refused_naming_it(threads: object) -> None:
    img = np.zeros((64, 64), np.uint8)
    with pytest.raises(InputArrayError, match=r"threads=.*integer from 1 to 64"):
        detect_markers(img, threads=threads)  # type: ignore[arg-type]
    with pytest.raises(InputArrayError, match=r"threads=.*integer from 1 to 64"):
        track_markers(img, np.zeros((1, 2)), threads=threads)  # type: ignore[arg-type]


def test_parts_run_on_other_threads_and_all_finish_before_an_error_is_raised() -> None:
    started, release = threading.Event(), threading.Event()
    done: list[int] = []

    def part(k: int) -> int:
        if k == 0:  # this thread: waits until another part is running, then fails
            assert started.wait(60)
            release.set()
            raise ValueError("part 0")
        started.set()
        assert release.wait(60)
        done.append(threading.get_ident())
        return k

    assert run_parts(lambda k: (k, threading.get_ident()), [(0,)])[0][1] == threading.get_ident()
    with pytest.raises(ValueError, match="part 0"):
        run_parts(part, [(0,), (1,)])
    assert len(done) == 1 and done[0] != threading.get_ident()  # part 1 ran elsewhere, and finished
    assert run_parts(lambda k: k * k, [(k,) for k in range(5)]) == [0, 1, 4, 9, 16]


@given(n=st.integers(0, 500), threads=st.integers(1, 8), least=st.integers(1, 40))
def test_split_covers_the_range_in_parts_of_at_least_least(n: int, threads: int, least: int) -> None:
    parts = split(n, threads, least)
    assert parts[0][0] == 0 and parts[-1][1] == n
    assert all(a[1] == b[0] for a, b in itertools.pairwise(parts))
    assert 1 <= len(parts) <= threads
    assert len(parts) == 1 or all(hi - lo >= least for lo, hi in parts)


def test_remembered_track_options_tell_equal_values_of_other_types_apart() -> None:
    img = np.zeros((64, 64), np.uint8)
    track_markers(img, np.zeros((1, 2)), threads=1, window_px=21)
    for threads in (True, 1.0):  # equal to 1 (and hashed alike), refused all the same
        with pytest.raises(InputArrayError, match="threads="):
            track_markers(img, np.zeros((1, 2)), threads=threads, window_px=21)  # type: ignore[arg-type]
    with pytest.raises(InputArrayError, match="window_px="):
        track_markers(img, np.zeros((1, 2)), window_px=[21])  # type: ignore[arg-type]


def _split_in_child(queue: Any) -> None:
    queue.put(run_parts(lambda k: (k, threading.get_ident()), [(0,), (1,)]))


def test_a_forked_child_gets_threads_of_its_own() -> None:
    """The parent's idle threads do not exist in a forked child: the child starts its own, not waits."""
    run_parts(lambda k: k, [(0,), (1,)])  # the parent's pool has an idle thread now
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_split_in_child, args=(queue,))
    child.start()
    try:
        (first, first_ident), (second, second_ident) = queue.get(timeout=120)
    finally:
        child.join(timeout=120)
        if child.is_alive():
            child.kill()
    assert (first, second) == (0, 1) and first_ident != second_ident
    assert child.exitcode == 0


def _meeting_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A frame, 24 predictions (some lost) and one thread's rows of them."""
    img, discs = _edge_scene(9)
    pred = np.array([[d.u_px, d.v_px] for d in discs])[:24] + 0.7
    pred[5] = np.nan
    one = track_markers(img, pred, window_px=31)
    return img, pred, one


def test_tracking_takes_any_frame_and_prediction_layout_alike() -> None:
    """The fast path of a C-contiguous uint8 frame and float64 (K, 2) predictions gives the rows of any
    other layout: a frame that is a view with strides, predictions as float32, a list, a Fortran array."""
    img, pred, one = _meeting_scene()
    wide = np.zeros((img.shape[0], 2 * img.shape[1]), np.uint8)
    wide[:, ::2] = img
    assert track_markers(wide[:, ::2], pred, window_px=31).tobytes() == one.tobytes()
    assert track_markers(img, np.asfortranarray(pred), window_px=31).tobytes() == one.tobytes()
    assert track_markers(img, pred.tolist(), window_px=31).tobytes() == one.tobytes()
    single = pred.astype(np.float32)
    assert track_markers(img, single, window_px=31).tobytes() \
        == track_markers(img, single.astype(np.float64), window_px=31).tobytes()
    with pytest.raises(InputArrayError, match=r"predicted_uv_px has shape \(4,\)"):
        track_markers(img, [1.0, 2.0, 3.0, 4.0])  # type: ignore[arg-type]

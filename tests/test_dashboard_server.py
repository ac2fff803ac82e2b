"""The dashboard's server and model without a run: SSE format and patches, token, loopback binding,
Abort, bounded plots, the plan's time remaining, the record observer and the frame tap."""

from __future__ import annotations

import json
import logging
import socket
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

from rig.dashboard.server import ABORT_HEADER, DashboardError, DashboardServer, is_loopback, sse_message
from rig.dashboard.state import DashboardState, Series
from rig.record.writer import RunRecord
from rig.run.clock import make_clock
from rig.run.frame_tap import FrameTap


def _doc(kind: str, t_s: float, **fields: object) -> dict:
    return {"type": kind, "time_s": t_s, **fields}


def _read_event(stream) -> tuple[list[str], dict]:
    """Lines of the next server-sent event (comments skipped) and its data."""
    lines: list[str] = []
    while True:
        line = stream.readline().decode()
        assert line, "the stream ended"
        if line == "\n":
            if lines:
                data = [ln for ln in lines if ln.startswith("data: ")]
                return lines, json.loads(data[0][len("data: "):])
            continue
        if not line.startswith(":"):
            lines.append(line)


def test_sse_message_is_event_id_and_one_data_line() -> None:
    raw = sse_message("state", {"a": [1, 2], "b": "x\ny"}, 7)
    assert raw == b'event: state\nid: 7\ndata: {"a":[1,2],"b":"x\\ny"}\n\n'
    with pytest.raises(ValueError):
        sse_message("state", {"a": float("nan")})


def test_stream_sends_state_then_only_the_new_plot_rows() -> None:
    state = DashboardState("sweep", plan_steps=lambda start: [("sweep", 10.0)])
    state.on_document(_doc("start", 0.0, run_id="r1", procedure="sweep",
                           rig={"station": {"simulated": True}}, parameters={}))
    for i in range(3):
        state.on_document(_doc("event", 0.1 * i, stream="exciter",
                               data={"frequency_hz": 1.0 + i, "setpoint_hz": 1.5 + i, "status": "running"}))
    with DashboardServer(state, port=0, min_interval_s=0.0) as server, \
            urllib.request.urlopen(server.url + "events", timeout=30) as stream:
            assert stream.headers["Content-Type"] == "text/event-stream"
            lines, first = _read_event(stream)
            assert lines[0] == "event: state\n" and lines[1] == f"id: {first['version']}\n"
            assert first["simulated"] is True and first["run_id"] == "r1"
            assert first["plots"]["exciter"]["start"] == 0
            assert [r[1:3] for r in first["plots"]["exciter"]["rows"]] == [[1.5, 1.0], [2.5, 2.0], [3.5, 3.0]]
            state.on_document(_doc("event", 0.4, stream="exciter",
                                   data={"frequency_hz": 9.0, "setpoint_hz": 9.5, "status": "running"}))
            _, second = _read_event(stream)
            assert second["plots"]["exciter"]["start"] == 3
            assert second["plots"]["exciter"]["rows"] == [[0.4, 9.5, 9.0, -0.5]]
            assert second["devices"]["exciter"]["frequency_hz"] == 9.0


def test_state_and_page_and_abort_endpoints() -> None:
    reasons: list[str] = []
    state = DashboardState("certify")
    # a tap of its own: the process-wide FRAMES may hold a frame an earlier test's run left there
    with DashboardServer(state, on_abort=reasons.append, frames=FrameTap()) as server:
        page = urllib.request.urlopen(server.url, timeout=30).read().decode()
        assert "EventSource" in page and "http" not in page.replace("http://www.w3.org", "")  # nothing remote
        got = json.loads(urllib.request.urlopen(server.url + "state", timeout=30).read())
        assert got["title"] == "certify"
        # a plain cross-site form post (no custom header) is refused; the page's own request is not
        with pytest.raises(urllib.error.HTTPError) as forged:
            urllib.request.urlopen(urllib.request.Request(server.url + "abort", method="POST"), timeout=30)
        assert forged.value.code == 403 and reasons == []
        abort = urllib.request.Request(server.url + "abort", method="POST", headers={ABORT_HEADER: "abort"})
        reply = urllib.request.urlopen(abort, timeout=30)
        assert reply.status == 202 and reasons == ["aborted by the operator (dashboard)"]
        with pytest.raises(urllib.error.HTTPError) as missing:
            urllib.request.urlopen(server.url + "frame/left.jpg", timeout=30)
        assert missing.value.code == 404
    with DashboardServer(state) as server, pytest.raises(urllib.error.HTTPError) as no_abort:
        urllib.request.urlopen(urllib.request.Request(server.url + "abort", method="POST",
                                                      headers={ABORT_HEADER: "abort"}), timeout=30)
    assert no_abort.value.code == 404


def test_bound_to_loopback_by_default_and_other_hosts_need_the_flag_and_a_token() -> None:
    state = DashboardState("x")
    with DashboardServer(state) as server:
        assert server._httpd.server_address[0] == "127.0.0.1" and server.token is None
        assert server.url == f"http://127.0.0.1:{server.port}/"
    assert is_loopback("localhost") and is_loopback("::1") and not is_loopback("0.0.0.0")
    with pytest.raises(DashboardError, match="--dashboard-host"):
        DashboardServer(state, host="0.0.0.0")
    with DashboardServer(state, host="0.0.0.0", allow_remote=True) as server:
        assert server.token and len(server.token) >= 16 and server.url.endswith(f"/?token={server.token}")
        base = f"http://127.0.0.1:{server.port}/"
        for path in ("", "state", "events"):
            with pytest.raises(urllib.error.HTTPError) as refused:
                urllib.request.urlopen(base + path + "?token=wrong", timeout=30)
            assert refused.value.code == 403
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(urllib.request.Request(base + "abort", method="POST"), timeout=30)
        assert refused.value.code == 403
        assert urllib.request.urlopen(base + f"state?token={server.token}", timeout=30).status == 200


def test_port_taken_is_an_os_error_and_a_bad_port_is_refused() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        with pytest.raises(OSError):
            DashboardServer(DashboardState("x"), port=taken.getsockname()[1]).start()
    with pytest.raises(DashboardError, match="65535"):
        DashboardServer(DashboardState("x"), port=70000)


def test_plots_are_bounded_and_a_late_cursor_gets_what_is_still_held() -> None:
    series = Series(("t_s", "y"), max_points=5)
    for i in range(12):
        series.append([float(i), float(i)])
    assert len(series.rows) == 5 and series.total == 12
    assert series.since(0) == (7, [[float(i), float(i)] for i in range(7, 12)])
    assert series.since(10) == (10, [[10.0, 10.0], [11.0, 11.0]])
    assert series.since(12) == (12, [])
    state = DashboardState("x", max_points=4)
    for i in range(10):
        state.on_document(_doc("event", float(i), stream="rotor", data={"frequency_hz": i, "setpoint_hz": 5}))
    patch, cursors = state.patch({})
    assert patch["plots"]["rotor"]["start"] == 6 and len(patch["plots"]["rotor"]["rows"]) == 4
    assert cursors["rotor"] == 10 and state.patch(cursors)[0]["plots"]["rotor"]["rows"] == []


def test_time_remaining_follows_the_plan_and_the_progress() -> None:
    state = DashboardState("p", plan_steps=lambda start: [("a", 10.0), ("b", 20.0)])
    state.on_document(_doc("start", 0.0, run_id="r", procedure="p", rig={}, parameters={}))
    assert state.fields["remaining_s"] == 30.0 and state.fields["simulated"] is False
    state.on_document(_doc("step", 1.0, name="a", status="begin"))
    state.on_document(_doc("log", 5.0, level="info", message="m"))
    assert state.fields["remaining_s"] == pytest.approx(26.0)  # no fraction: the rig time spent
    state.on_progress(0.5, "half")
    assert state.fields["remaining_s"] == pytest.approx(25.0)
    state.on_document(_doc("step", 6.0, name="a", status="done"))
    state.on_document(_doc("step", 6.0, name="report", status="begin"))  # a step the plan does not time
    assert [s["name"] for s in state.fields["steps"]] == ["a", "report", "b"]  # in the order they run
    assert state.fields["remaining_s"] == pytest.approx(20.0)
    state.on_document(_doc("stop", 7.0, exit_status="abort", outcome="aborted", exit_code=2, reason="r"))
    assert state.fields["remaining_s"] == 0.0 and state.fields["steps"][1]["status"] == "stopped"


def test_a_failing_observer_never_affects_the_record(tmp_path: Path,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    seen: list[str] = []
    rec = RunRecord.create(tmp_path, "p", {}, {}, make_clock(True), versions={})
    rec.add_observer(lambda doc: seen.append(doc["type"]))  # the start document is replayed

    def broken(doc: dict) -> None:
        raise RuntimeError("view failed")

    rec.add_observer(broken)
    with caplog.at_level(logging.WARNING, logger="rig.record.writer"):
        rec.event("exciter", {"frequency_hz": 1.0})
        rec.stop("success")
    rec.close()
    assert seen == ["start", "event", "stop"]
    lines = (rec.path).read_text().splitlines()
    assert [json.loads(ln)["type"] for ln in lines] == ["start", "event", "stop"]
    assert "record observer failed" in caplog.text


def test_frame_tap_keeps_a_reference_and_encodes_lazily_downscaled() -> None:
    tap = FrameTap(min_interval_s=3600.0)
    image = np.zeros((400, 960), np.uint8)
    cv2.circle(image, (480, 200), 8, 255, -1)
    tap.offer("left", 0, image, np.array([[480.0, 200.0]]), np.array([3]))
    assert tap.latest("left") is None  # disabled: nothing kept
    tap.enabled = True
    tap.offer("left", 5, image, np.array([[480.0, 200.0]]), np.array([3]))
    tap.offer("left", 6, image, np.array([[480.0, 200.0]]), np.array([3]))  # within the interval: dropped
    frame = tap.latest("left")
    assert frame is not None and frame.image is image and frame.frame_index == 5 and tap.seqs() == {"left": 1}
    jpeg = tap.jpeg("left", max_width_px=480)
    assert tap.jpeg("left", max_width_px=480) is jpeg  # cached per frame
    small = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert small.shape == (200, 480, 3)
    # the marker is circled in colour around its downscaled centre (240, 100)
    ring = small[100, 246].astype(int)
    assert ring[2] > 150 and ring[2] - ring[0] > 80

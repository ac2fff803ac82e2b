"""Test support for the heartbeat tests: the simulated station (real drivers over loopback/ptys to the
protocol mocks) with a paced clock, and a handle on each mock server for fault injection."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from rig.config.rig_config import default_config, override
from rig.run.clock import make_clock
from rig.run.station import Station, open_station

HEARTBEAT_TIMEOUT_S = 1.0  # the configured limit in these tests


def heartbeat_config(rate: float = 2.0, **settings: Any) -> Any:
    """The built-in simulated rig, paced at ``rate`` virtual s per wall s, a 1 s heartbeat limit and
    short device timeouts (so a dead device's safe-state attempt fails quickly)."""
    cfg = default_config()
    base = {"sim.rate": rate, "station.heartbeat_timeout_s": HEARTBEAT_TIMEOUT_S,
            "devices.robot.timeout_s": 0.8, "devices.exciter.timeout_s": 0.3, "devices.rotor.timeout_s": 0.3,
            "devices.generator.timeout_s": 0.4}
    for key, value in {**base, **settings}.items():
        cfg = override(cfg, key, value)
    return cfg


def mock_servers(station: Station) -> dict[str, Any]:
    """device name → its mock server object (from the station's shutdown list)."""
    out = {}
    for label, closer in station._closers:
        if label.endswith("mock server"):
            out[label.split()[0]] = closer.__self__  # type: ignore[attr-defined]
    return out


@contextlib.contextmanager
def sim_station(rate: float = 2.0, **settings: Any) -> Iterator[tuple[Station, dict[str, Any]]]:
    cfg = heartbeat_config(rate, **settings)
    clock = make_clock(True, rate=cfg.sim.rate)
    with open_station(cfg, clock) as station:
        yield station, mock_servers(station)


@dataclass
class BeatWatcher:
    """Calls ``device.heartbeat()`` every ``period_s`` in a thread (as the runner's watchdog does) and
    keeps the first error and the time it was seen."""

    device: Any
    period_s: float = 0.05
    beats: int = 0
    error: BaseException | None = None
    error_after_s: float | None = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def __enter__(self) -> BeatWatcher:
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                assert self.device.heartbeat() is True
                self.beats += 1
            except BaseException as exc:
                self.error, self.error_after_s = exc, time.monotonic() - self._t0
                return

    def wait_for_error(self, timeout_s: float) -> BaseException | None:
        assert self._thread is not None
        self._thread.join(timeout_s)
        return self.error

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)


def wait_until(predicate: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def run_body_on_sim_station(tmp_path: Any, body: Callable[[Any, dict[str, Any]], None],
                            **settings: Any) -> tuple[Any, Any, dict[str, Any]]:
    """Run ``body(ctx, servers)`` as the one step of a procedure on the simulated station (paced clock,
    watchdog every 0.05 s); returns (outcome, loaded record, {"station", "servers"})."""
    import types

    from rig.record.writer import load_run
    from rig.run.runner import Runner

    seen: dict[str, Any] = {}

    @contextlib.contextmanager
    def factory(config: Any, clock: Any) -> Iterator[Station]:
        with open_station(config, clock) as station:
            seen["station"], seen["servers"] = station, mock_servers(station)
            yield station

    mod = types.ModuleType("sim_station_probe")
    mod.NAME = "sim_station_probe"

    @dataclass(frozen=True)
    class Parameters:
        pass

    def run(ctx: Any, params: Any) -> dict[str, Any]:
        with ctx.step("work"):
            body(ctx, seen["servers"])
        return {"passed": True, "summary": "done"}

    mod.Parameters, mod.run = Parameters, run
    runner = Runner(mod, config=heartbeat_config(**settings), station_factory=factory,
                    runs_dir=tmp_path / "runs", watchdog_period_s=0.05)
    out = runner.run({})
    return out, load_run(out.run_dir), seen

"""The mock generator's two channels (33522B) and the one-channel model (33521B), in raw SCPI lines over a
real socket: per-channel state, the one Sync connector and its source, ``PHASe:SYNChronize`` giving both
channels (and with them the shaker and the fiducial LED) one phase origin, and the errors of a channel
the model does not have. Then the driver's channel helpers and the configuration's refusal (exit 4)."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.mock.generator_instrument import GeneratorInstrument, identity_for
from drivers.mock.generator_server import GeneratorServer
from drivers.sim.clock import VirtualClock
from drivers.sim.fiducial import SyncLed
from drivers.sim.world import World
from tests.certify_support import write_config
from tests.test_generator_mock import Line

ROOT = Path(__file__).resolve().parents[1]


def _instrument(channels: int) -> tuple[GeneratorInstrument, World, SyncLed]:
    world = World(VirtualClock(), seed=3)
    led = world.add_led(SyncLed("fiducial", (400.0, -200.0, 300.0), (0.0, 5.0, 0.0), (0.0, 0.0, 75.0)))
    instrument = GeneratorInstrument(world.shaker, world.clock, identity=identity_for(channels), sync_led=led)
    return instrument, world, led


@pytest.fixture
def two() -> Iterator[tuple[Line, GeneratorInstrument, World, SyncLed]]:
    instrument, world, led = _instrument(2)
    with GeneratorServer(instrument, mode="tcp") as server:
        line = Line(server)
        yield line, instrument, world, led
        line.close()


def test_the_two_channel_model_keeps_each_channels_state_apart(two) -> None:
    line, instrument, _, _ = two
    assert line.ask("*IDN?").split(",")[1] == "33522B"
    line.send("SOUR1:FREQ 35;:SOUR2:FREQ 10.27;:SOUR2:FUNC SQU;:OUTP1 ON")
    assert line.ask("SOUR1:FREQ?;:SOUR2:FREQ?") == "+3.50000000000000E+01;+1.02700000000000E+01"
    assert line.ask("FREQ?") == "+3.50000000000000E+01"  # no suffix: channel 1
    assert line.ask("SOUR2:FUNC?;:FUNC?") == "SQU;SIN"
    assert line.ask("OUTP1?;:OUTP2?") == "1;0"
    assert line.ask("SOUR2:VOLT 1.5;VOLT?") == "+1.50000000000000E+00"  # the path continues in SOUR2
    assert line.ask("SOUR1:VOLT?") == "+1.00000000000000E-01"
    assert instrument.channel(2).emf_vpp == pytest.approx(3.0) and instrument.emf_vpp == pytest.approx(0.2)
    assert line.ask("SYST:ERR?") == '+0,"No error"'


def test_the_sync_connector_follows_the_chosen_channel_while_channel_1_drives_the_shaker(two) -> None:
    line, _, world, led = two
    assert line.ask("OUTP:SYNC:SOUR?") == "CH1"  # *RST: channel 1
    line.send("SOUR1:FREQ 40;:OUTP1:LOAD INF;:SOUR1:VOLT 4;:OUTP1 ON")
    line.send("SOUR2:FREQ 10.27;:OUTP:SYNC:SOUR CH2;:OUTP:SYNC ON")
    line.sync()
    assert line.ask("OUTP:SYNC:SOUR?") == "CH2"
    t = world.clock.now_s()
    assert world.shaker.frequency_hz(t) == pytest.approx(40.0)
    assert world.shaker.amplitude_at_mm(t) == pytest.approx(0.5 * 2.0)  # 0.5 mm/V · 2 V peak
    assert led.waveform.frequency_hz(t) == pytest.approx(10.27)
    edges, _, _ = led.drive_edges(t, t + 1.0)
    assert edges.size in (20, 21)  # 2 per cycle of 10.27 Hz, not of the shaker's 40 Hz


def test_phase_synchronize_restarts_both_channels_on_one_timebase(two) -> None:
    line, _, world, led = two
    line.send("SOUR1:FREQ 37.5;:OUTP1 ON;:SOUR2:FREQ 10.27;:OUTP:SYNC:SOUR CH2")
    line.sync()
    world.clock.sleep_s(0.123)
    line.send("SOUR2:PHAS:SYNC")
    line.sync()
    t_sync = world.clock.now_s()
    world.clock.sleep_s(2.0)
    # the shaker's phase is channel 1's, 0 at the restart; the LED's edges are channel 2's from there
    for dt in (0.0, 0.25, 1.7):
        assert world.shaker.phase_rad(t_sync + dt) == pytest.approx(2 * math.pi * 37.5 * dt, abs=1e-9)
    edges, rising, _ = led.drive_edges(t_sync + 1e-6, t_sync + 1.0)
    np.testing.assert_allclose(edges, t_sync + np.arange(1, edges.size + 1) / (2 * 10.27), atol=1e-9)
    assert not rising[0]  # high over phase 0…π: the first edge falls


def test_the_one_channel_model_refuses_channel_2_and_the_sync_source() -> None:
    instrument, world, _ = _instrument(1)
    with GeneratorServer(instrument, mode="tcp") as server:
        line = Line(server)
        assert line.ask("*IDN?").split(",")[1] == "33521B"
        for command in ("SOUR2:FREQ 10", "OUTP2 ON", "OUTP2:LOAD INF", "TRIG2:SOUR IMM"):
            line.send(command)
            assert line.ask("SYST:ERR?") == '-114,"Header suffix out of range"', command
        line.send("OUTP:SYNC:SOUR CH2")
        assert line.ask("SYST:ERR?") == '-113,"Undefined header"'
        assert line.ask("OUTP1?;:SOUR1:FREQ?") == "0;+1.00000000000000E+03"  # channel 1 untouched
        line.close()
    assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0


def test_the_driver_sets_and_reads_the_other_channel_and_the_sync_source(two) -> None:
    from drivers.exciter.generator import ScpiGenerator
    from drivers.transport import open_transport

    _, instrument, _, _ = two
    with GeneratorServer(instrument, mode="tcp") as server:
        gen = ScpiGenerator(open_transport(server.url, timeout_s=5.0), channel=1, timeout_s=5.0)
        gen.set_frequency_hz(10.27, channel=2)
        gen.set_sync_source(2)
        assert gen.frequency_hz(channel=2) == pytest.approx(10.27)
        assert gen.frequency_hz() == pytest.approx(1000.0)
        assert gen.sync_source() == 2 and gen.output(channel=2) is False
        assert any("SOUR2:FREQ" in c for c in instrument.commands_seen)
        with pytest.raises(ValueError, match="channel=3"):
            gen.set_frequency_hz(1.0, channel=3)
        gen.close()


def test_a_fiducial_on_channel_2_of_a_one_channel_generator_is_refused_before_any_device(tmp_path: Path,
                                                                                          ) -> None:
    path = write_config(tmp_path)
    text, n = re.subn(r"^channels = 2 .*$", "channels = 1", path.read_text(), flags=re.M)
    assert n == 1
    path.write_text(text)
    proc = subprocess.run([sys.executable, "-m", "rig.cli", "certify", "--config", str(path),
                           "--no-dashboard"], cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 4, proc.stdout + proc.stderr
    assert "fiducial.channel" in proc.stderr and "devices.generator.channels = 1" in proc.stderr
    assert not (tmp_path / "runs").exists()


def test_a_station_configured_for_two_channels_refuses_a_one_channel_instrument() -> None:
    import copy
    import tomllib
    from importlib import resources

    from rig.config.rig_config import config_from_dict
    from rig.run.station import StationError, open_station

    instrument, _, _ = _instrument(1)
    with GeneratorServer(instrument, mode="tcp") as server:
        table = copy.deepcopy(tomllib.loads(resources.files("rig").joinpath("data/sim.toml").read_text()))
        table["devices"]["generator"]["address"] = f"tcp://127.0.0.1:{server.port}"
        with pytest.raises(StationError, match=r"devices.generator.channels = 2 .* 33521B with 1 channel"), \
                open_station(config_from_dict(table), VirtualClock()):
            pass

"""The mock generator's IEEE 488.2 status model and amplitude units, over a real socket with raw lines.

Truth: IEEE 488.2 (ESR bits, *CLS/*RST scope, STB summary bits), SCPI-99 (error classes, SYST:VERS?),
and the Keysight 33500 user's guide (open-circuit limits 20 Vpp / ±10 V, displayed amplitude follows the
load setting, no dBm into high impedance)."""

from __future__ import annotations

import math

import pytest
from test_generator_mock import generator

NO_ERROR = '+0,"No error"'


def test_mandatory_common_commands_answer() -> None:
    with generator() as (line, _, _):
        assert line.ask("*IDN?").startswith("Keysight Technologies,33521B,")
        assert line.ask("*ESR?") == "128"  # PON: the first read after power-on
        assert line.ask("*ESR?") == "0"  # reading cleared it
        assert line.ask("*TST?") == "0"
        assert line.ask("*OPC?") == "1"
        assert line.ask("SYST:VERS?") == "1999.0"
        line.send("*WAI")
        line.send("*ESE 36;*SRE 48")
        assert line.ask("*ESE?;*SRE?") == "36;48"
        line.send("*SRE 255")  # bit 6 of SRE is ignored
        assert line.ask("*SRE?") == "191"
        assert line.ask("SYST:ERR?") == NO_ERROR


@pytest.mark.parametrize(("bad", "bit"), [("BOGUS", 5), ("FREQ 1E9", 4), ("*ESE 300", 4)])
def test_each_error_class_sets_its_esr_bit(bad: str, bit: int) -> None:
    with generator() as (line, _, _):
        line.send("*CLS")
        line.send(bad)
        assert int(line.ask("*ESR?")) == 1 << bit
        assert line.ask("SYST:ERR?") != NO_ERROR


def test_device_error_pushed_sets_dde() -> None:
    with generator() as (line, _, instrument):
        line.send("*CLS")
        line.sync()
        instrument.push_error(-310)
        assert line.ask("*ESR?") == str(1 << 3)
        assert line.ask("SYST:ERR?") == '-310,"System error"'


def test_status_byte_summarises_queue_esr_and_output() -> None:
    with generator() as (line, _, _):
        line.send("*CLS")
        assert line.ask("*STB?") == "0"
        line.send("BOGUS")  # a command error: queue not empty (EAV, bit 2), ESR CME
        assert line.ask("*STB?") == str(1 << 2)  # ESE is 0: no ESB yet
        line.send("*ESE 32")
        assert line.ask("*STB?") == str((1 << 2) | (1 << 5))  # ESB
        line.send("*SRE 32")
        assert line.ask("*STB?") == str((1 << 2) | (1 << 5) | (1 << 6))  # MSS
        assert line.ask("*IDN?;*STB?").endswith(";" + str((1 << 2) | (1 << 4) | (1 << 5) | (1 << 6)))  # MAV
        line.send("*CLS")  # clears ESR and the queue, keeps ESE/SRE
        assert line.ask("*STB?;*ESE?;*SRE?") == "0;32;32"


def test_opc_sets_the_operation_complete_bit_and_rst_keeps_status() -> None:
    with generator() as (line, _, _):
        line.send("*CLS;*OPC")
        assert line.ask("*ESR?") == "1"
        line.send("*ESE 16;BOGUS")
        line.send("*RST")  # device settings only: the queue and ESE stay
        assert line.ask("*ESE?") == "16"
        assert line.ask("SYST:ERR:COUN?") == "1"
        assert line.ask("SYST:ERR?") == '-113,"Undefined header"'


def test_amplitude_limit_applies_in_every_unit() -> None:
    with generator() as (line, _, instrument):
        line.send("OUTP1:LOAD INF;:VOLT:UNIT VRMS")
        line.send("VOLT 20")  # 56.6 Vpp: above the 20 Vpp open-circuit limit
        assert line.ask("SYST:ERR?") == '-222,"Data out of range"'
        line.send("VOLT 7")  # 19.8 Vpp
        assert line.ask("SYST:ERR?") == NO_ERROR
        assert instrument.emf_vpp == pytest.approx(7 * 2 * math.sqrt(2))
        assert float(line.ask("VOLT?")) == pytest.approx(7.0)
        line.send("VOLT:UNIT DBM")  # no dBm into high impedance
        assert line.ask("SYST:ERR?") == '-221,"Settings conflict"'
        line.send("OUTP1:LOAD 50;:VOLT:UNIT DBM")
        # 50 Ω setting: 10 Vpp displayed max = 3.54 Vrms = 23.98 dBm
        line.send("VOLT 24")
        assert line.ask("SYST:ERR?") == '-222,"Data out of range"'
        line.send("VOLT 23.9")
        assert line.ask("SYST:ERR?") == NO_ERROR
        vrms_displayed = math.sqrt(50 * 1e-3 * 10 ** 2.39)
        assert instrument.emf_vpp == pytest.approx(vrms_displayed * 2 * math.sqrt(2) * 2)
        line.send("OUTP1:LOAD INF")  # the unit falls back to Vpp into high impedance
        assert line.ask("VOLT:UNIT?") == "VPP"
        line.send("VOLT MAX")
        assert float(line.ask("VOLT?")) == pytest.approx(20.0)


def test_offset_and_amplitude_share_the_10_v_peak() -> None:
    with generator() as (line, _, _):
        line.send("OUTP1:LOAD INF;:VOLT 10")
        line.send("VOLT:OFFS 6")  # 5 V peak + 6 V > 10 V
        assert line.ask("SYST:ERR?") == '-222,"Data out of range"'
        line.send("VOLT:OFFS 5")
        assert line.ask("SYST:ERR?") == NO_ERROR
        line.send("VOLT 12")
        assert line.ask("SYST:ERR?") == '-222,"Data out of range"'


def test_load_change_keeps_the_real_output() -> None:
    with generator(sensitivity=[(1.0, 0.5), (100.0, 0.5)]) as (line, world, _):
        line.send("FREQ 10;VOLT 2;:OUTP1 ON")  # 2 Vpp displayed for 50 Ω: 4 Vpp open circuit
        line.sync()
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == pytest.approx(0.5 * 2.0)
        line.send("OUTP1:LOAD INF")
        assert float(line.ask("VOLT?")) == pytest.approx(4.0)
        world.clock.sleep_s(0.1)
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == pytest.approx(0.5 * 2.0)

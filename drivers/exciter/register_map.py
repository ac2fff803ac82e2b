"""The Modbus register map of a variable-frequency drive, as data.

A new drive model is a new table, not new code: the VFD driver (:mod:`drivers.exciter.vfd`), the mock
drive (:mod:`drivers.mock.vfd_server`) and the documentation (``docs/exciter.md``) all read the same
:class:`RegisterMap`. Addresses are **wire addresses** (0-based, what goes into the Modbus PDU): a manual
number like "40001" is wire address 0, a hex address like Delta's ``0x2000`` already is one.

The default, :data:`DELTA_MAP`, follows the Delta VFD-E/EL/MS300 communication map (unit id 1,
frequencies in 0.01 Hz). The ramp-time parameters (Delta parameters 01-09 / 01-10, "acceleration /
deceleration time 1", wire addresses 0x0109 / 0x010A, 0.1 s) are taken from the VFD-E parameter list;
check them against your drive's manual (MS300 uses 01-12 / 01-13 and 0.01 s by default). The
communication-loss parameters are Delta 09-02 "transmission fault treatment" (1 = warn and ramp to
stop) and 09-03 "time-out detection" (0.1 s, 0 = off), wire addresses 0x0902 / 0x0903 by the same
group-parameter rule (VFD-E and MS300 manuals; **UNVERIFIED** against our drive).

A rig configuration can override any field from a TOML table (see :func:`register_map_from_dict`)::

    [exciter.registers]
    model = "my-drive"
    unit_id = 2
    command = 0x2000
    cmd_run_forward = 0x0012
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["DELTA_MAP", "REGISTER_MAPS", "RegisterMap", "get_register_map", "load_register_map",
           "register_map_from_dict"]

_ADDRESS_FIELDS = ("command", "freq_set", "aux_command", "fault", "status", "freq_cmd", "freq_out",
                   "current", "accel_time", "decel_time", "comm_fault_treatment", "comm_timeout")
_OPTIONAL_ADDRESS_FIELDS = ("aux_command", "current", "accel_time", "decel_time", "comm_fault_treatment",
                            "comm_timeout")
_CODE_FIELDS = ("cmd_stop", "cmd_run_forward", "cmd_run_reverse", "aux_fault_reset",
                "status_run_mask", "status_running", "status_decelerating", "status_standby",
                "status_stopped", "status_dir_mask", "status_dir_forward", "status_dir_reverse",
                "fault_code_mask", "comm_treatment_ramp_stop")
_SCALE_FIELDS = ("freq_unit_hz", "current_unit_a", "ramp_time_unit_s", "comm_timeout_unit_s")


@dataclass(frozen=True)
class RegisterMap:
    """Where a drive keeps each quantity, and how it codes it.

    Addresses are wire addresses 0..65535 (``None`` for a register the drive does not have). All
    registers are holding registers (FC03 read, FC06 write single, FC16 write multiple).

    Scales: a frequency register holds ``round(f_hz / freq_unit_hz)``; a current register
    ``current_a / current_unit_a``; a ramp time register ``time_s / ramp_time_unit_s`` where the ramp
    time is the time to go from 0 Hz to the drive's maximum output frequency (``max_output_hz``).
    """

    model: str = "delta"
    unit_id: int = 1
    # addresses
    command: int = 0x2000
    freq_set: int = 0x2001
    aux_command: int | None = 0x2002
    fault: int = 0x2100
    status: int = 0x2101
    freq_cmd: int = 0x2102
    freq_out: int = 0x2103
    current: int | None = 0x2104
    accel_time: int | None = 0x0109
    decel_time: int | None = 0x010A
    # communication loss (Delta 09-02 "transmission fault treatment", 09-03 "time-out detection"): with
    # a time-out set, a drive that receives no valid request for that long faults and stops by itself
    comm_fault_treatment: int | None = 0x0902
    comm_timeout: int | None = 0x0903
    # codes written to ``command`` / ``aux_command``
    cmd_stop: int = 0x0001
    cmd_run_forward: int = 0x0012
    cmd_run_reverse: int = 0x0022
    aux_fault_reset: int = 0x0002
    comm_treatment_ramp_stop: int = 0x0001  # 09-02 = 1: warn and ramp to stop (0 keeps running!)
    # status word decoding: (status & mask) == code
    status_run_mask: int = 0x0003
    status_stopped: int = 0x0000
    status_decelerating: int = 0x0001
    status_standby: int = 0x0002
    status_running: int = 0x0003
    status_dir_mask: int = 0x0018
    status_dir_forward: int = 0x0000
    status_dir_reverse: int = 0x0018
    # fault register: low byte fault code (0 = none), high byte warning
    fault_code_mask: int = 0x00FF
    # scales
    freq_unit_hz: float = 0.01
    current_unit_a: float = 0.01
    ramp_time_unit_s: float = 0.1
    comm_timeout_unit_s: float = 0.1  # 09-03 in 0.1 s; 0 = detection off

    def __post_init__(self) -> None:
        if not isinstance(self.model, str) or not self.model:
            raise ValueError(f"model={self.model!r}: must be a non-empty string")
        if not isinstance(self.unit_id, int) or not 1 <= self.unit_id <= 247:
            raise ValueError(f"unit_id={self.unit_id!r}: must be an integer 1..247 (Modbus unit address)")
        for name in _ADDRESS_FIELDS:
            value = getattr(self, name)
            if value is None and name in _OPTIONAL_ADDRESS_FIELDS:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF:
                raise ValueError(f"{name}={value!r}: must be a wire address 0..65535"
                                 + (" or None" if name in _OPTIONAL_ADDRESS_FIELDS else ""))
        for name in _CODE_FIELDS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF:
                raise ValueError(f"{name}={value!r}: must be a 16-bit register value 0..65535")
        for name in _SCALE_FIELDS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
                raise ValueError(f"{name}={value!r}: must be a positive number")
        used = [getattr(self, n) for n in _ADDRESS_FIELDS if getattr(self, n) is not None]
        if len(set(used)) != len(used):
            raise ValueError(f"register addresses must be distinct, got {dict(self.addresses())}")
        if (self.accel_time is None) != (self.decel_time is None):
            raise ValueError("accel_time and decel_time must both be given or both be None")
        if (self.comm_timeout is None) != (self.comm_fault_treatment is None):
            raise ValueError("comm_timeout and comm_fault_treatment must both be given or both be None")
        if len({self.cmd_stop, self.cmd_run_forward, self.cmd_run_reverse}) != 3:
            raise ValueError("cmd_stop, cmd_run_forward and cmd_run_reverse must be distinct codes")

    def addresses(self) -> dict[str, int]:
        """Every mapped register: name → wire address (unmapped ones left out)."""
        return {n: getattr(self, n) for n in _ADDRESS_FIELDS if getattr(self, n) is not None}

    @property
    def has_ramp_registers(self) -> bool:
        return self.accel_time is not None

    @property
    def has_comm_timeout(self) -> bool:
        """The drive's communication-loss stop can be set over Modbus."""
        return self.comm_timeout is not None

    # conversions at the boundary -------------------------------------------------------------------
    def freq_to_register(self, frequency_hz: float) -> int:
        """Drive frequency in Hz → register value; raises for a value the register cannot hold."""
        value = round(frequency_hz / self.freq_unit_hz)
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"frequency_hz={frequency_hz!r}: outside the register range "
                             f"0..{0xFFFF * self.freq_unit_hz:g} Hz")
        return value

    def register_to_freq(self, value: int) -> float:
        return value * self.freq_unit_hz

    def comm_timeout_to_register(self, timeout_s: float) -> int:
        """Communication time-out (s, > 0) → register value; raises outside 1..65535 steps."""
        value = round(timeout_s / self.comm_timeout_unit_s)
        if not 1 <= value <= 0xFFFF:
            raise ValueError(f"communication time-out {timeout_s!r} s: outside the register range "
                             f"{self.comm_timeout_unit_s:g}..{0xFFFF * self.comm_timeout_unit_s:g} s")
        return value

    def ramp_time_to_register(self, time_s: float) -> int:
        value = round(time_s / self.ramp_time_unit_s)
        if not 1 <= value <= 0xFFFF:
            raise ValueError(f"ramp time {time_s!r} s: outside the register range "
                             f"{self.ramp_time_unit_s:g}..{0xFFFF * self.ramp_time_unit_s:g} s")
        return value


DELTA_MAP = RegisterMap()
"""Delta VFD-E/EL/MS300 style map (see the module docstring)."""

REGISTER_MAPS: dict[str, RegisterMap] = {"delta": DELTA_MAP}
"""Built-in maps by the name a rig configuration uses (``register_map = "delta"``)."""


def get_register_map(spec: str | dict[str, Any] | RegisterMap) -> RegisterMap:
    """A built-in map by name, a map from a configuration table (overriding the map named by its
    ``base`` key, default ``"delta"``), or a map passed through."""
    if isinstance(spec, RegisterMap):
        return spec
    if isinstance(spec, str):
        if spec not in REGISTER_MAPS:
            raise ValueError(f"register_map={spec!r}: unknown; built-in maps are {sorted(REGISTER_MAPS)} "
                             "(or give a table of registers)")
        return REGISTER_MAPS[spec]
    if isinstance(spec, dict):
        table = dict(spec)
        base = get_register_map(table.pop("base", "delta"))
        return register_map_from_dict(table, base)
    raise ValueError(f"register_map={spec!r}: must be a name, a table or a RegisterMap")


def register_map_from_dict(table: dict[str, Any], base: RegisterMap = DELTA_MAP) -> RegisterMap:
    """A map from a configuration table: fields present in ``table`` override ``base``.

    Unknown keys raise ``ValueError`` naming them and the allowed keys (a typo must not silently fall
    back to the default address). ``"none"`` (any case) or an absent register can be given as the
    string ``"none"`` in TOML, which has no null.
    """
    allowed = {f.name for f in dataclasses.fields(RegisterMap)}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(f"unknown register map keys {unknown}; allowed: {sorted(allowed)}")
    # TOML values, any type: RegisterMap.__post_init__ checks each field
    values: dict[str, Any] = {k: (None if isinstance(v, str) and v.lower() == "none" and k != "model" else v)
                              for k, v in table.items()}
    return dataclasses.replace(base, **values)


def load_register_map(source: str | Path | dict[str, Any], *, table: str | None = None) -> RegisterMap:
    """Load a map from a TOML file (optionally a dotted sub-table such as ``"exciter.registers"``)
    or from an already parsed dict."""
    if isinstance(source, dict):
        data: Any = source
    else:
        with Path(source).open("rb") as fh:
            data = tomllib.load(fh)
    if table:
        for key in table.split("."):
            if not isinstance(data, dict) or key not in data:
                raise ValueError(f"table {table!r} not found in {source!s}")
            data = data[key]
    if not isinstance(data, dict):
        raise ValueError(f"register map must be a table, got {type(data).__name__}")
    return register_map_from_dict(data)

"""b-CAP result codes (HRESULT) and the exceptions of the Denso driver.

Codes and names follow the b-CAP reference (``../shared/notes/bcap.md`` §9). An HRESULT is a signed
32-bit value: >= 0 is success, < 0 failure. Codes are kept here as unsigned ints (``0x80000900``) and
compared after masking, so a signed or unsigned reading gives the same name.
"""

from __future__ import annotations

S_OK = 0x00000000
S_FALSE = 0x00000001
S_EXECUTING = 0x00000900

E_TIMEOUT = 0x80000900
E_NO_LICENSE = 0x80000901
E_NOT_CONNECTED = 0x80000902
E_INVALID_CMD_NAME = 0x80000904
E_MAX_OBJECT = 0x80000905
E_TOO_MUCH_DATA = 0x80000909
E_MAX_CONNECT = 0x8000090B
E_INVALIDPACKET = 0x80010000
E_BUSY_PROC = 0x809100AA
E_NOTIMPL = 0x80004001
E_FAIL = 0x80004005
DISP_E_TYPEMISMATCH = 0x80020005
E_ACCESSDENIED = 0x80070005
E_HANDLE = 0x80070006
E_INVALIDARG = 0x80070057
E_CAO_VARIANT_TYPE_NOSUPPORT = 0x80000203
E_CAO_OBJECT_NOTFOUND = 0x80000204
E_V1_INVALID_PACKET = 0x80010001
E_V1_BAD_ARG_TYPE = 0x80010003
E_V1_ROBOTISBUSY = 0x80010004
E_V1_INVALID_COMMAND = 0x80010005

#: code -> (name, description)
CODES: dict[int, tuple[str, str]] = {
    S_OK: ("S_OK", "success"),
    S_FALSE: ("S_FALSE", "success (false)"),
    S_EXECUTING: ("S_EXECUTING", "keep-alive: the call is still executing"),
    E_TIMEOUT: ("E_TIMEOUT", "no reply within the receive timeout"),
    E_NO_LICENSE: ("E_NO_LICENSE", "the controller has no licence for this function"),
    E_NOT_CONNECTED: ("E_NOT_CONNECTED", "not connected"),
    E_INVALID_CMD_NAME: ("E_INVALID_CMD_NAME", "invalid command name"),
    E_MAX_OBJECT: ("E_MAX_OBJECT", "too many objects"),
    E_TOO_MUCH_DATA: ("E_TOO_MUCH_DATA", "packet exceeds the 503-byte limit of UDP/serial b-CAP"),
    E_MAX_CONNECT: ("E_MAX_CONNECT", "too many clients connected"),
    E_INVALIDPACKET: ("E_INVALIDPACKET", "invalid packet"),
    E_BUSY_PROC: ("E_BUSY_PROC", "a previous request is still executing"),
    E_NOTIMPL: ("E_NOTIMPL", "function not implemented"),
    E_FAIL: ("E_FAIL", "unspecified failure"),
    DISP_E_TYPEMISMATCH: ("DISP_E_TYPEMISMATCH", "argument type mismatch"),
    E_ACCESSDENIED: ("E_ACCESSDENIED", "access denied"),
    E_HANDLE: ("E_HANDLE", "invalid or released handle"),
    E_INVALIDARG: ("E_INVALIDARG", "invalid argument"),
    E_CAO_VARIANT_TYPE_NOSUPPORT: ("E_CAO_VARIANT_TYPE_NOSUPPORT", "VARIANT type not supported"),
    E_CAO_OBJECT_NOTFOUND: ("E_CAO_OBJECT_NOTFOUND", "object not found"),
    E_V1_INVALID_PACKET: ("E_V1_INVALID_PACKET", "invalid packet (b-CAP v1)"),
    E_V1_BAD_ARG_TYPE: ("E_V1_BAD_ARG_TYPE", "bad argument type (b-CAP v1)"),
    E_V1_ROBOTISBUSY: ("E_V1_ROBOTISBUSY", "robot is busy (b-CAP v1, RC7)"),
    E_V1_INVALID_COMMAND: ("E_V1_INVALID_COMMAND", "invalid command (b-CAP v1)"),
}


def to_unsigned(hresult: int) -> int:
    """The code as an unsigned 32-bit int (accepts the signed reading)."""
    return int(hresult) & 0xFFFFFFFF


def to_signed(hresult: int) -> int:
    """The code as a signed 32-bit int (how it travels in the packet)."""
    code = to_unsigned(hresult)
    return code - (1 << 32) if code & 0x80000000 else code


def is_failure(hresult: int) -> bool:
    return to_signed(hresult) < 0


def is_controller_error(hresult: int) -> bool:
    """0x83xxxxxx / 0x84xxxxxx: controller errors, described by ``GetErrorDescription``."""
    return (to_unsigned(hresult) >> 24) in (0x83, 0x84)


def name_of(hresult: int) -> str:
    """Symbolic name; controller errors and unknown codes are named by their hex value."""
    code = to_unsigned(hresult)
    if code in CODES:
        return CODES[code][0]
    if is_controller_error(code):
        return f"CONTROLLER_ERROR_{code:08X}"
    return f"HRESULT_{code:08X}"


def describe(hresult: int) -> str:
    code = to_unsigned(hresult)
    return CODES[code][1] if code in CODES else "no description in the b-CAP code table"


class BcapError(RuntimeError):
    """A b-CAP call failed: carries the HRESULT (unsigned), its name and a description.

    For controller errors (0x83/0x84xxxxxx) the client fills ``description`` from the controller's
    ``GetErrorDescription`` when it can.
    """

    def __init__(self, hresult: int, name: str | None = None, description: str | None = None,
                 *, function: str | None = None) -> None:
        self.hresult = to_unsigned(hresult)
        self.name = name or name_of(self.hresult)
        self.description = description if description is not None else describe(self.hresult)
        self.function = function
        where = f"{function}: " if function else ""
        super().__init__(f"{where}{self.name} (0x{self.hresult:08X}): {self.description}")


class BcapTimeoutError(BcapError, TimeoutError):
    """No reply (E_TIMEOUT) within the receive timeout, after every allowed attempt."""

    def __init__(self, description: str, *, function: str | None = None) -> None:
        super().__init__(E_TIMEOUT, "E_TIMEOUT", description, function=function)


class BcapProtocolError(ValueError):
    """Malformed bytes: a packet or VARIANT that does not follow the b-CAP layout."""


class BcapConnectionError(BcapError):
    """The link to the controller failed (closed, I/O error) during a call."""

    def __init__(self, description: str, *, function: str | None = None) -> None:
        super().__init__(E_NOT_CONNECTED, "E_NOT_CONNECTED", description, function=function)

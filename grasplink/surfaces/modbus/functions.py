"""Which Modbus requests the server answers: checked on the request PDU's bytes (sans-IO),
before pymodbus decodes it, as the Modbus Application Protocol Specification V1.1b3 orders
the checks (its transaction state diagram, 4.1 and 6.x): the function code (exception 01),
then the quantity and the length the request implies (03); the address (02) and the
execution (04) are the register map's and the gateway's.

- Function codes this server does not implement are exception 01 ILLEGAL FUNCTION: the
  coil and discrete-input functions (there are none), the serial-line diagnostics (07
  Read Exception Status, 08 Diagnostics, 0B/0C the comm event counter and log, 11 Report
  Server ID: the specification defines them for serial lines only, and this server keeps
  none of the serial-line counters they report), file records (14, 15), mask write (16),
  FIFO (18), and 2B with a MEI type other than 0E.
- Codes 80..FF are not requests: the specification reserves 128..255 for exception
  responses (4.1). A request carrying one is answered 01 like any code the server does not
  support, with its function code as it came (its high bit is already set): the client
  learns it was refused rather than waiting for a timeout. Code 00 is not a function
  either: 80 01.
- 2B / 0E Read Device Identification names the server: grasplink, its version.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import version

from grasplink.surfaces.modbus.registers import MAX_READ, ExceptionCode, RegisterError

#: Registers one write may carry (function 16) and the write half of function 23 (spec 6.12, 6.17).
MAX_WRITE = 123
MAX_READ_WRITE_WRITE = 121
MEI_DEVICE_IDENTIFICATION = 0x0E
#: The installed distribution's version (the package's metadata, not the top-level module,
#: which the gateway layer must not import).
__version__ = version("grasplink")
#: Read Device Identification: the objects this server reports (spec 6.21), by object id.
IDENTIFICATION = {
    0x00: "grasplink",  # VendorName
    0x01: "grasplink-gateway",  # ProductCode
    0x02: __version__,  # MajorMinorRevision
    0x04: "grasplink gateway",  # ProductName
    0x05: "Modbus register map",  # ModelName
}


@dataclass(frozen=True)
class Function:
    code: int
    name: str
    note: str


#: The function codes this server answers (docs/modbus.md); any other is exception 01.
FUNCTIONS: tuple[Function, ...] = (
    Function(0x03, "Read Holding Registers", f"the command settings; 1..{MAX_READ} registers"),
    Function(0x04, "Read Input Registers", f"the gateway's state; 1..{MAX_READ} registers"),
    Function(0x06, "Write Single Register", "one command"),
    Function(0x10, "Write Multiple Registers", f"one command; 1..{MAX_WRITE} registers"),
    Function(
        0x17,
        "Read/Write Multiple Registers",
        f"a write of one command, then the read; read 1..{MAX_READ}, "
        f"write 1..{MAX_READ_WRITE_WRITE} registers",
    ),
    Function(
        0x2B,
        "Read Device Identification (MEI type 0E)",
        "read codes 01..04: VendorName grasplink, ProductCode grasplink-gateway, "
        f"MajorMinorRevision (the version, {__version__} now), ProductName, ModelName",
    ),
)
CODES = frozenset(f.code for f in FUNCTIONS)


def check_request(pdu: bytes) -> RegisterError | None:
    """Why a request PDU (function code and data) is refused before anything is read or
    written, as the exception code and a message; None when it is well formed."""
    if not pdu:
        return RegisterError(ExceptionCode.ILLEGAL_VALUE, "empty request")
    code, size = pdu[0], len(pdu)
    if code not in CODES:
        what = "an exception-response code, not a request" if code & 0x80 else "not supported"
        return RegisterError(ExceptionCode.ILLEGAL_FUNCTION, f"function 0x{code:02X}: {what}")
    if code in (0x03, 0x04, 0x06):
        if size != 5:
            return _length(code, size, 5)
        if code != 0x06:
            return _quantity(code, _word(pdu, 3), MAX_READ)
        return None
    if code == 0x10:
        if size < 6:
            return _length(code, size, 6)
        quantity = _word(pdu, 3)
        return _quantity(code, quantity, MAX_WRITE) or _bytes(code, pdu, 5, quantity)
    if code == 0x17:
        if size < 10:
            return _length(code, size, 10)
        quantity = _word(pdu, 7)
        return (
            _quantity(code, _word(pdu, 3), MAX_READ, "read ")
            or _quantity(code, quantity, MAX_READ_WRITE_WRITE, "write ")
            or _bytes(code, pdu, 9, quantity)
        )
    # 0x2B: encapsulated interface transport; only Read Device Identification
    if size < 2 or pdu[1] != MEI_DEVICE_IDENTIFICATION:
        mei = f"0x{pdu[1]:02X}" if size >= 2 else "missing"
        return RegisterError(
            ExceptionCode.ILLEGAL_FUNCTION, f"function 0x2B: MEI type {mei} not supported"
        )
    if size != 4:
        return _length(code, size, 4)
    if not 1 <= pdu[2] <= 4:
        return RegisterError(
            ExceptionCode.ILLEGAL_VALUE, f"function 0x2B/0E: read code {pdu[2]} outside 1..4"
        )
    return None


def _word(pdu: bytes, offset: int) -> int:
    return pdu[offset] << 8 | pdu[offset + 1]


def _length(code: int, size: int, expected: int) -> RegisterError:
    return RegisterError(
        ExceptionCode.ILLEGAL_VALUE,
        f"function 0x{code:02X}: a request of {size} bytes (expected {expected})",
    )


def _quantity(code: int, quantity: int, most: int, what: str = "") -> RegisterError | None:
    if 1 <= quantity <= most:
        return None
    message = f"function 0x{code:02X}: {what}quantity {quantity} outside 1..{most}"
    return RegisterError(ExceptionCode.ILLEGAL_VALUE, message)


def _bytes(code: int, pdu: bytes, at: int, quantity: int) -> RegisterError | None:
    count = pdu[at]
    if count == 2 * quantity and len(pdu) == at + 1 + count:
        return None
    return RegisterError(
        ExceptionCode.ILLEGAL_VALUE,
        f"function 0x{code:02X}: byte count {count} and {len(pdu) - at - 1} data bytes "
        f"for {quantity} registers",
    )


#: docs/modbus.md (docgen): how the server is built on pymodbus, and why that way.
SERVER_DOC: tuple[str, ...] = (
    "### The server: pymodbus's documented hooks",
    "",
    "The server is pymodbus's `ModbusTcpServer` or `ModbusSerialServer` (the version pinned "
    "in pyproject.toml), set up only through the parameters its documentation lists, so an "
    "upgrade breaks only what pymodbus's API changes say it changed "
    "(`tests/test_public_library_apis.py` fails on any private attribute of a library "
    "object, or an import of pymodbus's request handler, transaction manager or framers):",
    "",
    "- the datastore: a `SimDevice` per unit, holding and input tables, and its `action`, "
    "which pymodbus calls before every access: it fills the registers read from the "
    "gateway's snapshot and settings, and turns a write into a command, answering the "
    "exception code when the gateway refuses it or does not answer;",
    "- `custom_pdu`: each request class pymodbus decodes, behind a check of the request's "
    "bytes (`functions.check_request`) that runs before pymodbus's own decoding: 01 for a "
    "function this server does not implement, 03 for a quantity or length outside the "
    "specification (pymodbus alone answers several of those functions, and a bad quantity "
    "`80 01`); over TCP also a class answering 01 for every other code 01..7F;",
    "- `trace_pdu`, which sees each decoded request first, with `ignore_missing_devices`: "
    "a request to a unit no gateway has is answered 0B over TCP and not at all on a "
    "serial line (pymodbus would answer a write 04); an exception-response code sent as "
    "a request is answered 01 (pymodbus: 04);",
    "- `identity`: what Read Device Identification reports.",
    "",
    "Every request goes through pymodbus's own request path (a task per request). "
    "**Budget: the Modbus server costs at most 1 % of a core per gateway for a 10 Hz poll "
    "of the whole input map** (the busiest panel to expect; at other rates 1 ms of CPU "
    "per request); what a request costs, and whether the budget is met, is in "
    "docs/benchmarks/modbus.md.",
    "",
)

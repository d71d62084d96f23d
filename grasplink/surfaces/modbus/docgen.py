"""docs/modbus.md, generated from the register map (`grasplink gateway --print-register-map`).

The map is the source of truth; a test checks the committed file equals this
output, so the document cannot drift from what the server serves.
"""

from __future__ import annotations

from grasplink.gateway.config import MODBUS_DEVICE_BASE
from grasplink.profiles.kinds import KINDS
from grasplink.surfaces.modbus.functions import (
    FUNCTIONS,
    MAX_READ_WRITE_WRITE,
    MAX_WRITE,
    SERVER_DOC,
)
from grasplink.surfaces.modbus.registers import (
    COMMAND_TIMEOUT_S,
    MAP_CHANGES,
    MAP_VERSION,
    MAX_READ,
    ExceptionCode,
    Register,
    RegisterMap,
    WordType,
    register_map,
)
from grasplink.surfaces.modbus.url import DEFAULT_BAUD, EXAMPLE_TCP_PORT, MODBUS_TCP_PORT

TYPES = (
    ("u16", "one register, 0..65535", "0xFFFF", "0..65534"),
    ("i16", "one register, two's complement", "0x8000 (-32768)", "-32767..32767"),
    ("u32", "two registers, high word first", "0xFFFF 0xFFFF", "0..4294967294"),
    ("i32", "two registers, high word first, two's complement", "0x8000 0x0000", "±2147483647"),
)


def render_modbus_markdown(rmap: RegisterMap | None = None) -> str:
    """The whole document for `rmap` (default: the gateway's map)."""
    rmap = rmap or register_map()
    out = [
        "# Modbus register map",
        "",
        "<!-- Generated file: edit grasplink/surfaces/modbus/registers.py, then run "
        "`grasplink gateway --print-register-map > docs/modbus.md` or `make docs`. -->",
        "",
        "Generated from `grasplink/surfaces/modbus/registers.py` (map version "
        f"{MAP_VERSION}); do not edit by hand. Registers that carry a node's object take "
        "their type, raw unit and limits from that object in the node's EDS "
        "(docs/profiles.md), named in the *source* column.",
        "",
        *_connection(rmap),
        *_conventions(),
        *_versions(),
        "## Input registers (function 04, read-only)",
        "",
        f"Addresses 0..{rmap.input_count - 1}: one read of {rmap.input_count} registers "
        "returns the whole map. Values come from the gateway's snapshot (replaced every "
        "50 ms), so two reads within 50 ms may return the same values; `uptime_ms` changes "
        "with every snapshot. The snapshot's fields are defined once, in "
        "`grasplink/gateway/snapshot.py` (frozen dataclasses, units in the names); which of "
        "them the map carries, at which address, type and scale, is the map's own table, "
        "and every register's source path is checked against those fields when the map is "
        "built (a misspelt path fails, naming its register).",
        "",
    ]
    section = None
    for register in rmap.inputs:
        if register.section != section:
            section = register.section
            out += ["", f"### {section}", "", *_table_head()]
        out.append(_row(register))
    out += ["", *_enumerations(rmap)]
    out += _device_registers(rmap)
    out += _holding(rmap)
    out += _device_holding(rmap)
    out += _examples(rmap)
    return "\n".join(out).rstrip() + "\n"


def _connection(rmap: RegisterMap) -> list[str]:
    return [
        "## Connecting",
        "",
        "```sh",
        "grasplink gateway --modbus tcp://127.0.0.1:1502            # Modbus TCP",
        "grasplink gateway --modbus 'rtu:///dev/ttyUSB0?baud=115200&parity=N&unit=1'",
        "grasplink gateway --with-nodes --modbus tcp://127.0.0.1:1502   # self-contained",
        "```",
        "",
        "| URL | meaning |",
        "|---|---|",
        "| `tcp://HOST:PORT` | Modbus TCP server on HOST (default 127.0.0.1: only this "
        f"machine), PORT (required, e.g. {EXAMPLE_TCP_PORT}: a URL without one is refused; "
        f"Modbus's own {MODBUS_TCP_PORT}, like every port below 1024, needs privileges). A "
        "malformed host (`256.1.1.1`) or one that does not resolve is refused, naming it. "
        "Every interface only when "
        "asked: `tcp://0.0.0.0:1502`. Answers every unit id. Port 0: any free port, printed "
        "at start. |",
        "| `rtu://DEVICE?baud=B&parity=P&stopbits=S&unit=U` | Modbus RTU on a serial "
        f"line (pyserial): baud default {DEFAULT_BAUD}, parity N, E (default) or O, stop "
        "bits 1 (default) or 2, unit 1..247 (default 1). Requests for other units and "
        "broadcasts (unit 0) get no answer and change nothing: a prosthesis setting is "
        "never changed by a broadcast. |",
        "",
        "The server runs in its own thread and event loop; it reads the gateway's "
        "snapshot without locks and hands writes to the gateway's thread as commands, so "
        "a slow or misbehaving Modbus client never delays the feedback loop. A port in "
        "use, a missing serial device or a bad URL stops `grasplink gateway` at start "
        "with a one-line error.",
        "",
        *_functions(),
        "| exception | when |",
        "|---|---|",
        f"| {ExceptionCode.ILLEGAL_FUNCTION:02X} ILLEGAL FUNCTION | a function code not in "
        "the table above (coils and discrete inputs: there are none; serial-line "
        "diagnostics; 80..FF) |",
        f"| {ExceptionCode.ILLEGAL_ADDRESS:02X} ILLEGAL DATA ADDRESS | a read beyond the "
        "table; a write to holding registers that are not exactly one command (part of "
        "a pair, several commands, beyond the table). Nothing is applied. |",
        f"| {ExceptionCode.ILLEGAL_VALUE:02X} ILLEGAL DATA VALUE | a quantity outside the "
        f"function's range (a read of 0 or more than {MAX_READ} registers, a write of more "
        f"than {MAX_WRITE}), a byte count or request length that does not match it; a "
        "written value outside "
        "its range or codes, e_min not below e_max, or a command the gateway refuses "
        "(no such node, calibration it cannot use). Nothing is applied. |",
        f"| {ExceptionCode.DEVICE_FAILURE:02X} SERVER DEVICE FAILURE | the gateway did not "
        f"answer the command within {COMMAND_TIMEOUT_S:g} s. The command stays queued and "
        "may still be "
        "applied: read the holding registers back. |",
        f"| {ExceptionCode.DEVICE_BUSY:02X} SERVER DEVICE BUSY | too many commands are "
        "waiting for the gateway; nothing applied, try again. |",
        f"| {ExceptionCode.GATEWAY_NO_RESPONSE:02X} GATEWAY TARGET DEVICE FAILED TO RESPOND | "
        "(TCP, several buses) a unit id no gateway is served at. |",
        "",
        "One bus: a TCP server answers every unit id, a serial one the URL's `unit` only. "
        "Several buses (`--bus` repeated, a gateway each): one server, a unit per gateway "
        "in bus order - over TCP units 1, 2, ..., on a serial line the URL's unit and "
        "those after it; each unit has this whole map, its gateway's values and commands.",
        "",
        f"A read may ask for up to {MAX_READ} registers.",
        "",
        *SERVER_DOC,
    ]


def _functions() -> list[str]:
    """The function codes served (functions.FUNCTIONS) and what happens to the rest."""
    rows = [f"| {f.code:02X} ({f.code}) | {f.name} | {f.note} |" for f in FUNCTIONS]
    return [
        "Function codes (hexadecimal, decimal in brackets), as the Modbus Application "
        "Protocol Specification V1.1b3 defines them:",
        "",
        "| code | function | |",
        "|---|---|---|",
        *rows,
        "",
        "Every other function code is exception 01: coils and discrete inputs (01, 02, 05, "
        "0F: the map has none), the serial-line diagnostics (07, 08, 0B, 0C, 11 Report "
        "Server ID: the specification defines them for serial lines only, and this server "
        "keeps none of the serial-line counters they report; 2B/0E identifies it instead), "
        "file records (14, 15), mask write (16), the FIFO queue (18), 2B with another MEI "
        "type. Codes 80..FF are exception-response codes, not requests (the specification "
        "reserves 128..255 for them): a request carrying one is answered exception 01 with "
        "its code unchanged (e.g. `83 01`), so the client learns it was refused instead of "
        "waiting for a time-out. A request is checked in the specification's order: "
        f"function code (01), then quantity and length (03: reads 1..{MAX_READ}, function "
        f"16 1..{MAX_WRITE}, function 23's write 1..{MAX_READ_WRITE_WRITE} registers), then "
        "address (02), then execution (04, 06). On a serial line a function code whose "
        "frame length is unknown (no function defines it) cannot be delimited and gets no "
        "answer, like a garbled frame.",
        "",
    ]


def _conventions() -> list[str]:
    lines = [
        "## Conventions",
        "",
        "- **Addresses** are PDU addresses, counted from 0, as on the wire and in "
        "pymodbus. In 1-based reference notation input register *a* is 3x(*a*+1) "
        "(30001 + *a*) and holding register *a* is 4x(*a*+1) (40001 + *a*); mbpoll counts "
        "from 1 unless given `-0`.",
        "- **Scaling**: engineering value = raw × scale, in the unit given (raw 415 of a "
        "0.1 mm/s register is 41.5 mm/s). Names carry the engineering unit.",
        "- **32-bit values** take two consecutive registers, **high word first** (big-endian "
        'word order, "ABCD"; mbpoll `-B`, pymodbus `word_order="big"`). Read both in one '
        "request: the snapshot cannot change between them then.",
        "- **Signed values** are two's complement.",
        "- **Unknown** (never measured, node not configured, no estimate) reads as the "
        "type's sentinel; a known value beyond the type's range saturates one step short of "
        "it. Registers marked *counter* wrap modulo 2^16 or 2^32 and have no sentinel (0 "
        "when unknown); registers with a *default* read it instead of the sentinel.",
        "- **Enumerations** read a code, listed under *Codes*; an unknown state reads the "
        "sentinel. **Bit fields**: bit 0 is the least significant.",
        "",
        "| type | layout | sentinel (unknown) | known values |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {name} | {layout} | `{sentinel}` | {known} |" for name, layout, sentinel, known in TYPES
    ]
    return [*lines, ""]


def _versions() -> list[str]:
    """What each map version changed: a client reads `map_version` (input register 0)."""
    lines = [
        "## Map versions",
        "",
        "`map_version` (input register 0) tells a client which map it reads. Registers are "
        "only ever added at the end of a table, so an address, once given, keeps its value.",
        "",
        "| version | what changed |",
        "|---|---|",
    ]
    lines += [f"| {version} | {change} |" for version, change in MAP_CHANGES]
    return [*lines, ""]


def _table_head() -> list[str]:
    return [
        "| address | name | type | unit | scale | meaning | source |",
        "|---|---|---|---|---|---|---|",
    ]


def _addresses(register: Register) -> str:
    if register.words == 1:
        return str(register.address)
    return f"{register.address}–{register.end - 1}"


def _meaning(register: Register) -> str:
    text = register.description
    notes = []
    if register.codes is not None:
        notes.append(
            "codes: " + ", ".join(f"{code} {name}" for name, code in register.codes.items())
        )
    if register.bits:
        notes.append("bits: " + ", ".join(f"{i} {m}" for i, m in enumerate(register.bits) if m))
    if register.counter:
        notes.append("counter")
    if register.default is not None:
        notes.append(f"default {register.default}")
    return "; ".join([text, *notes])


def _scale(register: Register) -> str:
    return f"{register.scale:g}"


def _source(register: Register) -> str:
    if register.profile is not None:
        unit = f" [{register.profile.raw_unit}]" if register.profile.raw_unit else ""
        return f"{register.source}; type from EDS {register.profile}{unit}"
    return register.source


def _row(register: Register) -> str:
    return (
        f"| {_addresses(register)} | `{register.name}` | {_type(register.type)} | "
        f"{register.unit} | {_scale(register)} | {_meaning(register)} | {_source(register)} |"
    )


def _type(word_type: WordType) -> str:
    return word_type.name


def _enumerations(rmap: RegisterMap) -> list[str]:
    lines = ["### Codes", ""]
    seen: set[tuple[tuple[str, int], ...]] = set()
    for register in rmap.inputs + rmap.holding:
        if register.codes is None:
            continue
        key = tuple(register.codes.items())
        if key in seen:
            continue
        seen.add(key)
        users = [
            f"`{r.name}`"
            for r in rmap.inputs + rmap.holding
            if r.codes is not None and tuple(r.codes.items()) == key
        ]
        if len(users) > 3:
            users = [*users[:2], f"… ({len(users)} registers)"]
        lines += [
            f"{', '.join(users)}:",
            "",
            "| code | meaning |",
            "|---|---|",
            *(f"| {code} | {name} |" for name, code in register.codes.items()),
            "",
        ]
    lines += [
        "Node bits (`nodes_configured`, `nodes_live`, `nodes_operational`): "
        + ", ".join(f"bit {i} {kind}" for i, kind in enumerate(KINDS))
        + ". A node is *live* while its heartbeat is heard (any NMT state) and not "
        "overdue; *operational* once the gateway provisioned it and it runs.",
        "",
    ]
    return lines


def _device_registers(rmap: RegisterMap) -> list[str]:
    """The configuration's device objects (`[[modbus.registers]]`; none by default)."""
    if not rmap.device_registers:
        return []
    out = [
        "## Device objects (input registers, this configuration)",
        "",
        f"From `{rmap.source}` (`[[modbus.registers]]`, docs/gateway.md): objects that device "
        "nodes' TPDOs map, each at the input registers its entry gives (at or above "
        f"{MODBUS_DEVICE_BASE}; the fixed map above is unchanged). A read must lie inside "
        "the fixed map or on consecutive configured registers: a span that touches an "
        f"address neither maps is exception {ExceptionCode.ILLEGAL_ADDRESS:02X}. Integers "
        "read the object's value (saturated one short of the sentinel); float32 is IEEE 754 "
        'single precision, high word first ("ABCD", like every 32-bit value here). While '
        "the node is not operational, or before its first TPDO, a register reads the "
        "sentinel (float32: NaN, `0x7FC0 0x0000`): never a stale value.",
        "",
        "| address | name | type | unit | object | data type | node |",
        "|---|---|---|---|---|---|---|",
    ]
    for register in rmap.device_registers:
        entry = register.config
        span = str(entry.address) if entry.words == 1 else f"{entry.address}–{entry.end - 1}"
        out.append(
            f"| {span} | `{register.name}` | {entry.type} | {entry.unit} | "
            f"{entry.index:04X}h:{entry.subindex:02X} {entry.name} | {entry.data_type} | "
            f"{entry.node} |"
        )
    return [*out, ""]


def _device_holding(rmap: RegisterMap) -> list[str]:
    """The configuration's device objects a client writes (`[[modbus.holding]]`)."""
    if not rmap.device_holding:
        return []
    out = [
        "## Device objects (holding registers, this configuration)",
        "",
        f"From `{rmap.source}` (`[[modbus.holding]]`, docs/gateway.md): objects that device "
        f"nodes' RPDOs map, each at the holding registers its entry gives (at or above "
        f"{MODBUS_DEVICE_BASE}). A write covers exactly one entry (function 06 for one "
        "register, 16 for two) and becomes the command `write_object`: the gateway sends the "
        "value at once in the node's RPDO, the RPDO's other objects with the value last sent "
        "to them (else the file's ParameterValue or DefaultValue). A value the object does "
        f"not accept (its limits, its type; float32: NaN, infinite, or a fraction for an "
        f"integer object) is exception {ExceptionCode.ILLEGAL_VALUE:02X}, and so is a write "
        "while the node is not operational: a value is never queued for later. A read "
        "returns the value last sent, the sentinel before any and after the node rebooted.",
        "",
        "| address | name | type | unit | object | data type | accepts | node |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for register in rmap.device_holding:
        entry = register.config
        span = str(entry.address) if entry.words == 1 else f"{entry.address}–{entry.end - 1}"
        low, high = entry.limits
        accepts = "any finite number" if low == -high == float("inf") else f"{low:g}..{high:g}"
        out.append(
            f"| {span} | `{register.name}` | {entry.type} | {entry.unit} | "
            f"{entry.index:04X}h:{entry.subindex:02X} {entry.name} | {entry.data_type} | "
            f"{accepts} | {entry.node} |"
        )
    return [*out, ""]


def _holding(rmap: RegisterMap) -> list[str]:
    out = [
        "## Holding registers (functions 03, 06, 16, 23): commands",
        "",
        f"Addresses 0..{rmap.holding_count - 1}. Reading returns the gateway's current "
        "setting (not a snapshot: a write is visible as soon as it is answered). Writing "
        "sends the command of `grasplink/gateway/commands.py` (the same commands MQTT "
        "carries) to the gateway's thread and answers once the gateway has executed it. "
        "**A write must cover exactly one command**: one register, or both registers of "
        "the EMG calibration pair in one function 16 write; anything else is exception 02. "
        "Every value is checked before anything is sent (exception 03), and the gateway "
        "checks again; a refused write changes nothing. A configuration may add device "
        f"nodes' RPDO-mapped objects at holding registers {MODBUS_DEVICE_BASE} and above "
        "(`[[modbus.holding]]`, docs/gateway.md: a write is sent to the node in its RPDO); "
        "`grasplink gateway --config FILE --print-register-map` lists them.",
        "",
        "| address | name | type | unit | scale | accepted raw values | reads | source |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for register in rmap.holding:
        if register.codes is not None:
            accepted = ", ".join(f"{c} {n}" for n, c in register.codes.items())
        else:
            low = register.type.low if register.low is None else register.low
            high = register.type.high if register.high is None else register.high
            accepted = f"{low}..{high}"
            if register.scale != 1:
                scaled = f"{low * register.scale:g}..{high * register.scale:g}"
                accepted += f" ({scaled} {register.unit})"
        reads = register.description
        if register.default is None:
            reads += " (sentinel: no such node)" if register.profile else ""
        out.append(
            f"| {_addresses(register)} | `{register.name}` | {register.type.name} | "
            f"{register.unit} | {_scale(register)} | {accepted} | {reads} | "
            f"{_source(register)} |"
        )
    out += ["", "### Commands", "", "| write | command | what it does |", "|---|---|---|"]
    for group in rmap.groups:
        if len(group.registers) == 1:
            how = f"06 or 16 at {group.address}"
        else:
            how = (
                f"16 at {group.address}, count {group.end - group.address} ("
                + ", ".join(f"`{r.name}`" for r in group.registers)
                + ")"
            )
        out.append(f"| {how} | `{group.command}` | {group.description} |")
    out += [
        "",
        "The EMG calibration needs e_min < e_max, both in the EDS range of 2220h; it "
        "applies at once and is written to the EMG node in the order that keeps e_min < "
        "e_max after each SDO write. `emg_calibrate` and `restart_node` are actions: they "
        "read back the last one accepted (0: none yet).",
        "",
    ]
    return out


def _examples(rmap: RegisterMap) -> list[str]:
    uptime = rmap["uptime_ms"]
    speed = rmap["skin.slip_speed_mm_s"]
    low = rmap["skin.slip_speed_low_mm_s"]
    mode = rmap["feedback_mode"]
    threshold = rmap["reflex_threshold_mm_s"]
    pair = rmap["emg_e_min_uv"]
    return [
        "## Examples (mbpoll)",
        "",
        "```sh",
        f"mbpoll -0 -1 -t 3 -r 0 -c {rmap.input_count} -p 1502 127.0.0.1      # the whole "
        "input map",
        f"mbpoll -0 -1 -t 3:int -B -r {uptime.address} -p 1502 127.0.0.1        # uptime_ms "
        "(u32, high word first)",
        f"mbpoll -0 -1 -t 3 -r {speed.address} -p 1502 127.0.0.1 # slip speed (magnitude), "
        "raw × 0.1 mm/s",
        f"mbpoll -0 -1 -t 3 -r {low.address} -c 4 -p 1502 127.0.0.1 # its range, direction "
        "(mbpoll adds the signed reading in brackets) and direction confidence",
        f"mbpoll -0 -1 -t 4 -r {mode.address} -p 1502 127.0.0.1 2         # feedback mode 2 "
        "(slip_speed)",
        f"mbpoll -0 -1 -t 4 -r {threshold.address} -p 1502 127.0.0.1 400       # reflex "
        "threshold 40.0 mm/s",
        f"mbpoll -0 -1 -t 4 -r {pair.address} -p 1502 127.0.0.1 80 450    # EMG calibration "
        "80..450 uV (one write of both)",
        "```",
        "",
    ]

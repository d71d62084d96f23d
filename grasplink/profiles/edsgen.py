"""Write the shipped EDS files (one per node kind) from one description.

Why a generator: the files share ~20 communication objects and one PDO
scheme, and by hand a COB-ID off by 0x100 or a stale SubNumber slips in
easily. The generated .eds files are checked in and are what canopen loads at
run time; tests/test_profiles.py fails when they differ from this script's
output. After editing, run ``python -m grasplink.profiles.edsgen``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from grasplink.profiles import objects as ob
from grasplink.profiles.kinds import BY_NODE_ID, node_kind, per_kind
from grasplink.profiles.layouts import LAYOUTS_MM, MAX_NODE_SPACINGS, PRESET_CODES, spacings_um

I8, I16, I32, U8, U16, U32, VSTR = 0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x9
BITS = {I8: 8, I16: 16, I32: 32, U8: 8, U16: 16, U32: 32}
VAR, ARRAY, RECORD = 0x7, 0x8, 0x9
VENDOR_ID = 0x00000ABC
REVISION = 0x00010000
DATE, TIME = "11-21-2026", "08:39AM"


@dataclass(frozen=True)
class Entry:
    """One VAR or sub-index; `default` is written as given (str) or in decimal."""

    name: str
    dtype: int
    access: str
    default: int | str = 0
    low: int | None = None
    high: int | None = None
    pdo: bool = False


@dataclass(frozen=True)
class Obj:
    index: int
    name: str
    otype: int
    subs: dict[int, Entry]


@dataclass(frozen=True)
class Device:
    kind: str
    product_code: int
    device_type: int
    product_name: str
    comments: tuple[str, ...]
    dummies: bool
    objects: tuple[Obj, ...]


def var(
    index: int,
    name: str,
    dtype: int,
    access: str,
    default: int | str = 0,
    low: int | None = None,
    high: int | None = None,
    pdo: bool = False,
) -> Obj:
    return Obj(index, name, VAR, {0: Entry(name, dtype, access, default, low, high, pdo)})


def compound(index: int, name: str, otype: int, subs: dict[int, Entry]) -> Obj:
    return Obj(index, name, otype, subs)


def highest(n: int, access: str = "ro", name: str = "Highest sub-index supported") -> Entry:
    return Entry(name, U8, access, n)


def hexa(value: int) -> str:
    return f"0x{value:08X}"


# --- communication profile --------------------------------------------------
def communication(device_type: int, product_code: int, name: str) -> list[Obj]:
    """The CiA 301 objects every grasplink node carries."""
    store = {
        n: Entry(f"Save {what}", U32, "rw", 1)
        for n, what in (
            (1, "all parameters"),
            (2, "communication parameters"),
            (3, "application parameters"),
        )
    }
    restore = {
        n: Entry(f"Restore {what}", U32, "rw", 1)
        for n, what in (
            (1, "all default parameters"),
            (2, "communication default parameters"),
            (3, "application default parameters"),
        )
    }
    return [
        var(ob.DEVICE_TYPE, "Device type", U32, "ro", hexa(device_type)),
        var(ob.ERROR_REGISTER, "Error register", U8, "ro", 0, pdo=True),
        compound(
            ob.ERROR_HISTORY,
            "Pre-defined error field",
            ARRAY,
            {
                0: highest(0, "rw", "Number of errors"),
                **{n: Entry(f"Standard error field {n}", U32, "ro", 0) for n in range(1, 9)},
            },
        ),
        var(ob.COB_ID_SYNC, "COB-ID SYNC", U32, "rw", "0x00000080"),
        var(ob.DEVICE_NAME, "Manufacturer device name", VSTR, "const", name),
        var(
            ob.HARDWARE_VERSION,
            "Manufacturer hardware version",
            VSTR,
            "const",
            "simulated hardware 1.0",
        ),
        var(ob.SOFTWARE_VERSION, "Manufacturer software version", VSTR, "const", "grasplink 0.1.0"),
        compound(ob.STORE_PARAMETERS, "Store parameters", ARRAY, {0: highest(3), **store}),
        compound(
            ob.RESTORE_DEFAULTS, "Restore default parameters", ARRAY, {0: highest(3), **restore}
        ),
        var(ob.COB_ID_EMCY, "COB-ID EMCY", U32, "rw", "$NODEID+0x80"),
        var(ob.EMCY_INHIBIT_100US, "Inhibit time EMCY [100 us]", U16, "rw", 0),
        compound(
            ob.HEARTBEAT_CONSUMER,
            "Consumer heartbeat time",
            ARRAY,
            {
                0: highest(4),
                1: Entry(
                    "Consumer heartbeat time 1", U32, "rw", hexa(ob.GATEWAY_NODE_ID << 16 | 500)
                ),
                **{n: Entry(f"Consumer heartbeat time {n}", U32, "rw", hexa(0)) for n in (2, 3, 4)},
            },
        ),
        var(ob.HEARTBEAT_PRODUCER_MS, "Producer heartbeat time [ms]", U16, "rw", 100),
        compound(
            ob.IDENTITY,
            "Identity object",
            RECORD,
            {
                0: highest(4),
                1: Entry("Vendor-ID", U32, "ro", hexa(VENDOR_ID)),
                2: Entry("Product code", U32, "ro", hexa(product_code)),
                3: Entry("Revision number", U32, "ro", hexa(REVISION)),
                4: Entry("Serial number", U32, "ro", hexa(0)),
            },
        ),
        compound(
            ob.ERROR_BEHAVIOUR,
            "Error behaviour",
            ARRAY,
            {
                0: highest(1),
                1: Entry("Communication error", U8, "rw", 0, 0, 2),
            },
        ),
        compound(
            ob.SDO_SERVER,
            "SDO server parameter",
            RECORD,
            {
                0: highest(2),
                1: Entry("COB-ID client to server", U32, "ro", "$NODEID+0x600"),
                2: Entry("COB-ID server to client", U32, "ro", "$NODEID+0x580"),
            },
        ),
    ]


# --- PDOs -------------------------------------------------------------------
Mapped = tuple[int, int]  # (index, sub-index)


@dataclass(frozen=True)
class Pdo:
    mapping: tuple[Mapped, ...] = ()
    valid: bool = False
    ttype: int = 254
    inhibit: int = 0
    event: int = 0


def _map_object(index: int, label: str, pdo: Pdo, objs: dict[int, Obj]) -> Obj:
    subs = {0: Entry("Number of mapped objects", U8, "rw", len(pdo.mapping), 0, 8)}
    for n in range(1, 9):
        value = 0
        if n <= len(pdo.mapping):
            mi, ms = pdo.mapping[n - 1]
            value = mi << 16 | ms << 8 | BITS[objs[mi].subs[ms].dtype]
        subs[n] = Entry(f"Mapped object {n}", U32, "rw", hexa(value))
    return compound(index, f"{label} mapping parameter", RECORD, subs)


def tpdos(pdos: list[Pdo], objs: dict[int, Obj]) -> list[Obj]:
    out = []
    for n, pdo in enumerate(pdos):
        cob = 0x40000000 | (0x180 + 0x100 * n) | (0 if pdo.valid else 0x80000000)
        out.append(
            compound(
                ob.TPDO_COMM + n,
                f"TPDO{n + 1} communication parameter",
                RECORD,
                {
                    0: highest(6),
                    1: Entry("COB-ID used by TPDO", U32, "rw", f"$NODEID+{hexa(cob)}"),
                    2: Entry("Transmission type", U8, "rw", pdo.ttype),
                    3: Entry("Inhibit time [100 us]", U16, "rw", pdo.inhibit),
                    4: Entry("Compatibility entry", U8, "rw", 0),
                    5: Entry("Event timer [ms]", U16, "rw", pdo.event),
                    6: Entry("SYNC start value", U8, "rw", 0, 0, 240),
                },
            )
        )
    out += [_map_object(ob.TPDO_MAP + n, f"TPDO{n + 1}", p, objs) for n, p in enumerate(pdos)]
    return out


def rpdos(pdos: list[Pdo], objs: dict[int, Obj]) -> list[Obj]:
    out = []
    for n, pdo in enumerate(pdos):
        cob = (0x200 + 0x100 * n) | (0 if pdo.valid else 0x80000000)
        out.append(
            compound(
                ob.RPDO_COMM + n,
                f"RPDO{n + 1} communication parameter",
                RECORD,
                {
                    0: highest(5),
                    1: Entry("COB-ID used by RPDO", U32, "rw", f"$NODEID+{hexa(cob)}"),
                    2: Entry("Transmission type", U8, "rw", pdo.ttype),
                    5: Entry("Event timer [ms]", U16, "rw", pdo.event),
                },
            )
        )
    out += [_map_object(ob.RPDO_MAP + n, f"RPDO{n + 1}", p, objs) for n, p in enumerate(pdos)]
    return out


def _pad(pdos: list[Pdo]) -> list[Pdo]:
    return pdos + [Pdo() for _ in range(4 - len(pdos))]


# --- devices ----------------------------------------------------------------
UNITS_LINES = (
    "Units: every ParameterName states its unit in brackets. Integer SI-derived",
    "units (mN, um, uV, mrad/s, mHz, ms, 100 us), ASCII u stands for micro.",
)


def skin() -> tuple[list[Obj], list[Pdo], list[Pdo]]:
    alpha = spacings_um(LAYOUTS_MM[PRESET_CODES[1]])
    spacing = {
        n: Entry(
            f"Ridge spacing {n} [um]",
            U32,
            "rw",
            alpha[n - 1] if n <= len(alpha) else 4000,
            500,
            200000,
        )
        for n in range(1, MAX_NODE_SPACINGS + 1)
    }
    objs = [
        compound(
            ob.SKIN_SAMPLE_SLOTS,
            "FSR sample slots [ADC counts]",
            ARRAY,
            {
                0: highest(3, "const"),
                **{
                    n: Entry(f"FSR sample slot {n} [ADC counts]", U16, "ro", 0, pdo=True)
                    for n in (1, 2, 3)
                },
            },
        ),
        var(ob.SKIN_PACKET_SEQUENCE, "Sample packet sequence", U8, "ro", pdo=True),
        var(ob.SKIN_SAMPLE_COUNTER, "Sample counter", U32, "ro", pdo=True),
        var(ob.SKIN_STATIC_FORCE_MN, "Static force [mN]", I32, "ro", pdo=True),
        var(ob.SKIN_SAMPLE_RATE_HZ, "Sample rate [Hz]", U16, "rw", 400, 80, 1000),
        var(ob.SKIN_SAMPLES_PER_PDO, "Samples per TPDO", U8, "rw", 3, 1, 3),
        var(ob.SKIN_PACKETS_ON_SYNC, "Every packet on SYNC", U8, "rw", 0, 0, 1),
        compound(
            ob.SKIN_FSR_CALIBRATION,
            "FSR calibration",
            RECORD,
            {
                0: highest(3),
                1: Entry("ADC resolution [bit]", U8, "rw", 12, 8, 16),
                2: Entry("Full-scale force [mN]", U32, "rw", 98067, 1000, 200000),
                3: Entry("Zero offset [ADC counts]", U16, "rw", 0),
            },
        ),
        compound(
            ob.SKIN_RIDGE_SPACING_UM,
            "Ridge spacing [um]",
            ARRAY,
            {
                0: Entry("Number of spacings", U8, "rw", len(alpha), 1, MAX_NODE_SPACINGS),
                **spacing,
            },
        ),
        var(ob.SKIN_LAYOUT_PRESET, "Ridge layout preset", U8, "rw", 1, 0, len(PRESET_CODES)),
        var(ob.SKIN_RIDGE_SIDE_UM, "Ridge side length [um]", U32, "rw", 2500, 500, 20000),
    ]
    tx = [
        Pdo(
            (*((ob.SKIN_SAMPLE_SLOTS, n) for n in (1, 2, 3)), (ob.SKIN_PACKET_SEQUENCE, 0)),
            valid=True,
        ),
        Pdo(((ob.SKIN_STATIC_FORCE_MN, 0), (ob.SKIN_SAMPLE_COUNTER, 0)), valid=True, event=20),
    ]
    return objs, _pad(tx), []


def emg() -> tuple[list[Obj], list[Pdo], list[Pdo]]:
    objs = [
        var(ob.EMG_ENVELOPE_UV, "EMG envelope [uV]", U16, "ro", pdo=True),
        var(ob.EMG_LEVEL, "Contraction level", U8, "ro", 0, 0, 5, pdo=True),
        var(ob.EMG_ENVELOPE_SEQUENCE, "Envelope sequence", U8, "ro", pdo=True),
        compound(
            ob.EMG_RAW_SLOTS,
            "Raw sEMG [uV]",
            ARRAY,
            {
                0: highest(3, "const"),
                **{
                    n: Entry(f"Raw sEMG sample {n} [uV]", I16, "ro", 0, pdo=True) for n in (1, 2, 3)
                },
            },
        ),
        var(ob.EMG_RAW_SEQUENCE, "Raw packet sequence", U8, "ro", pdo=True),
        var(ob.EMG_SAMPLE_RATE_HZ, "Sample rate [Hz]", U16, "rw", 1500, 500, 4000),
        var(ob.EMG_WINDOW_MS, "Envelope window [ms]", U16, "rw", 100, 10, 1000),
        var(ob.EMG_ENVELOPE_PERIOD_MS, "Envelope period [ms]", U16, "rw", 10, 1, 1000),
        var(ob.EMG_PACKETS_ON_SYNC, "Every packet on SYNC", U8, "rw", 0, 0, 1),
        compound(
            ob.EMG_CALIBRATION,
            "EMG calibration",
            RECORD,
            {
                0: highest(2),
                1: Entry("e_min [uV]", U16, "rw", 50),
                2: Entry("e_max [uV]", U16, "rw", 500),
            },
        ),
    ]
    tx = [
        Pdo(
            ((ob.EMG_ENVELOPE_UV, 0), (ob.EMG_LEVEL, 0), (ob.EMG_ENVELOPE_SEQUENCE, 0)), valid=True
        ),
        Pdo(
            (*((ob.EMG_RAW_SLOTS, n) for n in (1, 2, 3)), (ob.EMG_RAW_SEQUENCE, 0)), valid=False
        ),  # raw stream: enabled by the gateway when it records
    ]
    return objs, _pad(tx), []


def drive_common(mode: int, supported: int) -> list[Obj]:
    """The CiA 402 objects shared by the belt and the hand."""
    return [
        var(ob.ERROR_CODE, "Error code", U16, "ro", pdo=True),
        var(ob.CONTROLWORD, "Controlword", U16, "rw", pdo=True),
        var(ob.STATUSWORD, "Statusword", U16, "ro", pdo=True),
        var(ob.QUICK_STOP_OPTION, "Quick stop option code", I16, "rw", 2, 0, 7),
        var(ob.MODES_OF_OPERATION, "Modes of operation", I8, "rw", mode, mode, mode),
        var(ob.MODES_OF_OPERATION_DISPLAY, "Modes of operation display", I8, "ro", mode, pdo=True),
        var(ob.SUPPORTED_DRIVE_MODES, "Supported drive modes", U32, "ro", hexa(supported)),
    ]


def belt() -> tuple[list[Obj], list[Pdo], list[Pdo]]:
    objs = [
        *drive_common(ob.MODE_PROFILE_VELOCITY, 0x00000004),
        var(ob.BELT_VELOCITY_ACTUAL_MRAD_S, "Velocity actual value [mrad/s]", I32, "ro", pdo=True),
        var(
            ob.BELT_MAX_PROFILE_VELOCITY_MRAD_S,
            "Max profile velocity [mrad/s]",
            U32,
            "rw",
            ob.FORCE_BELT_MAX_MRAD_S,
            0,
            ob.FORCE_BELT_MAX_MRAD_S,
        ),
        var(ob.BELT_PROFILE_ACCELERATION, "Profile acceleration [mrad/s^2]", U32, "rw", 40000),
        var(ob.BELT_PROFILE_DECELERATION, "Profile deceleration [mrad/s^2]", U32, "rw", 40000),
        var(
            ob.BELT_QUICK_STOP_DECELERATION, "Quick stop deceleration [mrad/s^2]", U32, "rw", 100000
        ),
        var(
            ob.BELT_TARGET_VELOCITY_MRAD_S,
            "Target velocity [mrad/s]",
            I32,
            "rw",
            0,
            -ob.SLIP_BELT_MAX_MRAD_S,
            ob.FORCE_BELT_MAX_MRAD_S,
            pdo=True,
        ),
        var(ob.BELT_TAP_FREQUENCY_MHZ, "Tap frequency [mHz]", U32, "ro", pdo=True),
        var(ob.BELT_SURFACE_SPEED_MM_S, "Slip belt surface speed [mm/s]", U16, "ro", pdo=True),
        var(ob.BELT_ACTIVE, "Active belt", U8, "ro", 0, 0, 2, pdo=True),
        var(ob.BELT_NUB_COUNT, "Force belt nub count", U8, "rw", 6, 1, 32),
        var(
            ob.BELT_EFFECTIVE_RADIUS_UM,
            "Slip belt effective radius [um]",
            U32,
            "rw",
            27000,
            1000,
            100000,
        ),
    ]
    rx = [Pdo(((ob.CONTROLWORD, 0), (ob.BELT_TARGET_VELOCITY_MRAD_S, 0)), valid=True, ttype=255)]
    tx = [
        Pdo(
            ((ob.STATUSWORD, 0), (ob.BELT_VELOCITY_ACTUAL_MRAD_S, 0)),
            valid=True,
            ttype=255,
            inhibit=100,
            event=50,
        ),
        Pdo(
            ((ob.BELT_TAP_FREQUENCY_MHZ, 0), (ob.BELT_SURFACE_SPEED_MM_S, 0), (ob.BELT_ACTIVE, 0)),
            valid=True,
            ttype=255,
            inhibit=100,
            event=100,
        ),
    ]
    return objs, _pad(tx), [*rx, *(Pdo(ttype=255) for _ in range(3))]


def hand() -> tuple[list[Obj], list[Pdo], list[Pdo]]:
    objs = [
        *drive_common(ob.MODE_GRIP_FORCE, 0x00010000),
        var(ob.HAND_TARGET_GRIP_MN, "Target grip force [mN]", U32, "rw", 0, 0, 100000, pdo=True),
        var(ob.HAND_ACTUAL_GRIP_MN, "Actual grip force [mN]", U32, "ro", pdo=True),
        var(ob.HAND_CRUSH_LIMIT_MN, "Crush limit [mN]", U32, "rw", 40000, 0, 100000),
        var(ob.HAND_MAX_GRIP_MN, "Maximum grip force [mN]", U32, "const", 100000),
        var(ob.HAND_GRIP_RATE_MN_S, "Grip force rate [mN/s]", U32, "rw", 50000, 1000, 1000000),
    ]
    rx = [Pdo(((ob.CONTROLWORD, 0), (ob.HAND_TARGET_GRIP_MN, 0)), valid=True, ttype=255)]
    tx = [
        Pdo(
            ((ob.STATUSWORD, 0), (ob.HAND_ACTUAL_GRIP_MN, 0)),
            valid=True,
            ttype=255,
            inhibit=100,
            event=20,
        )
    ]
    return objs, _pad(tx), [*rx, *(Pdo(ttype=255) for _ in range(3))]


_DEVICES: dict[str, tuple[int, int, str, bool, tuple[str, ...]]] = {
    # kind: (product code, device type, device name, dummy mapping, comment lines)
    "skin": (
        1,
        0x00000194,
        "grasplink skin sensor",
        False,
        (
            "Skin sensor node: a silicone skin with triangular ridges over one force-sensing",
            "resistor (FSR) on the prosthetic hand. TPDO1 streams raw FSR samples for slip",
            "decoding (3 samples per PDO, 400 Hz by default), TPDO2 the static grip force every",
            "20 ms. The ridge layout (0x2140..0x2142) tells the decoder where the ridges are.",
            "CiA 404 style measuring device, no RPDOs.",
        ),
    ),
    "belt": (
        2,
        0x00020192,
        "grasplink haptic belt",
        True,
        (
            "Haptic belt node on the forearm: one DC motor drives either the force belt",
            "(positive velocity, nubs tap the skin, tap frequency shows grip force) or the slip",
            "belt (negative velocity, pins brush the skin, speed shows slip speed), never both.",
            "CiA 402 servo drive in profile velocity mode: RPDO1 controlword + target velocity,",
            "TPDO1 statusword + actual velocity, TPDO2 what the wearer feels.",
        ),
    ),
    "emg": (
        3,
        0x00000194,
        "grasplink EMG sensor",
        False,
        (
            "EMG node: one surface EMG channel on a forearm flexor (1500 Hz). TPDO1 carries the",
            "rectified, smoothed envelope and its contraction level e0..e5 at every envelope",
            "update, TPDO2 the raw signal (disabled by default). e_min and e_max (0x2220) split",
            "the envelope range into four levels. CiA 404 style measuring device, no RPDOs.",
        ),
    ),
    "hand": (
        4,
        0x00020192,
        "grasplink hand grip actuator",
        True,
        (
            "Hand node: the grip actuator of the prosthetic hand. CiA 402 servo drive in the",
            "manufacturer-specific grip-force mode (-1): RPDO1 controlword + target grip force,",
            "TPDO1 statusword + actual grip force. Targets above the crush limit (0x2402) are",
            "limited to it.",
        ),
    ),
}
DEVICES = per_kind("profiles/edsgen.py DEVICES", _DEVICES)
BUILDERS = per_kind(
    "profiles/edsgen.py BUILDERS", {"skin": skin, "belt": belt, "emg": emg, "hand": hand}
)


def build(kind: str) -> tuple[Device, int, int]:
    """The device description plus its RPDO and TPDO counts."""
    code, device_type, name, dummies, comments = DEVICES[kind]
    objs, tx, rx = BUILDERS[kind]()
    by_index = {o.index: o for o in objs}
    all_objs = [
        *communication(device_type, code, name),
        *rpdos(rx, by_index),
        *tpdos(tx, by_index),
        *objs,
    ]
    all_objs.sort(key=lambda o: o.index)
    device = Device(
        kind, code, device_type, name, (*comments, *UNITS_LINES), dummies, tuple(all_objs)
    )
    return device, len(rx), len(tx)


def _entry_lines(entry: Entry) -> list[str]:
    lines = [
        f"ParameterName={entry.name}",
        f"ObjectType=0x{VAR:X}",
        f"DataType=0x{entry.dtype:04X}",
        f"AccessType={entry.access}",
        f"DefaultValue={entry.default}",
    ]
    if entry.low is not None:
        lines.append(f"LowLimit={entry.low}")
    if entry.high is not None:
        lines.append(f"HighLimit={entry.high}")
    lines.append(f"PDOMapping={int(entry.pdo)}")
    return lines


def render_eds(kind: str) -> str:
    """The EDS text for one device kind (deterministic, ASCII, LF line ends)."""
    device, n_rx, n_tx = build(kind)
    out = [
        "; Generated by grasplink/profiles/edsgen.py: edit that script, then run",
        "; python -m grasplink.profiles.edsgen (tests fail if this file differs).",
        "",
        "[FileInfo]",
        f"FileName={node_kind(kind).eds}",
        "FileVersion=1",
        "FileRevision=0",
        "EDSVersion=4.0",
        f"Description={device.product_name} (grasplink sensate prosthesis)",
        f"CreationTime={TIME}",
        f"CreationDate={DATE}",
        "CreatedBy=grasplink",
        f"ModificationTime={TIME}",
        f"ModificationDate={DATE}",
        "ModifiedBy=grasplink",
        "",
        "[DeviceInfo]",
        "VendorName=grasplink",
        f"VendorNumber={hexa(VENDOR_ID)}",
        f"ProductName={device.product_name}",
        f"ProductNumber={hexa(device.product_code)}",
        f"RevisionNumber={hexa(REVISION)}",
        *(f"BaudRate_{rate}=1" for rate in (10, 20, 50, 125, 250, 500, 800, 1000)),
        "SimpleBootUpMaster=0",
        "SimpleBootUpSlave=1",
        "Granularity=8",
        "DynamicChannelsSupported=0",
        "GroupMessaging=0",
        f"NrOfRXPDO={n_rx}",
        f"NrOfTXPDO={n_tx}",
        "LSS_Supported=0",
        "",
        "[DummyUsage]",
        *(f"Dummy{n:04d}={int(device.dummies and n >= 2)}" for n in range(1, 8)),
        "",
        "[Comments]",
        f"Lines={len(device.comments)}",
        *(f"Line{n}={line}" for n, line in enumerate(device.comments, start=1)),
    ]
    groups: dict[str, list[int]] = {
        "MandatoryObjects": [],
        "OptionalObjects": [],
        "ManufacturerObjects": [],
    }
    for obj in device.objects:
        if obj.index in (0x1000, 0x1001, 0x1018):
            groups["MandatoryObjects"].append(obj.index)
        elif 0x2000 <= obj.index < 0x6000:
            groups["ManufacturerObjects"].append(obj.index)
        else:
            groups["OptionalObjects"].append(obj.index)
    for group, indices in groups.items():
        out += ["", f"[{group}]", f"SupportedObjects={len(indices)}"]
        out += [f"{n}=0x{index:04X}" for n, index in enumerate(indices, start=1)]
    for obj in device.objects:
        out += ["", f"[{obj.index:04X}]"]
        if obj.otype == VAR:
            out += _entry_lines(obj.subs[0])
            continue
        out += [
            f"ParameterName={obj.name}",
            f"ObjectType=0x{obj.otype:X}",
            f"SubNumber={len(obj.subs)}",
        ]
        for sub, entry in sorted(obj.subs.items()):
            out += ["", f"[{obj.index:04X}sub{sub:X}]", *_entry_lines(entry)]
    return "\n".join(out) + "\n"


def write_all(directory: Path | None = None) -> list[Path]:
    """Regenerate every shipped EDS; returns the paths written."""
    directory = directory or Path(__file__).parent
    paths = []
    for kind in BY_NODE_ID:
        path = directory / node_kind(kind).eds
        path.write_text(render_eds(kind), encoding="ascii", newline="\n")
        paths.append(path)
    return paths


if __name__ == "__main__":
    for written in write_all(Path(sys.argv[1]) if len(sys.argv) > 1 else None):
        print(written)

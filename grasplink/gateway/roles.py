"""Roles bind the loop to objects, not to our node kinds.

The loop reads force samples (skin), an EMG envelope (emg) and drive feedback, and
writes a velocity (belt) and a grip (hand). Which objects carry them, and in which
units, is a binding: our own nodes' come from their EDS (scale 1); a vendor's node
in a loop role names its objects in the description (docs/gateway.md, "Roles"):

    [nodes.hand]                  # a CiA 402 drive as the hand
    eds = "vendor/gripper.eds"
    [nodes.hand.drive]
    target = "6071sub0"           # RPDO-mapped beside the controlword 6040h
    units_per_n = 10.0            # its units per newton of grip
    actual = "6077sub0"           # optional, TPDO-mapped: the grip it reports

    [nodes.skin]                  # an FSR on an analogue input module (CiA 401)
    eds = "vendor/ai.eds"
    sample_rate_hz = 100          # how often it sends a sample (its SYNC rate)
    [nodes.skin.samples]
    objects = ["6401sub1"]        # TPDO-mapped, in sample order
    newtons_per_unit = 0.01
    zero = 0

    [nodes.emg]                   # an envelope on an analogue input
    eds = "vendor/ai.eds"
    [nodes.emg.envelope]
    object = "6401sub2"
    uv_per_unit = 1.0

A binding is checked against the node's file when the configuration is read: the
objects exist, inputs are mapped in a TPDO, a drive's target shares an RPDO with the
controlword and nothing else, the statusword is in a TPDO.
"""

from __future__ import annotations

from dataclasses import dataclass

from grasplink.core.params import Params
from grasplink.decoding.skin_frames import SampleObjects, SkinCalibration
from grasplink.errors import ConfigError, PdoError
from grasplink.profiles import object_key
from grasplink.profiles import objects as obj
from grasplink.profiles.pdo_codec import Key, PdoCodec

CONTROLWORD: Key = (obj.CONTROLWORD, 0)
STATUSWORD: Key = (obj.STATUSWORD, 0)
MN_PER_N = 1000.0
MRAD_PER_RAD = 1000.0


@dataclass(frozen=True)
class SkinBinding:
    """Force samples (decoding.skin_frames), and what our own skin adds for plausibility."""

    objects: SampleObjects
    max_units: int | None = None  # what the sensor can read (ours: ADC full scale)
    static_force_range_mn: tuple[float, float] | None = None  # ours: 2110h's range
    # a vendor's samples in a synchronous TPDO: sent every that many SYNCs (its type 1-240),
    # so each is numbered by the SYNC it answered; 0: event-driven, timed by arrival
    sync_every: int = 0
    tpdo_can_id: int | None = None  # the TPDO the samples travel in


@dataclass(frozen=True)
class EmgBinding:
    envelope: Key
    uv_per_unit: float = 1.0


@dataclass(frozen=True)
class DriveBinding:
    """A CiA 402 drive: the loop's command (mN of grip, mrad/s of belt) x units_per_command
    goes to `target` in RPDO `rpdo` with the controlword; `actual` comes back likewise."""

    rpdo: int
    target: Key
    units_per_command: float = 1.0
    actual: Key | None = None


Binding = SkinBinding | EmgBinding | DriveBinding


def _key(p: Params, name: str) -> Key:
    text = p.string(name)
    try:
        return object_key(text)
    except ConfigError as exc:
        raise p.error(name, str(exc)) from None


def _factor(p: Params, name: str) -> float:
    value = p.number(name, low=0.0, low_open=True)
    if not value < 1e12:
        raise p.error(name, f"expected a factor below 1e12, got {value:g}")
    return value


def _in_tpdo(p: Params, name: str, codec: PdoCodec, key: Key) -> None:
    mapped = {k for can_id in codec.tpdo_can_ids() for k in codec.tpdo_keys(can_id)}
    if key not in mapped:
        raise p.error(name, f"0x{key[0]:04X}sub{key[1]:X} is in no TPDO of the node's file")


def skin(p: Params, codec: PdoCodec) -> SkinBinding:
    t = p.table_of("samples")
    texts = t.raw("objects")
    if not isinstance(texts, list) or not texts or not all(isinstance(x, str) for x in texts):
        raise t.error("objects", 'expected a list of objects, e.g. ["6401sub1"]')
    keys = []
    for i, text in enumerate(texts):
        try:
            key = object_key(text)
        except ConfigError as exc:
            raise t.error(f"objects[{i}]", str(exc)) from None
        _in_tpdo(t, f"objects[{i}]", codec, key)
        keys.append(key)
    homes = {can_id for can_id in codec.tpdo_can_ids() if set(keys) <= set(codec.tpdo_keys(can_id))}
    if not homes:
        raise t.error("objects", "the samples must travel in one TPDO")
    binding = SkinBinding(
        SampleObjects(tuple(keys), _factor(t, "newtons_per_unit"), t.number("zero", 0.0)),
        tpdo_can_id=min(homes),
    )
    t.finish()
    return binding


def emg(p: Params, codec: PdoCodec) -> EmgBinding:
    t = p.table_of("envelope")
    key = _key(t, "object")
    _in_tpdo(t, "object", codec, key)
    binding = EmgBinding(key, _factor(t, "uv_per_unit") if t.has("uv_per_unit") else 1.0)
    t.finish()
    return binding


def drive(p: Params, codec: PdoCodec, role: str) -> DriveBinding:
    """A belt's or hand's drive; units per N of grip (hand) or per rad/s (belt)."""
    t = p.table_of("drive")
    target = _key(t, "target")
    per = "units_per_n" if role == "hand" else "units_per_rad_s"
    scale = _factor(t, per) / (MN_PER_N if role == "hand" else MRAD_PER_RAD)
    actual = _key(t, "actual") if t.has("actual") else None
    if actual is not None:
        _in_tpdo(t, "actual", codec, actual)
    rpdo = _rpdo_of(codec, target)
    if rpdo is None:
        raise t.error("target", f"0x{target[0]:04X}sub{target[1]:X} is in no RPDO of the file")
    keys = _rpdo_keys(codec, rpdo)
    if keys != {CONTROLWORD, target}:
        extra = ", ".join(f"0x{i:04X}sub{s:X}" for i, s in sorted(keys - {target}))
        raise t.error(
            "target",
            f"RPDO{rpdo} maps {extra} beside it; the loop writes the controlword 6040h "
            "and the target, nothing else",
        )
    if not any(STATUSWORD in codec.tpdo_keys(can_id) for can_id in codec.tpdo_can_ids()):
        raise t.error(
            "target",
            "a CiA 402 drive reports its statusword 6041h in a TPDO; the "
            "node's file maps it in none",
        )
    t.finish()
    return DriveBinding(rpdo, target, scale, actual)


def _rpdo_keys(codec: PdoCodec, number: int) -> set[Key]:
    return {(m.index, m.subindex) for m in codec.rpdo_objects(number)}


def _rpdo_of(codec: PdoCodec, target: Key) -> int | None:
    return next((n for n in codec.rpdo_numbers() if target in _rpdo_keys(codec, n)), None)


def own_drive(role: str, codec: PdoCodec) -> DriveBinding:
    """The drive binding of grasplink's own belt or hand (its EDS, the loop's units)."""
    if role == "hand":
        target, actual = (obj.HAND_TARGET_GRIP_MN, 0), (obj.HAND_ACTUAL_GRIP_MN, 0)
    else:
        target, actual = (obj.BELT_TARGET_VELOCITY_MRAD_S, 0), None
    rpdo = _rpdo_of(codec, target)
    if rpdo is None:
        raise PdoError(f"the {role} EDS maps 0x{target[0]:04X} in no RPDO")
    return DriveBinding(rpdo, target, 1.0, actual)


def own_skin(calibration: SkinCalibration, samples_per_pdo: int) -> SkinBinding:
    """Our skin node's binding: its sample slots and packet number, its ADC's range."""
    return SkinBinding(
        SampleObjects.of_skin(calibration, samples_per_pdo),
        calibration.full_counts,
        calibration.static_force_range_mn(),
    )


OWN_EMG = EmgBinding((obj.EMG_ENVELOPE_UV, 0))

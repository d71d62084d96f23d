"""Every simulated signal by name, with its unit.

A signal's name carries its unit (`object.speed_mm_s`), so a column in
`truth.csv` reads unambiguously; effects, node bindings, the recorder and
the plots name signals through these constants, never as string literals.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Signal:
    name: str
    unit: str
    meaning: str


# Object kinematics (physics domain).
OBJECT_POSITION_MM = "object.position_mm"
OBJECT_SPEED_MM_S = "object.speed_mm_s"
OBJECT_SLIPPING = "object.slipping"
# Forces on the object.
LOAD_FORCE_N = "load.force_n"
# Hand (grip actuator).
HAND_TARGET_N = "hand.target_n"
HAND_GRIP_N = "hand.grip_n"
HAND_CRUSHED = "hand.crushed"
# Haptic belt.
BELT_COMMAND_MRAD_S = "belt.command_mrad_s"
BELT_VELOCITY_MRAD_S = "belt.velocity_mrad_s"
BELT_TAP_HZ = "belt.tap_hz"
BELT_SURFACE_MM_S = "belt.surface_mm_s"
# Wearer.
WEARER_LEVEL = "wearer.level"
WEARER_PERCEIVED = "wearer.perceived_level"
# Sensors (skin and EMG domains).
SKIN_FORCE_N = "skin.force_n"
EMG_RAW_UV = "emg.raw_uv"

CATALOGUE: dict[str, Signal] = {
    s.name: s
    for s in (
        Signal(OBJECT_POSITION_MM, "mm", "object's leading edge along the skin"),
        Signal(OBJECT_SPEED_MM_S, "mm/s", "object's signed speed along the skin"),
        Signal(OBJECT_SLIPPING, "0/1", "1 while the object slides over the skin"),
        Signal(LOAD_FORCE_N, "N", "tangential load pulling the object (weight, pull)"),
        Signal(HAND_TARGET_N, "N", "grip force the hand node commands its actuator"),
        Signal(HAND_GRIP_N, "N", "grip (normal) force the hand applies"),
        Signal(HAND_CRUSHED, "0/1", "latched 1 once the grip crushed the object"),
        Signal(BELT_COMMAND_MRAD_S, "mrad/s", "motor velocity the belt node commands"),
        Signal(BELT_VELOCITY_MRAD_S, "mrad/s", "belt motor velocity (+ force belt, - slip belt)"),
        Signal(BELT_TAP_HZ, "Hz", "force-belt tap frequency on the wearer's skin"),
        Signal(BELT_SURFACE_MM_S, "mm/s", "slip-belt surface speed on the wearer's skin"),
        Signal(WEARER_LEVEL, "level 0..5", "wearer's contraction level e0..e5 (thesis ch. 2.3)"),
        Signal(
            WEARER_PERCEIVED,
            "level, signed",
            "belt level the wearer last identified: +k force belt, -k slip belt, 0 nothing",
        ),
        Signal(SKIN_FORCE_N, "N", "force the skin's FSR reads"),
        Signal(EMG_RAW_UV, "uV", "surface EMG at the electrode"),
    )
}

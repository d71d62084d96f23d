"""Named object-dictionary indices shared by the EDS files, devices and gateway.

The EDS files in this package are the source of truth for types, access,
limits, defaults and units; this module only names the indices so code does
not carry magic numbers. A test checks every name here exists in its EDS.
"""

from __future__ import annotations

from grasplink.profiles.kinds import BY_NODE_ID, node_kind

# --- Communication profile area (CiA 301), on every node -------------------
DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
ERROR_HISTORY = 0x1003  # pre-defined error field
COB_ID_SYNC = 0x1005
DEVICE_NAME = 0x1008
HARDWARE_VERSION = 0x1009
SOFTWARE_VERSION = 0x100A
STORE_PARAMETERS = 0x1010  # sub1 all, sub2 communication, sub3 application
RESTORE_DEFAULTS = 0x1011  # same sub-indices
COB_ID_EMCY = 0x1014
EMCY_INHIBIT_100US = 0x1015
HEARTBEAT_CONSUMER = 0x1016  # subN = node_id << 16 | time_ms
HEARTBEAT_PRODUCER_MS = 0x1017
IDENTITY = 0x1018  # sub1 vendor, sub2 product, sub3 revision, sub4 serial
ERROR_BEHAVIOUR = 0x1029  # sub1: communication error -> 0 pre-op, 1 no change, 2 stopped
SDO_SERVER = 0x1200
RPDO_COMM = 0x1400
RPDO_MAP = 0x1600
TPDO_COMM = 0x1800
TPDO_MAP = 0x1A00

STORE_SIGNATURE = 0x65766173  # "save" little endian
RESTORE_SIGNATURE = 0x64616F6C  # "load" little endian

# --- Skin sensor node (CiA 404 style measuring device) ---------------------
SKIN_SAMPLE_SLOTS = 0x2100  # ARRAY U16 [ADC counts], sub1..3, mapped to TPDO1
SKIN_PACKET_SEQUENCE = 0x2101  # U8, +1 per TPDO1 packet (wraps), for loss detection
SKIN_SAMPLE_COUNTER = 0x2102  # U32, samples acquired since boot
SKIN_STATIC_FORCE_MN = 0x2110  # I32 [mN]
SKIN_SAMPLE_RATE_HZ = 0x2120  # U16 [Hz]
SKIN_SAMPLES_PER_PDO = 0x2121  # U8, 1..3
SKIN_PACKETS_ON_SYNC = 0x2122  # U8: 1 = a synchronous TPDO1 carries every packet since
SKIN_FSR_CALIBRATION = 0x2130  # RECORD: sub1 ADC bits, sub2 full scale [mN], sub3 zero [counts]
SKIN_RIDGE_SPACING_UM = 0x2140  # ARRAY U32 [µm]; sub0 = number of spacings (1..40)
SKIN_LAYOUT_PRESET = 0x2141  # U8: 0 custom, 1..7 named layouts (profiles.layouts)
SKIN_RIDGE_SIDE_UM = 0x2142  # U32 [µm], side of the triangular ridge section

# --- EMG node ---------------------------------------------------------------
EMG_ENVELOPE_UV = 0x2200  # U16 [µV], rectified and smoothed
EMG_LEVEL = 0x2201  # U8: 0 = e0 (below e_min) .. 5 = e5 (above e_max)
EMG_ENVELOPE_SEQUENCE = 0x2202  # U8, +1 per envelope update
EMG_RAW_SLOTS = 0x2203  # ARRAY I16 [µV], sub1..3, mapped to TPDO2 (raw stream)
EMG_RAW_SEQUENCE = 0x2204  # U8, +1 per raw packet
EMG_SAMPLE_RATE_HZ = 0x2210  # U16 [Hz]
EMG_WINDOW_MS = 0x2211  # U16 [ms], envelope smoothing window
EMG_ENVELOPE_PERIOD_MS = 0x2212  # U16 [ms], envelope update period
EMG_PACKETS_ON_SYNC = 0x2213  # U8: 1 = synchronous TPDO1/2 carry every packet since
EMG_CALIBRATION = 0x2220  # RECORD: sub1 e_min [µV], sub2 e_max [µV]

# --- CiA 402 drive objects (belt and hand) ---------------------------------
ERROR_CODE = 0x603F
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
QUICK_STOP_OPTION = 0x605A
MODES_OF_OPERATION = 0x6060
MODES_OF_OPERATION_DISPLAY = 0x6061
SUPPORTED_DRIVE_MODES = 0x6502

# --- Haptic belt node (CiA 402, profile velocity mode) ---------------------
BELT_VELOCITY_ACTUAL_MRAD_S = 0x606C  # I32 [mrad/s]; >0 force belt, <0 slip belt
BELT_MAX_PROFILE_VELOCITY_MRAD_S = 0x607F  # U32 [mrad/s]
BELT_PROFILE_ACCELERATION = 0x6083  # U32 [mrad/s^2]
BELT_PROFILE_DECELERATION = 0x6084  # U32 [mrad/s^2]
BELT_QUICK_STOP_DECELERATION = 0x6085  # U32 [mrad/s^2]
BELT_TARGET_VELOCITY_MRAD_S = 0x60FF  # I32 [mrad/s]
BELT_TAP_FREQUENCY_MHZ = 0x2300  # U32 [mHz], force belt display
BELT_SURFACE_SPEED_MM_S = 0x2301  # U16 [mm/s], slip belt display
BELT_ACTIVE = 0x2302  # U8: 0 none, 1 force belt, 2 slip belt
BELT_NUB_COUNT = 0x2310  # U8, nubs on the force belt
BELT_EFFECTIVE_RADIUS_UM = 0x2311  # U32 [µm], slip belt

# --- Hand (grip actuator) node (CiA 402, manufacturer grip-force mode) -----
HAND_TARGET_GRIP_MN = 0x2400  # U32 [mN]
HAND_ACTUAL_GRIP_MN = 0x2401  # U32 [mN]
HAND_CRUSH_LIMIT_MN = 0x2402  # U32 [mN], targets above are limited
HAND_MAX_GRIP_MN = 0x2403  # U32 [mN], const
HAND_GRIP_RATE_MN_S = 0x2404  # U32 [mN/s], slew of the grip-force loop

# Belt limits from SPEC.md (ch. 8): force belt <= 8 rad/s, slip belt 2.0..7.4 rad/s.
FORCE_BELT_MAX_MRAD_S = 8000
SLIP_BELT_MIN_MRAD_S = 2000
SLIP_BELT_MAX_MRAD_S = 7400

# Modes of operation
MODE_PROFILE_VELOCITY = 3
MODE_GRIP_FORCE = -1  # manufacturer-specific (negative values, CiA 402)

# Default node-IDs
GATEWAY_NODE_ID = 0x01
# kind -> its default node-ID, from the registry (kinds.py)
DEFAULT_NODE_IDS = {kind: node_kind(kind).node_id for kind in BY_NODE_ID}

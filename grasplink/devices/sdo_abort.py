"""SDO abort codes (CiA 301, 7.2.4.3.17) and the exception that carries one."""

from __future__ import annotations

from enum import IntEnum


class AbortCode(IntEnum):
    TOGGLE_BIT = 0x05030000
    TIMEOUT = 0x05040000
    COMMAND_SPECIFIER = 0x05040001
    BLOCK_SIZE = 0x05040002
    SEQUENCE_NUMBER = 0x05040003
    CRC = 0x05040004
    OUT_OF_MEMORY = 0x05040005
    UNSUPPORTED_ACCESS = 0x06010000
    WRITE_ONLY = 0x06010001  # attempt to read a write-only object
    READ_ONLY = 0x06010002  # attempt to write a read-only object
    NO_OBJECT = 0x06020000
    NOT_MAPPABLE = 0x06040041
    PDO_TOO_LONG = 0x06040042
    PARAMETER_INCOMPATIBLE = 0x06040043
    INTERNAL_INCOMPATIBLE = 0x06040047
    HARDWARE_ERROR = 0x06060000
    LENGTH_MISMATCH = 0x06070010
    LENGTH_TOO_HIGH = 0x06070012
    LENGTH_TOO_LOW = 0x06070013
    NO_SUBINDEX = 0x06090011
    INVALID_VALUE = 0x06090030
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    MAX_LESS_THAN_MIN = 0x06090036
    GENERAL = 0x08000000
    CANNOT_TRANSFER = 0x08000020
    LOCAL_CONTROL = 0x08000021
    DEVICE_STATE = 0x08000022
    NO_DATA = 0x08000024


class SdoAbort(Exception):
    """Raised by object access; the SDO server turns it into an abort frame."""

    def __init__(self, code: int, detail: str = ""):
        self.code = int(code)
        self.detail = detail
        try:
            name = AbortCode(self.code).name
        except ValueError:
            name = "UNKNOWN"
        super().__init__(f"SDO abort 0x{self.code:08X} ({name}){': ' + detail if detail else ''}")

"""The boundary between protocol engines (SDO server) and the object store."""

from __future__ import annotations

from typing import Protocol


class ObjectAccess(Protocol):
    """What the SDO server needs from a device's object dictionary.

    Both methods raise `SdoAbort` with the CiA 301 code for anything the
    device refuses (no object, wrong access, wrong length, value range...).
    """

    def sdo_read(self, index: int, subindex: int) -> bytes:
        """The encoded value of an entry, as it would be sent (little endian)."""
        ...

    def sdo_write(self, index: int, subindex: int, data: bytes) -> None:
        """Check and store an encoded value; side effects happen here."""
        ...

"""Conformance cases 4.1-4.9: the object dictionary against the EDS.

Every object and sub-index the EDS file lists is visited (not only a sample),
on a freshly booted node. Live values the device produces itself — ro,
PDO-mappable process inputs such as the statusword, the error register or the
skin's sample counter — have no fixed value, so their EDS DefaultValue is not
compared. CiA 306 ObjFlags are honoured (bit 0: refuse write on download,
bit 1: refuse read on scan); none of the grasplink EDS files sets any.
"""

from __future__ import annotations

import struct

import pytest

from grasplink.profiles import objects as obj
from tests.conformance.conftest import (
    ABORT_CANNOT_TRANSFER,
    ABORT_NO_SUBINDEX,
    ABORT_READ_ONLY,
    ABORT_VALUE_HIGH,
    ABORT_VALUE_LOW,
    ABORT_WRITE_ONLY,
    MAPPING_LOCKED,
    Dut,
    EdsEntry,
    SdoAbort,
    mapping_locked,
    records,
)

COMMAND_OBJECTS = (obj.STORE_PARAMETERS, obj.RESTORE_DEFAULTS)


def expected_default(entry: EdsEntry) -> bytes:
    return entry.encode(entry.var.default)


def check_read(dut: Dut, entry: EdsEntry) -> bytes:
    data = dut.read(entry.index, entry.subindex)
    if entry.size is not None:
        assert len(data) == entry.size, f"{entry}: {len(data)} bytes, type has {entry.size}"
    return data


def check_write_back(dut: Dut, entry: EdsEntry) -> None:
    """Write the value just read; where CiA 301 refuses such a write, check the refusal."""
    value = dut.read(entry.index, entry.subindex)
    if entry.index in COMMAND_OBJECTS and entry.subindex:
        # Reading gives the capability flag; as a write it is a wrong signature.
        code = dut.abort_of(dut.write, entry.index, entry.subindex, value)
        assert code == ABORT_CANNOT_TRANSFER, f"{entry}: 0x{code:08X}"
        return
    try:
        dut.write(entry.index, entry.subindex, value)
    except SdoAbort as exc:
        assert mapping_locked(dut, entry.index, entry.subindex) and exc.code in MAPPING_LOCKED, (
            f"{entry}: write-back refused with 0x{exc.code:08X}"
        )
    assert dut.read(entry.index, entry.subindex) == value, str(entry)


def check_write_refused(dut: Dut, entry: EdsEntry) -> None:
    value = dut.read(entry.index, entry.subindex) if entry.readable else b"\0" * (entry.size or 1)
    code = dut.abort_of(dut.write, entry.index, entry.subindex, value)
    assert code == ABORT_READ_ONLY, f"{entry}: 0x{code:08X}"


def test_4_1_access_by_access_type(dut: Dut) -> None:
    """4.1 OD 01: "Test access object according to access type."

    Every readable entry (ro, const, rw, rwr, rww) uploads, with exactly the
    size of its data type (strings: any length); wo entries refuse the read
    with 0x06010001.
    """
    for entry in dut.entries:
        if entry.readable:
            check_read(dut, entry)
        else:
            code = dut.abort_of(dut.read, entry.index, entry.subindex)
            assert code == ABORT_WRITE_ONLY, str(entry)


def test_4_2_compare_with_eds_default(dut: Dut) -> None:
    """4.2 OD 02: "Compare the read value against the default value in the EDS if it exists."

    Every readable entry with a DefaultValue ($NODEID resolved) reads exactly
    that value after boot — except live process inputs (ro + PDO-mappable),
    which the device updates itself.
    """
    compared = 0
    for entry in dut.entries:
        if entry.readable and entry.has_default and not entry.is_process_input:
            assert check_read(dut, entry) == expected_default(entry), str(entry)
            compared += 1
    assert compared > 50


def test_4_3_write_read_only(dut: Dut) -> None:
    """4.3 OD 03: "If the access type is [ro] try write access."

    Every ro and const entry refuses a write (of its own current value) with
    0x06010002 and keeps its value.
    """
    for entry in dut.entries:
        if entry.access in ("ro", "const"):
            before = dut.read(entry.index, entry.subindex)
            check_write_refused(dut, entry)
            if not entry.is_process_input:
                assert dut.read(entry.index, entry.subindex) == before, str(entry)


def test_4_4_read_write_only(dut: Dut) -> None:
    """4.4 OD 04: "If the access type is [wo] try read access."

    Every wo entry refuses a read with 0x06010001. No grasplink EDS has a wo
    entry, so the case does not apply.
    """
    write_only = [e for e in dut.entries if e.access == "wo"]
    if not write_only:
        pytest.skip(f"{dut.kind}.eds has no write-only (wo) entry")
    for entry in write_only:
        assert dut.abort_of(dut.read, entry.index, entry.subindex) == ABORT_WRITE_ONLY


def test_4_5_subindex_255(dut: Dut) -> None:
    """4.5 OD 05: "If the sub-index 255 exists, compare it to data type and object type in EDS."

    Sub-index FFh of every ARRAY/RECORD: if the device has it, it is the
    UNSIGNED32 (data type << 8 | object type) of CiA 301 7.4.3 and the object
    type matches the EDS; if not (the EDS files list none), the read aborts
    with 0x06090011.
    """
    for index in records(dut):
        object_type = next(e.object_type for e in dut.entries if e.index == index)
        try:
            data = dut.read(index, 0xFF)
        except SdoAbort as exc:
            assert exc.code == ABORT_NO_SUBINDEX, f"{index:04X}h:FF 0x{exc.code:08X}"
            assert not any(e.index == index and e.subindex == 0xFF for e in dut.entries)
            continue
        value = struct.unpack("<I", data)[0]
        assert value & 0xFF == object_type, f"{index:04X}h:FF = 0x{value:08X}"


def out_of_range(entry: EdsEntry) -> list[tuple[int, int]]:
    """(value, expected abort) just beyond the EDS limits, where the type can carry it."""
    cases = []
    for limit, step, code in (
        (entry.var.max, 1, ABORT_VALUE_HIGH),
        (entry.var.min, -1, ABORT_VALUE_LOW),
    ):
        if limit is None:
            continue
        try:
            entry.encode(limit + step)
        except Exception:  # the data type cannot hold it: nothing to test
            continue
        cases.append((limit + step, code))
    return cases


def test_4_6_value_limits(dut: Dut) -> None:
    """4.6 OD 06: "If the access type is [rw], [rwr] or [rww] check the value limits for the object,
    if they exist."

    For every writable entry with LowLimit/HighLimit: LowLimit-1 aborts with
    0x06090032, HighLimit+1 with 0x06090031 (where the data type can carry
    the value), and the entry keeps its value.
    """
    checked = 0
    for entry in dut.entries:
        if not entry.writable:
            continue
        for value, code in out_of_range(entry):
            before = dut.read(entry.index, entry.subindex)
            got = dut.abort_of(dut.write, entry.index, entry.subindex, entry.encode(value))
            assert got == code, f"{entry} = {value}: 0x{got:08X}"
            assert dut.read(entry.index, entry.subindex) == before, str(entry)
            checked += 1
    assert checked >= 5


def test_4_7_access_matrix(dut: Dut) -> None:
    """4.7 OD 07: "Access object according to access type."

    Read and write every entry as its access type says: const/ro read and
    refuse writes (0x06010002), rw read and take a write of their value (PDO
    mapping entries locked by the mapping procedure refuse it; 1010h/1011h
    refuse it as a wrong signature, 0x08000020), wo refuse reads (0x06010001).
    """
    for entry in dut.entries:
        if entry.readable:
            check_read(dut, entry)
        else:
            assert dut.abort_of(dut.read, entry.index, entry.subindex) == ABORT_WRITE_ONLY
        if entry.writable:
            check_write_back(dut, entry)
        else:
            check_write_refused(dut, entry)


def test_4_8_compare_rw_ro_with_default(dut: Dut) -> None:
    """4.8 OD 08: "Compare an object of type [rw] or [ro] against the default value in the EDS,
    dependent on the value of the ObjFlag in EDS."

    Every rw and ro entry without ObjFlags bit 1 (refuse read on scan) reads
    its EDS default after boot; live process inputs excepted (see module).
    """
    for entry in dut.entries:
        if entry.access not in ("rw", "ro") or entry.refuse_read_on_scan:
            continue
        if entry.has_default and not entry.is_process_input:
            assert dut.read(entry.index, entry.subindex) == expected_default(entry), str(entry)


def test_4_9_rw_write_back(dut: Dut) -> None:
    """4.9 OD 09: "If object is of type [rw] read the value from the device and write it back,
    dependent on the value of the ObjFlag in EDS."

    Every rw entry without ObjFlags bit 0 (refuse write on download) takes
    its own value back and reads the same afterwards. Exceptions CiA 301
    prescribes: PDO mapping entries of a valid PDO (or with sub-index 0 not
    0) refuse the write; 1010h/1011h sub-indices read as capability flags
    and refuse them as a wrong signature (0x08000020).
    """
    for entry in dut.entries:
        if entry.access == "rw" and not entry.refuse_write_on_download:
            check_write_back(dut, entry)

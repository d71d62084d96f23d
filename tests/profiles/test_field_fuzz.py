"""A malformed or hostile EDS/DCF never crashes the field loader.

Real files (tests/profiles/field and our own four) are mutated with a fixed
seed: truncated, bytes flipped, lines duplicated, dropped, re-cased or given
junk values, blocks of lines repeated. Every outcome must be a dictionary with
warnings naming file and line, or an EdsError naming file and line; any other
exception, or canopen refusing what the loader repaired, fails the test.
"""

from __future__ import annotations

import random
from pathlib import Path

import canopen
import pytest

from grasplink.errors import EdsError
from grasplink.profiles import eds_path
from grasplink.profiles.field import load_object_dictionary
from grasplink.profiles.kinds import KINDS

FIELD = Path(__file__).resolve().parent / "field"
SEEDS = sorted(p for p in FIELD.iterdir() if p.suffix in (".eds", ".dcf")) + [
    eds_path(kind) for kind in KINDS
]
CASES = 300
JUNK = [
    b"",
    b"0x",
    b"$NODEID",
    b"$NODEID+",
    b"-1",
    b"0xFFFFFFFFFFFFFFFFFFFF",
    b"010",
    b"09",
    b"=",
    b"[",
    b"]",
    b"\x00",
    b"\xff\xfe",
    b"\xc3",
    b";",
    b"1e400",
    b"nan",
    b"[1018sub1]",
    b"[FFFF]",
    b"[0000]",
    b"[0040sub1]",
    b"[1000Name]",
    b"[1003Value]",
    b"NrOfEntries=99",
    b"CompactSubObj=300",
    b"CompactSubObj=2",
    b"ObjectType=0x5",
    b"ObjectType=",
    b"DataType=",
    b"DataType=0x0040",
    b"[DeviceComissioning]",
    b"NodeID=0",
]


def _mutate(data: bytes, rng: random.Random) -> bytes:
    lines = data.split(b"\n")
    for _ in range(rng.randint(1, 6)):
        op = rng.randrange(8)
        if op == 0:
            return b"\n".join(lines)[: rng.randrange(len(data) + 1)]  # truncated
        i = rng.randrange(len(lines)) if lines else 0
        if not lines:
            lines.append(rng.choice(JUNK))
        elif op == 1:  # a byte flipped
            line = bytearray(lines[i])
            if line:
                line[rng.randrange(len(line))] = rng.randrange(256)
            lines[i] = bytes(line)
        elif op == 2:  # a line duplicated elsewhere
            lines.insert(rng.randrange(len(lines)), lines[i])
        elif op == 3:  # a line dropped
            del lines[i]
        elif op == 4:  # a line re-cased
            lines[i] = lines[i].lower() if rng.random() < 0.5 else lines[i].upper()
        elif op == 5:  # a junk value
            lines[i] = lines[i].split(b"=", 1)[0] + b"=" + rng.choice(JUNK)
        elif op == 6:  # a junk line
            lines.insert(i, rng.choice(JUNK))
        else:  # a block of lines repeated
            lines[i:i] = lines[i : i + rng.randrange(1, 40)]
    return b"\n".join(lines)


def test_mutated_field_files_load_or_fail_with_one_eds_error(tmp_path: Path) -> None:
    rng = random.Random(20261129)
    sources = {path: path.read_bytes() for path in SEEDS}
    outcomes = {"loaded": 0, "refused": 0}
    for case in range(CASES):
        seed = rng.choice(SEEDS)
        path = tmp_path / f"case{case}{seed.suffix}"
        data = _mutate(sources[seed], rng)
        path.write_bytes(data)
        node_id = rng.choice([None, 1, 0x22, 127])
        where = f"case {case} from {seed.name}"
        try:
            od, warnings = load_object_dictionary(path, node_id)
        except EdsError as exc:
            assert exc.line is not None, where
            assert str(exc).startswith(f"{path}:{exc.line}"), where
            assert "canopen cannot import" not in str(exc), f"{where}: {exc}"
            outcomes["refused"] += 1
            continue
        except Exception as exc:  # pragma: no cover - the failure being tested for
            pytest.fail(f"{where}: {type(exc).__name__}: {exc}")
        assert isinstance(od, canopen.ObjectDictionary) and len(od) > 0, where
        last = data.count(b"\n") + 1
        for warning in warnings:
            assert warning.path == str(path) and 1 <= warning.line <= last, f"{where}: {warning}"
        outcomes["loaded"] += 1
    assert outcomes["loaded"] > CASES // 2 and outcomes["refused"] > 0, outcomes

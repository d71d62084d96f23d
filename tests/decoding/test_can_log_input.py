"""CAN logs that lost, repeated, reordered or mangled frames (issue 11).

What a log loses is counted by reason, `grasplink decode` prints it on
stderr and refuses (exit 1) a log of which most skin frames were unusable;
frames a few packets out of order are put back by their sequence number.
"""

from __future__ import annotations

import random
from pathlib import Path

import can
import numpy as np
import pytest

from grasplink.cli import main
from grasplink.decoding import io
from grasplink.decoding.base import MIN_USABLE_SHARE
from tests.decoding.test_decode_cli import decode, skin_frames, write_log

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "slip_alpha0.1_20mm_s_forward.toml"
SKIN_ID = 0x190


def only_skin(frames: list[can.Message]) -> list[can.Message]:
    return [m for m in frames if m.arbitration_id == SKIN_ID]


def with_data(msg: can.Message, data: bytes, timestamp: float | None = None) -> can.Message:
    return can.Message(
        timestamp=msg.timestamp if timestamp is None else timestamp,
        arbitration_id=msg.arbitration_id,
        data=data,
        is_extended_id=msg.is_extended_id,
    )


def accounted(stats: io.CanStats) -> bool:
    return stats.frames == stats.packets + stats.dropped


# -- reading -------------------------------------------------------------------------------------
COUNTS = (np.arange(900) * 37) % 4096  # 300 packets: the U8 sequence wraps once


def test_payloads_swapped_in_delivery_are_put_back_by_sequence_number(tmp_path):
    """Reception order != sequence order, time stamps in log order (a reordering bridge)."""
    clean = only_skin(skin_frames(COUNTS))
    swapped = list(clean)
    for k in range(3, len(swapped) - 1, 5):  # swap neighbours, across the wrap too
        a, b = swapped[k], swapped[k + 1]
        swapped[k], swapped[k + 1] = with_data(a, b.data), with_data(b, a.data)
    t0, f0, _ = io.read_can_log(write_log(tmp_path / "clean.asc", clean))
    t, f, stats = io.read_can_log(write_log(tmp_path / "swapped.asc", swapped))
    np.testing.assert_array_equal(t, t0)
    np.testing.assert_array_equal(f, f0)
    assert stats.reordered == len(range(3, len(swapped) - 1, 5))
    assert stats.out_of_order == stats.lost_packets == stats.dropped == 0


def test_frames_shuffled_within_the_window_keep_their_own_time_stamps(tmp_path):
    clean = only_skin(skin_frames(COUNTS))
    rng = random.Random(4)
    shuffled = []
    for start in range(0, len(clean), io.REORDER_PACKETS):
        block = clean[start : start + io.REORDER_PACKETS]
        rng.shuffle(block)
        shuffled += block
    shuffled.insert(0, shuffled.pop(shuffled.index(clean[0])))  # the log starts at its start
    t0, f0, _ = io.read_can_log(write_log(tmp_path / "clean.blf", clean))
    t, f, stats = io.read_can_log(write_log(tmp_path / "shuffled.blf", shuffled))
    np.testing.assert_allclose(t, t0, atol=2e-6)
    np.testing.assert_array_equal(f, f0)
    assert stats.reordered > 0 and stats.dropped == 0 and stats.lost_packets == 0


def test_a_frame_later_than_the_window_is_dropped_not_counted_lost(tmp_path):
    clean = only_skin(skin_frames(COUNTS))
    late = list(clean)
    moved = late.pop(50)
    late.insert(50 + io.REORDER_PACKETS + 4, moved)
    t, _, stats = io.read_can_log(write_log(tmp_path / "late.asc", late))
    assert stats.out_of_order == 1
    assert stats.lost_packets == 0  # the frame is in the log, just too late to use
    assert stats.packets == len(clean) - 1 and accounted(stats)
    assert len(t) == 3 * (len(clean) - 1)


def test_repeated_sequence_numbers_are_re_publishes(tmp_path):
    clean = only_skin(skin_frames(COUNTS[:60]))
    doubled = []
    for m in clean:
        doubled += [m, with_data(m, m.data, m.timestamp + 1e-4)]
    t, _, stats = io.read_can_log(write_log(tmp_path / "doubled.asc", doubled))
    assert stats.republished == len(clean)
    assert stats.packets == len(clean) and accounted(stats)
    assert len(t) == 60


@pytest.mark.parametrize("seed", range(5))
def test_every_frame_is_accounted_for_however_the_log_is_mangled(tmp_path, seed):
    rng = random.Random(seed)
    frames = only_skin(skin_frames(COUNTS))
    mangled = []
    for m in frames:
        roll = rng.random()
        if roll < 0.1:
            mangled.append(with_data(m, bytes(m.data)[:4]))  # truncated
        elif roll < 0.2:
            mangled += [m, m]  # repeated
        elif roll < 0.25:
            continue  # lost
        else:
            mangled.append(m)
    for _ in range(20):  # some far out of order
        k = rng.randrange(1, len(mangled) - 30)
        mangled.insert(k + rng.randrange(10, 30), mangled.pop(k))
    _, _, stats = io.read_can_log(write_log(tmp_path / "mangled.asc", mangled))
    assert stats.frames == len(mangled)
    assert accounted(stats)
    assert stats.malformed == sum(1 for m in mangled if len(m.data) != 7)


def test_summary_names_every_reason(tmp_path):
    frames = skin_frames(COUNTS[:300])
    skin = [k for k, m in enumerate(frames) if m.arbitration_id == SKIN_ID]
    frames[skin[5]] = with_data(frames[skin[5]], b"\x01\x02")
    frames.insert(skin[9], frames[skin[8]])
    _, _, stats = io.read_can_log(write_log(tmp_path / "log.asc", frames))
    line = stats.summary("log.asc")
    assert line.startswith(f"log.asc: {len(frames)} frames read; skin TPDO1 (0x190): ")
    assert f"{stats.frames} frames, {stats.packets} used" in line
    assert "1 wrong data length" in line and "1 repeated sequence number" in line
    assert "1 packets missing" in line  # the truncated frame's number never arrived
    assert "frames of other CAN-IDs (0x710)" in line


# -- grasplink decode on a real run's log ---------------------------------------------------
@pytest.fixture(scope="module")
def run_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    assert main(["run", str(SCENE), "--out", str(out)]) == 0
    return out, list(can.LogReader(str(out / "can.asc")))


def write_asc(path: Path, frames: list[can.Message]) -> Path:
    writer = can.ASCWriter(str(path))
    for m in frames:
        writer.on_message_received(m)
    writer.stop()
    return path


def decode_log(capsys, path: Path) -> tuple[int, list[dict], list[str]]:
    rc, lines, err = decode(capsys, path, "--skin", "alpha0.1", "--decoder", "ratio")
    return rc, lines, err.splitlines()


def test_decode_reports_a_third_of_frames_malformed(tmp_path, capsys, run_log):
    _, frames = run_log
    skin = [k for k, m in enumerate(frames) if m.arbitration_id == SKIN_ID]
    broken = list(frames)
    third = skin[1:-1:3]  # not the last: nothing after it would tell it was missing
    for k in third:
        broken[k] = with_data(broken[k], bytes(broken[k].data)[:5])
    rc, lines, err = decode_log(capsys, write_asc(tmp_path / "third.asc", broken))
    assert rc == 0 and lines
    summary = err[0]
    assert summary.startswith("grasplink: ") and f"{len(frames)} frames read" in summary
    assert f"skin TPDO1 (0x190): {len(skin)} frames" in summary
    assert f"{len(third)} wrong data length" in summary
    assert f"{len(third)} packets missing from the sequence numbers" in summary


def test_decode_refuses_a_log_with_most_frames_malformed(tmp_path, capsys, run_log):
    _, frames = run_log
    skin = [k for k, m in enumerate(frames) if m.arbitration_id == SKIN_ID]
    broken = list(frames)
    for k in skin[: int(0.6 * len(skin))]:
        broken[k] = with_data(broken[k], bytes(broken[k].data)[:5])
    rc, lines, err = decode_log(capsys, write_asc(tmp_path / "most.asc", broken))
    assert rc == 1 and not lines
    assert len(err) == 2 and "wrong data length" in err[0]
    assert err[1].startswith("grasplink: error: ") and "skin TPDO1 frames usable" in err[1]
    assert f"below {MIN_USABLE_SHARE:.0%}" in err[1]


def test_decode_refuses_a_shuffled_log(tmp_path, capsys, run_log):
    _, frames = run_log
    shuffled = frames[1:]
    random.Random(2).shuffle(shuffled)
    path = write_asc(tmp_path / "shuffled.asc", [frames[0], *shuffled])  # its start first
    rc, lines, err = decode_log(capsys, path)
    assert rc == 1 and not lines
    # each frame keeps its own time stamp, seconds from its number's place in the log
    assert "time stamp far from its sequence number's place" in err[0] and "error: " in err[1]


def test_decode_of_a_locally_reordered_log_equals_the_original(tmp_path, capsys, run_log):
    out, frames = run_log
    skin = [k for k, m in enumerate(frames) if m.arbitration_id == SKIN_ID]
    swapped = list(frames)
    for a, b in zip(skin[10::6], skin[11::6], strict=False):
        swapped[a] = with_data(frames[a], frames[b].data)
        swapped[b] = with_data(frames[b], frames[a].data)
    rc, original, _ = decode_log(capsys, out / "can.asc")
    rc2, lines, err = decode_log(capsys, write_asc(tmp_path / "swapped.asc", swapped))
    assert rc == rc2 == 0
    assert lines == original
    assert "put back in order by sequence number" in err[0]


def test_decode_of_a_log_with_a_time_jump_resets_and_stays_bounded(tmp_path, capsys, run_log):
    _, frames = run_log
    half = len(frames) // 2
    jumped = frames[:half] + [with_data(m, m.data, m.timestamp + 1e5) for m in frames[half:]]
    rc, lines, err = decode_log(capsys, write_asc(tmp_path / "jump.asc", jumped))
    assert rc == 0
    assert len(lines) <= (frames[-1].timestamp - frames[0].timestamp) / 0.01 + 3
    assert not [d for d in lines if frames[half - 1].timestamp + 0.01 < d["t_s"] < 1e5]
    assert "1 gap(s)" in err[-1] and "longest 100000 s" in err[-1]

"""PEAK PCAN-View traces (.trc) in `grasplink record`, `replay` and `decode` (issue 21, item 9).

python-can reads and writes TRC (TRCReader/TRCWriter through can.LogReader/can.Logger);
grasplink refused it for record and replay and parsed it as CSV in decode.
"""

from __future__ import annotations

import os
import threading
from itertools import count

import can
import numpy as np

from grasplink.bus import open_bus
from grasplink.bus.logs import read_log, record_bus, scan_log
from grasplink.cli import main
from grasplink.core.frames import TPDO_BASES
from grasplink.decoding import io
from tests.decoding.test_decode_cli import decode, skin_frames, write_log

_channels = count()


def _channel() -> str:
    return f"virtual:trc-{os.getpid()}-{next(_channels)}"


def test_recording_a_trc_keeps_every_data_frame_and_counts_what_trc_cannot_hold(tmp_path):
    url = _channel()
    recorder, sender = open_bus(url), open_bus(url)
    frames = [
        can.Message(
            arbitration_id=TPDO_BASES[0] + 0x10, data=bytes([i, 2, 3]), is_extended_id=False
        )
        for i in range(20)
    ]
    remote = can.Message(arbitration_id=0x710, is_remote_frame=True, is_extended_id=False)
    try:
        for frame in [*frames[:10], remote, *frames[10:]]:
            sender.send(frame)
        path = tmp_path / "bus.trc"
        stats = record_bus(recorder, path, duration_s=0.3)
    finally:
        recorder.shutdown()
        sender.shutdown()
    assert stats.frames == len(frames) and stats.left_out == 1
    back = list(read_log(path))
    assert [(m.arbitration_id, bytes(m.data)) for m in back] == [
        (m.arbitration_id, bytes(m.data)) for m in frames
    ]
    assert scan_log(path).frames == len(frames)


def test_record_command_writes_a_trc_and_says_what_it_left_out(tmp_path, capsys):
    url = _channel()
    sender = open_bus(url)
    path = tmp_path / "cli.trc"
    sent = threading.Event()

    def send_while_recording() -> None:
        sent.wait(5)
        sender.send(can.Message(arbitration_id=0x190, data=b"\x01", is_extended_id=False))
        sender.send(can.Message(arbitration_id=0x710, is_remote_frame=True, is_extended_id=False))

    thread = threading.Thread(target=send_while_recording)
    thread.start()
    try:
        # the recording opens its bus first; the frames go once it listens
        threading.Timer(0.3, sent.set).start()
        assert main(["record", str(path), "--bus", url, "--duration", "1.0"]) == 0
    finally:
        thread.join(5)
        sender.shutdown()
    out = capsys.readouterr().out
    assert "(PEAK PCAN-View trace)" in out
    assert "1 frames, 1 error/remote frames left out" in out
    assert [bytes(m.data) for m in can.LogReader(str(path))] == [b"\x01"]


def test_replay_command_sends_every_frame_of_a_trc(tmp_path, capsys):
    path = tmp_path / "short.trc"
    with can.Logger(str(path)) as writer:
        for i in range(5):
            writer.on_message_received(
                can.Message(
                    timestamp=i * 0.01, arbitration_id=0x190, data=bytes([i]), is_extended_id=False
                )
            )
    url = _channel()
    listener = open_bus(url)
    try:
        assert main(["replay", str(path), "--bus", url, "--speed", "4"]) == 0
        got = [listener.recv(1.0) for _ in range(5)]
    finally:
        listener.shutdown()
    assert [bytes(m.data) for m in got if m is not None] == [bytes([i]) for i in range(5)]
    assert "sent 5 frames" in capsys.readouterr().out


def test_decode_reads_a_trc_as_the_same_log_in_candump(tmp_path, capsys):
    """candump -L keeps absolute times to the µs, as TRC (its start time and offsets) does."""
    frames = skin_frames((np.arange(900) * 37) % 4096, drop=(40,), repeat=(80,))
    asc = write_log(tmp_path / "skin.log", frames)
    trc = write_log(tmp_path / "skin.trc", frames)
    t_asc, f_asc, _ = io.read_can_log(asc)
    t_trc, f_trc, stats = io.read_can_log(trc)
    np.testing.assert_array_equal(t_trc, t_asc)
    np.testing.assert_array_equal(f_trc, f_asc)
    assert stats.lost_packets == 1 and stats.republished == 1
    args = ("--skin", "alpha0.1", "--decoder", "ratio")
    rc_asc, lines_asc, _ = decode(capsys, asc, *args)
    rc_trc, lines_trc, err = decode(capsys, trc, *args)
    assert rc_asc == rc_trc == 0 and lines_trc == lines_asc and lines_trc
    assert "skin TPDO1 (0x190): 300 frames" in err

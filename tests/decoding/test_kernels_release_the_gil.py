"""A compiled kernel releases the GIL for its call, so the live gateway's heartbeat thread
(the runner's pacer) runs while the decoder is inside a contact step."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from grasplink.decoding.kernels.detector import sos_run


@pytest.mark.slow
def test_another_python_thread_runs_while_a_kernel_is_in_its_call() -> None:
    # A Python thread notes the time of each of its loops. While a kernel holds the GIL no
    # Python thread runs at all, so none of those times could fall in the kernel's call
    # (beyond the switch before it starts); with the GIL released they fill it.
    seen_s: list[float] = []
    stop = threading.Event()

    def note_times() -> None:
        while not stop.is_set():
            seen_s.append(time.monotonic())
            time.sleep(0)

    sos = np.array([[1.0, 0.5, 0.25, 1.0, -0.5, 0.1]] * 4)
    state = np.zeros((4, 2))
    x = np.ones(20_000_000)
    out = np.empty_like(x)
    sos_run(sos, state, x[:10], out[:10])  # compiled or loaded before the measured call
    noter = threading.Thread(target=note_times, daemon=True)
    noter.start()
    while not seen_s:  # the noter is running
        time.sleep(0.001)
    started_s = time.monotonic()
    sos_run(sos, state, x, out)
    ended_s = time.monotonic()
    stop.set()
    noter.join(5.0)
    call_s = ended_s - started_s
    # Inside the call, clear of its edges: a thread waiting for the GIL also runs in the
    # switch just before the kernel starts and just after it returns (ended_s is read
    # after that switch), so times there prove nothing.
    inside = [t for t in seen_s if started_s + 0.1 * call_s < t < ended_s - 0.1 * call_s]
    assert inside, f"no other thread ran inside a {call_s * 1e3:.0f} ms kernel call"

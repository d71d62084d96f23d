"""Asking the host to run a thread ahead of ordinary work: real-time if allowed, else nice.

Why: a thread that produces a heartbeat others watch (CiA 301 1016h) must wake on time
on a loaded machine; at the default priority it waits its turn behind every busy
process. Linux applies both the scheduling policy and the nice value per thread.
"""

from __future__ import annotations

import os
import threading

RT_PRIORITY = 10  # SCHED_FIFO 1..99: above ordinary work, below the kernel's own threads
NICE = -10


def raise_thread_priority(rt_priority: int = RT_PRIORITY, nice: int = NICE) -> tuple[bool, str]:
    """Raise the calling thread: SCHED_FIFO `rt_priority`, or failing that nice `nice`.

    Returns (real-time granted, what the thread got and why, for a log line). Never
    raises: a host that refuses both leaves the thread as it was.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
        return True, f"SCHED_FIFO priority {rt_priority}"
    except (OSError, AttributeError) as exc:  # EPERM without CAP_SYS_NICE; not Linux
        refused = f"real-time scheduling refused ({_why(exc)})"
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
        return False, f"nice {nice}: {refused}"
    except (OSError, AttributeError) as exc:
        return False, f"normal priority: {refused}, nice {nice} refused ({_why(exc)})"


def raise_thread_nice(nice: int = NICE) -> tuple[bool, str]:
    """Lower the calling thread's nice value to `nice` (ahead of ordinary work, still
    sharing the CPU: for a thread whose work can grow, like decoding, real-time would let
    it starve the host). Returns (granted, what the thread got, for a log line)."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
        return True, f"nice {nice}"
    except (OSError, AttributeError) as exc:
        return False, f"normal priority: nice {nice} refused ({_why(exc)})"


def _why(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__

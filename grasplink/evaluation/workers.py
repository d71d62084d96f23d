"""Independent tasks on every local core or on a Dask cluster, with results in task order.

Studies (the loop trials, the skin-layout search) are many independent tasks; `open_workers`
gives one way to run them: in this process (1 worker), in local processes (default: all
cores) or on a Dask distributed cluster (`dask="tcp://HOST:PORT"`, the engine a study uses
when it outgrows one machine). Results never depend on who ran a task or when it finished:
`map` returns them in task order, and a task's randomness comes from `derive_seed` (the
run's seed and the task's identity), never from the worker or the order of completion.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Callable, Iterable, Sequence
from types import TracebackType
from typing import Any, TypeVar

from grasplink.errors import ConfigError

T = TypeVar("T")
R = TypeVar("R")

#: How long to wait for a Dask scheduler (and for its first worker) before giving up: long
#: enough for a LAN, short enough that a wrong address fails before any work starts.
CONNECT_TIMEOUT_S = 5.0
DASK_ADDRESS = re.compile(r"^(tcp|tls)://[^\s/:]+:\d{1,5}$")

Progress = Callable[[int, int], None]  # (tasks done, tasks in all)


def derive_seed(run_seed: int, *identity: object) -> int:
    """A task's seed: a hash of the run's seed and what the task is (< 2**63).

    `identity` must be plain values whose repr is stable (ints, floats, strings, tuples):
    the same task gets the same seed in any process, on any machine, in any order.
    """
    text = repr((int(run_seed), identity)).encode()
    return int.from_bytes(hashlib.blake2b(text, digest_size=8).digest(), "big") >> 1


def local_cores() -> int:
    """The cores this process may run on (all of the machine's unless pinned)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def check_dask_address(address: str) -> str:
    """`address` if it looks like a scheduler's (tcp://HOST:PORT), else ConfigError."""
    if not DASK_ADDRESS.match(address.strip()):
        raise ConfigError(
            f"--dask {address!r}: expected a Dask scheduler address tcp://HOST:PORT "
            "(as `dask scheduler` prints it)"
        )
    return address.strip()


class Workers:
    """Runs `fn` over tasks; a context manager that releases its processes or connection."""

    kind = "this process"
    count = 1

    def map(
        self, fn: Callable[[T], R], tasks: Iterable[T], progress: Progress | None = None
    ) -> list[R]:
        """`fn(task)` for every task, results in task order; a task's exception is raised."""
        items = list(tasks)
        out = []
        for i, task in enumerate(items, 1):
            out.append(fn(task))
            if progress is not None:
                progress(i, len(items))
        return out

    def describe(self) -> str:
        return f"{self.count} worker{'s' if self.count != 1 else ''} ({self.kind})"

    def close(self) -> None:
        """Release processes or connections (nothing for this process)."""

    def __enter__(self) -> Workers:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class LocalWorkers(Workers):
    """`count` local processes, started fresh (spawn) whatever threads the caller has."""

    kind = "local processes"

    def __init__(self, count: int):
        self.count = count
        self._pool: Any = None

    def map(
        self, fn: Callable[[T], R], tasks: Iterable[T], progress: Progress | None = None
    ) -> list[R]:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        items = list(tasks)
        if self._pool is None:  # started on first use, kept for the next map (a search's)
            context = multiprocessing.get_context("spawn")
            self._pool = ProcessPoolExecutor(self.count, mp_context=context)
        futures = [self._pool.submit(fn, task) for task in items]
        out = []
        for i, future in enumerate(futures, 1):
            out.append(future.result())
            if progress is not None:
                progress(i, len(futures))
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class DaskWorkers(Workers):
    """The workers of a Dask distributed scheduler (they must have grasplink installed)."""

    kind = "Dask"

    def __init__(self, address: str, connect_timeout_s: float = CONNECT_TIMEOUT_S):
        from distributed import Client

        self.address = check_dask_address(address)
        try:
            self._client = Client(self.address, timeout=connect_timeout_s)
        except (OSError, TimeoutError) as exc:
            raise ConfigError(
                f"--dask {self.address}: no Dask scheduler answered within "
                f"{connect_timeout_s:g} s ({type(exc).__name__}); start one with "
                "`dask scheduler` and check the address and the firewall"
            ) from None
        try:
            self._client.wait_for_workers(1, timeout=connect_timeout_s)
        except TimeoutError:
            self._client.close()
            raise ConfigError(
                f"--dask {self.address}: the scheduler has no workers; start some with "
                f"`dask worker {self.address}`"
            ) from None
        self.count = len(self._client.scheduler_info().get("workers", {}))
        self.kind = f"Dask at {self.address}"

    def map(
        self, fn: Callable[[T], R], tasks: Iterable[T], progress: Progress | None = None
    ) -> list[R]:
        from distributed import as_completed

        items = list(tasks)
        if not items:
            return []
        futures = self._client.map(fn, items, pure=False)
        if progress is not None:
            for i, _ in enumerate(as_completed(futures), 1):
                progress(i, len(futures))
        return list(self._client.gather(futures))

    def close(self) -> None:
        self._client.close()


def open_workers(
    workers: int | None = None,
    dask: str | None = None,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
) -> Workers:
    """Workers for a study: Dask at `dask`, else `workers` local processes (None: all cores).

    Connects (or checks the count) now, so a bad address or count is one error before any
    work starts.
    """
    if dask is not None:
        if workers is not None:
            raise ConfigError("give --workers N or --dask ADDRESS, not both")
        return DaskWorkers(dask, connect_timeout_s)
    count = local_cores() if workers is None else workers
    if count < 1:
        raise ConfigError(f"--workers: expected at least 1 process, got {count}")
    return Workers() if count == 1 else LocalWorkers(count)


def run_all(
    fn: Callable[[T], R],
    tasks: Sequence[T],
    workers: int | None = None,
    dask: str | None = None,
    progress: Progress | None = None,
) -> list[R]:
    """`open_workers(...).map(fn, tasks)`: one batch of tasks, workers released after.

    Local processes are capped at the number of tasks (starting more would only cost).
    """
    if dask is None and workers is None:
        workers = local_cores()
    if dask is None and workers is not None and workers > 1:
        workers = max(1, min(workers, len(tasks)))
    with open_workers(workers, dask) as pool:
        return pool.map(fn, tasks, progress)

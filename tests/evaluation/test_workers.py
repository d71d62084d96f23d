"""workers.py: ordered results, per-task seeds, and one clear error for a bad pool or scheduler."""

from __future__ import annotations

import socket
import time

import pytest

from grasplink.controllers import build_controllers
from grasplink.errors import ConfigError
from grasplink.evaluation import loop
from grasplink.evaluation import workers as wk


def later_first(task: tuple[int, int]) -> tuple[int, int]:
    """Task i of n sleeps longer the earlier it is, so the last submitted finishes first."""
    i, n = task
    time.sleep(0.05 * (n - i))
    return i, wk.derive_seed(7, "task", i)


def fails_on_three(i: int) -> int:
    if i == 3:
        raise ValueError("task 3 is bad")
    return i


def test_results_come_in_task_order_with_seeds_from_the_task_not_the_worker():
    tasks = [(i, 6) for i in range(6)]
    here = wk.Workers().map(later_first, tasks)
    with wk.open_workers(2) as pool:
        assert isinstance(pool, wk.LocalWorkers)
        there = pool.map(later_first, tasks)
    assert here == there == [(i, wk.derive_seed(7, "task", i)) for i in range(6)]


def test_a_seed_changes_with_the_run_seed_and_the_task_identity_only():
    seed = wk.derive_seed(1, (19.0, 12.0, 5.0), 0)
    assert seed == wk.derive_seed(1, (19.0, 12.0, 5.0), 0)
    assert seed != wk.derive_seed(2, (19.0, 12.0, 5.0), 0)
    assert seed != wk.derive_seed(1, (19.0, 12.0, 5.0), 1)
    assert seed != wk.derive_seed(1, (19.0, 5.0, 12.0), 0)
    assert 0 <= seed < 2**63


def test_progress_is_told_for_every_task_and_a_task_error_is_raised():
    seen: list[tuple[int, int]] = []
    assert wk.Workers().map(fails_on_three, [0, 1, 2], lambda d, n: seen.append((d, n))) == [
        0,
        1,
        2,
    ]
    assert seen == [(1, 3), (2, 3), (3, 3)]
    with pytest.raises(ValueError, match="task 3"):
        wk.run_all(fails_on_three, [1, 2, 3], workers=2)


def test_one_worker_runs_in_this_process_and_the_default_is_every_core():
    assert type(wk.open_workers(1)) is wk.Workers
    with wk.open_workers() as pool:
        assert pool.count == wk.local_cores()


@pytest.mark.parametrize(
    ("workers", "dask", "message"),
    [
        (0, None, "at least 1 process"),
        (2, "tcp://127.0.0.1:8786", "not both"),
        (None, "127.0.0.1:8786", "tcp://HOST:PORT"),
        (None, "http://127.0.0.1:8786", "tcp://HOST:PORT"),
    ],
)
def test_bad_worker_settings_are_one_clear_error(workers, dask, message):
    with pytest.raises(ConfigError, match=message):
        wk.open_workers(workers, dask)


def test_an_unreachable_scheduler_is_one_error_naming_it():
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    with pytest.raises(ConfigError, match=f"{address}: no Dask scheduler answered"):
        wk.open_workers(dask=address, connect_timeout_s=1.0)


def test_loop_trials_give_the_same_rows_in_one_process_and_on_two():
    trials = [loop.Trial("slip_speed", reflex, 150.0, 3, settle_s=1.0) for reflex in (False, True)]
    one = loop.run_trials(trials, build_controllers, workers=1, log=lambda _: None)
    two = loop.run_trials(trials, build_controllers, workers=2, log=lambda _: None)
    assert one == two
    assert [row["reflex"] for row in two] == [False, True]

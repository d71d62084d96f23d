"""Suite-wide fixtures and the `slow` marker.

`slow` marks tests that run in real (wall-clock) time: threads, sleeps,
subprocesses, the loopback hub, ``--realtime``. ``make test`` runs them all
(in parallel, pytest-xdist); ``make test-fast`` leaves them out. Tests that use
a fixture starting real-time machinery are marked here, so a new test using
one cannot forget it; other real-time tests carry ``@pytest.mark.slow``.

The suite runs in several worker processes at once: a test that needs a file
uses ``tmp_path``, a server binds port 0, and python-can ``virtual`` channels
are private to each process (and named uniquely within it).
"""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest

# Fixtures whose set-up starts threads, sockets or a hub that run on the wall clock.
REALTIME_FIXTURES = frozenset(
    {
        "dut",  # conformance: a device in a NodeRunner thread and a canopen master
        "make_link",  # SDO server pumped by a thread, canopen client (test_sdo_server)
        "hub",  # loopback CAN hub (websocket server thread)
    }
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if REALTIME_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def refused_port() -> Iterator[int]:
    """A local TCP port where a connection is refused, held for the whole test.

    The socket is bound but never listens: connecting gets a reset, and no other
    test or worker can bind the port meanwhile (a port found free and closed
    again could be taken by a parallel worker's hub before the test uses it).
    """
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        yield sock.getsockname()[1]

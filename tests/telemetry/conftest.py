"""Brokers and a gateway stand-in for the telemetry tests (each test its own, stopped after)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.telemetry.broker import FakeGateway, broker, secured

__all__ = ["broker", "fake", "secured"]  # the brokers are shared with tests/view


@pytest.fixture
def fake() -> Iterator[FakeGateway]:
    gateway = FakeGateway()
    yield gateway
    gateway.close()

"""Brokers and a gateway stand-in for the telemetry tests (each test its own, stopped after)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.telemetry.broker import FakeGateway, Mosquitto


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Mosquitto]:
    """mosquitto with anonymous clients allowed."""
    server = Mosquitto(tmp_path / "broker").start()
    yield server
    server.stop()


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[Mosquitto]:
    """mosquitto with a password file and an ACL: gateway, reader (read only), operator."""
    server = Mosquitto(tmp_path / "secured", secured=True).start()
    yield server
    server.stop()


@pytest.fixture
def fake() -> Iterator[FakeGateway]:
    gateway = FakeGateway()
    yield gateway
    gateway.close()

"""A broker (tests/telemetry's: open, or `secured` with its password file and ACL) and a
headless browser for each live-view test (stopped after)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from selenium import webdriver

from grasplink.surfaces.view.snapshot import chromium
from tests.telemetry.broker import broker, secured

__all__ = ["broker", "browser", "secured"]


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[webdriver.Chrome]:
    driver = chromium(tmp_path / "chromium-profile")
    yield driver
    driver.quit()

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


@pytest.fixture(scope="session")
def headline_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The loop headline as `grasplink run` writes it (once: ~40 s of CPU), for the
    recording's tests; the scene named by its absolute path, as summary.json keeps it."""
    from grasplink import cli

    out = tmp_path_factory.mktemp("headline") / "loop-headline"
    scene = Path(__file__).resolve().parents[2] / "scenes" / "loop_headline.toml"
    assert cli.main(["run", str(scene), "--out", str(out)]) == 0
    return out

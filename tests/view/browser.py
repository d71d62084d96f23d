"""Real peers for the browser tests: Debian's headless Chromium driven by selenium through
chromedriver, `grasplink view` and `grasplink gateway` as processes, and waits on what the
page shows (never a fixed sleep)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from selenium import webdriver
from selenium.common.exceptions import TimeoutException
from selenium.webdriver.support.wait import WebDriverWait

GRASPLINK = [sys.executable, "-m", "grasplink.cli"]
PAGE_S = 60.0  # bounds for a loaded machine (load 6 on 2 cores), never waited through


def wait_for_page(driver: webdriver.Chrome, script: str, what: str, timeout_s: float = PAGE_S):
    """Until `script` (JavaScript returning a value) returns something truthy; its value."""
    try:
        return WebDriverWait(driver, timeout_s, poll_frequency=0.1).until(
            lambda d: d.execute_script(script)
        )
    except TimeoutException:
        banner = driver.execute_script("return document.getElementById('banner').textContent")
        raise AssertionError(
            f"the page did not show {what} within {timeout_s} s: {banner}"
        ) from None


def node_phases(driver: webdriver.Chrome) -> dict[str, str]:
    return driver.execute_script(
        "return Object.fromEntries([...document.querySelectorAll('#nodes tbody tr')]"
        ".map((tr) => [tr.dataset.node, tr.dataset.phase]))"
    )


def phases_are(driver: webdriver.Chrome, phase: str, nodes: tuple[str, ...]) -> str:
    """JavaScript true when each of `nodes` shows `phase`."""
    checks = " && ".join(
        f'document.querySelector(\'#nodes tr[data-node="{n}"][data-phase="{phase}"]\')'
        for n in nodes
    )
    return f"return !!({checks})"


def banner_state(driver: webdriver.Chrome) -> str:
    return driver.execute_script("return document.getElementById('banner').dataset.state")


def page_errors(driver: webdriver.Chrome) -> list[dict[str, Any]]:
    return [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]


class Process:
    """A grasplink command as its own process, its output in a file; stopped on close."""

    def __init__(self, args: list[str], log: Path) -> None:
        self.log = log
        with open(log, "wb") as out:
            self.process = subprocess.Popen(
                [*GRASPLINK, *args], stdout=out, stderr=subprocess.STDOUT
            )

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def wait_for_line(self, needle: str, timeout_s: float = 120.0) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            for line in self.output().splitlines():
                if needle in line:
                    return line
            assert self.process.poll() is None, f"exited: {self.output()}"
            assert time.monotonic() < deadline, f"no {needle!r} in {timeout_s} s: {self.output()}"
            time.sleep(0.05)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)


def start_view(mqtt_url: str, folder: Path, *options: str) -> tuple[Process, str]:
    """`grasplink view` on a free port; the process and the page's URL."""
    view = Process(
        ["view", "--mqtt", mqtt_url, "--http", "127.0.0.1:0", *options], folder / "view.log"
    )
    line = view.wait_for_line("view: http://")
    return view, line.split()[1]

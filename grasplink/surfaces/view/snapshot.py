"""A picture of the live page: headless Chromium (selenium and Debian's chromedriver) opens
the view, waits for what was asked and saves a PNG (docs/view.md, `make demo`).

    python -m grasplink.surfaces.view.snapshot URL OUT.png [--until-slip] [--timeout S]
        [--ready-file FILE]

`--ready-file` is written once the page takes frames, so a demo starts the run it wants
pictured only when the browser is watching. selenium is a development dependency (`make
demo` and `make test` install it); the browser tests drive the same browser, same flags.
"""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
import tempfile
from pathlib import Path

from selenium import webdriver
from selenium.common.exceptions import TimeoutException, WebDriverException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.support.wait import WebDriverWait

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
# The bench may have no network and must not reach one: no QUIC, no background fetches, no
# component or sync updates; a fresh profile each time.
CHROMIUM_FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--window-size=1400,1250",
)
TIMEOUT_S = 120.0  # for a loaded machine (load 6 on 2 cores); never waited through when it works
TAKING_FRAMES = "return window.viewStats !== undefined && window.viewStats.frames > 0"
# the skin slipping now with a decoded speed, or (missed between two polls) the last such slip
SLIP_WITH_SPEED = (
    "const now = document.getElementById('slip'), last = document.getElementById('last-slip');"
    "return (now.dataset.slip === 'true' && now.dataset.speed !== '') || last.dataset.speed !== ''"
)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class SnapshotError(Exception):
    """Why no picture was taken: one line."""


def chromium(profile: Path) -> webdriver.Chrome:
    """Headless Chromium through chromedriver, its profile in `profile`, console kept."""
    for path, package in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not Path(path).exists():
            raise SnapshotError(f"{path} missing: apt-get install {package} (make does)")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={profile}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))


def wait_for(driver: webdriver.Chrome, script: str, what: str, timeout_s: float) -> object:
    """Until `script` (JavaScript) returns something truthy; SnapshotError naming `what`
    and the page's banner otherwise."""
    try:
        return WebDriverWait(driver, timeout_s, poll_frequency=0.1).until(
            lambda d: d.execute_script(script)
        )
    except TimeoutException:
        banner = driver.execute_script(
            "const b = document.getElementById('banner'); return b ? b.textContent : '(no page)'"
        )
        raise SnapshotError(f"the page showed no {what} within {timeout_s:g} s: {banner}") from None


def take(
    url: str,
    out: Path,
    *,
    until_slip: bool = False,
    timeout_s: float = TIMEOUT_S,
    ready_file: Path | None = None,
) -> None:
    """Open `url`, wait for frames (then `ready_file`) and, if asked, a decoded slip; save."""
    with tempfile.TemporaryDirectory(prefix="grasplink-snapshot-") as profile:
        driver = chromium(Path(profile))
        try:
            driver.get(url)
            wait_for(driver, TAKING_FRAMES, "frame from the view server", timeout_s)
            if ready_file is not None:
                ready_file.write_text(url + "\n")
            if until_slip:
                wait_for(driver, SLIP_WITH_SPEED, "decoded slip with its speed", timeout_s)
            out.parent.mkdir(parents=True, exist_ok=True)
            if not driver.save_screenshot(str(out)) or out.read_bytes()[:8] != PNG_MAGIC:
                raise SnapshotError(f"{out}: the browser saved no PNG")
        finally:
            driver.quit()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m grasplink.surfaces.view.snapshot")
    parser.add_argument("url", help="the page, as `grasplink view` prints it")
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("--until-slip", action="store_true", help="wait for a decoded slip")
    parser.add_argument("--timeout", type=float, default=TIMEOUT_S, help="bound of each wait, s")
    parser.add_argument("--ready-file", type=Path, default=None, help="written once watching")
    args = parser.parse_args(argv)
    # stopped by the demo on its way out: still quit the browser and its driver (finally)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit("snapshot: stopped before the picture"))
    try:
        take(
            args.url,
            args.out,
            until_slip=args.until_slip,
            timeout_s=args.timeout,
            ready_file=args.ready_file,
        )
    except SnapshotError as exc:
        print(f"snapshot: {exc}", file=sys.stderr)
        return 1
    except (WebDriverException, OSError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        print(f"snapshot: {first}", file=sys.stderr)
        return 1
    print(f"snapshot: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A recording in the live page, in a real browser: headless Chromium against `grasplink
view DIR` playing the loop headline's run folder (docs/view.md, Recordings).

The page shows the four nodes, the decoded slip with its speed beside the true speed,
says it is a recording (never live), plays at the speed chosen, holds its time when
paused, and shows no slip once sought back to before it. Every wait is on what the page
shows, bounded generously.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from tests.view.browser import Process, page_errors, phases_are, wait_for_page

pytestmark = pytest.mark.slow
KINDS = ("skin", "emg", "belt", "hand")
SHOT_ENV = "GRASPLINK_VIEW_RECORDING_SCREENSHOT"  # where to copy the screenshot (docs)
POSITION = "return Number(document.getElementById('banner').dataset.position)"
LAST_SLIP = (
    "const s = document.getElementById('last-slip');"
    "return s.dataset.speed !== '' && Number(s.dataset.speed) > 0"
    " ? [Number(s.dataset.speed), s.dataset.truth === '' ? null : Number(s.dataset.truth)]"
    " : null"
)


def test_a_recording_plays_with_the_truth_pauses_and_seeks(
    headline_run: Path, browser, tmp_path: Path
) -> None:
    view = Process(["view", str(headline_run), "--http", "127.0.0.1:0"], tmp_path / "view.log")
    try:
        url = view.wait_for_line("view: http://").split()[1]
        browser.get(url)
        wait_for_page(browser, phases_are(browser, "operational", KINDS), "four nodes")
        banner = browser.execute_script(
            "const b = document.getElementById('banner');"
            "return [b.dataset.state, b.textContent, document.body.classList.contains('stale')]"
        )
        assert banner[0] == "recording" and banner[1].startswith("recording loop-headline: ")
        assert banner[2] is False  # a recording is not greyed out, nor ever called live
        # a quarter of the speed: the 6 s run lasts 24 s, so a loaded machine is not at its
        # end before the pause below
        browser.execute_script(
            "const r = document.getElementById('rate'); r.value = '0.25';"
            "r.dispatchEvent(new Event('change'))"
        )
        wait_for_page(
            browser,
            "return document.getElementById('banner').textContent.includes('playing ×0.25')",
            "the speed at ×0.25",
        )
        decoded, true = wait_for_page(browser, LAST_SLIP, "a decoded slip with its speed")
        assert 0 < decoded < 1000 and true is not None and 20 < true < 60  # pulled at 40 mm/s
        legend = browser.execute_script("return document.getElementById('plots').textContent")
        assert "true |speed| (mm/s)" in legend and "true grip (N)" in legend
        if os.environ.get(SHOT_ENV):
            browser.save_screenshot(str(tmp_path / "recording.png"))
            shutil.copyfile(tmp_path / "recording.png", os.environ[SHOT_ENV])
        # pause: the time holds while frames keep coming
        browser.find_element("id", "play").click()
        wait_for_page(
            browser,
            "return document.getElementById('banner').dataset.paused === 'true'",
            "the page paused",
        )
        held = browser.execute_script(POSITION)
        frames = browser.execute_script("return window.viewStats.frames")
        wait_for_page(
            browser, f"return window.viewStats.frames >= {frames + 10}", "ten frames more"
        )
        assert browser.execute_script(POSITION) == held
        assert "paused" in browser.execute_script(
            "return document.getElementById('banner').textContent"
        )
        # seek to before the slip: no slip, and none remembered
        browser.execute_script(
            "const s = document.getElementById('seek'); s.value = '0.5';"
            "s.dispatchEvent(new Event('change'))"
        )
        wait_for_page(browser, f"{POSITION} === 0.5", "the page at 0.5 s")
        shown = browser.execute_script(
            "return [document.getElementById('slip').dataset.slip,"
            " document.getElementById('last-slip').dataset.speed]"
        )
        assert shown[0] != "true" and shown[1] == ""
        wait_for_page(browser, phases_are(browser, "operational", KINDS), "four nodes again")
        assert page_errors(browser) == []
    finally:
        view.close()

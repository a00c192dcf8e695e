"""``dexmon dry-run --web`` in a real headless Chromium: clicking a finding while the job
runs says why its stage cannot be shown yet (predicted, or not in the run file yet), and
once the run file holds it shows the model at that stage until the user goes back to the
machine."""

from __future__ import annotations

import re

import pytest

from tests.monitor.web.browser import (WAIT_S, Served, chromium_or_skip, changed_fraction, open_browser,
                                       picture_src, view_picture, wait_changed_picture)

pytestmark = pytest.mark.timeout(300)

#: what the page may say on a first click, whatever the machine has cut by then
CLEAR_NOTE = re.compile(r"^Finding 1: (predicted at line 22, not cut yet|happened at stage \d+, which the run "
                        r"file does not hold yet)|^Showing stage \d+, where finding 1 happened")


def happened(served: Served) -> dict:
    """The update event of the first finding that happened."""
    while True:
        rec = served.event("finding_update")
        if rec.get("status") == "happened":
            return rec


def test_clicking_a_finding_of_a_running_job_shows_its_stage(tmp_path):
    from playwright.sync_api import sync_playwright

    chromium = chromium_or_skip()
    served = Served(["dry-run", "--clock", "sim", "--speed", "4", "--json", "--run", str(tmp_path / "r.dexrun"),
                     "--web"])
    try:
        url = served.event("web")["url"]
        with sync_playwright() as pw:
            browser = open_browser(pw, chromium)
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.set_default_timeout(WAIT_S * 1e3)
            page.goto(url)                                   # the machine starts now
            served.event("start")
            page.click("#finding-0")                         # waits until it is listed (predicted)
            page.wait_for_selector("#finding-note")
            assert CLEAR_NOTE.match(page.inner_text("#finding-note")), page.inner_text("#finding-note")
            stage = happened(served)["stage"]
            # click until the run file holds the stage (it is written every few dozen stages)
            page.wait_for_function("() => { const n = document.querySelector('#finding-note');"
                                   " if (n && n.innerText.startsWith('Showing stage')) return true;"
                                   " document.querySelector('#finding-0').click(); return false; }",
                                   polling=500)
            assert page.inner_text("#finding-note").startswith(f"Showing stage {stage}, where finding 1 happened")
            assert page.locator("#live-status").count() == 1 and page.locator("#timeline").count() == 0  # still live
            src, shown = picture_src(page), view_picture(page)
            page.click("#live-back")
            page.wait_for_selector("#finding-note", state="detached")
            live = wait_changed_picture(page, shown, src)
            assert changed_fraction(live, shown) > 0.001
            served.event("summary")
            browser.close()
        assert served.interrupt() == 1
    finally:
        served.kill()

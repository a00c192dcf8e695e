"""``dexmon dry-run --web`` in a real headless Chromium: the dry run starts when the page
has opened, the page follows the machine (state, position, line, the next predicted
finding), then shows the run file's timeline; Ctrl-C ends it with the run's status."""

from __future__ import annotations

import pytest

from tests.monitor.web.browser import WAIT_S, Served, chromium_or_skip, drawn_fraction, open_browser, view_picture

pytestmark = pytest.mark.timeout(300)


def test_a_dry_run_updates_the_page_as_the_machine_runs(tmp_path):
    from playwright.sync_api import sync_playwright

    chromium = chromium_or_skip()
    run = tmp_path / "live.dexrun"
    served = Served(["dry-run", "--clock", "sim", "--speed", "10", "--json", "--run", str(run), "--web"])
    try:
        url = served.event("web")["url"]
        with sync_playwright() as pw:
            browser = open_browser(pw, chromium)
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.set_default_timeout(WAIT_S * 1e3)
            page.goto(url)                                   # the machine starts now
            served.event("start")
            page.wait_for_selector("#live-status")
            seen = set()
            # the page follows the machine: the shown line and position change while it runs
            for _ in range(3):
                status = page.inner_text("#live-status")
                seen.add(status)
                page.wait_for_function("(s) => document.querySelector('#live-status').innerText !== s", arg=status)
            assert len(seen) == 3
            assert any(" Run " in f" {s} " or s.startswith("Run") for s in seen), seen
            # a predicted finding is counted down before the spindle gets there
            page.wait_for_function("() => /next: .* line \\d+ in [\\d.]+ s/.test("
                                   "document.querySelector('#live-next').innerText)")
            served.event("summary")
            # the run is over: its file's timeline and both findings are on the page
            page.wait_for_selector("#timeline .v-slider-thumb")
            page.wait_for_function("() => document.querySelector('#live-status').innerText.startsWith('ended')")
            assert page.locator("#findings .dexmon-finding").count() == 2
            assert drawn_fraction(view_picture(page)) > 0.05
            browser.close()
        assert served.interrupt() == 1                      # the run's status: findings
    finally:
        served.kill()

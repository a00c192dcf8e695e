"""``dexmon view RUN`` in a real headless Chromium (Debian's): the page loads, the 3-D view
draws the part, scrubbing the timeline changes the picture, clicking a finding or a line
of the listing moves to its stage."""

from __future__ import annotations

import re

import numpy as np
import pytest

from monitor.cli import main
from monitor.trace_io import RunView
from tests.monitor.web.browser import (WAIT_S, Served, chromium_or_skip, changed_fraction, drawn_fraction,
                                       open_browser, picture_src, view_picture, wait_changed_picture)

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def chromium():
    return chromium_or_skip()


@pytest.fixture(scope="module")
def run_file(tmp_path_factory, chromium):
    """A dry run of the bundled example (a gouge and a rapid into stock)."""
    path = tmp_path_factory.mktemp("web") / "example.dexrun"
    assert main(["dry-run", "--clock", "sim", "--speed", "50", "--run", str(path), "--quiet"]) == 1
    return path


@pytest.fixture(scope="module")
def page(run_file, chromium):
    from playwright.sync_api import sync_playwright

    served = Served(["view", str(run_file), "--json"])
    try:
        url = served.event("web")["url"]
        assert url.startswith("http://127.0.0.1:")
        with sync_playwright() as pw:
            browser = open_browser(pw, chromium)
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.set_default_timeout(WAIT_S * 1e3)
            page.requested = []
            page.on("request", lambda r: page.requested.append(r.url))
            page.goto(url)
            page.wait_for_selector("#view img")
            page.wait_for_function("() => document.querySelector('#view img').src")
            yield page
            browser.close()
        assert served.interrupt() == 0
    finally:
        served.kill()


def stage_shown(page) -> int:
    return int(re.match(r"stage (\d+) /", page.inner_text("#stage-text")).group(1))


def stage_count(page) -> int:
    return int(re.match(r"stage \d+ / (\d+)", page.inner_text("#stage-text")).group(1))


def wait_stage(page, stage: int) -> None:
    page.wait_for_function("(s) => document.querySelector('#stage-text').innerText.startsWith('stage ' + s + ' /')",
                           arg=stage)


def test_page_loads_with_the_run_at_its_last_stage(page, run_file):
    with RunView(run_file) as view:
        last, findings = view.last_stage, view.findings
    assert stage_shown(page) == last
    assert page.locator("#findings .dexmon-finding").count() == len(findings) == 2
    assert page.locator("#listing .current-line").count() == 1


def test_nothing_is_fetched_from_elsewhere(page):
    """Scripts, styles and fonts all come from the local server (nothing downloaded)."""
    assert page.requested
    others = [u for u in page.requested if not u.startswith(("http://127.0.0.1:", "ws://127.0.0.1:", "data:", "blob:"))]
    assert others == []


def test_the_3d_view_draws_the_part(page):
    img = view_picture(page)
    assert img.shape[0] > 200 and img.shape[1] > 200
    assert drawn_fraction(img) > 0.05   # not a blank canvas: the part, the path, the colour bar


def test_scrubbing_the_timeline_changes_the_picture(page):
    before_src, before = picture_src(page), view_picture(page)
    slider = page.locator("#timeline .v-slider-thumb")
    slider.focus()
    page.keyboard.press("Home")            # drag to the start: the stock before the first cut
    wait_stage(page, 0)
    stock = wait_changed_picture(page, before, before_src)
    assert drawn_fraction(stock) > 0.05
    assert changed_fraction(stock, before) > 0.01   # the cut surface is gone, the tool too
    src = picture_src(page)
    page.keyboard.press("End")             # and back to the end: the picture it started with
    wait_stage(page, stage_count(page))
    end = wait_changed_picture(page, stock, src)
    assert changed_fraction(end, before) < changed_fraction(stock, before)


def test_clicking_a_finding_moves_to_its_stage(page, run_file):
    with RunView(run_file) as view:
        f = view.findings[1]
    src, before = picture_src(page), view_picture(page)
    page.click("#finding-1")
    wait_stage(page, f["stage"])
    wait_changed_picture(page, before, src)
    assert "at" in page.get_attribute("#finding-1", "class").split()
    # the listing shows the current line of that stage, highlighted
    assert page.locator("#listing .current-line").count() == 1


def test_clicking_a_line_goes_to_its_first_stage(page, run_file):
    with RunView(run_file) as view:
        tab = view.stage_table
    shown = [int(x.split("-")[1]) for x in page.locator("#listing .line").evaluate_all("ls => ls.map(l => l.id)")]
    current = int(page.inner_text("#listing .current-line").split()[0])
    line = next(n for n in shown if n != current and n in set(tab["line"].tolist()))
    first = int(tab["stage"][np.nonzero(tab["line"] == line)[0][0]])
    page.click(f"#line-{line}")
    wait_stage(page, first)
    assert f"line {line}" in page.inner_text("#stage-text")
    assert page.inner_text("#listing .current-line").split()[0] == str(line)


def test_play_runs_the_timeline_to_the_end(page, run_file):
    with RunView(run_file) as view:
        last, near_end = view.last_stage, view.findings[1]["stage"]   # a few stages before the end
    assert near_end < last
    page.click("#finding-1")
    wait_stage(page, near_end)
    page.click("#play")
    wait_stage(page, last)
    page.wait_for_function("() => document.querySelector('#play').innerText.trim().toLowerCase() === 'play'")

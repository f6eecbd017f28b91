"""The demo report in a real headless browser (slow; ``make browser-test``).

The fast tests of ``test_sweep_report.py`` check the HTML structure; this one loads the
real demo report in Chromium through Playwright and checks what a person sees: no
error-styled element when nothing failed, every image decoded with a non-zero size, the
3-D cells' viewers embedded in frames that load and draw (``test_demo_viewer.py``), no
error on the console of the report or of a frame, and a screenshot saved for a look (its
path is printed; ``CELLPLAN_SCREENSHOT=FILE`` keeps it).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from browser import ARGS, CHROMIUM
from test_demo_viewer import check_embedded_viewers, watch_console

pytestmark = pytest.mark.slow


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium: run `make browser-test`")
def test_demo_report_in_a_browser(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="run `make browser-test`")
    from rich.console import Console

    from cellplan.demo import CELLS_3D, run_demo

    index = run_demo(tmp_path / "demo", console=Console(quiet=True))
    screenshot = Path(os.environ.get("CELLPLAN_SCREENSHOT", tmp_path / "report.png"))
    console: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1000})
            watch_console(page, console)
            page.goto(index.as_uri())
            page.wait_for_load_state("load")
            errors = page.locator(".error").all_inner_texts()
            images = page.evaluate(
                "Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth,"
                " i.naturalHeight])"
            )
            sections = page.locator("section h2").all_inner_texts()
            viewers = check_embedded_viewers(page, len(CELLS_3D))
            page.screenshot(path=str(screenshot), full_page=True)
        finally:
            browser.close()
    print(f"screenshot: {screenshot}")
    assert console == []
    assert len(viewers) == len(CELLS_3D)
    assert "Real arms in 3-D cells" in sections
    assert errors == []
    assert len(images) >= 10
    broken = [alt for alt, done, w, h in images if not (done and w > 0 and h > 0)]
    assert broken == []
    assert "Showcase: one run of each planner" in sections
    assert "Bundled workcells" in sections
    assert screenshot.stat().st_size > 10_000

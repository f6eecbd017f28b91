"""The demo's section "Real arms in 3-D cells": pictures, reachability and embedded viewers.

The fast test builds the section into a temporary folder through the function the demo
uses (:func:`cellplan.demo.show_3d_cells`) and checks the files and the report's HTML. The
slow one (``make browser-test``; Chromium from Debian's packages) opens that report in
headless Chromium and checks what a person sees: each viewer's frame loads and draws a
picture that is not blank, and no error reaches the console, of the report or of a frame.
:func:`check_embedded_viewers` is shared with the whole demo's browser test.
"""

from __future__ import annotations

import io
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from browser import ARGS, CHROMIUM
from cellplan.demo import CELLS_3D, show_3d_cells
from cellplan.report import write_report


class _Frames(HTMLParser):
    """The ``src`` of every ``<iframe>`` and the ``href`` of every link."""

    def __init__(self) -> None:
        super().__init__()
        self.frames: list[str] = []
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if tag == "iframe":
            self.frames.append(values.get("src") or "")
        elif tag == "a":
            self.links.append(values.get("href") or "")


def _report(folder: Path) -> tuple[Path, Any]:
    """The 3-D section built into ``folder/workcells`` and a report of it alone."""
    section = show_3d_cells(folder / "workcells")
    return write_report(folder, [], [], None, title="3-D cells", extra=[section]), section


def test_demo_shows_the_3d_cells(tmp_path):
    index, section = _report(tmp_path)
    assert section.errors == []
    assert section.title == "Real arms in 3-D cells"
    for name in CELLS_3D:
        png = tmp_path / "workcells" / f"cell_{name}.png"
        viewer = tmp_path / "workcells" / f"viewer_{name}.html"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert Image.open(png).size == (1200, 900)
        page = viewer.read_text(encoding="utf-8")
        assert page.startswith("<!DOCTYPE html>") and "cellplanMessages" in page
        assert "40 frames" in page  # the motion is animated
    text = index.read_text(encoding="utf-8")
    parser = _Frames()
    parser.feed(text)
    expected = [f"workcells/viewer_{name}.html" for name in CELLS_3D]
    assert parser.frames == expected  # relative: the folder opens offline as a whole
    assert all(src in parser.links for src in expected)  # each can be opened alone
    assert all((tmp_path / src).is_file() for src in parser.frames)
    assert 'id="cells-3d"' in text and "Real arms in 3-D cells" in text
    assert 'class="error"' not in text
    assert text.count("data:image/png") == len(CELLS_3D)
    for name, arm in zip(CELLS_3D, ("ur5", "panda"), strict=True):
        assert f"{name}: {arm}" in text
    assert "conservative sphere cover" in text
    assert text.count("reachable (IK, collision-free)") + text.count("not found") == 5
    assert "straight joint-space motion" in text
    # ur5_cell's motion into bin_a is free; panda_shelf's into the shelf is not.
    assert "it is collision-free" in text and "it collides somewhere along the way" in text


@pytest.mark.parametrize(
    ("reached", "says"),
    [("none", "no configuration reaching source"), ("start", "already reaches source")],
)
def test_no_motion_gives_a_still_viewer(tmp_path, monkeypatch, reached, says):
    """No configuration found, or the start itself: the viewer shows the start, still."""
    from cellplan.workcell3d import Workcell3D

    def reach(self, name, seed=0):
        return [None if reached == "none" else self.robot.start.copy()]

    monkeypatch.setattr(Workcell3D, "reach_region", reach)
    section = show_3d_cells(tmp_path, names=["ur5_cell"])
    assert section.errors == []
    (article,) = section.articles
    assert says in article.pages[0].caption
    rows = article.tables[0][1]
    expected = "not found" if reached == "none" else "reachable (IK, collision-free)"
    assert [row["result"] for row in rows] == [expected] * 3
    page = (tmp_path / "viewer_ur5_cell.html").read_text(encoding="utf-8")
    assert "a still scene" in page


def test_one_bad_cell_is_an_error_line(tmp_path):
    section = show_3d_cells(tmp_path, names=["discs_swap"])
    assert section.articles == []
    assert len(section.errors) == 1 and section.errors[0].startswith("discs_swap: ")


def _blank(png: bytes) -> bool:
    """A picture of one colour, or of a smooth background only."""
    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)
    return bool(pixels.std() < 10 or len(np.unique(pixels.reshape(-1, 3), axis=0)) < 200)


def check_embedded_viewers(page: Any, expected: int) -> list[bytes]:
    """Check the report's viewer frames in a loaded Playwright page; return screenshots.

    Each ``<iframe>`` must load its viewer (meshcat's canvas present, the scene's objects
    and its animation there) and, scrolled into view, draw something that is not blank.
    Console errors are collected by the caller (:func:`watch_console`).
    """
    frames = page.locator("iframe")
    assert frames.count() == expected
    shots = []
    for i in range(expected):
        frame = frames.nth(i)
        frame.scroll_into_view_if_needed()
        inner = page.frame_locator("iframe").nth(i)
        inner.locator("#meshcat-pane canvas").wait_for(timeout=30_000)
        handle = frame.element_handle()
        assert handle is not None
        content = handle.content_frame()
        assert content is not None
        # The scene's robot is there, and its moving links are animated.
        robot = content.evaluate(
            "() => Object.keys(viewer.scene_tree.find(['meshcat', 'robot']).children).length"
        )
        assert robot > 0
        assert content.evaluate("() => viewer.animator.actions.length") > 0
        page.wait_for_timeout(500)  # let the frame render once it is in view
        shot = frame.screenshot()
        assert not _blank(shot), f"viewer {i} is blank"
        shots.append(shot)
    return shots


def watch_console(page: Any, errors: list[str]) -> None:
    """Collect console errors and uncaught exceptions of ``page`` and all its frames."""
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium: run `make browser-test`")
def test_embedded_viewers_in_a_browser(tmp_path):
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="no Playwright: pip install playwright"
    )
    index, _ = _report(tmp_path)
    errors: list[str] = []
    requests: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            watch_console(page, errors)
            page.on("request", lambda r: requests.append(r.url))
            page.goto(index.as_uri())
            page.wait_for_load_state("load")
            shots = check_embedded_viewers(page, len(CELLS_3D))
            page.wait_for_timeout(300)
        finally:
            browser.close()
    assert errors == []
    assert len(shots) == len(CELLS_3D)
    assert shots[0] != shots[1]  # two cells, two pictures
    # Nothing fetched from a network: the report, its two pages (embedded pictures are
    # data: URIs, which are no requests).
    assert all(url.startswith(("file://", "data:")) for url in requests), requests
    assert {url for url in requests if url.startswith("file://")} == {
        index.as_uri(),
        *((tmp_path / "workcells" / f"viewer_{n}.html").as_uri() for n in CELLS_3D),
    }

"""The 3-D viewer page in a real headless browser (slow; Chromium from Debian's packages).

test_view3d.py checks the page's content; this one opens it from disk in Chromium through
Playwright and checks what a person sees: a WebGL canvas that is not blank, the scene's
objects loaded and moving, no error on the console, and no request other than the page
itself (it works offline). The screenshot is kept in ``CELLPLAN_SCREENSHOT_3D`` when set.

The page is rendered by SwiftShader (software WebGL) under ``--disable-gpu``: meshcat's
grid lines that pass behind the camera are dropped there, which a GPU does not do.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from browser import ARGS, CHROMIUM
from cellplan.view3d import write_viewer
from test_view3d import small_scene

pytestmark = pytest.mark.slow


# The robot's second link, as the viewer's scene tree names it, and its world position.
LINK_POSITION = """() => {
    const node = viewer.scene_tree.find(["meshcat", "robot", "link2"]);
    const p = node.object.getWorldPosition(node.object.position.clone());
    return [p.x, p.y, p.z];
}"""


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium: run `make browser-test`")
def test_viewer_page_in_a_browser(tmp_path):
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="no Playwright: pip install playwright"
    )
    page_file = tmp_path / "viewer.html"
    write_viewer(small_scene(), page_file)
    screenshot = tmp_path / "viewer.png"
    errors: list[str] = []
    requests: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("request", lambda r: requests.append(r.url))
            page.goto(page_file.as_uri())
            page.wait_for_selector("#meshcat-pane canvas", timeout=20_000)
            counts = page.evaluate(
                "() => [viewer.animator.actions.length,"
                " document.querySelectorAll('#cellplan-caption .swatch').length]"
            )
            before = page.evaluate(LINK_POSITION)
            page.wait_for_timeout(700)  # the 4 s animation plays on
            after = page.evaluate(LINK_POSITION)
            page.screenshot(path=str(screenshot))
        finally:
            browser.close()
    if os.environ.get("CELLPLAN_SCREENSHOT_3D"):
        keep = Path(os.environ["CELLPLAN_SCREENSHOT_3D"])
        keep.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(screenshot, keep)

    assert errors == []
    assert requests == [page_file.as_uri()]  # nothing fetched but the page
    assert counts == [2, 4]  # two links animated; obstacle, robot, source, tool path
    assert not np.allclose(before, after)  # the link moves
    pixels = np.asarray(Image.open(screenshot).convert("RGB"), dtype=float)
    assert pixels.shape == (800, 1280, 3)
    assert pixels.std() > 10
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 200  # not one colour, nor a gradient
    # The scene's grey table is drawn: a block of its shaded greys (not the blue sky
    # gradient behind) in the middle third of the picture.
    middle = pixels[250:550, 400:880]
    grey = (np.ptp(middle, axis=2) < 12) & (middle.mean(axis=2) > 60) & (middle.mean(axis=2) < 140)
    assert grey.mean() > 0.1


# The held part's position in the cell after seeking the paused animation to ``t`` seconds.
PART_AT = """(t) => {
    viewer.animator.pause();
    viewer.animator.seek(t);
    const node = viewer.scene_tree.find(["meshcat", "part", "P1"]);
    const p = node.object.getWorldPosition(node.object.position.clone());
    // in the cell's frame (z up): meshcat's root turns it into three.js' y-up world
    const q = viewer.scene_tree.find(["meshcat"]).object.worldToLocal(p);
    return [q.x, q.y, q.z];
}"""


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium: run `make browser-test`")
def test_view_page_carries_the_part_on_the_tool_between_pick_and_place(tmp_path, cellplan):
    """`cellplan view ur5_cell --trajectory T`: the part's node exists and, frame by frame,
    sits on the tool (its position by the arm's forward kinematics here) from the pick to
    the place, and stays where it was put down after."""
    from cellplan import arm as arms
    from test_view3d_held import PICK, PLACE, SAMPLES, ur5_trajectory

    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="no Playwright: pip install playwright"
    )
    cell, traj = ur5_trajectory()
    saved = traj.save(tmp_path / "t.json")
    page_file = tmp_path / "view.html"
    r = cellplan("view", "ur5_cell", "--trajectory", str(saved), "-o", str(page_file))
    assert r.returncode == 0, r.stderr
    tool = arms.tool_pose(cell.robot.arm, traj.q)[:, :3, 3]
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 640, "height": 400})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(page_file.as_uri())
            page.wait_for_selector("#meshcat-pane canvas", timeout=20_000)
            # 9 samples 0.5 s apart: a 4 s span is played in real time (clip time = t).
            seen = np.array([page.evaluate(PART_AT, float(t)) for t in traj.t])
        finally:
            browser.close()
    assert errors == []
    assert len(seen) == SAMPLES
    np.testing.assert_allclose(seen[PICK : PLACE + 1], tool[PICK : PLACE + 1], atol=1e-5)
    assert np.ptp(seen[PICK : PLACE + 1], axis=0).max() > 0.05  # it moves with the tool
    np.testing.assert_allclose(seen[:PICK], np.repeat(tool[[PICK]], PICK, 0), atol=1e-5)
    np.testing.assert_allclose(seen[PLACE + 1 :], np.repeat(tool[[PLACE]], 2, 0), atol=1e-5)

"""The 3-D drawings of cellplan.view3d: the PNG (matplotlib) and the viewer page (meshcat).

The page is checked as written: its messages are decoded back to meshcat's commands. One
test sends the same messages to meshcat's own server and compares its static page's
messages with ours; the browser test (test_view3d_browser.py, slow) opens the page.
"""

from __future__ import annotations

import base64
import os
import re
import selectors
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import umsgpack
from PIL import Image

from cellplan.errors import ArgumentError
from cellplan.view3d import (
    MAX_DRAWN_TRIANGLES,
    MAX_VIEWER_BYTES,
    VIEWS,
    MeshItem,
    Scene3D,
    _triangle_budget,  # the decimation's arithmetic
    draw_figure,
    draw_png,
    viewer_bytes,
    write_viewer,
)

FRAMES = 5


def box(size: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A box centred at the origin: 8 vertices, 12 triangles facing out."""
    sx, sy, sz = np.asarray(size) / 2
    vertices = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    faces = np.array(
        [
            [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
            [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
        ]
    )  # fmt: skip
    return vertices, faces


def cylinder(radius: float, height: float, sides: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder along z, centred at the origin."""
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.c_[radius * np.cos(a), radius * np.sin(a)]
    vertices = np.r_[
        np.c_[ring, np.full(sides, -height / 2)],
        np.c_[ring, np.full(sides, height / 2)],
        [[0, 0, -height / 2], [0, 0, height / 2]],
    ]
    faces = []
    for i in range(sides):
        j = (i + 1) % sides
        faces += [[i, j, sides + j], [i, sides + j, sides + i]]
        faces += [[2 * sides, j, i], [2 * sides + 1, sides + i, sides + j]]
    return vertices, np.array(faces)


def pose(xyz, yaw: float = 0.0) -> np.ndarray:
    """A rigid pose: a turn of ``yaw`` radians about z, then a translation."""
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    m[:3, 3] = xyz
    return m


def small_scene(frames: int = FRAMES) -> Scene3D:
    """A table, a post (cylinder), a translucent source box and a two-link "robot" of two
    boxes turning over ``frames`` frames; the tool path follows the second link's tip."""
    items = (
        MeshItem("obstacle/table", *box((1.2, 0.8, 0.05)), color=(0.42, 0.42, 0.42)),
        MeshItem("obstacle/post", *cylinder(0.06, 0.5), color=(0.3, 0.3, 0.35)),
        MeshItem(
            "source/S1", *box((0.3, 0.3, 0.1)), color=(0.23, 0.62, 0.36), opacity=0.35,
            group="source",
        ),
        MeshItem("robot/link1", *box((0.4, 0.08, 0.08)), color=(0.88, 0.54, 0.12), group="robot"),
        MeshItem("robot/link2", *box((0.3, 0.06, 0.06)), color=(0.95, 0.65, 0.2), group="robot"),
    )  # fmt: skip
    q = np.linspace(0.0, 1.2, frames)
    base = np.array([0.0, -0.3, 0.5])
    poses = np.empty((frames, len(items), 4, 4))
    tip = np.empty((frames, 3))
    for k, a in enumerate(q):
        elbow = base + 0.4 * np.array([np.cos(a), np.sin(a), 0.0])
        poses[k, 0] = pose((0, 0, 0.4))
        poses[k, 1] = pose((0.4, 0.25, 0.675))
        poses[k, 2] = pose((-0.4, -0.2, 0.475))
        poses[k, 3] = pose(base + 0.2 * np.array([np.cos(a), np.sin(a), 0.0]), a)
        poses[k, 4] = pose(elbow + 0.15 * np.array([np.cos(2 * a), np.sin(2 * a), 0.0]), 2 * a)
        tip[k] = elbow + 0.3 * np.array([np.cos(2 * a), np.sin(2 * a), 0.0])
    return Scene3D(
        title="two-link test cell",
        bounds=(np.array([-0.8, -0.8, 0.0]), np.array([0.8, 0.8, 1.0])),
        items=items,
        poses=poses,
        times=np.linspace(0.0, 4.0, frames),
        path=tip if frames > 1 else None,
    )


@pytest.fixture(scope="module")
def scene() -> Scene3D:
    return small_scene()


def page_messages(text: str) -> list[dict]:
    """The meshcat commands a viewer page carries, decoded, in order."""
    block = text.split("var cellplanMessages = [", 1)[1].split("];", 1)[0]
    return [
        umsgpack.unpackb(base64.b64decode(m)) for m in re.findall(r'"([A-Za-z0-9+/=]+)"', block)
    ]


def child_processes() -> set[int]:
    """Process ids whose parent is this process (from /proc)."""
    children = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == os.getpid():
            children.add(int(stat.parent.name))
    return children


# --- the picture -----------------------------------------------------------------------------


def test_png_has_the_requested_size_and_shows_something(scene, tmp_path):
    out = tmp_path / "cell.png"
    draw_png(scene, out, frame=2, size_px=(640, 480))
    image = np.asarray(Image.open(out).convert("RGB"), dtype=float)
    assert image.shape == (480, 640, 3)
    assert image.std() > 20  # not blank
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 100  # shaded faces, text, legend
    assert [p.name for p in tmp_path.iterdir()] == ["cell.png"]  # no temporary file left


def test_figure_has_a_legend_per_group_labels_and_equal_aspect(scene):
    fig = draw_figure(scene, frame=4)
    (ax,) = fig.axes
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["obstacle", "robot", "source", "tool path"]
    assert fig.get_suptitle() == "two-link test cell"
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("x (m)", "y (m)", "z (m)")
    aspect = np.asarray(ax.get_box_aspect())
    assert np.allclose(aspect / aspect[0], np.array([1.6, 1.6, 1.0]) / 1.6)
    counter = [t.get_text() for t in ax.texts if t.get_gid() == "frame-counter"]
    assert counter == ["t (s) = 4 (frame 5 of 5)"]
    (triangles,) = ax.collections[:1]  # one face colour per triangle (paths come at draw)
    assert len(triangles.get_facecolor()) == sum(len(it.faces) for it in scene.items)


@pytest.mark.parametrize("view", [*VIEWS, (10.0, 45.0)])
def test_views(scene, view):
    ax = draw_figure(scene, view=view).axes[0]
    expected = VIEWS[view] if isinstance(view, str) else view
    assert (ax.elev, ax.azim) == pytest.approx(expected)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"view": "below"}, "view"),
        ({"view": (10.0, float("nan"))}, "view"),
        ({"frame": FRAMES}, "frame"),
        ({"frame": -1}, "frame"),
        ({"size_px": (50, 50)}, "size_px"),
    ],
)
def test_bad_drawing_arguments_are_one_line(scene, kwargs, field):
    with pytest.raises(ArgumentError) as err:
        draw_figure(scene, **kwargs)
    assert "\n" not in str(err.value)
    assert err.value.problems[0].field == field


def test_large_meshes_are_decimated_for_drawing():
    n = 160  # a wavy sheet of 2 * 159 * 159 = 50,562 triangles, twice
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    vertices = np.c_[x.ravel(), y.ravel(), 0.05 * np.sin(8 * x.ravel())]
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.r_[np.c_[i, i + 1, i + n + 1], np.c_[i, i + n + 1, i + n]]
    items = (
        MeshItem("part/a", vertices, faces, color=(0.5, 0.1, 0.1), group="part"),
        MeshItem(
            "part/b", vertices + np.array([0, 0, 0.5]), faces, color=(0.1, 0.1, 0.5), group="part"
        ),
        MeshItem("obstacle/box", *box((0.1, 0.1, 0.1)), color=(0.4, 0.4, 0.4)),
    )
    scene = Scene3D(
        "big",
        (np.zeros(3), np.ones(3)),
        items,
        np.broadcast_to(np.eye(4), (1, 3, 4, 4)),
        np.zeros(1),
    )
    ax = draw_figure(scene).axes[0]
    drawn = len(ax.collections[0].get_facecolor())
    assert MAX_DRAWN_TRIANGLES - 10 <= drawn <= MAX_DRAWN_TRIANGLES
    (note,) = [t.get_text() for t in ax.texts]
    assert note == f"{drawn:,} of {2 * len(faces) + 12:,} triangles drawn"
    # The box stays whole; the sheets share the rest.
    share = (MAX_DRAWN_TRIANGLES - 12) // 2
    assert _triangle_budget(np.array([len(faces), len(faces), 12])).tolist() == [share, share, 12]
    # Small items alone over the cap: everything in proportion.
    assert _triangle_budget(np.full(7000, 12)).tolist() == [8] * 7000
    assert _triangle_budget(np.array([10, 20])).tolist() == [10, 20]


def test_scene_checks_are_one_line_per_problem():
    v, f = box((1, 1, 1))
    with pytest.raises(ArgumentError) as err:
        MeshItem("a//b", v, f + 5, color=(1.2, 0, 0), opacity=0, group="robots")
    fields = [p.field for p in err.value.problems]
    assert fields == ["a//b.name", "a//b.faces", "a//b.color", "a//b.opacity", "a//b.group"]
    # Names reach the viewer's controls panel as HTML.
    with pytest.raises(ArgumentError, match="letters, digits"):
        MeshItem("robot/<img src=x onerror=alert(1)>", v, f, color=(1, 0, 0))
    item = MeshItem("a", v, f, color=(1, 0, 0))
    skew = np.eye(4)
    skew[0, 1] = 0.5
    with pytest.raises(ArgumentError) as err:
        Scene3D("t", (np.ones(3), np.zeros(3)), (item, item), skew[None, None].repeat(2, 1),
                np.zeros(1))  # fmt: skip
    assert [p.field for p in err.value.problems] == ["bounds", "items", "poses"]
    with pytest.raises(ArgumentError, match="strictly increasing"):
        Scene3D("t", (np.zeros(3), np.ones(3)), (item,), np.tile(np.eye(4), (2, 1, 1, 1)),
                np.array([1.0, 1.0]))  # fmt: skip


# --- the viewer page ------------------------------------------------------------------------


def test_viewer_is_one_offline_page_with_the_animation(scene, tmp_path):
    out = tmp_path / "viewer.html"
    write_viewer(scene, out)
    assert [p.name for p in tmp_path.iterdir()] == ["viewer.html"]
    text = out.read_text(encoding="utf-8")
    # Nothing for a browser to fetch: no external script, style, link or import; the only
    # URLs are the XHTML namespace names three.js passes to createElementNS.
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", text, re.IGNORECASE)
    assert not re.search(r"<link|@import|<iframe", text, re.IGNORECASE)
    assert set(re.findall(r"https?://[^\s\"'`)]*", text)) <= {"http://www.w3.org/1999/xhtml"}
    assert "new MeshCat.Viewer" in text and "<title>two-link test cell</title>" in text
    caption = text.split('<div id="cellplan-caption">', 1)[1].split("</div>", 1)[0]
    for word in ("obstacle", "robot", "source", "tool path", "t (s): 0 to 4, 5 frames"):
        assert word in caption

    messages = page_messages(text)
    kinds = [m["type"] for m in messages]
    assert kinds.count("set_object") == len(scene.items) + 1  # the items and the tool path
    assert kinds[-1] == "set_animation"  # after the objects it moves
    objects = {m["path"]: m for m in messages if m["type"] == "set_object"}
    assert set(objects) == {f"/meshcat/{it.name}" for it in scene.items} | {"/meshcat/tool path"}
    source = objects["/meshcat/source/S1"]["object"]["materials"][0]
    assert source["transparent"] is True and source["opacity"] == pytest.approx(0.35)
    animation = messages[-1]
    assert animation["options"]["repetitions"] == float("inf")
    clips = {a["path"]: a["clip"] for a in animation["animations"]}
    assert set(clips) == {"/meshcat/robot/link1", "/meshcat/robot/link2"}  # only what moves
    tracks = {t["name"]: t for t in clips["/meshcat/robot/link2"]["tracks"]}
    assert set(tracks) == {".position", ".quaternion"}
    keys = tracks[".position"]["keys"]
    assert [k["time"] for k in keys] == pytest.approx(scene.times)
    assert np.allclose([k["value"] for k in keys], scene.poses[:, 4, :3, 3])
    assert clips["/meshcat/robot/link2"]["fps"] == pytest.approx(1.0)  # 4 s played in 4 s
    assert os.path.getsize(out) <= viewer_bytes(scene)


def test_still_scene_has_no_animation(tmp_path):
    still = small_scene(frames=1)
    write_viewer(still, tmp_path / "still.html")
    text = (tmp_path / "still.html").read_text(encoding="utf-8")
    assert "set_animation" not in [m["type"] for m in page_messages(text)]
    assert "(a still scene)" in text


def test_viewer_page_is_the_same_bytes_for_the_same_scene(scene, tmp_path):
    # meshcat's uuid1 names (machine address, time) are replaced by ones from the names.
    write_viewer(scene, tmp_path / "a.html")
    write_viewer(small_scene(), tmp_path / "b.html")
    assert (tmp_path / "a.html").read_bytes() == (tmp_path / "b.html").read_bytes()
    node = f"{uuid.getnode():012x}"
    uuids = {
        u
        for m in page_messages((tmp_path / "a.html").read_text(encoding="utf-8"))
        if m["type"] == "set_object"
        for u in re.findall(r"'uuid': '([0-9a-f-]{36})'", repr(m["object"]))
    }
    assert len(uuids) == 3 * (len(scene.items) + 1)
    assert not any(u.replace("-", "").endswith(node) for u in uuids)


def test_viewer_leaves_no_process_or_thread_running(scene, tmp_path):
    threads = set(threading.enumerate())
    children = child_processes()
    write_viewer(scene, tmp_path / "viewer.html")
    assert set(threading.enumerate()) == threads
    assert child_processes() == children


def test_oversized_page_is_refused_in_one_line_before_any_work(tmp_path):
    count = 10_000_000  # views, not arrays: the scene costs no memory
    item = MeshItem(
        "part/huge",
        np.broadcast_to(np.zeros(3), (count, 3)),
        np.broadcast_to(np.array([0, 0, 0], dtype=np.int64), (count, 3)),
        color=(0.5, 0.5, 0.5),
        group="part",
    )
    huge = Scene3D("huge", (np.zeros(3), np.ones(3)), (item,), np.eye(4)[None, None], np.zeros(1))
    assert viewer_bytes(huge) > MAX_VIEWER_BYTES
    start = time.perf_counter()
    with pytest.raises(ArgumentError) as err:
        write_viewer(huge, tmp_path / "huge.html")
    assert time.perf_counter() - start < 1.0
    assert "\n" not in str(err.value)
    assert str(err.value).startswith("scene: the viewer page would be about ")
    assert "the limit is 200 MB" in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_messages_match_meshcats_own_static_page(scene, tmp_path):
    """meshcat's server, sent the same messages, embeds the same ones in its static page."""
    zmq = pytest.importorskip("zmq")
    write_viewer(scene, tmp_path / "viewer.html")
    ours = page_messages((tmp_path / "viewer.html").read_text(encoding="utf-8"))
    server = subprocess.Popen(
        [sys.executable, "-u", "-m", "meshcat.servers.zmqserver"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    context = zmq.Context()
    socket = context.socket(zmq.REQ)
    try:
        url = _read_zmq_url(server, timeout=30.0)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.RCVTIMEO, 20_000)
        socket.setsockopt(zmq.SNDTIMEO, 20_000)
        socket.connect(url)
        for message in ours:
            socket.send_multipart(
                [message["type"].encode(), message["path"].encode(), umsgpack.packb(message)]
            )
            assert socket.recv() == b"ok"
        socket.send(b"get_scene")
        page = socket.recv().decode("utf-8")
    finally:
        socket.close()
        context.term()
        server.kill()
        server.wait(timeout=10)
    theirs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", page)
    # The server's order is its scene tree's (the root's animation first), ours the
    # order the viewer needs; the messages are the same bytes.
    assert sorted(theirs) == sorted(base64.b64encode(umsgpack.packb(m)).decode() for m in ours)


def _read_zmq_url(server: subprocess.Popen, timeout: float) -> str:
    """The ``zmq_url=`` line meshcat's server prints when it listens, waiting at most
    ``timeout`` seconds (skips the test if it does not start)."""
    assert server.stdout is not None
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as sel:
        sel.register(server.stdout, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if not sel.select(timeout=deadline - time.monotonic()):
                break
            line = server.stdout.readline().decode("utf-8", "replace").strip()
            if line.startswith("zmq_url="):
                return line.removeprefix("zmq_url=")
            if not line and server.poll() is not None:
                break
    pytest.skip("meshcat's server did not start (no local ports?)")

"""Drawing 3-D workcells: a still picture (PNG, matplotlib) and a viewer page (HTML, meshcat).

Both take a :class:`Scene3D`, a neutral description of what to draw: triangle meshes
(:class:`MeshItem`), each with a world pose at each of ``T`` frames, the cell's bounds,
and an optional tool path. Whoever builds the scene (a 3-D workcell, a URDF arm's links
at the configurations of a trajectory) turns its own model into meshes and poses; this
module knows nothing of robots or planners.

* :func:`draw_png` (and :func:`draw_figure`, which returns the figure unsaved): one frame
  with matplotlib's ``mplot3d``, equal aspect, a legend by group. Depth sorting is per
  triangle over the whole scene (one collection), which is approximate where triangles
  cross, as always with ``mplot3d``.
* :func:`write_viewer`: one self-contained HTML page, meshcat's three.js viewer with the
  scene, animated over the frames when they move. It needs no network: the viewer script
  is inlined and the scene is embedded as meshcat's own messages.

The viewer page is assembled here rather than by meshcat's ``Visualizer.static_html()``.
That call starts meshcat's server (a Python subprocess listening on two local ports), sends
every object to it over ZeroMQ and asks it for the page, which is its viewer script
followed by the messages it was sent. Building the same messages with meshcat's own
classes (geometry, materials, animation, commands, msgpack) and inlining the same script
gives the same scene without a subprocess, ports, sockets or threads, so nothing can hang
on a busy port or outlive the call. The one difference: the messages are decoded in order
by a plain loop instead of meshcat's one ``fetch`` of a ``data:`` URL each, whose promises
need not settle in order (an animation could arrive before the objects it moves).
"""

from __future__ import annotations

import base64
import html
import math
import os
import re
import uuid
import warnings
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cellplan import units
from cellplan.budget import format_bytes
from cellplan.errors import ArgumentError, PersistenceError, Problem, raise_if
from cellplan.fileio import atomic_path
from cellplan.plots import COLORS
from cellplan.schema import NAME_PATTERN

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "GROUPS",
    "MAX_DRAWN_TRIANGLES",
    "MAX_VIEWER_BYTES",
    "VIEWS",
    "WHOLE_ITEM",
    "MeshItem",
    "Scene3D",
    "draw_figure",
    "draw_png",
    "viewer_bytes",
    "write_viewer",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

GROUPS = ("obstacle", "robot", "part", "source", "destination")
"""The groups an item may belong to, in the order the legends list them."""

VIEWS: Mapping[str, tuple[float, float]] = MappingProxyType(
    {"iso": (30.0, -60.0), "front": (0.0, -90.0), "side": (0.0, 0.0), "top": (90.0, -90.0)}
)
"""Named views of :func:`draw_png`: ``(elevation, azimuth)`` in degrees, matplotlib's
convention. ``front`` looks along +y, ``side`` along -x, ``top`` down -z with +y up."""

MAX_DRAWN_TRIANGLES = 60_000
"""Triangles :func:`draw_png` draws at most; larger scenes are subsampled. matplotlib
sorts and paints each triangle: 60,000 take about 2.5 s."""

WHOLE_ITEM = 500
"""Items of this many triangles or fewer (boxes, cylinders) are never decimated, unless
they alone exceed :data:`MAX_DRAWN_TRIANGLES`: a box missing faces reads as broken."""

MAX_VIEWER_BYTES = 200_000_000
"""Largest viewer page :func:`write_viewer` writes (bytes, estimated before any work)."""

#: Pixels per inch of the PNG; the figure's size in inches is ``size_px / DPI``.
DPI = 100
#: Accepted PNG width and height, pixels (inclusive).
SIZE_RANGE = (200, 4000)
#: Tolerance of the rigid-motion check on poses (rotation orthonormal to this).
RIGID_TOL = 1e-6

# The camera of meshcat's viewer: a three.js PerspectiveCamera with a vertical field of
# view of 75 degrees (meshcat's create_camera). The page frames the bounds with it.
_MESHCAT_FOV_DEG = 75.0
# Playback of the viewer's animation lasts the scene's own time span when that lies in
# this range (seconds); a longer or shorter span is played faster or slower to fit, and
# the page says by how much.
_PLAYBACK_S = (2.0, 60.0)
# Name of the tool path in the viewer's scene tree; no item can take it (a space).
_PATH_NAME = "tool path"
# Estimate of the page's bytes (see viewer_bytes): the inlined viewer script (meshcat 0.3.2
# ships 853 kB; rounded up for the page around it), bytes of message per vertex or triangle
# (three float32 or three uint32), per moving item and frame (two keyframes: a time and
# three or four float64 values each, with msgpack's keys; measured 113) and per object
# (three.js' JSON header and material, measured about 700). Each is rounded up: the
# estimate is meant to stay above the page.
_PAGE_BYTES = 1_000_000
_BYTES_PER_VERTEX = 12
_BYTES_PER_TRIANGLE = 12
_BYTES_PER_KEYFRAME = 150
_BYTES_PER_OBJECT = 1_000
_BASE64 = 4 / 3


@dataclass(frozen=True, eq=False)
class MeshItem:
    """One rigid triangle mesh of a scene.

    Equality is identity (``eq=False``): arrays have no single truth value.

    Parameters
    ----------
    name
        Unique in the scene, ``/``-separated (``"obstacle/table"``, ``"robot/upper_arm"``);
        the viewer shows the parts as a tree. Each part is a scenario name: letters,
        digits, ``_``, ``.`` and ``-`` (:data:`cellplan.schema.NAME_PATTERN`).
    vertices
        ``(V, 3)`` metres, in the item's own frame.
    faces
        ``(T, 3)`` vertex indices, counter-clockwise seen from outside (both sides are
        drawn, so the order only matters for shading).
    color
        RGB, each from 0 to 1.
    opacity
        From 0 (excluded) to 1; regions are drawn translucent.
    group
        One of :data:`GROUPS`; the legends have one entry per group present.

    Raises
    ------
    ArgumentError
        One line per problem, naming the item and field.
    """

    name: str
    vertices: FloatArray
    faces: IntArray
    color: tuple[float, float, float]
    opacity: float = 1.0
    group: str = "obstacle"

    def __post_init__(self) -> None:
        where = self.name if isinstance(self.name, str) and self.name else "<unnamed>"
        problems: list[Problem] = []
        if not isinstance(self.name, str) or not self.name:
            problems.append(Problem("name", "an item needs a non-empty name"))
        elif not all(re.fullmatch(NAME_PATTERN, part) for part in self.name.split("/")):
            # The viewer's controls panel shows names as HTML (dat.gui's innerHTML): only
            # the scenario format's name characters are let through.
            problems.append(
                Problem(
                    f"{where}.name",
                    "expected names of letters, digits, '_', '.' and '-' joined by '/', "
                    f"got {self.name!r}",
                )
            )
        vertices = _real_array(self.vertices, f"{where}.vertices", problems)
        faces = np.asarray(self.faces)
        if vertices is not None and (vertices.ndim != 2 or vertices.shape[1] != 3):
            problems.append(
                Problem(f"{where}.vertices", f"expected shape (V, 3), got {vertices.shape}")
            )
            vertices = None
        elif vertices is not None and not np.isfinite(vertices).all():
            problems.append(Problem(f"{where}.vertices", "every coordinate must be finite"))
        if faces.dtype.kind not in "iu" or faces.ndim != 2 or faces.shape[1] != 3:
            problems.append(
                Problem(
                    f"{where}.faces",
                    f"expected integer indices of shape (T, 3), got {faces.dtype} {faces.shape}",
                )
            )
        elif len(faces) == 0:
            problems.append(Problem(f"{where}.faces", "an item needs at least one triangle"))
        elif vertices is not None and (faces.min() < 0 or faces.max() >= len(vertices)):
            problems.append(
                Problem(
                    f"{where}.faces",
                    f"indices must lie from 0 to {len(vertices) - 1}, got "
                    f"{faces.min()} to {faces.max()}",
                )
            )
        color = _real_array(self.color, f"{where}.color", problems)
        if color is not None and (
            color.shape != (3,)
            or not np.isfinite(color).all()
            or (color < 0).any()
            or (color > 1).any()
        ):
            problems.append(
                Problem(f"{where}.color", f"expected three numbers from 0 to 1, got {self.color!r}")
            )
        if not _is_real(self.opacity) or not 0 < float(self.opacity) <= 1:
            problems.append(
                Problem(f"{where}.opacity", f"expected a number in (0, 1], got {self.opacity!r}")
            )
        if self.group not in GROUPS:
            problems.append(
                Problem(
                    f"{where}.group", f"expected one of {', '.join(GROUPS)}, got {self.group!r}"
                )
            )
        raise_if(problems, ArgumentError)
        # Stored as float64 and int64 (no copy when they already are), so the drawing code
        # needs no conversions; broadcast views stay views.
        object.__setattr__(self, "vertices", np.asarray(self.vertices, dtype=np.float64))
        object.__setattr__(self, "faces", np.asarray(faces, dtype=np.int64))
        object.__setattr__(self, "color", tuple(float(c) for c in self.color))
        object.__setattr__(self, "opacity", float(self.opacity))


@dataclass(frozen=True, eq=False)
class Scene3D:
    """What to draw: meshes, their poses over time, the bounds, an optional tool path.

    Equality is identity (``eq=False``).

    Parameters
    ----------
    title
        Shown above the picture and in the viewer's caption and tab.
    bounds
        ``(lo, hi)``, each ``(3,)`` metres, ``hi > lo`` on every axis: the drawn region.
    items
        At least one :class:`MeshItem`, names unique.
    poses
        ``(T, len(items), 4, 4)``: the world pose of each item at each frame, rigid
        (rotation orthonormal with determinant +1, last row ``0 0 0 1``). A static item
        has the same pose in every frame. ``T = 1`` for a still scene.
    times
        ``(T,)``, strictly increasing: seconds, or the trajectory's parameter.
    time_label
        What ``times`` measure, with their unit (``"t (s)"``, ``"s (path parameter)"``).
    path
        ``(P, 3)`` points, ``P >= 2``, drawn as a polyline (the tool's path); usually one
        point per frame (``P = T``), when the PNG also marks the current one.

    Raises
    ------
    ArgumentError
        One line per problem, naming the field.
    """

    title: str
    bounds: tuple[FloatArray, FloatArray]
    items: tuple[MeshItem, ...]
    poses: FloatArray
    times: FloatArray
    time_label: str = "t (s)"
    path: FloatArray | None = None

    def __post_init__(self) -> None:
        problems: list[Problem] = []
        if not isinstance(self.title, str):
            problems.append(Problem("title", f"expected text, got {type(self.title).__name__}"))
        if not isinstance(self.time_label, str) or not self.time_label:
            problems.append(Problem("time_label", "expected non-empty text"))
        lo, hi = _check_bounds(self.bounds, problems)
        items = tuple(self.items)
        if not items or not all(isinstance(item, MeshItem) for item in items):
            problems.append(Problem("items", "expected at least one MeshItem, and only those"))
        names = Counter(item.name for item in items if isinstance(item, MeshItem))
        duplicates = sorted(name for name, count in names.items() if count > 1)
        if duplicates:
            problems.append(Problem("items", f"names must be unique: {', '.join(duplicates)}"))
        times = _real_array(self.times, "times", problems)
        if times is not None:
            if times.ndim != 1 or len(times) == 0:
                problems.append(Problem("times", f"expected shape (T,), T >= 1, got {times.shape}"))
                times = None
            elif not np.isfinite(times).all() or (np.diff(times) <= 0).any():
                problems.append(Problem("times", "expected finite, strictly increasing times"))
        poses = _real_array(self.poses, "poses", problems)
        if poses is not None and times is not None:
            expected = (len(times), len(items), 4, 4)
            if poses.shape != expected:
                problems.append(
                    Problem(
                        "poses", f"expected shape {expected} (T, items, 4, 4), got {poses.shape}"
                    )
                )
            elif not _rigid(poses):
                problems.append(
                    Problem(
                        "poses",
                        "every pose must be a finite rigid motion (orthonormal rotation, "
                        "determinant +1, last row 0 0 0 1)",
                    )
                )
        path = None
        if self.path is not None:
            path = _real_array(self.path, "path", problems)
            if path is not None and (path.ndim != 2 or path.shape[1] != 3 or len(path) < 2):
                problems.append(Problem("path", f"expected shape (P, 3), P >= 2, got {path.shape}"))
            elif path is not None and not np.isfinite(path).all():
                problems.append(Problem("path", "every coordinate must be finite"))
        raise_if(problems, ArgumentError)
        assert lo is not None and hi is not None
        object.__setattr__(self, "bounds", (lo, hi))
        object.__setattr__(self, "items", items)
        object.__setattr__(self, "poses", np.asarray(self.poses, dtype=np.float64))
        object.__setattr__(self, "times", np.asarray(self.times, dtype=np.float64))
        if self.path is not None:
            object.__setattr__(self, "path", np.asarray(self.path, dtype=np.float64))

    @property
    def frames(self) -> int:
        """``T``, the number of frames."""
        return len(self.times)

    def moving(self) -> NDArray[np.bool_]:
        """``(len(items),)``: whether each item's pose changes over the frames."""
        return np.asarray((self.poses != self.poses[:1]).any(axis=(0, 2, 3)))


def _is_real(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def _real_array(value: Any, field: str, problems: list[Problem]) -> FloatArray | None:
    """``value`` as a float array, or None with a problem if it is not real numbers."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        arr = np.asarray(None)
    if arr.dtype.kind not in "iuf":
        problems.append(Problem(field, f"expected real numbers, got {arr.dtype}"))
        return None
    return np.asarray(arr, dtype=np.float64)


def _check_bounds(
    bounds: Any, problems: list[Problem]
) -> tuple[FloatArray | None, FloatArray | None]:
    try:
        lo_value, hi_value = bounds
    except (TypeError, ValueError):
        problems.append(Problem("bounds", "expected (lo, hi)"))
        return None, None
    lo = _real_array(lo_value, "bounds", problems)
    hi = _real_array(hi_value, "bounds", problems)
    if lo is None or hi is None:
        return None, None
    if lo.shape != (3,) or hi.shape != (3,):
        problems.append(Problem("bounds", f"expected two (3,) arrays, got {lo.shape}, {hi.shape}"))
    elif not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi > lo).all()):
        problems.append(Problem("bounds", "expected finite lo < hi on every axis"))
    return lo, hi


def _rigid(poses: FloatArray) -> bool:
    if not np.isfinite(poses).all():
        return False
    bottom = poses[..., 3, :]
    if np.abs(bottom - np.array([0.0, 0.0, 0.0, 1.0])).max(initial=0.0) > RIGID_TOL:
        return False
    rot = poses[..., :3, :3]
    gram = np.einsum("...ji,...jk->...ik", rot, rot)
    if np.abs(gram - np.eye(3)).max(initial=0.0) > RIGID_TOL:
        return False
    return bool((np.linalg.det(rot) > 0).all()) if rot.size else True


# --- the picture -----------------------------------------------------------------------------


def draw_figure(
    scene: Scene3D,
    *,
    frame: int = 0,
    view: str | tuple[float, float] = "iso",
    size_px: tuple[int, int] = (1200, 900),
) -> Figure:
    """One frame of ``scene`` as a matplotlib figure, not saved (see :func:`draw_png`).

    The figure is made without pyplot (``matplotlib.figure.Figure``), so it is never
    registered as an open window and is freed with its last reference.

    Parameters
    ----------
    scene
        What to draw.
    frame
        Which frame, from 0 to ``scene.frames - 1``.
    view
        A name of :data:`VIEWS` or ``(elevation, azimuth)`` in degrees.
    size_px
        ``(width, height)`` of the picture in pixels, each in :data:`SIZE_RANGE`.

    Returns
    -------
    Figure
        One 3-D axes with the meshes, the tool path, a legend and the title.

    Raises
    ------
    ArgumentError
        One line: a frame out of range, an unknown view, a size out of range.
    """
    elev, azim = _check_view(view)
    width, height = _check_size(size_px)
    if (
        isinstance(frame, bool)
        or not isinstance(frame, int | np.integer)
        or not (0 <= frame < scene.frames)
    ):
        raise ArgumentError(
            f"expected a frame from 0 to {scene.frames - 1}, got {frame!r}", "frame"
        )
    frame = int(frame)

    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
    ax: Any = fig.add_subplot(projection="3d")
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.02, top=0.93)
    triangles, colors, drawn, total = _world_triangles(scene, frame)
    # One collection for the whole scene: mplot3d sorts by depth within a collection but
    # orders separate collections by one depth each, which paints a large table over a
    # small part resting on it. Edges in the face colour hide the hairline seams
    # antialiasing leaves between the triangles of one flat face.
    ax.add_collection3d(
        Poly3DCollection(triangles, facecolors=colors, edgecolors=colors, linewidths=0.3, zorder=1)
    )
    handles: list[Any] = []
    for group in GROUPS:
        item = next((it for it in scene.items if it.group == group), None)
        if item is not None:
            handles.append(
                Patch(facecolor=(*item.color, item.opacity), edgecolor="black", label=group)
            )
    # The path is drawn over the meshes, whatever the depth: it is what the picture shows.
    ax.computed_zorder = False
    if scene.path is not None:
        p = scene.path
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=COLORS["path"], lw=1.8, zorder=3)
        handles.append(Line2D([], [], color=COLORS["path"], lw=1.8, label="tool path"))
        if len(p) == scene.frames:
            ax.scatter(*p[frame], color=COLORS["path"], s=30, zorder=4, depthshade=False)
    lo, hi = scene.bounds
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(hi - lo))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.view_init(elev=elev, azim=azim)
    ax.legend(handles=handles, loc="upper left", fontsize=9, framealpha=0.85)
    fig.suptitle(scene.title, parse_math=False)
    notes = []
    if scene.frames > 1:
        notes.append(
            f"{scene.time_label} = {scene.times[frame]:.4g} (frame {frame + 1} of {scene.frames})"
        )
    if drawn < total:
        notes.append(f"{drawn:,} of {total:,} triangles drawn")
    if notes:
        ax.text2D(
            0.01,
            0.01,
            "; ".join(notes),
            transform=ax.transAxes,
            fontsize=9,
            family="monospace",
            parse_math=False,
            bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "#57606a", "alpha": 0.85},
            gid="frame-counter",
        )
    return fig


def draw_png(
    scene: Scene3D,
    path: str | os.PathLike[str],
    *,
    frame: int = 0,
    view: str | tuple[float, float] = "iso",
    size_px: tuple[int, int] = (1200, 900),
) -> None:
    """Draw one frame of ``scene`` into a PNG of exactly ``size_px`` pixels (atomically).

    matplotlib's ``mplot3d``: equal aspect (metres are the same length on every axis),
    axes labelled in metres, a legend with one entry per group present (the colour of
    its first item) and the tool path, the title, and, for a moving scene, the frame's
    time. Faces are shaded by their angle to a fixed light.

    A scene of more than :data:`MAX_DRAWN_TRIANGLES` triangles is decimated for drawing:
    items of up to :data:`WHOLE_ITEM` triangles stay whole, and each larger one keeps a
    share of the rest in proportion to its size, as evenly spaced triangles of its list,
    so it shows gaps but keeps its extent; the picture says how many were drawn.

    Parameters
    ----------
    scene
        What to draw.
    path
        The PNG file; replaced atomically.
    frame, view, size_px
        As for :func:`draw_figure`.

    Raises
    ------
    ArgumentError
        One line: a bad frame, view or size, or ``path`` not a regular file.
    """
    target = Path(path)
    fig = draw_figure(scene, frame=frame, view=view, size_px=size_px)
    # Not plots.save_figure: its tight bounding box changes the picture's size in pixels.
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=DPI, format="png")


def _check_view(view: str | tuple[float, float]) -> tuple[float, float]:
    if isinstance(view, str):
        if view not in VIEWS:
            raise ArgumentError(
                f"expected one of {', '.join(VIEWS)} or (elevation, azimuth) in degrees, "
                f"got {view!r}",
                "view",
            )
        return VIEWS[view]
    if (
        isinstance(view, Sequence)
        and len(view) == 2
        and all(_is_real(v) and math.isfinite(float(v)) for v in view)
    ):
        return float(view[0]), float(view[1])
    raise ArgumentError(
        f"expected one of {', '.join(VIEWS)} or (elevation, azimuth) in degrees, got {view!r}",
        "view",
    )


def _check_size(size_px: tuple[int, int]) -> tuple[int, int]:
    lo, hi = SIZE_RANGE
    if (
        isinstance(size_px, Sequence)
        and len(size_px) == 2
        and all(isinstance(s, int | np.integer) and not isinstance(s, bool) for s in size_px)
        and all(lo <= s <= hi for s in size_px)
    ):
        return int(size_px[0]), int(size_px[1])
    raise ArgumentError(
        f"expected (width, height), whole pixels from {lo} to {hi}, got {size_px!r}", "size_px"
    )


def _triangle_budget(counts: IntArray) -> IntArray:
    """How many triangles of each item to draw: all when the scene is within
    :data:`MAX_DRAWN_TRIANGLES`; else small items (:data:`WHOLE_ITEM` triangles or fewer)
    whole and the others a share of the rest in proportion to their size (every item
    in proportion when the small ones alone exceed the cap)."""
    cap = MAX_DRAWN_TRIANGLES
    if counts.sum() <= cap:
        return counts
    small = counts <= WHOLE_ITEM
    room = cap - int(counts[small].sum())
    large = int(counts[~small].sum())
    if room <= 0:
        return np.maximum(1, counts * cap // counts.sum())
    return np.where(small, counts, np.maximum(1, counts * room // max(large, 1)))


def _world_triangles(scene: Scene3D, frame: int) -> tuple[FloatArray, FloatArray, int, int]:
    """Every drawn triangle in world coordinates ``(n, 3, 3)``, its shaded RGBA ``(n, 4)``,
    and how many were drawn of how many (decimated to :data:`MAX_DRAWN_TRIANGLES`)."""
    counts = np.array([len(item.faces) for item in scene.items])
    total = int(counts.sum())
    keep = _triangle_budget(counts)
    light = np.array([0.35, -0.45, 0.82])
    light /= np.linalg.norm(light)
    tris: list[FloatArray] = []
    rgba: list[FloatArray] = []
    for item, pose, n in zip(scene.items, scene.poses[frame], keep, strict=True):
        faces = item.faces
        if n < len(faces):
            faces = faces[np.linspace(0, len(faces) - 1, int(n)).round().astype(np.int64)]
        world = item.vertices[faces] @ pose[:3, :3].T + pose[:3, 3]
        normal = np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0])
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
        # Both sides are lit alike (abs): an open mesh seen from inside is not black.
        shade = 0.55 + 0.45 * np.abs(normal @ light)
        color = np.empty((len(faces), 4))
        color[:, :3] = np.clip(np.outer(shade, item.color), 0.0, 1.0)
        color[:, 3] = item.opacity
        tris.append(world)
        rgba.append(color)
    return np.concatenate(tris), np.concatenate(rgba), int(keep.sum()), total


# --- the viewer page ------------------------------------------------------------------------


def viewer_bytes(scene: Scene3D) -> int:
    """Estimated size in bytes of the page :func:`write_viewer` writes for ``scene``.

    From the counts alone (vertices, triangles, moving items x frames, path points),
    before anything is built. It errs high: pages measured from 870 kB (a still box
    scene) to 3.3 MB (100,000 triangles) came 4 % to 20 % under it.
    """
    vertices = sum(len(item.vertices) for item in scene.items)
    triangles = sum(len(item.faces) for item in scene.items)
    moving = int(scene.moving().sum()) if scene.frames > 1 else 0
    points = 0 if scene.path is None else len(scene.path)
    message = (
        vertices * _BYTES_PER_VERTEX
        + triangles * _BYTES_PER_TRIANGLE
        + moving * scene.frames * _BYTES_PER_KEYFRAME
        + points * _BYTES_PER_VERTEX
        + (len(scene.items) + 2) * _BYTES_PER_OBJECT
    )
    return _PAGE_BYTES + math.ceil(message * _BASE64)


def write_viewer(scene: Scene3D, path: str | os.PathLike[str]) -> None:
    """Write ``scene`` as one self-contained HTML page with meshcat's 3-D viewer.

    The page holds meshcat's viewer script (three.js and its controls, inlined) and the
    scene as meshcat's messages (base64 msgpack): no file or network access is needed
    to open it, from disk or a server. Every item is a triangle mesh (Lambert material,
    translucent below opacity 1) placed at its frame-0 pose, under its ``/``-separated
    name in the viewer's scene tree; the tool path is a line; the camera frames the
    bounds from the ``iso`` view. When items move, an animation over the frames plays
    in a loop (meshcat's Controls > Animations: play, pause, scrub, speed). It lasts
    the scene's time span in seconds when that lies between 2 s and 60 s, and is
    stretched or squeezed to the nearer end otherwise (the caption says by how much). A
    fixed caption at the bottom left gives the title, each group's colour, the time
    label and the frames.

    No server, subprocess, port or thread is used (see the module docstring), so
    nothing outlives the call.

    Parameters
    ----------
    scene
        What to show.
    path
        The HTML file; replaced atomically.

    Raises
    ------
    ArgumentError
        One line: the page would exceed :data:`MAX_VIEWER_BYTES` (:func:`viewer_bytes`,
        checked before any work), or ``path`` is not a regular file.
    PersistenceError
        One line: meshcat's viewer script is missing from its installation.
    """
    target = Path(path)
    estimate = viewer_bytes(scene)
    if estimate > MAX_VIEWER_BYTES:
        vertices = sum(len(item.vertices) for item in scene.items)
        triangles = sum(len(item.faces) for item in scene.items)
        raise ArgumentError(
            f"the viewer page would be about {format_bytes(estimate)} ({vertices:,} vertices, "
            f"{triangles:,} triangles, {scene.frames:,} frames); the limit is "
            f"{format_bytes(MAX_VIEWER_BYTES)}: simplify the meshes or pass fewer frames",
            "scene",
        )
    script = _viewer_script()
    with atomic_path(target) as tmp, open(tmp, "w", encoding="utf-8") as out:
        out.write(_page_head(scene))
        out.write("<script>\n")
        out.write(script)
        out.write("\n</script>\n<script>\n")
        out.write('var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));\n')
        out.write("var cellplanMessages = [\n")
        for message in _messages(scene):
            out.write('"')
            out.write(base64.b64encode(message).decode("ascii"))
            out.write('",\n')
        out.write("];\n")
        out.write(_DECODE_LOOP)
        out.write("</script>\n")
        out.write(_caption(scene))
        out.write('<script id="embedded-json"></script>\n</body>\n</html>\n')


def _viewer_script() -> str:
    """meshcat's viewer bundle (``viewer/dist/main.min.js``), checked safe to inline."""
    with warnings.catch_warnings():
        # meshcat's package imports its server, which imports a module pyzmq 17 deprecated;
        # the server is never used here.
        warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat

    bundle = Path(meshcat.viewer_assets_path()) / "dist" / "main.min.js"
    try:
        text = bundle.read_text(encoding="utf-8")
    except OSError as exc:
        raise PersistenceError(
            f"meshcat's viewer script {bundle} cannot be read ({exc.strerror or exc}); "
            "reinstall meshcat",
            "meshcat",
        ) from None
    # Inside <script>, "</script" would end the element early and "<!--" would change how
    # the parser reads the rest; meshcat's own static page inlines the bundle the same way.
    if "</script" in text.lower() or "<!--" in text:
        raise PersistenceError(
            f"meshcat's viewer script {bundle} cannot be inlined in a page (it holds "
            "'</script' or '<!--'); use meshcat 0.3.2",
            "meshcat",
        )
    return text


# Each message is decoded and handled in the order written: meshcat's own page issues one
# fetch() per message, and their promises need not settle in that order.
_DECODE_LOOP = """\
for (var i = 0; i < cellplanMessages.length; i++) {
    var text = atob(cellplanMessages[i]);
    var bytes = new Uint8Array(text.length);
    for (var j = 0; j < text.length; j++) { bytes[j] = text.charCodeAt(j); }
    viewer.handle_command_bytearray(bytes);
}
cellplanMessages = null;
// Orbit about the bounds' centre, the origin of the camera's parent frame: meshcat's
// controls turn about the world origin, and no message can move their target.
if (viewer.controls && viewer.camera && viewer.camera.parent) {
    viewer.camera.parent.updateWorldMatrix(true, false);
    viewer.controls.target.setFromMatrixPosition(viewer.camera.parent.matrixWorld);
    viewer.controls.update();
    viewer.set_dirty();
}
"""


def _messages(scene: Scene3D) -> Iterator[bytes]:
    """meshcat's messages for the scene, msgpack-encoded, in the order they must be handled:
    objects and their frame-0 poses, the tool path, the camera, then the animation."""
    import umsgpack
    from meshcat import geometry as g
    from meshcat.commands import SetAnimation, SetObject, SetProperty, SetTransform
    from meshcat.path import Path as MeshcatPath

    def where(name: str) -> MeshcatPath:
        # Built from its parts: MeshcatPath.append would read a leading "/" as the root.
        return MeshcatPath(("meshcat", *name.split("/")))

    for item, pose in zip(scene.items, scene.poses[0], strict=True):
        # Phong with flat shading: the shader takes each triangle's normal from its screen
        # derivatives. meshcat sends no normals, and Lambert (per-vertex lighting in the
        # three.js meshcat bundles) would paint every face of a mesh one flat colour.
        material = g.MeshPhongMaterial(
            color=_hex_color(item.color),
            opacity=item.opacity,
            transparent=item.opacity < 1.0,
            flatShading=True,
        )
        mesh = g.Mesh(g.TriangularMeshGeometry(item.vertices, item.faces), material)
        _name_uuids(mesh, item.name)
        yield umsgpack.packb(SetObject(mesh, path=where(item.name)).lower())
        yield umsgpack.packb(SetTransform(pose, where(item.name)).lower())
    if scene.path is not None:
        line = g.Line(
            g.PointsGeometry(np.ascontiguousarray(scene.path.T, dtype=np.float32)),
            g.LineBasicMaterial(color=_hex_color(_rgb(COLORS["path"]))),
        )
        _name_uuids(line, _PATH_NAME)
        yield umsgpack.packb(SetObject(line, path=where(_PATH_NAME)).lower())
    centre, offset = _camera(scene)
    camera = MeshcatPath(("Cameras", "default"))
    yield umsgpack.packb(SetTransform(_translation(centre), camera).lower())
    # The camera sits in meshcat's "rotated" frame, three.js' y-up: world (x, y, z) is
    # (x, z, -y) there.
    lens = camera.append("rotated/<object>")
    local = [float(offset[0]), float(offset[2]), float(-offset[1])]
    yield umsgpack.packb(SetProperty("position", local, lens).lower())
    # meshcat's camera sees 100 m at most; a large cell needs more.
    far = max(100.0, 10.0 * float(np.linalg.norm(offset)))
    yield umsgpack.packb(SetProperty("far", far, lens).lower())
    animation = _animation(scene, where)
    if animation is not None:
        # Repeats without end: a viewer is watched for as long as someone likes.
        yield umsgpack.packb(SetAnimation(animation, play=True, repetitions=math.inf).lower())


def _name_uuids(obj: Any, name: str) -> None:
    """Give a meshcat object, its geometry and its material uuids derived from ``name``.

    meshcat draws them with ``uuid1``, which holds the machine's network (MAC) address and
    the time: a page shared would carry both, and the same scene would never give the same
    bytes. three.js only needs them unique within one message.
    """
    for part, element in (("object", obj), ("geometry", obj.geometry), ("material", obj.material)):
        element.uuid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"cellplan.view3d:{name}:{part}"))


def _animation(scene: Scene3D, where: Callable[[str], Any]) -> Any:
    """meshcat's Animation of the moving items, or None when nothing moves."""
    from meshcat.animation import Animation, AnimationClip, AnimationTrack
    from scipy.spatial.transform import Rotation

    moving = np.flatnonzero(scene.moving()) if scene.frames > 1 else np.zeros(0, np.int64)
    if len(moving) == 0:
        return None
    rel = scene.times - scene.times[0]
    span = float(rel[-1])
    playback = min(max(span, _PLAYBACK_S[0]), _PLAYBACK_S[1])
    # three.js reads a key's time in frames of the clip's fps: time / fps seconds.
    fps = span / playback
    keys = rel.tolist()
    clips = {}
    for index in moving:
        pose = scene.poses[:, index]
        quat = Rotation.from_matrix(pose[:, :3, :3]).as_quat()  # x, y, z, w: three.js' order
        # Neighbouring keys on the same side of the sphere: the shorter way round.
        flips = np.cumprod(np.where(np.sum(quat[1:] * quat[:-1], axis=1) < 0, -1.0, 1.0))
        quat[1:] *= flips[:, None]
        tracks = {
            "position": AnimationTrack("position", "vector3", list(keys), pose[:, :3, 3].tolist()),
            "quaternion": AnimationTrack("quaternion", "quaternion", list(keys), quat.tolist()),
        }
        clips[where(scene.items[index].name)] = AnimationClip(tracks=tracks, fps=fps)
    return Animation(clips=clips)


def _playback_rate(scene: Scene3D) -> float:
    """Scene time units shown per second of playback (1 when played in real time)."""
    span = float(scene.times[-1] - scene.times[0])
    return span / min(max(span, _PLAYBACK_S[0]), _PLAYBACK_S[1])


def _camera(scene: Scene3D) -> tuple[FloatArray, FloatArray]:
    """Where the camera looks (the bounds' centre) and its offset from there: the ``iso``
    view's direction, far enough that the bounds' sphere fits the field of view."""
    lo, hi = scene.bounds
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2
    elev, azim = (units.radians(a) for a in VIEWS["iso"])
    direction = np.array(
        [math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)]
    )
    distance = 1.05 * radius / math.sin(units.radians(_MESHCAT_FOV_DEG / 2))
    return centre, direction * distance


def _translation(xyz: FloatArray) -> FloatArray:
    matrix = np.eye(4)
    matrix[:3, 3] = xyz
    return matrix


def _hex_color(rgb: Sequence[float]) -> int:
    r, g, b = (round(255 * c) for c in rgb)
    return (r << 16) | (g << 8) | b


def _rgb(hex_text: str) -> tuple[float, float, float]:
    value = int(hex_text.lstrip("#"), 16)
    return ((value >> 16) / 255, ((value >> 8) & 0xFF) / 255, (value & 0xFF) / 255)


def _css(rgb: Sequence[float], opacity: float = 1.0) -> str:
    r, g, b = (round(255 * c) for c in rgb)
    return f"rgba({r}, {g}, {b}, {opacity:.3g})"


def _page_head(scene: Scene3D) -> str:
    title = html.escape(scene.title or "cellplan 3-D viewer")
    return f"""<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
body {{ margin: 0; }}
#meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
#cellplan-caption {{
    position: fixed; left: 10px; bottom: 10px; max-width: 40vw; padding: 6px 10px;
    font: 13px/1.45 system-ui, sans-serif; color: #1f2328;
    background: rgba(255, 255, 255, 0.88); border: 1px solid #57606a; border-radius: 4px;
    pointer-events: none;
}}
#cellplan-caption .swatch {{
    display: inline-block; width: 0.9em; height: 0.9em; margin: 0 0.3em 0 0.8em;
    vertical-align: -0.1em; border: 1px solid #1f2328;
}}
#cellplan-caption .swatch:first-of-type {{ margin-left: 0; }}
</style>
</head>
<body>
<div id="meshcat-pane"></div>
"""


def _caption(scene: Scene3D) -> str:
    """The fixed caption: title, one swatch per group, the time label and the frames."""
    parts = [f"<b>{html.escape(scene.title)}</b>"] if scene.title else []
    swatches = []
    for group in GROUPS:
        item = next((it for it in scene.items if it.group == group), None)
        if item is not None:
            swatches.append(
                f'<span class="swatch" style="background: {_css(item.color, item.opacity)}">'
                f"</span>{group}"
            )
    if scene.path is not None:
        swatches.append(
            f'<span class="swatch" style="background: {_css(_rgb(COLORS["path"]))}"></span>'
            "tool path"
        )
    parts.append("".join(swatches))
    label = html.escape(scene.time_label)
    if scene.frames == 1:
        parts.append(f"{label} = {scene.times[0]:.4g} (a still scene)")
    else:
        line = f"{label}: {scene.times[0]:.4g} to {scene.times[-1]:.4g}, {scene.frames} frames"
        if scene.moving().any():
            rate = _playback_rate(scene)
            if rate != 1.0:
                line += f"; playback shows {rate:.3g} of {label} per second"
            line += " (Open Controls &gt; Animations)"
        parts.append(line)
    parts.append("drag: turn, scroll: zoom, right-drag: pan")
    return '<div id="cellplan-caption">' + "<br>".join(parts) + "</div>\n"

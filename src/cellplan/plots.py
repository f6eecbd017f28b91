"""Shared drawing: workcells, robots, C-space bitmaps, figure and GIF saving.

matplotlib is imported lazily (inside functions, Agg backend), so importing
cellplan never pulls it in. Paper packages keep their own figures in
``<paper>/plots.py`` and build on these helpers. Every file is written
atomically.
"""

from __future__ import annotations

import gc
import io
import math
import struct
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from shapely.geometry.base import BaseGeometry

from cellplan import units
from cellplan.errors import ArgumentError
from cellplan.fileio import atomic_path
from cellplan.scenario3d import planar_workcell
from cellplan.workcell import Workcell

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from cellplan.cspace import Grid
    from cellplan.setup import Setup
    from cellplan.trajectory import Trajectory
    from cellplan.validity import ValiditySpace

COLORS = {
    "obstacle": "#6b6b6b",
    "source": "#3a9d5d",
    "destination": "#3b6fb6",
    "robot": "#e08a1e",
    "part": "#8c1c13",
    "free": "#f4f1ea",
    "blocked": "#2f2f2f",
    "path": "#c0392b",
}


def new_figure(
    ncols: int = 1, nrows: int = 1, size: float = 4.8, **subplot_kw: Any
) -> tuple[Figure, Any]:
    """A figure with an ``nrows x ncols`` grid of axes (Agg backend, no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        nrows,
        ncols,
        figsize=(size * ncols, size * nrows),
        squeeze=False,
        layout="constrained",
        **subplot_kw,
    )
    return fig, axes


def save_figure(fig: Figure, path: str | Path, dpi: int = 110) -> Path:
    """Save atomically and close the figure (also when the save fails: pyplot keeps every
    open figure, and a long process, such as a fuzzer calling the CLI in-process, would
    hold them all)."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=path.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return path


GIF_SIZE = 640
"""Default width of GIF frames in pixels (``--gif-size``); the height follows the picture."""
GIF_SIZE_RANGE = (240, 2400)
"""Accepted ``--gif-size`` values, in pixels (inclusive)."""


def check_gif_size(size: int | str, field: str = "--gif-size") -> int:
    """``size`` (an integer, or its text as typed) as an int if it lies in
    :data:`GIF_SIZE_RANGE` and one frame that wide fits in memory
    (:func:`check_gif_memory`); an :class:`ArgumentError` naming ``field`` otherwise."""
    lo, hi = GIF_SIZE_RANGE
    value: int | None = None
    if isinstance(size, int) and not isinstance(size, bool):
        value = size
    elif isinstance(size, str) and size.strip().lstrip("+").isdigit():
        value = int(size)
    if value is None or not lo <= value <= hi:
        raise ArgumentError(
            f"expected a whole number of pixels from {lo} to {hi}, got {size!r}", field
        )
    check_gif_memory(value, field=field)
    return value


def figure_to_rgb(fig: Figure, width: int = GIF_SIZE) -> np.ndarray:
    """Render a figure ``width`` pixels wide to an ``(H, W, 3)`` uint8 array (GIF frames).

    The resolution is chosen so the figure's width in inches spans ``width`` pixels, so
    text and lines keep their proportions at any size.
    """
    fig.set_dpi(width / fig.get_figwidth())
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())  # type: ignore[attr-defined]
    return np.array(rgba[..., :3])


def frame_counter(ax: Axes, text: str) -> None:
    """The stage or time counter of a GIF frame, boxed in the top-left corner of ``ax``
    (2-D or 3-D axes)."""
    # On 3-D axes ``text`` takes (x, y, z); ``text2D`` places text in axes coordinates.
    draw = getattr(ax, "text2D", ax.text)
    draw(
        0.02,
        0.98,
        text,
        transform=ax.transAxes,
        ha="left",
        va="top",
        fontsize=9,
        family="monospace",
        bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "#57606a", "alpha": 0.85},
        gid="frame-counter",
    )


def grid_shape(count: int, aspect: float, target: float = 1.6) -> tuple[int, int]:
    """``(rows, cols)`` to lay out ``count`` panels of width/height ``aspect``.

    Chooses the columns whose whole grid (``cols * aspect`` wide, ``rows`` high) comes
    nearest the ``target`` width/height (a report page), preferring fewer empty panels
    on ties, so wide workcells stack in fewer columns and tall ones in more.
    """
    if count < 1:
        raise ValueError("a grid needs at least one panel")
    if not (math.isfinite(aspect) and aspect > 0):
        raise ValueError(f"aspect must be positive, got {aspect}")

    def cost(cols: int) -> tuple[float, int]:
        rows = math.ceil(count / cols)
        return abs(math.log(cols * aspect / rows / target)), rows * cols - count

    cols = min(range(1, count + 1), key=cost)
    return math.ceil(count / cols), cols


GIF_BYTES_PER_PIXEL = 24
"""Memory per pixel of one GIF frame while it is drawn and written (:func:`save_gif`):
matplotlib's RGBA canvas (4), the RGB copy (3), the padded frame and the previous one
(3 + 3), the changed part cropped, its image and palette image (3 + 3 + 1), and Pillow's
quantizer, which works on the crop (about 4). Measured peak of a 2400 x 2400 frame: see
docs/reliability.md."""


def check_gif_memory(width: int, height: int | None = None, field: str = "--gif-size") -> None:
    """Refuse (naming ``field``) a GIF frame ``width`` pixels wide that cannot fit in memory.

    :func:`save_gif` holds one or two frames at a time, whatever their number, so the
    frame's size is the whole estimate. ``height`` defaults to ``width`` (the square
    figures of the animations).
    """
    from cellplan import budget

    pixels = width * (width if height is None else height)
    budget.require(pixels * GIF_BYTES_PER_PIXEL, f"{field} {width}", "to draw one GIF frame")


def save_gif(
    frames: Iterable[np.ndarray],
    path: str | Path,
    fps: float = 8.0,
    hold_last: int = 4,
    collect: bool = True,
) -> Path:
    """Write RGB frames as an animated GIF (atomically), one frame at a time.

    ``frames`` may be a generator: each frame is quantized and written as it comes, so
    memory holds one or two frames however many there are (Pillow's ``save_all`` keeps
    every frame until the end). A frame only stores the box where it differs from the one
    before; an unchanged frame lengthens the previous one. Frames smaller than the largest
    are padded with white to its size. The last frame is shown ``hold_last`` frames longer.
    ``collect=False`` skips the full garbage collection after each frame, for producers
    that draw every frame on one reused figure (it cost about 0.2 s a frame in a large
    process: issue 34, docs/benchmarks.md "Drawing time").
    """
    path = Path(path)
    delay = max(1, round(100 / fps))  # GIF delays are in hundredths of a second
    with atomic_path(path) as tmp, open(tmp, "wb") as out:
        out.write(_GIF_HEAD)
        previous: np.ndarray | None = None
        pending: tuple[bytes, int] | None = None  # a frame's bytes wait for its delay
        for frame in frames:
            frame = np.asarray(frame)
            # A drawn frame's figure is a web of reference cycles that only the cycle
            # collector frees; left to its own pace it let RSS grow by 1-4 MB a frame
            # (1200 px, 40 frames: 326 MB with, 253 MB without the growth).
            if collect:
                gc.collect()
            if previous is None:
                canvas = np.array(frame[..., :3], np.uint8)
            else:
                h = max(previous.shape[0], frame.shape[0])
                w = max(previous.shape[1], frame.shape[1])
                canvas = np.full((h, w, 3), 255, np.uint8)
                canvas[: frame.shape[0], : frame.shape[1]] = frame[..., :3]
            box = _changed_box(previous, canvas)
            if box is None:
                assert pending is not None
                pending = (pending[0], pending[1] + delay)
                continue
            if pending is not None:
                out.write(_gif_frame(*pending))
            top, left, bottom, right = box
            pending = (_encode_part(canvas[top:bottom, left:right], left, top), delay)
            previous = canvas
        if pending is None or previous is None:
            raise ValueError("a GIF needs at least one frame")
        out.write(_gif_frame(pending[0], pending[1] + hold_last * delay))
        out.write(b";")
        # The screen is as large as the largest frame, known only now.
        out.seek(6)
        out.write(struct.pack("<HH", previous.shape[1], previous.shape[0]))
    return path


# GIF89a, a logical screen whose size is written at the end and without a global colour
# table (each frame has its own), and the NETSCAPE2.0 extension: loop forever.
_GIF_HEAD = (
    b"GIF89a"
    + struct.pack("<HHBBB", 0, 0, 0, 0, 0)
    + b"\x21\xff\x0bNETSCAPE2.0\x03\x01"
    + struct.pack("<H", 0)
    + b"\x00"
)


def _changed_box(previous: np.ndarray | None, canvas: np.ndarray) -> tuple[int, ...] | None:
    """``(top, left, bottom, right)`` of the pixels that differ, the whole canvas for the
    first frame or a new size, ``None`` when nothing changed."""
    if previous is None or previous.shape != canvas.shape:
        return (0, 0, canvas.shape[0], canvas.shape[1])
    diff = np.any(previous != canvas, axis=2)
    rows = np.flatnonzero(diff.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(diff.any(axis=0))
    return (int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1)


def _encode_part(rgb: np.ndarray, left: int, top: int) -> bytes:
    """One image of a GIF (descriptor, local colour table, LZW data) at ``(left, top)``.

    Pillow writes the part as a one-frame GIF (adaptive palette); its colour table and
    image data are taken from that file and given the part's position.
    """
    from PIL import Image

    buffer = io.BytesIO()
    image = Image.fromarray(np.ascontiguousarray(rgb)).convert("P", palette=Image.Palette.ADAPTIVE)
    image.save(buffer, format="GIF", interlace=False)
    data = buffer.getvalue()
    flags = data[10]
    table = b""
    at = 13
    if flags & 0x80:
        size = 3 * 2 ** ((flags & 0x07) + 1)
        table, at = data[at : at + size], at + size
    while data[at] == 0x21:  # extensions Pillow may add: skipped
        at += 2
        while data[at]:
            at += data[at] + 1
        at += 1
    if data[at] != 0x2C:
        raise ValueError("Pillow wrote a GIF without an image")  # pragma: no cover
    width, height, local = struct.unpack_from("<HHB", data, at + 5)
    at += 10
    if local & 0x80:
        size = 3 * 2 ** ((local & 0x07) + 1)
        table, at, flags = data[at : at + size], at + size, local
    start = at
    at += 1  # the LZW minimum code size, then sub-blocks up to an empty one
    while data[at]:
        at += data[at] + 1
    descriptor = b"\x2c" + struct.pack("<HHHHB", left, top, width, height, 0x80 | (flags & 0x07))
    return descriptor + table + data[start : at + 1]


def _gif_frame(image: bytes, delay: int) -> bytes:
    """A graphic control extension (``delay`` in 1/100 s, keep the frame: disposal 1) and
    the image."""
    return b"\x21\xf9\x04" + struct.pack("<BHBB", 0x04, min(delay, 0xFFFF), 0, 0) + image


# --- workcell drawing ------------------------------------------------------------------------


def draw_geometry(ax: Axes, geom: BaseGeometry, **style: Any) -> None:
    """Fill a shapely polygon / multipolygon (holes respected) or draw a line or point."""
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    if geom.is_empty:
        return
    if geom.geom_type in ("MultiPolygon", "GeometryCollection", "MultiLineString", "MultiPoint"):
        for g in geom.geoms:
            draw_geometry(ax, g, **style)
        return
    if geom.geom_type == "Polygon":
        rings = [geom.exterior, *geom.interiors]
        verts = np.concatenate([np.asarray(r.coords) for r in rings])
        codes = np.concatenate(
            [
                [MplPath.MOVETO] + [MplPath.LINETO] * (len(r.coords) - 2) + [MplPath.CLOSEPOLY]
                for r in rings
            ]
        )
        ax.add_patch(PathPatch(MplPath(verts, codes), **style))
    elif geom.geom_type == "LineString":
        xy = np.asarray(geom.coords)
        ax.plot(xy[:, 0], xy[:, 1], color=style.get("edgecolor", style.get("facecolor", "k")), lw=2)
    elif geom.geom_type == "Point":
        ax.plot(geom.x, geom.y, "o", color=style.get("facecolor", "k"), ms=5)


def _label(ax: Axes, geom: BaseGeometry, text: str, color: str) -> None:
    p = geom.representative_point()
    ax.annotate(
        text,
        (p.x, p.y),
        ha="center",
        va="center",
        fontsize=8,
        color=color,
        weight="bold",
        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7},
        parse_math=False,
    )


def draw_workcell(
    ax: Axes,
    cell: Workcell,
    highlight: Sequence[str] = (),
    labels: bool = True,
    offsets: Mapping[str, tuple[float, float]] | None = None,
) -> None:
    """Bounds, obstacles, sources and destinations; ``highlight``ed regions are shaded darker.

    ``offsets`` moves regions by ``(dx, dy)``, by name (a region on a conveyor belt).
    """
    from shapely import affinity

    offsets = offsets or {}
    xmin, ymin, xmax, ymax = cell.bounds
    ax.add_patch(_rect(xmin, ymin, xmax, ymax))
    for name, geom in cell.obstacle_geometries.items():
        draw_geometry(ax, geom, facecolor=COLORS["obstacle"], edgecolor="black", lw=0.8)
        if labels:
            _label(ax, geom, name, "black")
    for regions, color in (
        (cell.sources, COLORS["source"]),
        (cell.destinations, COLORS["destination"]),
    ):
        for name, region in regions.items():
            on = name in highlight
            for geom in region.geometries:
                if name in offsets:
                    geom = affinity.translate(geom, *offsets[name])
                draw_geometry(
                    ax,
                    geom,
                    facecolor=color,
                    alpha=0.75 if on else 0.25,
                    edgecolor=color,
                    lw=2.0 if on else 1.0,
                )
                if labels:
                    _label(ax, geom, name, color)
    pad = 0.02 * max(xmax - xmin, ymax - ymin)
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (workcell units)")
    ax.set_ylabel("y (workcell units)")


def _rect(xmin: float, ymin: float, xmax: float, ymax: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, lw=1.5, ec="black")


def draw_robot(
    ax: Axes,
    cell: Workcell,
    q: np.ndarray,
    carrying: str | None = None,
    alpha: float = 1.0,
    color: str | None = None,
) -> None:
    """The robot (and the carried part, in the part colour) at configuration ``q``."""
    bodies, part = cell.robot_shapes(np.asarray(q, float), carrying)
    c = color or COLORS["robot"]
    for g in bodies:
        draw_geometry(ax, g, facecolor=c, edgecolor="black", lw=0.6, alpha=alpha)
    if part is not None:
        draw_geometry(ax, part, facecolor=COLORS["part"], edgecolor="black", lw=0.6, alpha=alpha)
    if cell.robot.kind == "arm":
        joints = cell.robot.joint_positions(q)[0]  # type: ignore[attr-defined]
        ax.plot(joints[:, 0], joints[:, 1], "o", color="black", ms=3, alpha=alpha)


def save_workcell(
    cell: Workcell, path: str | Path, q: np.ndarray | None = None, carrying: str | None = None
) -> Path:
    """:func:`workcell_figure` saved as a PNG."""
    return save_figure(workcell_figure(cell, q, carrying), path)


def workcell_figure(
    cell: Workcell, q: np.ndarray | None = None, carrying: str | None = None
) -> Figure:
    """The workcell, the robot at ``q`` (default: start) carrying a part (default: the first)."""
    from matplotlib.patches import Patch

    fig, axes = new_figure(size=6.0)
    fig.set_size_inches(8.5, 6.0)
    ax = axes[0, 0]
    draw_workcell(ax, cell)
    if carrying is None and cell.parts:
        carrying = next(iter(cell.parts))
    draw_robot(ax, cell, cell.robot.start if q is None else q, carrying)
    handles = [
        Patch(color=COLORS["obstacle"], label="obstacle"),
        Patch(color=COLORS["source"], alpha=0.5, label="source"),
        Patch(color=COLORS["destination"], alpha=0.5, label="destination"),
        Patch(color=COLORS["robot"], label=f"robot ({cell.robot.kind}) at start"),
    ]
    if carrying is not None:
        handles.append(Patch(color=COLORS["part"], label=f"carried part {carrying}"))
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False
    )
    # Names are the user's text: "$x^$" is a title, not matplotlib math to parse.
    ax.set_title(cell.name or "workcell", parse_math=False)
    return fig


def save_scenario(setup: Setup, path: str | Path) -> Path:
    """:func:`scenario_figure` saved as a PNG."""
    return save_figure(scenario_figure(setup), path)


def scenario_figure(setup: Setup) -> Figure:
    """Everything a 2-D scenario describes: the workcell with the robot at its start (when
    it has one) and what each package's section adds (:attr:`cellplan.core.Package.draw`)."""
    from matplotlib.patches import Patch

    from cellplan.registry import packages

    fig, axes = new_figure(size=6.0)
    fig.set_size_inches(8.5, 6.0)
    ax = axes[0, 0]
    sc = setup.scenario
    handles: list[Any] = [Patch(color=COLORS["obstacle"], label="obstacle")]
    if setup.has_robot:
        cell = setup.planar_workcell
        draw_workcell(ax, cell)
        carrying = next(iter(cell.parts), None)
        draw_robot(ax, cell, cell.robot.start, carrying)
        if cell.sources:
            handles.append(Patch(color=COLORS["source"], alpha=0.5, label="source"))
        if cell.destinations:
            handles.append(Patch(color=COLORS["destination"], alpha=0.5, label="destination"))
        handles.append(Patch(color=COLORS["robot"], label=f"robot ({cell.robot.kind}) at start"))
        if carrying is not None:
            handles.append(Patch(color=COLORS["part"], label=f"carried part {carrying}"))
    else:
        spec = planar_workcell(sc)
        b = spec.bounds
        ax.add_patch(_rect(b.xmin, b.ymin, b.xmax, b.ymax))
        for name, shape in spec.planar_obstacles.items():
            geom = shape.to_shapely()
            draw_geometry(ax, geom, facecolor=COLORS["obstacle"], edgecolor="black", lw=0.8)
            _label(ax, geom, name, "black")
        pad = 0.02 * max(b.xmax - b.xmin, b.ymax - b.ymin)
        ax.set_xlim(b.xmin - pad, b.xmax + pad)
        ax.set_ylim(b.ymin - pad, b.ymax + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("x (workcell units)")
        ax.set_ylabel("y (workcell units)")
    present = sc.section_names()
    for pkg in packages().values():
        if pkg.draw is not None and pkg.section in present:
            handles.extend(pkg.draw(setup, ax))
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False
    )
    ax.set_title(sc.name or setup.name, parse_math=False)
    return fig


# --- C-space drawing -------------------------------------------------------------------------


def _axis_extent(grid: Grid, i: int, robot_axis: str) -> tuple[float, float, str]:
    lo, hi = float(grid.lower[i]), float(grid.upper[i])
    if robot_axis in ("x", "y"):
        return lo, hi, f"{robot_axis} (workcell units)"
    return units.degrees(lo), units.degrees(hi), f"{robot_axis} (deg)"


def draw_cspace_slice(
    ax: Axes, grid: Grid, free2d: np.ndarray, names: tuple[str, str], title: str = ""
) -> None:
    """One 2-D slice of a free bitmap (first two axes), free light and blocked dark."""
    from matplotlib.colors import ListedColormap

    x0, x1, xl = _axis_extent(grid, 0, names[0])
    y0, y1, yl = _axis_extent(grid, 1, names[1])
    ax.imshow(
        free2d.T,
        origin="lower",
        extent=(x0, x1, y0, y1),
        interpolation="nearest",
        cmap=ListedColormap([COLORS["blocked"], COLORS["free"]]),
        vmin=0,
        vmax=1,
        aspect="auto",
    )
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    if names[0] in ("x", "y") and names[1] in ("x", "y"):
        ax.set_aspect("equal")
    if title:
        ax.set_title(title, fontsize=9)


def cspace_legend(fig: Figure, carrying: bool) -> None:
    """The legend of C-space pictures: what light and dark mean, below the axes."""
    from matplotlib.patches import Patch

    blocked = "blocked: the robot touches an obstacle or leaves the bounds"
    if carrying:
        blocked = (
            "blocked: the robot or the carried part touches an obstacle or another source "
            "(other sources are obstacles while carrying), or leaves the bounds"
        )
    handles = [
        Patch(facecolor=COLORS["free"], edgecolor="#888888", label="free configuration"),
        Patch(facecolor=COLORS["blocked"], label=blocked),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=1, fontsize=9, frameon=False)


def save_cspace(
    cell: ValiditySpace,
    grid: Grid,
    free: np.ndarray,
    path: str | Path,
    slice_index: int | None = None,
    title_extra: str = "",
    carrying: bool = False,
) -> Path:
    """The workcell beside its free-configuration bitmap (2-D), or slices of a 3-D one.

    For 3-D spaces, ``slice_index`` picks one slice along the last axis; by
    default six evenly spaced slices are drawn. A legend says what light and dark
    mean (``carrying``: other sources count as obstacles).
    """
    names = cell.robot.axis_names
    if grid.ndim == 2:
        fig, axes = new_figure(ncols=2, size=5.0)
        _workspace_panel(axes[0, 0], cell, labels=True)
        draw_cspace_slice(
            axes[0, 1],
            grid,
            free,
            (names[0], names[1]),
            f"free configurations ({title_extra}): {free.mean():.1%} free",
        )
        cspace_legend(fig, carrying)
        return save_figure(fig, path)
    if grid.ndim != 3:
        raise ValueError("C-space pictures are for 2-D and 3-D spaces")
    n = grid.shape[2]
    picks = (
        [slice_index]
        if slice_index is not None
        else list(np.linspace(0, n - 1, 6).round().astype(int))
    )
    if any(not 0 <= k < n for k in picks):
        raise ArgumentError(f"must be in [0, {n - 1}] for this grid", "--slice")
    ncols = min(3, len(picks)) + 1
    nrows = math.ceil(len(picks) / (ncols - 1))
    fig, axes = new_figure(ncols=ncols, nrows=nrows, size=3.6)
    _workspace_panel(axes[0, 0], cell, labels=False)
    for r in range(1, nrows):
        axes[r, 0].axis("off")
    third = grid.axis(2)
    angle = cell.robot.angular[2]
    unit = " deg" if angle else ""
    for idx, k in enumerate(picks):
        ax = axes[idx // (ncols - 1), 1 + idx % (ncols - 1)]
        value = units.degrees(third[k]) if angle else third[k]
        draw_cspace_slice(
            ax,
            grid,
            free[:, :, k],
            (names[0], names[1]),
            f"{names[2]} = {value:.1f}{unit}: {free[:, :, k].mean():.0%} free",
        )
    for idx in range(len(picks), nrows * (ncols - 1)):
        axes[idx // (ncols - 1), 1 + idx % (ncols - 1)].axis("off")
    fig.suptitle(f"free configurations ({title_extra}), {free.mean():.1%} of {grid.size} cells")
    cspace_legend(fig, carrying)
    return save_figure(fig, path)


def _workspace_panel(ax: Any, cell: ValiditySpace, labels: bool) -> None:
    """The planar workcell with its robot at the start; a 3-D cell has its own picture
    (``cellplan show``), so the panel says so."""
    if isinstance(cell, Workcell):
        draw_workcell(ax, cell, labels=labels)
        draw_robot(ax, cell, cell.robot.start)
        ax.set_title("workcell", fontsize=None if labels else 9)
        return
    ax.axis("off")
    ax.text(0.5, 0.5, "3-D cell:\nsee cellplan show", ha="center", va="center", fontsize=11)


# --- trajectories ----------------------------------------------------------------------------


def plot_trajectory(
    traj: Trajectory, path: str | Path | None = None, ax: Axes | None = None
) -> Any:
    """Draw a :class:`~cellplan.trajectory.Trajectory`; return the figure (saved to ``path``).

    Columns that come in ``NAME.x`` / ``NAME.y`` pairs (the discs of an assembly) are drawn
    as planar paths, start (circle) to end (square). Otherwise each configuration column is
    drawn against ``t`` (angles in degrees for reading), the background shaded by mode, and
    the events marked as vertical lines, with legends for both.
    """
    pairs = _xy_pairs(traj.columns)
    fig: Any
    if pairs:
        if ax is None:
            fig, axes = new_figure(size=6.0)
            ax = axes[0, 0]
        else:
            fig = ax.get_figure()
        for name, (ix, iy) in pairs.items():
            (line,) = ax.plot(traj.q[:, ix], traj.q[:, iy], lw=1.4, label=name)
            ax.plot(traj.q[0, ix], traj.q[0, iy], "o", color=line.get_color(), ms=5)
            ax.plot(traj.q[-1, ix], traj.q[-1, iy], "s", color=line.get_color(), ms=5)
        ax.set_aspect("equal")
        ax.set_xlabel("x (workcell units)")
        ax.set_ylabel("y (workcell units)")
        ax.set_title("paths: start (circle) to end (square)")
        ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8, frameon=False)
    else:
        n = traj.dim
        if ax is None:
            fig, axes = new_figure(nrows=n, size=1.0)
            fig.set_size_inches(9.0, 1.9 * n + 0.6)
            axs = list(axes[:, 0])
        else:
            fig, axs = ax.get_figure(), [ax] * n
        _shade_modes(axs, traj)
        for j, a in enumerate(axs[:n]):
            values = traj.q[:, j]
            unit = traj.units[j]
            if unit == "rad":
                values, unit = units.degrees(values), "deg"
            a.plot(traj.t, values, color="#1f3b73", lw=1.3)
            a.set_ylabel(f"{traj.columns[j]}\n({unit})", fontsize=9)
        _mark_events(axs, traj)
        axs[-1].set_xlabel(f"t ({traj.time_unit})")
    return save_figure(fig, path) if path is not None else fig


def _xy_pairs(columns: tuple[str, ...]) -> dict[str, tuple[int, int]]:
    index = {c: i for i, c in enumerate(columns)}
    pairs = {}
    for c in columns:
        if c.endswith(".x") and c[:-2] + ".y" in index:
            pairs[c[:-2]] = (index[c], index[c[:-2] + ".y"])
    return pairs if 2 * len(pairs) == len(columns) else {}


def _shade_modes(axs: list[Any], traj: Trajectory) -> None:
    import matplotlib.pyplot as plt

    if len(traj) < 2 or len(traj.modes) < 2:
        return
    cmap = plt.get_cmap("tab20")
    change = np.flatnonzero(np.diff(traj.mode)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(traj) - 1]])
    seen: set[int] = set()
    for s, e in zip(starts, ends, strict=True):
        m = int(traj.mode[s])
        label = traj.modes[m] if m not in seen and len(seen) < 12 else None
        seen.add(m)
        for a in axs:
            a.axvspan(traj.t[s], traj.t[e], color=cmap(m % 20), alpha=0.18, lw=0, label=label)
            label = None
    axs[0].legend(
        title="mode", loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False
    )


def _mark_events(axs: list[Any], traj: Trajectory) -> None:
    kinds = sorted({e.kind for e in traj.events})
    if not kinds:
        return
    styles = dict(zip(kinds, ["-", "--", ":", "-."] * 4, strict=False))
    for kind in kinds:
        times = [traj.t[e.index] for e in traj.events if e.kind == kind]
        for k, t in enumerate(times):
            for a in axs:
                a.axvline(
                    t,
                    color="#8c1c13",
                    ls=styles[kind],
                    lw=0.8,
                    alpha=0.7,
                    label=kind if (k == 0 and a is axs[-1]) else None,
                )
    axs[-1].legend(
        title="events", loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False
    )

"""Pictures of the strategies paper: Fig. 8 (cost-to-go contours and the optimal actions as
a vector field) and Figs. 9-15 (sample paths, one frame per mode change, and a GIF).

matplotlib is imported lazily through :mod:`cellplan.plots`.
"""

from __future__ import annotations

import textwrap
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from cellplan import plots as base
from cellplan import units
from cellplan.strategies.policy.decisions import FMP, STAY, Action
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.sim.simulate import Simulation

OTHER_AXIS = 99  # marker code: the optimal move changes only the axes not shown


def _slice(
    strategy: Strategy, values: np.ndarray, fixed: np.ndarray | None
) -> tuple[np.ndarray, tuple[int, ...]]:
    """A 2-D view of a layer: the first two C-space axes, other axes at ``fixed``'s cell."""
    mdp = strategy.mdp
    grid = values.reshape(tuple(mdp.shape))
    if len(mdp.shape) == 2:
        return grid, ()
    q = fixed if fixed is not None else mdp.lower + 0.5 * (mdp.upper - mdp.lower)
    rest = tuple(
        int(np.clip(np.floor((q[j] - mdp.lower[j]) / mdp.spacing[j]), 0, mdp.shape[j] - 1))
        for j in range(2, len(mdp.shape))
    )
    index: tuple[Any, ...] = (slice(None), slice(None), *rest)
    view: Any = grid[index]
    return view, rest


def _axes_labels(strategy: Strategy, cell: Any) -> tuple[str, str, bool]:
    """Names of the two plotted axes, and whether they are angles (drawn in degrees)."""
    names = tuple(cell.robot.axis_names)
    angular = all(units.angular_axes(names[:2]))
    return str(names[0]), str(names[1]), angular


def plot_mode(
    strategy: Strategy,
    cell: Any,
    mode: int,
    path: str | Path,
    fixed: np.ndarray | None = None,
    arrows: int = 24,
) -> Path:
    """Fig. 8 for one mode: level sets of the cost-to-go and the optimal actions.

    For 3-D C-spaces both panels show the slice through ``fixed`` (default: the middle) on
    the remaining axes. In a time-varying model (Section VI-1) ``mode`` is a layer (a mode
    at a phase): the titles give the phase, and where the plotted axes are the workcell's
    x and y both panels outline the sources and destinations where they lie at that phase
    (a region on a conveyor belt moved by :func:`~.periodic.region_offset`).
    """
    mdp = strategy.mdp
    fig, axes = base.new_figure(ncols=2, size=5.0)
    h2, rest = _slice(strategy, strategy.values[mode], fixed)
    xs = mdp.lower[0] + (np.arange(mdp.shape[0]) + 0.5) * mdp.spacing[0]
    ys = mdp.lower[1] + (np.arange(mdp.shape[1]) + 0.5) * mdp.spacing[1]
    xl, yl, angular = _axes_labels(strategy, cell)
    scale = units.degrees if angular else (lambda v: v)
    X, Y = np.meshgrid(scale(xs), scale(ys), indexing="ij")
    ax = axes[0, 0]
    masked = np.ma.masked_invalid(h2)
    ax.set_facecolor(base.COLORS["blocked"])
    if masked.count() > 1:
        cs = ax.contourf(X, Y, masked, levels=24, cmap="viridis")
        ax.contour(X, Y, masked, levels=24, colors="white", linewidths=0.3)
        fig.colorbar(cs, ax=ax, shrink=0.8, label="relative cost-to-go (stages)")
    label = layer_title(strategy, mode)
    where = "" if not rest else f" (slice at cells {rest} of the other axes)"
    ax.set_title(wrap_title(f"cost-to-go, mode {label}{where}", 60), fontsize=9)
    ax.set_xlabel(xl + (" (deg)" if angular else ""))
    ax.set_ylabel(yl + (" (deg)" if angular else ""))
    ax.set_aspect("equal" if not angular else "auto")
    # Vector field of the optimal actions at a coarse subset of cell centres.
    ax2 = axes[0, 1]
    ax2.set_facecolor(base.COLORS["blocked"])
    step = max(1, int(max(mdp.shape[0], mdp.shape[1]) // arrows))
    pts, vec, marks = _action_marks(strategy, mode, (xs[::step], ys[::step]), rest)
    ax2.imshow(
        np.isfinite(h2).T,
        origin="lower",
        cmap="gray",
        vmin=-1,
        vmax=1.5,
        aspect="auto",
        extent=(scale(mdp.lower[0]), scale(mdp.upper[0]), scale(mdp.lower[1]), scale(mdp.upper[1])),
    )
    if pts:
        P = np.array(pts)
        V = np.array(vec)
        n = np.linalg.norm(V, axis=1, keepdims=True)
        V = V / np.where(n > 0, n, 1)
        ax2.quiver(
            scale(P[:, 0]),
            scale(P[:, 1]),
            V[:, 0],
            V[:, 1],
            color=base.COLORS["path"],
            angles="xy",
            pivot="mid",
            scale=arrows * 1.4,
            width=0.004,
        )
    symbols = {FMP: ("o", "#1f77b4"), STAY: ("x", "k"), OTHER_AXIS: ("+", "#7b2cbf")}
    names = {
        FMP: "fine motion (pick or place)",
        STAY: "stay",
        OTHER_AXIS: "move along another axis",
    }
    for x, y, u in marks:
        sym, color = symbols[u]
        ax2.plot(scale(x), scale(y), sym, color=color, ms=3)
    # One legend entry per kind of mark shown (handles only: nothing more is plotted).
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], marker=symbols[u][0], ls="", color=symbols[u][1], ms=4, label=names[u])
        for u in sorted({u for _, _, u in marks})
    ]
    if pts:
        handles.append(Line2D([], [], color=base.COLORS["path"], label="move (arrow: direction)"))
    if handles:
        ax2.legend(handles=handles, fontsize=7, loc="upper right", framealpha=0.85)
    words = spell_mode(replace(mdp.modes[mode], phase=-1))  # the label gives the phase
    ax2.set_title(wrap_title(f"optimal actions, mode {label} ({words})", 60), fontsize=9)
    ax2.set_xlabel(xl + (" (deg)" if angular else ""))
    ax2.set_ylabel(yl + (" (deg)" if angular else ""))
    ax2.set_aspect("equal" if not angular else "auto")
    if mdp.belts and tuple(cell.robot.axis_names[:2]) == ("x", "y"):  # regions that move
        for panel in (ax, ax2):
            draw_belts(panel, strategy, cell, filled=False)
            draw_regions_at(panel, strategy, cell, mode)
    return base.save_figure(fig, path)


def _action_marks(
    strategy: Strategy, mode: int, axes: tuple[np.ndarray, np.ndarray], rest: tuple[int, ...]
) -> tuple[list[np.ndarray], list[np.ndarray], list[tuple[float, float, int]]]:
    """The optimal actions of ``mode`` at the live cell centres ``axes`` (x and y values),
    the other axes at the cells ``rest``: the points and steps of the moves in the plane,
    and a mark ``(x, y, kind)`` where the action is an FMP, a stay or a move along another
    axis."""
    mdp = strategy.mdp
    others = [mdp.lower[k + 2] + (r + 0.5) * mdp.spacing[k + 2] for k, r in enumerate(rest)]
    pts, vec, marks = [], [], []
    for x in axes[0]:
        for y in axes[1]:
            q = np.array([x, y, *others])
            if not strategy.in_domain(q, mode):
                continue
            try:
                action = strategy.action(q, mode)
            except ValueError:  # live, but no action has a value here
                continue
            assert isinstance(action, Action)  # one configuration, one action
            if action.kind != "move":  # any pick or drop (Section VI-2: of any request)
                marks.append((q[0], q[1], FMP if action.is_fmp else STAY))
                continue
            dq = np.asarray(action.step)
            if np.linalg.norm(dq[:2]) <= 1e-12:
                marks.append((q[0], q[1], OTHER_AXIS))  # a turn or a move of joint 3
                continue
            pts.append(q[:2])
            vec.append(dq[:2])
    return pts, vec, marks


def layer_title(strategy: Strategy, layer: int) -> str:
    """How a title names a layer: its mode's label, and in a time-varying model (Section
    VI-1) its phase of the period."""
    mdp = strategy.mdp
    mode = mdp.modes[layer]
    if mdp.period == 1:
        return mode.label
    return f"{replace(mode, phase=-1).label}, phase {mode.phase} of {mdp.period}"


def region_offsets(strategy: Strategy, layer: int) -> dict[str, tuple[float, float]]:
    """Where each region on a belt lies at ``layer``'s phase (Section VI-1): its offset
    from the scenario position, by name (empty in a stationary model)."""
    from cellplan.strategies.variants.periodic import region_offset

    offsets = {}
    for name in strategy.mdp.belts:
        offset = region_offset(strategy.mdp, name, layer)
        if offset is not None:
            offsets[name] = offset
    return offsets


BELT_COLOR = "#d9d2c3"
"""Fill of a conveyor belt's track (Section VI-1): paler than every region and obstacle."""
BELT_EDGE = "#8a7f6a"
"""Outline of a belt's track over a plot of values, and the arrow of its motion."""


def draw_belts(ax: Any, strategy: Strategy, cell: Any, filled: bool = True) -> None:
    """Draw the track of every region on a conveyor belt (Section VI-1): the band its
    region sweeps over the period, from where a part comes in to where the last phase
    leaves it, with an arrow along the belt's motion; shaded under the workcell
    (``filled``), or outlined above a plot of values. Nothing in a stationary model.
    Each band's ``gid`` is ``belt:<region>``."""
    # Deferred for start-up time: the experiment list loads without these.
    from shapely import affinity
    from shapely.ops import unary_union

    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.strategies.variants.periodic import belt_offset

    mdp = strategy.mdp
    for name, velocity in mdp.belts.items():
        region = cell.region(name)
        end = belt_offset(velocity, mdp.period - 1, mdp.stage_time)
        for geom in region.geometries:
            track = unary_union([geom, affinity.translate(geom, *end)]).convex_hull
            # Under the workcell's regions, or above the values' contours.
            zorder = 0.5 if filled else 2.5
            style: dict[str, Any] = (
                {"facecolor": BELT_COLOR, "edgecolor": "none"}
                if filled
                else {"facecolor": "none", "edgecolor": BELT_EDGE, "ls": "--"}
            )
            base.draw_geometry(ax, track, gid=f"belt:{name}", zorder=zorder, **style)
            start = geom.centroid
            ax.annotate(
                "",
                xy=(start.x + end[0], start.y + end[1]),
                xytext=(start.x, start.y),
                arrowprops={"arrowstyle": "->", "color": BELT_EDGE, "lw": 1.0},
                zorder=zorder + 0.1,
            )


def draw_regions_at(ax: Any, strategy: Strategy, cell: Any, layer: int) -> None:
    """Outline every source and destination where it lies at ``layer``'s phase (a region
    on a conveyor belt moves, Section VI-1); each outline's ``gid`` is the region's name."""
    # Deferred for start-up time: the experiment list loads without these.
    from shapely import affinity

    offsets = region_offsets(strategy, layer)
    for regions, color in (
        (cell.sources, base.COLORS["source"]),
        (cell.destinations, base.COLORS["destination"]),
    ):
        for name, region in regions.items():
            dx, dy = offsets.get(name, (0.0, 0.0))
            for geom in region.geometries:
                moved = affinity.translate(geom, dx, dy)
                base.draw_geometry(
                    ax, moved, facecolor="none", edgecolor=color, lw=1.5, gid=name, zorder=3
                )
                p = moved.representative_point()
                ax.annotate(
                    name,
                    (p.x, p.y),
                    ha="center",
                    va="center",
                    fontsize=7,
                    color=color,
                    parse_math=False,
                    zorder=4,
                )


def mode_regions(mode: Any) -> list[str]:
    """The regions a frame highlights: the request's source and destination, and the reject
    region of an X mode (Section VI-3); with simultaneous requests (a Q mode, Section VI-2)
    the sources of the waiting requests and the carried request's source and destination."""
    if mode.kind == "NR":
        return []
    if mode.kind == "Q":
        regions = [w.split(",")[1] for w in mode.waiting]
        if mode.part:
            regions += [mode.source, mode.destination]
        return list(dict.fromkeys(regions))
    return [mode.source, mode.destination] + ([mode.reject] if mode.kind == "X" else [])


def carried_part(mode: Any) -> str | None:
    """The part the robot holds in a mode (drawn with it), or None."""
    if mode.kind in ("C", "X") or (mode.kind == "Q" and mode.part):
        return str(mode.part)
    return None


def spell_mode(mode: Any) -> str:
    """A mode in words for a title: ``<P1,S1,D1,W>`` is "waiting: P1 from S1 to D1"
    (the paper's shorthand, Section II-C, spelled out)."""
    at = f" (phase {mode.phase})" if mode.phase >= 0 else ""
    route = f"{mode.part} from {mode.source} to {mode.destination}"
    if mode.kind == "NR":
        text = "no request"
    elif mode.kind == "W":
        text = f"waiting: {route}"
    elif mode.kind == "C":
        text = f"carrying {route}"
    elif mode.kind == "X":
        text = f"carrying rejected {mode.part} (from {mode.source}) to {mode.reject}"
    else:  # Q: simultaneous requests (Section VI-2)
        waiting = ", ".join(w.replace(",", " ", 1).replace(",", "->") for w in mode.waiting)
        text = f"waiting: {waiting or 'none'}"
        if mode.part:
            text += f"; carrying {route}"
    return text + at


def wrap_title(text: str, width: int) -> str:
    """A title on lines of at most ``width`` characters (a mode label of simultaneous
    requests lists every waiting request); lines break at spaces only."""
    return textwrap.fill(text, width, break_long_words=False, break_on_hyphens=False)


def _frame(
    ax: Any, strategy: Strategy, cell: Any, sim: Simulation, first: int, last: int, title: str
) -> None:
    mode = strategy.mdp.modes[int(sim.modes[first])]
    highlight = mode_regions(mode)
    # A region on a belt (Section VI-1) is drawn where it is when the segment ends.
    offsets = region_offsets(strategy, int(sim.modes[last]))
    base.draw_workcell(ax, cell, highlight=highlight, labels=False, offsets=offsets)
    draw_belts(ax, strategy, cell)
    carrying = carried_part(mode)
    tool = cell.robot.tool_pose(sim.q[first : last + 1])[:, :2]
    ax.plot(tool[:, 0], tool[:, 1], "-", color=base.COLORS["path"], lw=1.2)
    base.draw_robot(ax, cell, sim.q[first], carrying, alpha=0.25)
    base.draw_robot(ax, cell, sim.q[last], carrying)
    ax.set_title(title, fontsize=8 if "\n" not in title else 7)
    ax.set_xlabel("")
    ax.set_ylabel("")


def _axis_labels(ax: Any, cell: Any, x: bool = True, y: bool = True) -> None:
    """The workcell's axes, in its length unit where the scenario gives one."""
    unit = getattr(cell, "units", None)
    suffix = f" ({unit})" if isinstance(unit, str) and unit else ""
    if x:
        ax.set_xlabel(f"x{suffix}", fontsize=7)
    if y:
        ax.set_ylabel(f"y{suffix}", fontsize=7)


def _frame_legend(ax: Any, fig: Any = None) -> None:
    """What a frame draws: the tool's path, the robot at the segment's start (faded) and
    end, the carried part, and the regions (the request's shaded). With ``fig``, one
    legend under the whole grid of panels instead of on ``ax``."""
    # Deferred for start-up time: the experiment list loads without these.
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    c = base.COLORS
    handles = [
        Line2D([], [], color=c["path"], lw=1.2, label="tool path"),
        Patch(facecolor=c["robot"], edgecolor="black", alpha=0.25, label="robot, segment start"),
        Patch(facecolor=c["robot"], edgecolor="black", label="robot, segment end"),
        Patch(facecolor=c["part"], edgecolor="black", label="carried part"),
        Patch(facecolor=c["source"], alpha=0.5, label="source"),
        Patch(facecolor=c["destination"], alpha=0.5, label="destination"),
        Patch(facecolor=c["obstacle"], label="obstacle"),
    ]
    if fig is not None:
        fig.legend(
            handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=7
        )
        return
    ax.legend(handles=handles, fontsize=6, loc="upper right", framealpha=0.85)


FRAMES_SHOWN = 60
"""Most mode segments drawn, in ``frames.png`` and as ``frame_###.png`` each; a longer run
says how many it leaves out."""


def plot_frames(
    strategy: Strategy,
    cell: Any,
    sim: Simulation,
    outdir: str | Path,
    max_frames: int = FRAMES_SHOWN,
    each: bool = False,
) -> list[Path]:
    """Figs. 9-15: one panel per mode segment (regions of the request shaded, the carried
    part drawn) in ``frames.png``, a grid laid out for the workcell's aspect ratio
    (:func:`cellplan.plots.grid_shape`), with axis labels and a legend; with ``each``,
    also one PNG per segment (``frame_NNN.png``). Returns the paths, ``frames.png`` last.

    Only the first ``max_frames`` segments are drawn: a long run has thousands of segments
    (about one per ten stages), and the trajectory file holds them all. The separate
    PNGs are off by default: saving them was most of ``simulate``'s time (docs/benchmarks.md).
    """
    outdir = Path(outdir)
    segs = sim.segments()
    shown = segs[:max_frames]
    paths = []
    for i, (a, b) in enumerate(shown if each else []):
        fig, axes = base.new_figure(size=4.0)
        words = spell_mode(strategy.mdp.modes[int(sim.modes[a])])
        title = wrap_title(f"({i + 1}) stages {a}-{b}: {words}", 52)
        _frame(axes[0, 0], strategy, cell, sim, a, b, title)
        _axis_labels(axes[0, 0], cell)
        _frame_legend(axes[0, 0])
        paths.append(base.save_figure(fig, outdir / f"frame_{i + 1:03d}.png", dpi=80))
    xmin, ymin, xmax, ymax = cell.bounds
    aspect = (xmax - xmin) / (ymax - ymin)
    rows, cols = base.grid_shape(len(shown), aspect)
    panel = min(3.2, 13.0 / cols)  # panel width in inches; the page is about 13 wide
    titles = [
        wrap_title(
            f"({i + 1}) {spell_mode(strategy.mdp.modes[int(sim.modes[a])])}, stages {a}-{b}",
            int(16 * panel),  # about the characters of a 7-point line across the panel
        )
        for i, (a, b) in enumerate(shown)
    ]
    lines = max([t.count("\n") + 1 for t in titles], default=1)
    fig, axes = base.new_figure(ncols=cols, nrows=rows, size=panel)
    fig.set_size_inches(cols * panel, rows * (panel / aspect + 0.35 + 0.12 * (lines - 1)))
    for ax in axes.ravel()[len(shown) :]:
        ax.set_axis_off()
    for i, (a, b) in enumerate(shown):
        _frame(axes.ravel()[i], strategy, cell, sim, a, b, titles[i])
        # Axis names on the left column and the bottom row of the panels drawn.
        _axis_labels(axes.ravel()[i], cell, x=i + cols >= len(shown), y=i % cols == 0)
    if shown:
        _frame_legend(axes.ravel()[0], fig)
    if len(segs) > len(shown):
        fig.suptitle(
            f"the first {len(shown)} of {len(segs)} mode segments (all stages: trajectory.csv)",
            fontsize=9,
        )
    paths.append(base.save_figure(fig, outdir / "frames.png", dpi=90))
    return paths


def save_animation(
    strategy: Strategy,
    cell: Any,
    sim: Simulation,
    path: str | Path,
    max_frames: int = 40,
    size: int = base.GIF_SIZE,
) -> Path:
    """An animated GIF of the sample path (stages subsampled to at most ``max_frames``),
    ``size`` pixels wide, each frame with its stage counter and mode."""
    # Deferred for start-up time: the experiment list loads without these.
    import matplotlib.pyplot as plt

    size = base.check_gif_size(size, "size")
    n = len(sim.modes)
    ks = np.unique(np.linspace(0, n - 1, min(n, max_frames)).astype(int))

    def frames() -> Iterator[np.ndarray]:  # drawn one at a time, as save_gif writes them
        for k in ks:
            fig, axes = base.new_figure(size=4.8)
            ax = axes[0, 0]
            mode = strategy.mdp.modes[int(sim.modes[k])]
            highlight = mode_regions(mode)
            offsets = region_offsets(strategy, int(sim.modes[k]))
            base.draw_workcell(ax, cell, highlight=highlight, labels=False, offsets=offsets)
            draw_belts(ax, strategy, cell)
            tool = cell.robot.tool_pose(sim.q[max(0, k - 30) : k + 1])[:, :2]
            ax.plot(tool[:, 0], tool[:, 1], "-", color=base.COLORS["path"], lw=1.0)
            base.draw_robot(ax, cell, sim.q[k], carried_part(mode))
            base.frame_counter(ax, f"stage {k:>{len(str(n - 1))}d} / {n - 1}")
            title = wrap_title(f"mode {mode.label}", 56)
            ax.set_title(title, fontsize=9 if "\n" not in title else 8)
            rgb = base.figure_to_rgb(fig, size)
            plt.close(fig)
            yield rgb

    return base.save_gif(frames(), path, fps=8.0)

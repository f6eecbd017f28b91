"""Draw a scenario from Python: the picture ``cellplan show`` writes, 2-D or 3-D.

:func:`draw` returns a matplotlib figure (and saves it when given a path); Jupyter shows
a :class:`~cellplan.setup.Setup` as this picture (``Setup._repr_png_``). matplotlib,
Pinocchio and the 3-D scene code are imported on first use, so importing cellplan stays
light.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellplan.errors import ArgumentError
from cellplan.fileio import atomic_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from cellplan.setup import Setup


def _sections_figure3d(setup: Setup, view: str | tuple[float, float]) -> Figure:
    """A 3-D cell without a robot: its bounds, and what each package's section draws on
    3-D axes (:attr:`cellplan.core.Package.draw`, packages whose ``workcells`` include
    ``"3d"``; spheres' starts and goals), seen from ``view``."""
    from matplotlib.figure import Figure

    from cellplan.registry import packages
    from cellplan.view3d import DPI, VIEWS

    sc = setup.scenario
    present = sc.section_names()
    drawers = [
        pkg.draw
        for pkg in packages().values()
        if pkg.draw is not None and pkg.section in present and "3d" in pkg.workcells
    ]
    if not drawers:
        raise ArgumentError(
            "a 3-D cell is drawn with its robot or a section that draws in 3-D (discs:); "
            "this scenario has neither",
            "robot",
        )
    if isinstance(view, str) and view not in VIEWS:
        raise ArgumentError(
            f"expected one of {', '.join(VIEWS)} or (elevation, azimuth) in degrees, got {view!r}",
            "view",
        )
    elev, azim = VIEWS[view] if isinstance(view, str) else (float(view[0]), float(view[1]))
    # Not pyplot: the figure is freed with its last reference (as view3d.draw_figure's).
    fig = Figure(figsize=(1000 / DPI, 800 / DPI), dpi=DPI)
    ax: Any = fig.add_subplot(projection="3d")
    b = sc.workcell.bounds
    lo = (b.xmin, b.ymin, getattr(b, "zmin", 0.0))
    hi = (b.xmax, b.ymax, getattr(b, "zmax", 1.0))
    handles: list[Any] = []
    for drawer in drawers:
        handles.extend(drawer(setup, ax))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(h - low for h, low in zip(hi, lo, strict=True)))
    ax.view_init(elev=elev, azim=azim)
    if handles:
        ax.legend(handles=handles, loc="upper left", fontsize=8, frameon=False)
    ax.set_title(sc.name or setup.name, parse_math=False)
    return fig


def draw(
    setup: Setup, path: str | Path | None = None, *, view: str | tuple[float, float] = "iso"
) -> Figure:
    """Draw a scenario: its workcell, the robot at its start carrying its first part, and
    what each section adds (disc starts and goals, adaptive goals and changes).

    Parameters
    ----------
    setup
        The scenario (``cellplan.load(...)``).
    path
        A PNG to write (atomically); ``None`` draws without saving.
    view
        3-D cells: a name of :data:`cellplan.view3d.VIEWS` (``iso``, ``front``,
        ``side``, ``top``) or ``(elevation, azimuth)`` in degrees. A 2-D workcell is
        drawn from above, and any other view is refused.

    Returns
    -------
    matplotlib.figure.Figure
        The picture (closed in pyplot, so it is not shown twice in a notebook).

    Raises
    ------
    ArgumentError
        A 3-D cell with neither a robot nor a section that draws in 3-D, or a view a
        2-D workcell cannot have.
    """
    from cellplan import plots
    from cellplan.scenario3d import is_3d

    if not is_3d(setup.scenario):
        if view != "iso":
            raise ArgumentError(
                "views apply to 3-D cells; a 2-D workcell is drawn from above", "view"
            )
        fig = plots.scenario_figure(setup)
        if path is not None:
            plots.save_figure(fig, path)
        return fig

    from cellplan.scene3d import cell_scene
    from cellplan.view3d import DPI, draw_figure
    from cellplan.workcell3d import Workcell3D

    if not setup.has_robot:
        fig = _sections_figure3d(setup, view)
        if path is not None:
            with atomic_path(Path(path)) as tmp:
                fig.savefig(tmp, dpi=DPI, format="png")
        return fig
    cell = setup.workcell
    assert isinstance(cell, Workcell3D)  # is_3d with a robot builds a Workcell3D
    carrying = next(iter(cell.parts), None)
    title = f"{setup.name}: {cell.robot.arm.name} at its start" + (
        f", carrying {carrying}" if carrying else ""
    )
    fig = draw_figure(cell_scene(cell, carrying=carrying, title=title), view=view)
    if path is not None:
        # Not plots.save_figure: its tight bounding box would change the size in pixels.
        with atomic_path(Path(path)) as tmp:
            fig.savefig(tmp, dpi=DPI, format="png")
    return fig


def png_bytes(setup: Setup, width_px: int = 720) -> bytes:
    """:func:`draw` as PNG bytes about ``width_px`` wide (for notebooks)."""
    fig = draw(setup)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=width_px / fig.get_figwidth())
    return buffer.getvalue()

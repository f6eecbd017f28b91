"""``cellplan demo``: the quick version of every experiment plus the bundled workcells, as HTML.

The demo is the main job of ``make demo``: it must finish well under two minutes
on a 2-core machine. It sweeps the experiments that decide their claims at a small
size, each in its quick version with its own seed count
(:attr:`cellplan.core.Experiment.demo_runs`; cached under ``OUTPUT/cache``, so a
second run is fast), and lists the others apart with the ``cellplan reproduce``
command that decides them; it draws each bundled workcell, shows the bundled 3-D cells with
their real arms (a picture, each region's reachability and an interactive viewer page
per cell, :func:`show_3d_cells`), and writes ``OUTPUT/index.html`` in the same format
as ``cellplan reproduce``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

SWEEP_BUDGET_S = 150.0
"""Seconds the demo's sweep may take. The pictures are made while it runs, so this bounds
the whole demo (drawings, showcase, cluster start, sweep) but for the report's figures.
Runs not finished by then are shown as skipped (and their experiments listed under "run
`cellplan reproduce` to decide"). At 90 s, three experiments' runs were all skipped on 2
idle cores (2026-11-27, the browser test of the report): the sweep and the pictures
together take about 210 CPU seconds."""

CELLS_3D = ("ur5_cell", "panda_shelf")
"""The bundled 3-D cells the demo shows with their arms (:func:`show_3d_cells`)."""

CELL_VIEWS: dict[str, tuple[float, float]] = {"panda_shelf": (25.0, -150.0)}
"""Views of the 3-D cells' pictures other than ``iso`` (elevation, azimuth in degrees):
the shelf is seen from its open side, where the arm reaches in."""

MOTION_FRAMES = 40
"""Frames of the motion each 3-D cell's viewer page plays."""

MOTION_STEP_M = 0.01
"""Step (metres) of the certified collision check of that motion
(:meth:`cellplan.workcell3d.Workcell3D.motion_collides`)."""

INTRO = (
    "This is the quick demonstration: the experiments of the three papers that decide "
    "their claims at a small size, each in its small version with enough seeds for the "
    "same decision rules as the full reproduction, so it runs in under two minutes on a "
    "laptop. Every verdict shown is decided (reproduced or differs). What needs more runs "
    "or larger problems is listed in each paper's section under “Run `cellplan reproduce` "
    "to decide”, with the command that decides it; the full reproduction, with the papers' "
    "own repetition counts, is `cellplan reproduce all -o DIR` (see docs/reproduce.md for "
    "how long it takes and how to run it on a Dask cluster)."
)


def run_demo(
    output: Path, console: Any = None, serial: bool = False, showcase: bool = True
) -> Path:
    """Run the demo into ``output`` and return the path of ``output/index.html``.

    Parameters
    ----------
    output
        The report folder (created if missing; must not be a file).
    console
        A :class:`rich.console.Console` for progress and notes (default: stderr).
    serial
        Run the experiments in this process instead of on a local Dask cluster.
    showcase
        Also run each planner once through its command (:func:`run_showcase`).
    """
    from rich.console import Console

    from cellplan.reproduce_cli import check_output_dir, reproduce_sweep

    output = check_output_dir(Path(output))
    console = console if console is not None else Console(stderr=True)
    # The pictures are made in this process while the sweep's runs go to the Dask workers,
    # so both cores work from the start (the showcase alone keeps one busy for most of it).
    pictures = _Background(lambda: make_pictures(output, console, showcase))
    if serial:
        pictures.join()
    t0 = time.perf_counter()
    index, sweep = reproduce_sweep(
        None,
        output,
        serial=serial,
        console=console,
        title="cellplan demo: the three papers in small",
        intro=INTRO,
        extra=pictures.join,
        time_budget_s=SWEEP_BUDGET_S,
        demo=True,
    )
    rest = time.perf_counter() - t0 - sweep.wall_s
    console.print(
        f"swept {sweep.n_runs} runs of {len(sweep.runs)} experiments in {sweep.wall_s:.1f} s, "
        f"then finished the pictures and the report in {rest:.1f} s",
        highlight=False,
    )
    return index


def make_pictures(output: Path, console: Any, showcase: bool = True) -> list[Any]:
    """The demo's report sections that are not experiments: the showcase (if asked), the
    bundled workcells and the 3-D cells, each phase timed on ``console``."""
    t0 = time.perf_counter()
    workcells = draw_bundled_workcells(output / "workcells")
    console.print(
        f"drew {len(workcells.figures)} bundled workcells in {time.perf_counter() - t0:.1f} s",
        highlight=False,
    )
    t0 = time.perf_counter()
    cells = show_3d_cells(output / "workcells")
    console.print(
        f"showed {len(cells.articles)} 3-D cells (pictures, reachability, viewers) "
        f"in {time.perf_counter() - t0:.1f} s",
        highlight=False,
    )
    sections = [workcells, cells]
    if showcase:
        t0 = time.perf_counter()
        section = run_showcase(output / "showcase")
        sections.insert(0, section)
        console.print(
            f"ran the showcase ({len(section.items)} items) in {time.perf_counter() - t0:.1f} s",
            highlight=False,
        )
    return sections


class _Background:
    """``make()`` run in a daemon thread; :meth:`join` waits and returns its value (or
    raises its exception). A daemon, so an interrupted demo does not wait for it."""

    def __init__(self, make: Callable[[], list[Any]]) -> None:
        self._value: list[Any] = []
        self._error: BaseException | None = None

        def target() -> None:
            try:
                self._value = make()
            except BaseException as exc:  # handed to the caller of join
                self._error = exc

        self._thread = threading.Thread(target=target, name="demo-pictures", daemon=True)
        self._thread.start()

    def join(self) -> list[Any]:
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value


def draw_bundled_workcells(folder: Path) -> Any:
    """Draw every bundled scenario's workcell into ``folder``; return the report section.

    A scenario that cannot be loaded or drawn is listed in the section's errors
    instead of stopping the demo. 3-D cells are not drawn here (a note names them): the
    section of :func:`show_3d_cells` shows them.
    """
    from cellplan.registry import scenario_names
    from cellplan.report import ExtraSection
    from cellplan.scenario3d import is_3d

    section = ExtraSection(
        "Bundled workcells",
        "Every scenario shipped with cellplan (`cellplan scenarios` lists them; "
        "`cellplan show NAME -o file.png` draws one).",
        anchor="workcells",
    )
    from cellplan.api import load
    from cellplan.plots import save_scenario

    names = scenario_names()
    if not names:
        section.notes.append("no bundled scenarios yet")
    three_d = []
    for name in names:
        target = folder / f"{name}.png"
        try:
            setup = load(name)
            if is_3d(setup.scenario):
                three_d.append(name)
                continue
            save_scenario(setup, target)
        except Exception as exc:  # one bad scenario must not hide the rest of the demo
            section.errors.append(f"{name}: {type(exc).__name__}: {exc}")
            continue
        section.figures.append(target)
    if three_d:
        section.notes.append(
            f"{', '.join(three_d)}: 3-D cells, shown in “Real arms in 3-D cells” "
            "(`cellplan show NAME -o file.png` draws one, `cellplan view NAME -o file.html` "
            "writes its viewer page)."
        )
    return section


def show_3d_cells(folder: Path, names: Any = CELLS_3D) -> Any:
    """Show the bundled 3-D cells ``names`` with their arms; return the report section.

    For each cell, into ``folder``: ``cell_NAME.png``, the cell with the arm at its start
    (:func:`cellplan.view3d.draw_png`), and ``viewer_NAME.html``, the interactive viewer
    page (:func:`cellplan.view3d.write_viewer`), which plays the straight joint-space
    motion from the start to the configuration found for the first source. The section
    has one :class:`~cellplan.report.Article` per cell: the picture, a table of each
    region's reachability (:meth:`~cellplan.workcell3d.Workcell3D.reach_region`) and the
    viewer embedded in a frame. A cell that cannot be loaded or shown is listed in the
    section's errors instead of stopping the demo.

    Parameters
    ----------
    folder
        Where the pictures and pages go (created if missing); the report must lie in it
        or above it, since it links the pages by relative path.
    names
        Bundled 3-D scenarios (default :data:`CELLS_3D`).

    Returns
    -------
    ExtraSection
        The section "Real arms in 3-D cells".
    """
    from cellplan.report import ExtraSection

    section = ExtraSection(
        "Real arms in 3-D cells",
        "The bundled 3-D cells: URDF arms (a UR5, a Franka Panda) among solid obstacles, "
        "loaded through `cellplan.load(NAME).workcell`. Each picture is the arm at its "
        "start; the table says whether inverse kinematics found, for each region, a "
        "collision-free configuration with the tool point inside it (the other sources "
        "count as obstacles, as when a part is picked there). The viewer below each "
        "(meshcat, offline) can be turned with the mouse and plays a short motion.",
        anchor="cells-3d",
    )
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        try:
            section.articles.append(_cell_article(name, folder))
        except Exception as exc:  # one bad cell must not hide the rest of the demo
            section.errors.append(f"{name}: {type(exc).__name__}: {exc}")
    return section


def _cell_article(name: str, folder: Path) -> Any:
    """The report article of one 3-D cell (see :func:`show_3d_cells`)."""
    import numpy as np

    from cellplan import units
    from cellplan.api import load
    from cellplan.report import Article, EmbeddedPage
    from cellplan.scene3d import cell_scene
    from cellplan.view3d import draw_png, write_viewer
    from cellplan.workcell3d import Workcell3D

    cell = load(name).workcell
    if not isinstance(cell, Workcell3D):
        raise TypeError(f"{name} is not a 3-D cell")
    robot = cell.robot
    arm = robot.arm
    picture = folder / f"cell_{name}.png"
    draw_png(
        cell_scene(cell, title=f"{name}: {arm.name} at its start"),
        picture,
        view=CELL_VIEWS.get(name, "iso"),
    )

    units_text = "joint values, degrees" + ("" if all(arm.angular) else " or metres")
    rows: list[dict[str, Any]] = []
    found: dict[str, list[Any]] = {}
    for role, regions in (("source", cell.sources), ("destination", cell.destinations)):
        for region in regions:
            found[region] = cell.reach_region(region)
            for i, q in enumerate(found[region]):
                degrees = (
                    ""
                    if q is None
                    else ", ".join(
                        f"{v:.1f}" for v in units.config_to_file(robot.axis_names, q, arm.angular)
                    )
                )
                rows.append(
                    {
                        "region": region,
                        "role": role,
                        "component": i,
                        "result": "not found" if q is None else "reachable (IK, collision-free)",
                        f"configuration ({units_text})": degrees,
                    }
                )

    source = next(iter(cell.sources), None)
    target = found[source][0] if source is not None and found[source] else None
    motion_text, scene_title, seconds = _motion(cell, name, source, target)
    if target is None or seconds <= 0.0:
        scene = cell_scene(cell, title=scene_title)
    else:
        d = robot.difference(robot.start, target)
        s = np.linspace(0.0, 1.0, MOTION_FRAMES)
        qs = robot.wrap(robot.start + s[:, None] * d)
        scene = cell_scene(cell, qs, times=s * seconds, title=scene_title)
    viewer = folder / f"viewer_{name}.html"
    write_viewer(scene, viewer)

    joints = ", ".join(arm.joint_names)
    caption = (
        f"Robot `{arm.name}` ({arm.dim} active joints: {joints}; tool frame "
        f"`{arm.tool_frame}`). Collision geometry: a conservative sphere cover of the "
        f"URDF's collision meshes ({len(arm.spheres)} spheres on the moving links), tested "
        "against the exact solids: a configuration it calls free is free; it may call one "
        "in collision a little before the meshes touch."
    )
    return Article(
        title=f"{name}: {arm.name}",
        caption=caption,
        figures=[picture],
        tables=[(f"{name}: can the arm reach each region?", rows)],
        pages=[EmbeddedPage(viewer, f"3-D viewer of {name}", motion_text)],
        code=(
            f'cell = cellplan.load("{name}").workcell\n'
            f'draw_png(cell_scene(cell), "cell_{name}.png")  # or: cellplan show {name}\n'
            "{r: cell.reach_region(r) for r in [*cell.sources, *cell.destinations]}\n"
            f'write_viewer(cell_scene(cell, q, times), "viewer_{name}.html")\n'
            f"# or: cellplan view {name} -o viewer_{name}.html --trajectory FILE"
        ),
    )


def _duration(arm: Any, d: Any) -> tuple[float, str]:
    """Seconds a joint-space move of ``d`` takes at the URDF velocity limits (the slowest
    joint's time), and that joint's name; joints without a positive finite limit are
    taken at 1 rad/s (or 1 m/s)."""
    import numpy as np

    limits = np.asarray(arm.velocity_limit, dtype=float)
    usable = np.isfinite(limits) & (limits > 0)
    speed = np.where(usable, limits, 1.0)
    times = np.abs(np.asarray(d, dtype=float)) / speed
    slowest = int(np.argmax(times))
    return float(times[slowest]), arm.joint_names[slowest]


def _motion(cell: Any, name: str, source: str | None, target: Any) -> tuple[str, str, float]:
    """The viewer's caption in the report, the scene's title and the motion's duration
    (seconds; 0 for none), after checking the straight joint-space motion from the start
    to ``target`` for collisions."""
    robot = cell.robot
    still = f"{name} (start)"
    if source is None:
        return "The viewer shows the arm at its start (the cell has no source).", still, 0.0
    if target is None:
        return (
            f"The viewer shows the arm at its start: no configuration reaching source "
            f"`{source}` was found, so there is no motion to play.",
            still,
            0.0,
        )
    d = robot.difference(robot.start, target)
    seconds, joint = _duration(robot.arm, d)
    if seconds <= 0.0:
        return (
            f"The viewer shows the arm at its start, which already reaches source `{source}`.",
            still,
            0.0,
        )
    collides = bool(
        cell.motion_collides(
            robot.start[None],
            target[None],
            step=MOTION_STEP_M,
            avoid_sources=cell.sources_except(source),
        )[0]
    )
    verdict = (
        "it collides somewhere along the way (a planner would have to go around)"
        if collides
        else "it is collision-free"
    )
    text = (
        f"The viewer plays the straight joint-space motion from the start to the "
        f"configuration found for source `{source}` ({MOTION_FRAMES} frames over "
        f"{seconds:.2f} s: the time `{joint}`, the slowest joint, needs at its URDF "
        f"velocity limit). It is not planned: checked with the certified "
        f"`cell.motion_collides` (step {MOTION_STEP_M * 100:g} cm, the other sources "
        f"as obstacles), {verdict}."
    )
    state = "collides" if collides else "collision-free"
    return text, f"{name}: start to {source}, straight in joint space ({state})", seconds


def run_showcase(folder: Path, packages: Any = None) -> Any:
    """Run each registered package's showcase through the library API; return the report section.

    These are the pictures a person looks at first (each package's
    :attr:`~cellplan.core.Package.showcase`: the strategy's cost-to-go and a sample path,
    a disc assembly, the experience graph), each with a caption and the Python lines that
    make it. A package whose showcase fails is listed as an error in the section instead of
    stopping the demo.
    """
    from cellplan.registry import packages as registered
    from cellplan.report import ExtraSection

    section = ExtraSection(
        "Showcase: one run of each planner",
        "Each picture comes from the Python shown under it, run on a bundled scenario "
        "through the planning API (`cellplan.load`, `cellplan.plan`).",
        anchor="showcase",
    )
    pkgs = registered() if packages is None else packages
    for name, pkg in pkgs.items():
        if pkg.showcase is None:
            continue
        try:
            section.items.extend(pkg.showcase(folder / name))
        except Exception as exc:  # one failing package must not hide the rest of the demo
            section.errors.append(f"{name}: showcase failed: {type(exc).__name__}: {exc}")
    return section

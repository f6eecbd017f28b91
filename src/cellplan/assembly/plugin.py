"""The assembly package's declaration: its scenario section, planners, experiments, commands.

This is the only place the core learns about the package (see
:data:`cellplan.registry.BUILTIN_PACKAGES`). It imports nothing heavy: planners import
their algorithm modules when they run.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from cellplan.assembly.drawing import draw_discs
from cellplan.assembly.options import ControlOptions, GradientOptions, SequentialOptions
from cellplan.assembly.robot_options import RobotAssemblyOptions
from cellplan.assembly.section import DiscsSection
from cellplan.core import (
    Fact,
    Options,
    Package,
    PlannerSpec,
    Progress,
    Result,
    ShowcaseItem,
)

TITLE = "Navigation-function assembly planning for disc assemblies"
CITATION = (
    "L. L. Whitcomb, D. E. Koditschek, “Automatic assembly planning and control via "
    "potential functions”, Proc. IEEE/RSJ IROS Workshop, 1991, pp. 17-23."
)
SUMMARY = (
    "Section 5 measures the path-length ratio (path length over straight-line distance) "
    "over 25 random starts per point: it falls with k to about 1.25 for 7 discs and under "
    "1.25 for 10 discs (Figs. 3-4); it is nearly independent of the goal's packing "
    "β(d) from 1e-2 to 1e-44 (Figs. 6-7); permuted starts on packed goals about double "
    "it; the sequential (switched) algorithm is about 10% longer, with about three "
    "switches per disc, more for harder assemblies (Figs. 8-9)."
)

if TYPE_CHECKING:
    from pathlib import Path

    from cellplan.setup import Setup


# The run functions import the algorithm modules only when a planner runs.


def _gradient(setup: Setup, options: Options, progress: Progress | None) -> Result:
    from cellplan.assembly.planners import plan_gradient

    assert isinstance(options, GradientOptions)
    return plan_gradient(setup, options, progress)


def _sequential(setup: Setup, options: Options, progress: Progress | None) -> Result:
    from cellplan.assembly.planners import plan_sequential

    assert isinstance(options, SequentialOptions)
    return plan_sequential(setup, options, progress)


def _control(setup: Setup, options: Options, progress: Progress | None) -> Result:
    from cellplan.assembly.planners import plan_control

    assert isinstance(options, ControlOptions)
    return plan_control(setup, options, progress)


def _robot(setup: Setup, options: Options, progress: Progress | None) -> Result:
    from cellplan.assembly.robot import plan_robot

    assert isinstance(options, RobotAssemblyOptions)
    return plan_robot(setup, options, progress)


def _showcase(folder: Path) -> list[ShowcaseItem]:
    from cellplan.assembly.showcase import showcase

    return showcase(folder)


#: A small bundled problem every planner solves in well under a second (three discs,
#: two of which swap places).
SMOKE = "discs_swap"

PLANNERS = (
    PlannerSpec(
        name="assembly.gradient",
        package="assembly",
        summary="all discs along -grad phi of the navigation function (W&K 1991, Sec. 4.1)",
        options=GradientOptions,
        run=_gradient,
        section="discs",
        smoke=(SMOKE, {}),
    ),
    PlannerSpec(
        name="assembly.sequential",
        package="assembly",
        summary="one disc at a time: the paper's map T (rule=paper, Sec. 4.2) or ours (place)",
        options=SequentialOptions,
        run=_sequential,
        section="discs",
        smoke=(SMOKE, {}),
    ),
    PlannerSpec(
        name="assembly.control",
        package="assembly",
        summary="double-integrator discs, gradient plus damping controller (Sec. 3.4)",
        options=ControlOptions,
        run=_control,
        section="discs",
        smoke=(SMOKE, {}),
    ),
    PlannerSpec(
        name="assembly.robot",
        package="assembly",
        summary="the sequential assembly executed by a URDF arm, each move planned by "
        "Adapt's experience graph (Sec. 4.2 with Chen 1994)",
        options=RobotAssemblyOptions,
        run=_robot,
        section="discs",
        smoke=("ur5_assembly", {}),
    ),
)


def describe(setup: Setup) -> Sequence[Fact]:
    """``cellplan validate``'s fact about the discs, listed or generated, and k.

    One :class:`~cellplan.core.Fact` keyed ``discs``: its text is the line a person
    reads, its value the same with types for ``--json`` (``count`` an int, ``k`` a float
    or ``None`` for the rule's default, ``seed`` an int).
    """
    d = setup.scenario.discs
    k = "from n and the workspace" if d.k is None else f"{d.k:g}"
    # spheres in a 3-D cell (the discs' dimension is the workcell's)
    spheres = hasattr(setup.scenario.workcell.bounds, "zmin")
    kind = " spheres" if spheres else ""
    boundary = "ball" if spheres and d.boundary.type == "disc" else d.boundary.type
    value: dict[str, Any] = {
        "bodies": "spheres" if spheres else "discs",
        "boundary": boundary,
        "k": None if d.k is None else float(d.k),
    }
    if d.discs is not None:
        value |= {"count": len(d.discs), "source": "listed"}
        text = f"{len(d.discs)}{kind} listed, boundary {boundary}, k = {k}"
    else:
        g = d.generate
        value |= {
            "count": int(g.n),
            "source": "generated",
            "seed": int(g.seed),
            "pattern": g.pattern,
            "starts": g.starts,
        }
        text = (
            f"{g.n}{kind} generated (seed {g.seed}, {g.pattern} goals, {g.starts} starts), "
            f"boundary {boundary}, k = {k}"
        )
    return [Fact("discs", "discs", value, text)]


PACKAGE = Package(
    name="assembly",
    title=TITLE,
    citation=CITATION,
    summary=SUMMARY,
    section="discs",
    section_model=DiscsSection,
    planners=PLANNERS,
    experiments="cellplan.assembly.experiments",
    commands="cellplan.assembly.commands",
    paper_runs=25,
    describe=describe,
    showcase=_showcase,
    draw=draw_discs,
    workcells=("2d", "3d"),
)

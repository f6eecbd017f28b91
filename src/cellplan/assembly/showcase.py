"""The assembly package's part of the demo report: seven discs assembled through the API.

:func:`showcase` plans the bundled ``discs_seven`` problem (Whitcomb & Koditschek 1991,
Fig. 1) with the gradient algorithm (Section 4.1) and the sequential algorithm
(Section 4.2, the paper's rule) through :func:`cellplan.plan`, and draws each run as
Figs. 1-2 do; then the same gradient algorithm on seven spheres in 3-D
(``spheres_cluster7``, equations (2)-(8) in R^21), drawn on 3-D axes. It prints nothing.
"""

from __future__ import annotations

from pathlib import Path

from cellplan.core import ShowcaseItem

SCENARIO = "discs_seven"
FRAMES = 30

GRADIENT_CODE = """\
import cellplan
from cellplan.assembly.plots import save_animation, save_sequence

result = cellplan.plan(cellplan.load("discs_seven"), "assembly.gradient")
run = result.solution  # the flow: run.path (steps x discs x 2), run.problem
save_sequence(run.problem, run.path, "sequence.png")
save_animation(run.problem, run.path, "assembly.gif", trajectory=result.trajectory)"""

SPHERES = "spheres_cluster7"

SPHERES_CODE = """\
import cellplan
from cellplan.assembly.plots import save_sequence

result = cellplan.plan(cellplan.load("spheres_cluster7"), "assembly.gradient")
run = result.solution  # run.path: steps x spheres x 3
save_sequence(run.problem, run.path, "sequence.png")  # 3-D axes for spheres"""

SEQUENTIAL_CODE = """\
import cellplan
from cellplan.assembly.plots import save_sequence

result = cellplan.plan(cellplan.load("discs_seven"), "assembly.sequential", rule="paper")
run = result.solution  # run.grasps: one pick / move / release per switch
save_sequence(run.problem, run.path, "sequence.png")"""


def showcase(folder: str | Path) -> list[ShowcaseItem]:
    """Two assemblies of ``discs_seven`` with pictures under ``folder`` (see module doc)."""
    from cellplan import api
    from cellplan.assembly.plots import save_animation, save_sequence
    from cellplan.assembly.run import run_title

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    setup = api.load(SCENARIO)
    items = []

    flow = api.plan(setup, "assembly.gradient")
    run = flow.solution
    title = run_title(flow)
    figures = [
        save_sequence(run.problem, run.path, out / "assembly_gradient_sequence.png", title),
        save_animation(
            run.problem,
            run.path,
            out / "assembly_gradient.gif",
            FRAMES,
            title,
            trajectory=flow.trajectory,
        ),
    ]
    items.append(
        ShowcaseItem(
            title=f"{run.problem.n} discs ({SCENARIO}), gradient algorithm (Sec. 4.1, Fig. 1)",
            figures=figures,
            caption=f"All discs move together along -grad phi ({flow.status.value}: "
            f"{flow.message}). Four moments of the run ({len(run.path) - 1} steps) and the "
            f"animation ({FRAMES} frames, its time in each frame); dashed circles are the "
            "goals, lines the paths so far.",
            code=GRADIENT_CODE,
        )
    )

    seq = api.plan(setup, "assembly.sequential", rule="paper")
    run = seq.solution
    items.append(
        ShowcaseItem(
            title=f"{run.problem.n} discs ({SCENARIO}), sequential algorithm (Sec. 4.2, the "
            "paper's rule)",
            figures=[
                save_sequence(
                    run.problem,
                    run.path,
                    out / "assembly_sequential_sequence.png",
                    run_title(seq),
                )
            ],
            caption=f"One disc moves at a time, chosen by the map T of equations (13)-(16) "
            f"({seq.status.value}: {seq.message}; {int(seq.stats['switches'])} switches).",
            code=SEQUENTIAL_CODE,
        )
    )

    spheres = api.plan(api.load(SPHERES), "assembly.gradient")
    run = spheres.solution
    items.append(
        ShowcaseItem(
            title=f"{run.problem.n} spheres in 3-D ({SPHERES}), gradient algorithm "
            "(equations (2)-(8) in R^21)",
            figures=[
                save_sequence(
                    run.problem,
                    run.path,
                    out / "assembly_spheres_sequence.png",
                    run_title(spheres),
                )
            ],
            caption=f"The navigation function holds in any dimension: seven unit spheres "
            f"from random starts into a close-packed cluster ({spheres.status.value}: "
            f"{spheres.message}; the clearance is exact over every segment). Wire spheres "
            "are the goals, lines the paths so far, axes in metres.",
            code=SPHERES_CODE,
        )
    )
    return items

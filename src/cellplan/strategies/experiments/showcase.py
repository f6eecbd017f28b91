"""The strategies package's part of the demo report, made through the library API.

Problem 1 of Section V: its optimal strategy's cost-to-go and actions while waiting for
and while carrying part 1 (Fig. 8), and a 300-stage sample run with a frame per mode
change (Fig. 9) and an animation. Then the same process on the first three joints of a
UR5 (``strategies_ur5``): a sample run drawn at its first pick, while carrying and at its
first delivery, and played in the offline viewer page. Nothing is printed; the pictures
go to ``folder``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellplan.core import ShowcaseItem

SCENARIO = "strategies_p1"
STAGES = 300
SEED = 3
GIF_FRAMES = 24
"""Frames of the sample run's animation (its stages subsampled): each frame costs about
0.4 s of the demo's time to draw."""

SOLVE_CODE = """import cellplan
from cellplan.strategies.experiments.plots import plot_mode

setup = cellplan.load("strategies_p1")
result = cellplan.plan(setup, "strategies")  # result.solution is the Strategy
strategy, cell = result.solution, setup.workcell
for mode, name in (("1,1,1,W", "p1_waiting.png"), ("1,1,1,C", "p1_carrying.png")):
    plot_mode(strategy, cell, strategy.mode_index(mode), name, fixed=cell.robot.start)"""

SIMULATE_CODE = f"""from cellplan.strategies.experiments.plots import plot_frames, save_animation

run = cellplan.simulate(strategy, {STAGES}, {SEED}, cell=cell)  # run.solution: the Simulation
run.trajectory.save("p1_simulation/trajectory.csv")
plot_frames(strategy, cell, run.solution, "p1_simulation")
gif = "p1_simulation/simulation.gif"
save_animation(strategy, cell, run.solution, gif, max_frames={GIF_FRAMES})"""


WITH_UR5 = True
"""Whether the showcase includes the UR5 run (about 17 s of one idle core, most of it the
48^3 solve; a test of the planar items turns it off)."""
UR5_SCENARIO = "strategies_ur5"
UR5_STAGES = 200
UR5_SEED = 1

UR5_CODE = """import cellplan
from cellplan.scene3d import cell_scene
from cellplan.strategies.sim.records import carried_part
from cellplan.view3d import write_viewer

setup = cellplan.load("strategies_ur5")        # a UR5, wrist locked: a 48^3 grid of 3 joints
strategy = cellplan.plan(setup, "strategies").solution
run = cellplan.simulate(strategy, 200, 1, cell=setup.workcell)
held = [carried_part(strategy.mdp.modes[m]) for m in run.solution.modes]
scene = cell_scene(setup.workcell, run.trajectory.q, run.trajectory.t, held)
write_viewer(scene, "ur5_run.html")  # or: cellplan simulate strategies_ur5 --strategy S -o DIR"""


def showcase(folder: Path) -> list[ShowcaseItem]:
    """Solve problem 1, draw Fig. 8 for two modes and simulate a Fig. 9 sample run.

    Returns the two report items (figures under ``folder``, each with its caption and the
    lines of Python that make it).
    """
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.api import load, plan
    from cellplan.strategies.experiments.plots import plot_frames, plot_mode, save_animation
    from cellplan.strategies.sim.simulate import simulate_result

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    setup = load(SCENARIO)
    result = plan(setup, "strategies")
    strategy, cell = result.solution, setup.workcell
    fig8 = [
        plot_mode(strategy, cell, strategy.mode_index(mode), folder / name, fixed=cell.robot.start)
        for mode, name in (("1,1,1,W", "p1_waiting.png"), ("1,1,1,C", "p1_carrying.png"))
    ]
    run = simulate_result(strategy, STAGES, SEED, cell=cell)
    sim_dir = folder / "p1_simulation"
    sim_dir.mkdir(parents=True, exist_ok=True)
    assert run.trajectory is not None
    run.trajectory.save(sim_dir / "trajectory.csv")
    frames = plot_frames(strategy, cell, run.solution, sim_dir)
    gif = save_animation(
        strategy, cell, run.solution, sim_dir / "simulation.gif", max_frames=GIF_FRAMES
    )
    return [
        ShowcaseItem(
            title="Problem 1: the optimal strategy while waiting and while carrying (Fig. 8)",
            figures=fig8,
            caption=(
                f"{result.status.value}: {result.message}. Level sets of the relative "
                "cost-to-go and the optimal action at a grid of configurations in modes "
                "<P1,S1,D1,W> (going to pick part 1 at source 1) and <P1,S1,D1,C> "
                "(carrying it to destination 1)."
            ),
            code=SOLVE_CODE,
        ),
        ShowcaseItem(
            title=f"Problem 1: a {STAGES}-stage sample run (Fig. 9)",
            figures=[frames[-1], gif],
            caption=(
                f"{run.status.value}: {run.message}. One frame per mode segment (the "
                "request's source and destination shaded) and the animation of the run "
                f"({GIF_FRAMES} frames spread over its stages); "
                "the trajectory (stage, configuration, mode, events) is in "
                "p1_simulation/trajectory.csv."
            ),
            code=SIMULATE_CODE,
        ),
        *([ur5_showcase(folder)] if WITH_UR5 else []),
    ]


def ur5_showcase(folder: Path) -> ShowcaseItem:
    """Solve ``strategies_ur5`` and run it for :data:`UR5_STAGES` stages: three pictures
    of the arm (its first pick, carrying, its first delivery) and the viewer page
    ``ur5_simulation.html`` where the whole run plays."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.api import load, plan
    from cellplan.scene3d import cell_scene
    from cellplan.strategies.sim.records import carried_part
    from cellplan.strategies.sim.simulate import simulate_result
    from cellplan.view3d import draw_png, write_viewer

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    setup = load(UR5_SCENARIO)
    result = plan(setup, "strategies", sample_stages=1)
    strategy, cell = result.solution, setup.workcell
    run = simulate_result(strategy, UR5_STAGES, UR5_SEED, cell=cell)
    sim = run.solution
    held = [carried_part(strategy.mdp.modes[int(m)]) for m in sim.modes]
    scene = cell_scene(
        cell,  # type: ignore[arg-type]  # a 3-D scenario's workcell is a Workcell3D
        sim.q,
        np.arange(len(sim.q), dtype=float),
        held,
        title=f"{UR5_SCENARIO}: simulated assembly process",
        time_label="stage",
    )
    write_viewer(scene, folder / "ur5_simulation.html")
    # Carrying stretches (first and last stage holding a part); shown: the first one
    # that crosses the gate (the shoulder pan changes sign), else the first one.
    loaded = np.array([h is not None for h in held] + [False])
    starts = np.flatnonzero(loaded[1:] & ~loaded[:-1]) + 1
    starts = np.concatenate([[0], starts]) if loaded[0] else starts
    stretches = [(int(a), int(a + np.argmin(loaded[a:]) - 1)) for a in starts]
    crossing = [(a, b) for a, b in stretches if np.sign(sim.q[a, 0]) != np.sign(sim.q[b, 0])]
    first, end = (crossing or stretches or [(0, 0)])[0]
    frames = {"pick": first, "carrying": (first + end) // 2, "delivery": end}
    figures = []
    for name, k in frames.items():
        path = folder / f"ur5_{name}.png"
        draw_png(scene, path, frame=k, size_px=(800, 600))
        figures.append(path)
    return ShowcaseItem(
        title="The strategies paper on the first three joints of a UR5",
        figures=figures,
        caption=(
            f"{result.status.value}: {result.message}. A {UR5_STAGES}-stage run of the "
            f"optimal strategy ({run.status.value}: {run.message}) at stages "
            f"{', '.join(str(k) for k in frames.values())}: the pick, the middle and the end "
            "of the first carrying stretch that crosses the gate, if one does (the 25 cm "
            "part keeps the arm out of the low passage under it). The whole run plays in "
            "ur5_simulation.html beside these pictures."
        ),
        code=UR5_CODE,
    )

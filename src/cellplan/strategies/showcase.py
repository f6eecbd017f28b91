"""The strategies package's part of the demo report, made through the library API.

Problem 1 of Section V: its optimal strategy's cost-to-go and actions while waiting for
and while carrying part 1 (Fig. 8), and a 300-stage sample run with a frame per mode
change (Fig. 9) and an animation. Nothing is printed; the pictures go to ``folder``.
"""

from __future__ import annotations

from pathlib import Path

from cellplan.core import ShowcaseItem

SCENARIO = "strategies_p1"
STAGES = 300
SEED = 3

SOLVE_CODE = """import cellplan
from cellplan.strategies.plots import plot_mode

setup = cellplan.load("strategies_p1")
result = cellplan.plan(setup, "strategies")  # result.solution is the Strategy
strategy, cell = result.solution, setup.workcell
for mode, name in (("1,1,1,W", "p1_waiting.png"), ("1,1,1,C", "p1_carrying.png")):
    plot_mode(strategy, cell, strategy.mode_index(mode), name, fixed=cell.robot.start)"""

SIMULATE_CODE = """from cellplan.strategies.plots import plot_frames, save_animation

run = cellplan.simulate(strategy, 300, 3, cell=cell)  # a Result; run.solution: the Simulation
run.trajectory.save("p1_simulation/trajectory.csv")
plot_frames(strategy, cell, run.solution, "p1_simulation")
save_animation(strategy, cell, run.solution, "p1_simulation/simulation.gif")"""


def showcase(folder: Path) -> list[ShowcaseItem]:
    """Solve problem 1, draw Fig. 8 for two modes and simulate a Fig. 9 sample run.

    Returns the two report items (figures under ``folder``, each with its caption and the
    lines of Python that make it).
    """
    from cellplan.api import load, plan
    from cellplan.strategies.plots import plot_frames, plot_mode, save_animation
    from cellplan.strategies.simulate import simulate_result

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
    gif = save_animation(strategy, cell, run.solution, sim_dir / "simulation.gif")
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
                "request's source and destination shaded) and the animation of the run; "
                "the trajectory (stage, configuration, mode, events) is in "
                "p1_simulation/trajectory.csv."
            ),
            code=SIMULATE_CODE,
        ),
    ]

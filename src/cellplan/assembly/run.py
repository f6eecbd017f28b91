"""One assembly run for the CLI: build the problem, plan, write pictures and metrics."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellplan.assembly.problems import (
    DEFAULT_FILL,
    DiscProblem,
    default_workspace,
    generate_problem,
    generator_problems,
)
from cellplan.assembly.section import GeneratorSpec
from cellplan.core import PlanResult
from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.fileio import write_json


def load_problem(scenario: str) -> tuple[DiscProblem, float, float, float]:
    """Problem, k, epsilon and tolerance of a scenario file with a ``discs:`` section."""
    from cellplan.assembly.problems import problem_from_section
    from cellplan.scenario import load_scenario

    sc = load_scenario(scenario)
    if sc.discs is None:
        raise ScenarioError([Problem("discs", "this scenario has no discs: section")])
    return problem_from_section(sc.discs, sc), sc.discs.k, sc.discs.epsilon, sc.discs.tolerance


def run_assembly(scenario: str | None, random_n: int | None, algorithm: str, k: float | None,
                 epsilon: float | None, rule: str, seed: int, permutation: bool,
                 log10_beta: float | None, radius: float, frames: int, output: Path,
                 escapes: int = 0, fill: float = DEFAULT_FILL) -> dict[str, Any]:
    """Plan and write ``sequence.png``, ``assembly.gif`` and ``metrics.json`` under ``output``.

    ``escapes``: gradient algorithm and the sequential paper rule, how often k may be
    halved after the run is stuck (:func:`planners.run_gradient`,
    :func:`planners.run_sequential`). ``fill``: ``--random``
    only, the fraction of the workspace area the generated discs cover.
    """
    from cellplan.assembly import plots
    from cellplan.assembly.planners import run_control, run_gradient, run_sequential

    if scenario is not None:
        problem, k_file, eps_file, tol = load_problem(scenario)
    else:
        assert random_n is not None
        gen = GeneratorSpec(n=random_n, seed=seed, radius=radius,
                            starts="permutation" if permutation else "random",
                            log10_beta_goal=log10_beta)
        ws = default_workspace(random_n, radius, fill)
        # name the command-line option behind each generator problem
        option = "--log10-beta" if log10_beta is not None else "--random"
        bad = generator_problems(gen, ws)
        if bad:
            raise ArgumentError([Problem(option, p.message) for p in bad])
        problem = generate_problem(gen, ws)
        k_file, eps_file, tol = 32.0, 1e-3, 1e-3 * radius
    k = k_file if k is None else k
    epsilon = eps_file if epsilon is None else epsilon
    result: PlanResult
    if algorithm == "gradient":
        result = run_gradient(problem, k, epsilon, tol, escapes)
        path = result.payload.path
    elif algorithm == "sequential":
        result = run_sequential(problem, k, rule, epsilon, max(tol, 1e-2), escapes)
        path = result.payload.path
    else:
        result = run_control(problem, k)
        path = result.payload.path
    output.mkdir(parents=True, exist_ok=True)
    title = f"{algorithm} k={k:g}" + (f" ({rule})" if algorithm == "sequential" else "")
    plots.save_sequence(problem, path, output / "sequence.png", title)
    plots.save_animation(problem, path, output / "assembly.gif", frames, title)
    metrics: dict[str, Any] = {"status": result.status.value, "algorithm": algorithm, "k": k,
                               "epsilon": epsilon, "n": problem.n, **result.stats}
    if algorithm == "sequential":
        metrics["rule"] = rule
        metrics["actions"] = result.payload.actions()
    metrics["start"] = problem.start
    metrics["goal"] = problem.goal
    metrics["final"] = np.asarray(path[-1])
    write_json(output / "metrics.json", metrics)
    return metrics

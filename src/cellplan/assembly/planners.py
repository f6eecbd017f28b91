"""Planners of the assembly package, listed for the registry (CLI, benchmarks, conformance test).

Each entry wraps one algorithm as a function ``problem -> PlanResult`` with plain-number
statistics (path-length ratio as in Section 5.1, switches, minimum clearance, steps,
wall time) and a tiny deterministic ``smoke(seed)`` run.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from cellplan.assembly.control import simulate_control
from cellplan.assembly.flows import gradient_flow
from cellplan.assembly.problems import CircleWorkspace, DiscProblem, generate_problem
from cellplan.assembly.section import GeneratorSpec
from cellplan.assembly.sequential import sequential_assembly
from cellplan.core import PlannerEntry, PlanResult, Status

#: default number of k-halvings after a stuck stage (1024 -> 16 at most)
ESCAPES = 6


def run_gradient(problem: DiscProblem, k: float, epsilon: float = 1e-3,
                 tol: float = 1e-3, escapes: int = ESCAPES) -> PlanResult:
    """The gradient assembly algorithm (Section 4.1); ratio in the R^2n norm (Section 5.1).

    A run stuck at a spurious minimum continues at k/2, k/4, ... (at most ``escapes``
    times; Section 3.2, see :func:`flows.gradient_flow`). The statistics say so:
    ``solved_at_k`` (1.0 when the flow at the given k alone reached the goal),
    ``escapes`` (how often k was lowered) and ``k_final``; ``ratio`` is over the
    whole path, every stage included.
    """
    t0 = time.perf_counter()
    res = gradient_flow(problem, k, epsilon, tol, escapes=escapes)
    straight = float(np.linalg.norm(problem.start - problem.goal))
    first = res.stages[0]
    stats = {
        "ratio": res.length() / straight if straight > 0 else 1.0,
        "solved_at_k": float(first.status is Status.SOLVED),
        "escapes": float(res.escapes),
        "k_final": float(res.stages[-1].k),
        "length": res.length(),
        "min_clearance": res.min_clearance,
        "steps": float(res.steps),
        "evaluations": float(res.evaluations),
        "log10_flow_time": float(res.log_time / np.log(10.0)) if np.isfinite(res.log_time) else 0.0,
        "final_error": float(np.linalg.norm(res.end - problem.goal)),
        "wall_s": time.perf_counter() - t0,
    }
    return PlanResult(res.status, stats, res)


def run_sequential(problem: DiscProblem, k: float, rule: str = "paper", epsilon: float = 1e-3,
                   tol: float = 1e-2, escapes: int = ESCAPES) -> PlanResult:
    """Sequential assembly (Section 4.2); ratio over summed disc distances (footnote 6).

    Rule ``paper``: a stuck T map (every disc blocked away from the goal, or no progress
    over 2 n switches) continues at k/2, k/4, ... (at most ``escapes`` times; Section
    3.2, see :func:`sequential.sequential_assembly`); ``solved_at_k``, ``escapes`` and
    ``k_final`` say so, as for the gradient planner, and ``switches`` counts every grasp
    of every stage. The ``place`` rule does not lower k.
    """
    t0 = time.perf_counter()
    res = sequential_assembly(problem, k, rule, epsilon=epsilon, tol=tol,  # type: ignore[arg-type]
                              escapes=escapes if rule == "paper" else 0)
    straight = float(np.sum(np.linalg.norm(problem.start - problem.goal, axis=1)))
    stats = {
        "ratio": float(np.sum(res.disc_lengths())) / straight if straight > 0 else 1.0,
        "switches": float(res.switches),
        "switches_per_disc": res.switches / problem.n,
        "switches_per_disc_within_0.1": res.switches_within(problem.goal, 0.1) / problem.n,
        "solved_at_k": float(res.solved_at_k),
        "escapes": float(res.escapes),
        "k_final": float(res.k_final),
        "min_clearance": res.min_clearance,
        "evaluations": float(res.evaluations),
        "final_error": float(np.linalg.norm(res.path[-1] - problem.goal)),
        "wall_s": time.perf_counter() - t0,
    }
    return PlanResult(res.status, stats, res)


def run_control(problem: DiscProblem, k: float) -> PlanResult:
    """The double-integrator controller of Section 3.4, simulated to rest at the goal."""
    t0 = time.perf_counter()
    res = simulate_control(problem, k)
    straight = float(np.linalg.norm(problem.start - problem.goal))
    stats = {
        "ratio": res.length() / straight if straight > 0 else 1.0,
        "min_clearance": res.min_clearance,
        "steps": float(res.steps),
        "settling_time": float(res.times[-1]),
        "wall_s": time.perf_counter() - t0,
    }
    return PlanResult(res.status, stats, res)


def smoke_problem(seed: int) -> DiscProblem:
    """Four unit discs in a circle of radius 7, hex goals, random legal starts."""
    return generate_problem(GeneratorSpec(n=4, seed=seed, gap=0.2),
                            CircleWorkspace(np.zeros(2), 7.0))


def _smoke(run: Callable[[DiscProblem], PlanResult]) -> Callable[[int], PlanResult]:
    def smoke(seed: int) -> PlanResult:
        res = run(smoke_problem(seed))
        stats = {key: value for key, value in res.stats.items() if key != "wall_s"}
        return PlanResult(res.status, stats, None)

    return smoke


PLANNERS: list[PlannerEntry] = [
    PlannerEntry("assembly.gradient", "assembly",
                 "all discs along -grad phi of the navigation function (W&K 1991, Sec. 4.1)",
                 _smoke(lambda p: run_gradient(p, 32.0))),
    PlannerEntry("assembly.sequential", "assembly",
                 "one disc at a time, the paper's high-level map T (Sec. 4.2)",
                 _smoke(lambda p: run_sequential(p, 32.0, "paper"))),
    PlannerEntry("assembly.sequential_place", "assembly",
                 "one disc at a time, our placement rule (about 1-2 grasps per disc)",
                 _smoke(lambda p: run_sequential(p, 32.0, "place"))),
    PlannerEntry("assembly.control", "assembly",
                 "double-integrator discs, gradient plus damping controller (Sec. 3.4)",
                 _smoke(lambda p: run_control(p, 32.0))),
]

"""Benchmark of policy iteration against the structured solver and relative value iteration.

Run: ``.venv/bin/python benchmarks/bench_policy_iteration.py`` (``--grids 50,100``,
``--failure 0.3``, ``--rework 2``, ``--skip-general`` to leave out the slow baseline).

In one process, on problem 1 at each grid:

* the Section V model: :func:`~cellplan.strategies.solve.solver.solve_structured`,
  :func:`~cellplan.strategies.solve.policy_iteration.solve_policy_iteration` and
  :func:`~cellplan.strategies.solve.solver.solve_general` (relative value iteration, the only
  solver for general models before policy iteration);
* a failure model (Section VI-3, ``strategy.failures``): every delivery fails with
  probability ``--failure`` and is retried in place after ``--rework`` time units. The
  structured solver does not apply; policy iteration and relative value iteration do.

Then each ``--bundled`` Section VI scenario (failure modes, noisy motion) at its own grid,
by policy iteration alone (relative value iteration would take minutes).

Each row prints the live states, the time (numba compilation excluded: a warm-up solve on
a small grid first), the gain with its certified bracket, the iterations or sweeps, and
the ratio of relative value iteration's time to policy iteration's.
"""

from __future__ import annotations

import argparse
from typing import Any

import cellplan
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.section import FailureSpec
from cellplan.strategies.solve.policy_iteration import solve_policy_iteration
from cellplan.strategies.solve.solver import SolveResult, solve_general, solve_structured


def retry_scenario(scenario: Any, f: float, rework: float) -> Any:
    """Problem 1 with every delivery failing with probability ``f``, retried in place after
    ``rework`` time units (``strategy.failures``, Section VI-3); picks always succeed."""
    failures = [
        FailureSpec(region=d, probability=f, then="retry", rework=rework)
        for d in scenario.destinations
    ]
    sec = scenario.strategy.model_copy(update={"failures": failures})
    return scenario.model_copy(update={"strategy": sec})


def row(label: str, states: int, res: SolveResult, base: float | None = None) -> None:
    count = (
        f"{res.outer_iterations} iterations"
        if res.method == "policy"
        else f"{res.sweeps} sweeps"
        if res.method == "general"
        else f"{res.outer_iterations} passes"
    )
    ratio = f"  general/policy {base / res.seconds:6.1f}x" if base is not None else ""
    print(
        f"{label:<34} {states:>8,} states  {res.method:<10} {res.seconds:7.2f} s  "
        f"gain {res.gain:.9f} [{res.gain_lower:.9f}, {res.gain_upper:.9f}]  "
        f"{res.status.value:<13} {count}{ratio}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", default="50,100")
    ap.add_argument("--failure", type=float, default=0.3)
    ap.add_argument("--rework", type=float, default=2.0)
    ap.add_argument("--skip-general", action="store_true")
    ap.add_argument(
        "--bundled",
        default="strategies_failures,strategies_noise",
        help="bundled Section VI scenarios solved by policy iteration alone ('' for none)",
    )
    args = ap.parse_args()
    setup = cellplan.load("strategies_p1")
    failing = retry_scenario(setup.scenario, args.failure, args.rework)
    warm = build_model(setup.scenario, setup.workcell, [34, 34])
    for mdp in (warm, build_model(failing, setup.workcell, [34, 34])):
        solve_policy_iteration(mdp)
        solve_general(mdp, max_sweeps=5)
    solve_structured(warm)
    for n in (int(v) for v in args.grids.split(",") if v):
        mdp = build_model(setup.scenario, setup.workcell, [n, n])
        fail = build_model(failing, setup.workcell, [n, n])
        states = int(mdp.live.sum())
        label = f"P1 {n}x{n} Section V"
        row(label, states, solve_structured(mdp))
        pi = solve_policy_iteration(mdp)
        base = None
        if not args.skip_general:
            gen = solve_general(mdp)
            row(label, states, gen)
            base = gen.seconds
        row(label, states, pi, base)
        label = f"P1 {n}x{n} retry f={args.failure:g}"
        states = int(fail.live.sum())
        pi = solve_policy_iteration(fail)
        base = None
        if not args.skip_general:
            gen = solve_general(fail)
            row(label, states, gen)
            base = gen.seconds
        row(label, states, pi, base)
    for name in filter(None, args.bundled.split(",")):
        bundled = cellplan.load(name)
        mdp = build_model(bundled.scenario, bundled.workcell)
        solve_policy_iteration(mdp, max_iterations=1)  # compile this model's kernels
        row(f"{name} (bundled)", int(mdp.live.sum()), solve_policy_iteration(mdp))


if __name__ == "__main__":
    main()

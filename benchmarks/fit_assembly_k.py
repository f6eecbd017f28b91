"""Fitting the default-k rule of the gradient planner on the fitting grid (not the reporting sets).

Run: ``.venv/bin/python benchmarks/fit_assembly_k.py [--n 5 10 20 30] [--c 0.025 0.05 ...]
[--escape place|halve-k]``. The rule is ``k = C n^2 / fill`` (:func:`layout.rule_k`);
for every problem of :func:`assembly_sets.fitting_set` and every constant C the planner
``assembly.gradient`` runs once with that k (other options at their defaults, or the
given escape). Printed per run: the problem, C, k, ``gamma(b0)`` (equation (3)), status,
whether the flow at k alone solved it, seconds and ratio; then per n and C: solved,
solved at k alone, mean seconds, mean ratio of the solved runs. docs/assembly.md
"The default k" records the constant read from it.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import cellplan
from assembly_sets import fitting_set
from cellplan.assembly.layout import K_RULE_C, rule_k
from cellplan.assembly.navigation import evaluate
from cellplan.assembly.problems import problem_from_section


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="*")
    ap.add_argument("--c", type=float, nargs="*", default=[0.025, 0.05, 0.1, 0.2])
    ap.add_argument("--escape", default=None)
    args = ap.parse_args()
    extra = {} if args.escape is None else {"escape": args.escape}
    table: dict[tuple[int, float], list[tuple[bool, bool, float, float]]] = {}
    for case in fitting_set(args.n):
        setup = case.setup()
        problem = problem_from_section(setup.section("discs"), setup.scenario)
        gamma0 = math.exp(evaluate(problem.start, problem, 1.0).log_gamma)
        for c in args.c:
            k = rule_k(problem.radii, problem.workspace) * c / K_RULE_C
            t0 = time.perf_counter()
            res = cellplan.plan(setup, "assembly.gradient", k=k, **extra)
            wall = time.perf_counter() - t0
            ok = res.status.value == "solved"
            at_k = bool(res.stats["solved_at_k"])
            print(
                f"{case.label:30s} C {c:6.3f} k {k:7.1f} gamma0 {gamma0:9.1f} "
                f"{res.status.value:8s} at_k {int(at_k)} {wall:6.2f} s "
                f"ratio {res.stats['ratio']:7.3f}",
                flush=True,
            )
            table.setdefault((case.n, c), []).append((ok, at_k, wall, res.stats["ratio"]))
    print("\n| n | C | solved | solved at k | mean s | max s | mean ratio (solved) |")
    print("|---|---|---|---|---|---|---|")
    for (n, c), runs in sorted(table.items()):
        ok = [r for r in runs if r[0]]
        ratio = statistics.fmean(r[3] for r in ok) if ok else float("nan")
        print(
            f"| {n} | {c:g} | {len(ok)}/{len(runs)} | {sum(r[1] for r in runs)}/{len(runs)} | "
            f"{statistics.fmean(r[2] for r in runs):.2f} | {max(r[2] for r in runs):.2f} | "
            f"{ratio:.3f} |"
        )


if __name__ == "__main__":
    main()

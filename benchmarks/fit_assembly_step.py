"""Fitting the implicit flow's default step length on the fitting grid (not the reporting sets).

Run: ``.venv/bin/python benchmarks/fit_assembly_step.py [--n 5 10 20 30] [--c 0 0.02 ...]``.
The rule is ``step_max = max(0.05, c sqrt(n))`` (:func:`flows.step_max_rule`; ``c = 0``:
the fixed 0.05 used before). For every problem of :func:`assembly_sets.fitting_set` and
every c, the default planner ``assembly.gradient`` runs once with that ``step_max`` (k
from its rule, place-rule escape, automatic integrator: only the problems that get the
implicit step depend on c). Printed per run: problem, c, step_max, status, whether the
flow alone solved it, flow steps, seconds, ratio; then per n and c: solved, solved by
the flow alone, mean and max seconds, mean ratio of the solved runs, and the accuracy:
the largest relative ratio difference from ``c = 0`` over the runs both solved with the
flow alone. docs/assembly.md "The step length" records the constant read from it.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import cellplan
from assembly_sets import fitting_set
from cellplan.assembly.flows import FlowSettings


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="*")
    ap.add_argument("--c", type=float, nargs="*", default=[0.0, 0.02, 0.03, 0.04])
    args = ap.parse_args()
    print(f"load {os.getloadavg()[0]:.2f}", flush=True)
    # (n, c) -> label -> (solved, solved by the flow alone, wall, ratio, steps)
    table: dict[tuple[int, float], dict[str, tuple[bool, bool, float, float, float]]] = {}
    for case in fitting_set(args.n):
        setup = case.setup()
        for c in args.c:
            step = max(FlowSettings.step_max, c * math.sqrt(case.n))
            t0 = time.perf_counter()
            res = cellplan.plan(setup, "assembly.gradient", step_max=step)
            wall = time.perf_counter() - t0
            ok = res.status.value == "solved"
            at_k = bool(res.stats["solved_at_k"])
            ratio, steps = res.stats["ratio"], res.stats["steps"]
            print(
                f"{case.label:30s} c {c:5.3f} step {step:5.3f} {res.status.value:8s} "
                f"alone {int(at_k)} rk4 {int(res.stats['rk4'])} steps {steps:6.0f} "
                f"{wall:6.2f} s ratio {ratio:7.3f}",
                flush=True,
            )
            table.setdefault((case.n, c), {})[case.label] = (ok, at_k, wall, ratio, steps)
    print(f"load {os.getloadavg()[0]:.2f}")
    print(
        "\n| n | c | step_max | solved | flow alone | mean s | max s | mean ratio | max ratio dev |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for (n, c), runs in sorted(table.items()):
        ref = table[(n, args.c[0])]
        ok = [r for r in runs.values() if r[0]]
        ratio = statistics.fmean(r[3] for r in ok) if ok else float("nan")
        devs = [
            abs(r[3] / ref[label][3] - 1.0) for label, r in runs.items() if r[1] and ref[label][1]
        ]
        vals = list(runs.values())
        print(
            f"| {n} | {c:g} | {max(FlowSettings.step_max, c * math.sqrt(n)):.3f} | "
            f"{len(ok)}/{len(vals)} | {sum(r[1] for r in vals)}/{len(vals)} | "
            f"{statistics.fmean(r[2] for r in vals):.2f} | {max(r[2] for r in vals):.2f} | "
            f"{ratio:.3f} | {max(devs) if devs else float('nan'):.4f} |"
        )


if __name__ == "__main__":
    main()

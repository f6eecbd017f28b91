"""Fitting the automatic integrator choice on the fitting grid (never the reporting sets).

Run: ``.venv/bin/python benchmarks/fit_assembly_integrator.py [--n 10 20 30]``. For every
problem of :func:`assembly_sets.fitting_set` the flow at the rule's k
(:func:`layout.rule_k`, ``escapes=0``) runs with the linearly implicit step and with RK4
in the same process; printed per run: n, the goal pattern's smallest gap and its number
of tight pairs (gap below one radius), each method's status, steps and seconds, and the
time ratio rk4 / implicit. docs/assembly.md "The integrator" records the rule read from it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from assembly_sets import fitting_set
from cellplan.assembly.flows import FlowSettings, gradient_flow
from cellplan.assembly.layout import clearances, rule_k
from cellplan.assembly.problems import problem_from_section


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="*")
    args = ap.parse_args()
    for case in fitting_set(args.n):
        setup = case.setup()
        p = problem_from_section(setup.section("discs"), setup.scenario)
        k = rule_k(p.radii, p.workspace)
        gaps, _ = clearances(p.goal, p.radii, p.workspace)
        iu = np.triu_indices(p.n, 1)
        g = gaps[iu]
        out = []
        for method in ("implicit", "rk4"):
            t0 = time.perf_counter()
            # a 10,000-step budget: a run that needs more has lost the comparison
            r = gradient_flow(p, k, settings=FlowSettings(method=method, max_steps=10000))
            out.append((r.status.value, r.steps, time.perf_counter() - t0))
        (s1, n1, t1), (s2, n2, t2) = out
        print(
            f"{case.label:30s} k {k:7.1f} min goal gap {g.min():7.3f} "
            f"tight {int(np.sum(g < 1.0)):4d}"
            f" | implicit {s1:8s} {n1:6d} {t1:6.2f} s | rk4 {s2:16s} {n2:6d} {t2:6.2f} s"
            f" | rk4/implicit {t2 / t1:6.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()

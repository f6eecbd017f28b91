"""Fit the structured solver's rules on one set of problems, report them on another.

The outer loop of :func:`cellplan.strategies.solve.solver.solve_structured` has a few rules with a
constant (when the passes stop being capped, when the certificate is tried along the
Newton step, how exact the inner solves are). They are chosen on the *fit* set, problems 2,
4, 5 and problem 1 at 141 x 141, and reported on the *held-out* set, the targets of the
benchmark: problem 1 at 100 x 100 and 200 x 200, problem 6 at 64^3.

Each setting is a comma-separated list of ``NAME=VALUE`` overrides of the solver module's
constants (``-`` for the defaults); every problem is solved best of ``--repeat`` (wall
time, the default thread count; with ``--cpu`` the CPU time of one thread, which other
jobs on the shared machine disturb less) and the line gives each time, the passes and
the total. The numba kernels' own constants (``sweeps.PI_FRACTION``, ...) are compiled in:
edit the module and run again to compare them.

Run: ``.venv/bin/python benchmarks/fit_solver_rules.py --set fit - EARLY_SHAPE=1e3``.
"""

from __future__ import annotations

import argparse
import os
import time

from cellplan.strategies.model.mdp import LayeredMDP, build_model
from cellplan.strategies.solve import solver
from cellplan.workcell import load_workcell

SETS = {
    "fit": [("p2", None), ("p4", None), ("p5", None), ("p1", [141, 141])],
    "held-out": [("p1", [100, 100]), ("p1", [200, 200]), ("p6", None)],
}


def apply(setting: str) -> dict[str, float]:
    """Set the solver constants of ``setting``; returns their old values."""
    old: dict[str, float] = {}
    if setting == "-":
        return old
    for item in setting.split(","):
        name, _, value = item.partition("=")
        if not hasattr(solver, name):
            raise SystemExit(f"{name}: not a constant of cellplan.strategies.solve.solver")
        old[name] = getattr(solver, name)
        setattr(solver, name, type(old[name])(float(value)))
    return old


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--set", choices=sorted(SETS), default="fit")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument(
        "--cpu",
        action="store_true",
        help="one thread, CPU time (less disturbed by other jobs than the wall time)",
    )
    ap.add_argument("settings", nargs="+", help="NAME=VALUE[,NAME=VALUE] or - (defaults)")
    args = ap.parse_args()
    models: list[tuple[str, LayeredMDP]] = []
    for name, cells in SETS[args.set]:
        sc, cell = load_workcell(f"strategies_{name}")
        mdp = build_model(sc, cell, cells)
        solver.solve(mdp, "structured")  # compile and warm up
        label = name if cells is None else f"{name} {'x'.join(str(c) for c in cells)}"
        models.append((label, mdp))
    for setting in args.settings:
        old = apply(setting)
        total = 0.0
        cols = []
        for label, mdp in models:
            times = []
            clock = time.process_time if args.cpu else time.perf_counter
            for _ in range(args.repeat):
                t = clock()
                res = solver.solve(mdp, "structured", threads=1 if args.cpu else None)
                times.append(clock() - t)
            total += min(times)
            cols.append(f"{label} {min(times):.3f} s / {res.outer_iterations} passes")
        for name, value in old.items():
            setattr(solver, name, value)
        print(
            f"{setting}: total {total:.3f} s | {' | '.join(cols)} | load {os.getloadavg()[0]:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()

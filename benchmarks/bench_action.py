"""Benchmark of the online query of a solved strategy (Section IV-B of the strategies paper).

``Strategy.action`` answers with a typed :class:`~cellplan.strategies.policy.decisions.Action`
(one configuration) or an :class:`~cellplan.strategies.policy.decisions.Actions` bundle (an
``(n, dim)`` batch); ``Strategy.action_code`` with the raw integer code the simulators
use. Both evaluate equation (9) once per configuration with the same compiled kernel, so
the difference is the typed answer's overhead. Timed in the same process on problem 1
(the bundled grid, solved once): one configuration, best of 3 x ``--repeat`` queries
cycling over the modes live at the point, and batches of ``--batch`` configurations
against as many code queries. Prints microseconds per configuration, the ratios typed /
code and the machine load.

Run: ``.venv/bin/python benchmarks/bench_action.py`` (``--problem strategies_tiny`` for a
quick run).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np

import cellplan
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.solve.solver import solve


def load() -> str:
    """The machine's load averages (1, 5, 15 minutes)."""
    return "load " + " ".join(f"{v:.2f}" for v in os.getloadavg())


def best_us(fn: Callable[[], object], n: int, per: int = 1) -> float:
    """Best of 3 runs of ``n`` calls of ``fn``: microseconds per call divided by ``per``."""
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t) / n * 1e6 / per)
    return float(best)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problem", default="strategies_p1")
    ap.add_argument("--repeat", type=int, default=20000, help="single queries per run")
    ap.add_argument("--batch", type=int, default=1000, help="configurations per batch")
    args = ap.parse_args()
    print(f"start: {load()}", flush=True)
    setup = cellplan.load(args.problem)
    mdp = build_model(setup.scenario, setup.workcell)
    strategy = Strategy.from_solution(mdp, solve(mdp), setup.scenario)
    strategy.attach(setup.workcell)  # as the planner returns it: FMPs confirmed exactly
    rng = np.random.default_rng(0)
    # Configurations in NR's domain (every mode below is live there or skipped).
    cells = rng.choice(np.flatnonzero(mdp.live[0]), args.batch)
    index = np.array(np.unravel_index(cells, tuple(mdp.shape))).T
    centres = mdp.lower + (index + 0.5) * mdp.spacing
    qs = centres + rng.uniform(-0.4, 0.4, centres.shape) * mdp.spacing
    q = qs[0]
    modes = [m for m in range(mdp.n_modes) if strategy.in_domain(q, m)]
    strategy.action(q, modes[0])  # compile, or load numba's cache
    counter = iter(range(10**12))

    def typed_one() -> object:
        return strategy.action(q, modes[next(counter) % len(modes)])

    def code_one() -> object:
        return strategy.action_code(q, modes[next(counter) % len(modes)])

    inside = [r for r in qs if strategy.in_domain(r, 0)]
    batch = np.array(inside)

    def typed_batch() -> object:
        return strategy.action(batch, 0)

    def code_batch() -> object:
        return [strategy.action_code(r, 0) for r in batch]

    one_t = best_us(typed_one, args.repeat)
    one_c = best_us(code_one, args.repeat)
    many = max(1, args.repeat // len(batch))
    batch_t = best_us(typed_batch, many, len(batch))
    batch_c = best_us(code_batch, many, len(batch))
    print(
        f"{args.problem}: one configuration: typed action {one_t:.1f} us, action_code "
        f"{one_c:.1f} us, ratio {one_t / one_c:.2f} (best of 3 x {args.repeat}, "
        f"{len(modes)} modes)",
        flush=True,
    )
    print(
        f"{args.problem}: batch of {len(batch)}: typed action {batch_t:.2f} us per "
        f"configuration, action_code loop {batch_c:.2f} us, ratio {batch_t / batch_c:.2f} "
        f"(best of 3 x {many})",
        flush=True,
    )
    print(f"end: {load()}")


if __name__ == "__main__":
    main()

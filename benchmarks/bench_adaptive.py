"""Benchmarks of the adaptive package (run: ``.venv/bin/python benchmarks/bench_adaptive.py``).

1. One Reach query on the Figure 4 workcell (1 degree resolution, certified
   margin): Reach in bisection order, one batch per level, against the plain
   go-straight that checks the points one by one from the start (baseline, same
   process, same answers).
2. The cost of Adapt (A3) against Solve alone over 80 tasks (collision checks,
   the paper's measure), for a few seeds, through ``cellplan.plan(setup, "adaptive")``.
"""

from __future__ import annotations

import gc
import statistics
import sys
import time

import numpy as np

import cellplan.api as api
from cellplan import units
from cellplan.adaptive.reach import reach, segment_points
from cellplan.adaptive.runner import cumulative_ratio
from cellplan.adaptive.space import PlanSpace
from cellplan.adaptive.world import World

RESOLUTION = units.radians(1.0)


def sequential_reach(space: PlanSpace, a: np.ndarray, b: np.ndarray) -> bool:
    """The baseline go-straight: check the segment's points one by one from ``a``."""
    for q in segment_points(a, b, space.resolution):
        if not space.free(q[None, :])[0]:
            return False
    return True


def bench_reach(n_queries: int = 400) -> None:
    world = World(api.load("adaptive_fig4").scenario, RESOLUTION)
    names = sorted(world.goals)
    goals = np.array([world.goal_config(n) for n in names])
    pairs = np.random.default_rng(0).integers(len(goals), size=(n_queries, 2))
    results = {}
    for label, planner in (("bisection", reach), ("sequential", sequential_reach)):
        space = PlanSpace(world.is_free, world.robot.lower, world.robot.upper, RESOLUTION)
        planner(space, goals[0], goals[1])  # warm caches and compiled kernels
        warm_checks = space.counter.total
        times, answers = [], []
        for a, b in pairs:
            t0 = time.perf_counter()
            answers.append(planner(space, goals[a], goals[b]))
            times.append(time.perf_counter() - t0)
        results[label] = (np.array(times), answers, space.counter.total - warm_checks)
    assert results["bisection"][1] == results["sequential"][1], "the two orders disagree"
    print(f"Reach query, {n_queries} goal pairs of adaptive_fig4 (1 deg), mean / median / max:")
    for label, (t, _, checks) in results.items():
        print(
            f"  {label:<10}: {t.mean() * 1e3:.3f} / {np.median(t) * 1e3:.3f} / "
            f"{t.max() * 1e3:.3f} ms"
            f"  ({checks / n_queries:.0f} checks per query)"
        )
    tb, ts = results["bisection"][0], results["sequential"][0]
    print(f"  speed-up of bisection order (mean time): {ts.mean() / tb.mean():.1f}x")


def bench_adapt(seeds: tuple[int, ...] = (0, 1, 2)) -> None:
    setup = api.load("adaptive_fig4")
    r40, r80, walls = [], [], []
    for seed in seeds:
        t0 = time.perf_counter()
        result = api.plan(setup, "adaptive", repair="A3", seed=seed)
        walls.append(time.perf_counter() - t0)
        assert result.success, result.message
        rows = result.solution.tasks
        ratio = cumulative_ratio(rows)
        r40.append(ratio[39])
        r80.append(ratio[79])
        assert all(r["path_ok"] for r in rows)
        gc.collect()
    print(f"Adapt A3 / Solve only, cumulative collision checks, adaptive_fig4, seeds {seeds}:")
    print(
        f"  task 40: {', '.join(f'{r:.3f}' for r in r40)} "
        f"(mean {statistics.mean(r40):.3f}; paper 0.67; target <= 0.3)"
    )
    print(
        f"  task 80: {', '.join(f'{r:.3f}' for r in r80)} "
        f"(mean {statistics.mean(r80):.3f}; target <= 0.25)"
    )
    print(f"  wall per 80-task run incl. the Solve-only baseline: {statistics.mean(walls):.2f} s")


if __name__ == "__main__":
    bench_reach()
    if "--reach-only" not in sys.argv:
        bench_adapt()
    gc.collect()

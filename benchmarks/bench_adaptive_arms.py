"""Adapt on a UR5 against its peers, same tasks, same process (issue 31).

Run: ``.venv/bin/python benchmarks/bench_adaptive_arms.py [TASKS] [SEEDS]`` (default 40
tasks, seeds 0 and 1). On ``adaptive_ur5`` (no workcell change within the first 40
tasks) for each seed:

* Adapt (A3): :meth:`cellplan.ExperiencePlanner.plan` from where the robot stands to
  each task's goal, wall time of the whole call (argument checks included);
* OMPL RRTConnect from scratch on every task (Solve alone);
* OMPL PRM with its roadmap kept across the tasks;

per-query wall time (median, mean) and collision checks (mean), and the ratios of
Adapt's to each peer's. Then the repeated-task query: after the sequence, each of
the 9 goals is asked again three times in turn (the robot moving between them); its
median wall time is the figure behind the goal "under 10 ms on the UR5".
"""

from __future__ import annotations

import gc
import sys
import time

import numpy as np

import cellplan
from cellplan.adaptive.experiments3d import scenario
from cellplan.adaptive.peers import run_peer
from cellplan.adaptive.runner import choose_goal
from cellplan.setup import Setup


def adapt_rows(tasks: int, seed: int) -> tuple[list[dict[str, float]], list[float]]:
    """Per-task wall time and checks of Adapt, and the repeated queries' wall times."""
    sc = scenario(tasks, tasks, seed)
    sec = sc.adaptive
    planner = cellplan.ExperiencePlanner(Setup(sc, "adaptive_ur5"), "A3", seed=seed)
    rows = []
    current = None
    for t in range(tasks):
        goal = choose_goal(sec, sorted(planner.world.goals), t, current, seed)
        t0 = time.perf_counter()
        result = planner.plan(None, goal)
        rows.append(
            {
                "seconds": time.perf_counter() - t0,
                "checks": result.stats["checks"],
                "success": float(result.success),
            }
        )
        current = goal if result.success else current
    repeated = []
    for _ in range(3):
        for goal in sorted(planner.world.goals):
            t0 = time.perf_counter()
            result = planner.plan(None, goal)
            repeated.append(time.perf_counter() - t0)
            assert result.success
    gc.collect()
    return rows, repeated


def summary(label: str, rows: list[dict[str, float]]) -> tuple[float, float, float]:
    s = np.array([r["seconds"] for r in rows])
    c = np.array([r["checks"] for r in rows])
    ok = int(sum(r["success"] for r in rows))
    print(
        f"  {label:<22} wall median {np.median(s) * 1e3:9.1f} ms  mean {s.mean() * 1e3:9.1f} ms"
        f"  checks mean {c.mean():9.0f}  solved {ok}/{len(rows)}"
    )
    return float(np.median(s)), float(s.mean()), float(c.mean())


def main() -> None:
    tasks = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    seeds = [int(s) for s in sys.argv[2].split(",")] if len(sys.argv) > 2 else [0, 1]
    with open("/proc/loadavg") as f:
        print(f"load average at start: {f.read().strip()}")
    every: dict[str, list[dict[str, float]]] = {"adapt": [], "rrtconnect": [], "prm": []}
    repeated: list[float] = []
    for seed in seeds:
        rows, rep = adapt_rows(tasks, seed)
        every["adapt"] += rows
        repeated += rep
        sc = scenario(tasks, tasks, seed)
        for peer in ("rrtconnect", "prm"):
            every[peer] += run_peer(sc, peer)
            gc.collect()
    print(f"adaptive_ur5 (UR5, 6 joints), {tasks} tasks x seeds {seeds}, per query:")
    stats = {k: summary(k, v) for k, v in every.items()}
    for peer in ("rrtconnect", "prm"):
        a, p = stats["adapt"], stats[peer]
        print(
            f"  Adapt / {peer}: median wall {a[0] / p[0]:.3f}, mean wall {a[1] / p[1]:.3f}, "
            f"mean checks {a[2] / p[2]:.3f}"
        )
    r = np.array(repeated)
    print(
        f"repeated tasks ({len(r)} queries, 9 goals x 3 rounds x {len(seeds)} seeds): Adapt "
        f"wall median {np.median(r) * 1e3:.2f} ms, 90th percentile "
        f"{np.percentile(r, 90) * 1e3:.2f} ms (goal: under 10 ms median)"
    )
    with open("/proc/loadavg") as f:
        print(f"load average at end: {f.read().strip()}")


if __name__ == "__main__":
    main()

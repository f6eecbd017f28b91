"""Planners of the adaptive package, listed for the registry (CLI, benchmarks, conformance test)."""

from __future__ import annotations

import gc
import math

import numpy as np

from cellplan.core import PlannerEntry, PlanResult, Status
from cellplan.scenario import Scenario


def _fig4() -> Scenario:
    from cellplan.registry import scenario_path
    from cellplan.scenario import load_scenario

    return load_scenario(scenario_path("adaptive_fig4"))


def smoke_adapt(seed: int) -> PlanResult:
    """Adapt (A3) over 6 tasks of the Figure 4 workcell."""
    from cellplan.adaptive.runner import cumulative_ratio, run_adaptive

    out = run_adaptive(_fig4(), "A3", tasks=6, seed=seed)
    rows = out.rows
    assert out.adapter is not None
    stats = {
        "tasks": float(len(rows)),
        "solved": float(sum(r["success"] for r in rows)),
        "checks": float(sum(r["adapt"] for r in rows)),
        "solve_only_checks": float(sum(r["baseline"] for r in rows)),
        "ratio": float(cumulative_ratio(rows)[-1]),
        "vertices": float(len(out.adapter.graph)),
        "seconds": float(sum(r["seconds"] for r in rows)),
    }
    gc.collect()
    ok = all(r["success"] and r["path_ok"] for r in rows)
    return PlanResult(Status.SOLVED if ok else Status.STUCK, stats, rows)


def _peer(peer: str, seed: int) -> PlanResult:
    from cellplan.adaptive.peers import run_peer

    rows = run_peer(_fig4(), peer, tasks=3, seed=seed)
    gc.collect()
    # PRM's counts depend on its threads' timing, so they carry the timing marker.
    key = "checks_time_dependent" if peer == "prm" else "checks"
    stats = {
        "tasks": float(len(rows)),
        "solved": sum(r["success"] for r in rows),
        key: sum(r["checks"] for r in rows),
    }
    ok = all(r["success"] for r in rows)
    return PlanResult(Status.SOLVED if ok else Status.TIMEOUT, stats, rows)


def smoke_rrtconnect(seed: int) -> PlanResult:
    """OMPL RRTConnect from scratch on 3 tasks of the Figure 4 workcell."""
    return _peer("rrtconnect", seed)


def smoke_prm(seed: int) -> PlanResult:
    """OMPL PRM with its roadmap kept, on 3 tasks of the Figure 4 workcell."""
    return _peer("prm", seed)


def smoke_reach(seed: int) -> PlanResult:
    """Straight-line Reach between random goal configurations (counted)."""
    from cellplan.adaptive.reach import reach
    from cellplan.adaptive.space import PlanSpace
    from cellplan.adaptive.world import World

    world = World(_fig4(), math.radians(1.0))
    space = PlanSpace(world.is_free, world.robot.lower, world.robot.upper, math.radians(1.0))
    rng = np.random.default_rng(seed)
    names = sorted(world.goals)
    hits = 0
    for _ in range(10):
        a, b = rng.choice(len(names), 2, replace=False)
        qa, qb = world.goal_config(names[a]), world.goal_config(names[b])
        assert qa is not None and qb is not None
        hits += reach(space, qa, qb)
    return PlanResult(
        Status.SOLVED,
        {"queries": 10.0, "successes": float(hits), "checks": float(space.counter.total)},
    )


PLANNERS: list[PlannerEntry] = [
    PlannerEntry(
        "adaptive.adapt",
        "adaptive",
        "Adapt with the experience graph, repair A0-A3 (Chen 1994)",
        smoke_adapt,
    ),
    PlannerEntry(
        "adaptive.reach",
        "adaptive",
        "Reach: straight joint-space line, bisection-order checks",
        smoke_reach,
    ),
    PlannerEntry(
        "adaptive.rrtconnect",
        "adaptive",
        "OMPL RRTConnect from scratch per task (Solve only)",
        smoke_rrtconnect,
    ),
    PlannerEntry(
        "adaptive.prm", "adaptive", "OMPL PRM with its roadmap kept across tasks", smoke_prm
    ),
]

"""The modern peers on the same task sequence (Section 4 comparison).

* ``prm``: OMPL PRM whose roadmap is kept across queries (multi-query); after
  an environment change the roadmap is rebuilt from scratch, since OMPL's PRM
  cannot tell which of its edges a change invalidated.
* ``rrtconnect``: RRTConnect from scratch on every task (this is "Solve only",
  the denominator of Figure 5's ratio).

Both count collision checks through the same :class:`~.space.PlanSpace`.
"""

from __future__ import annotations

import time

import numpy as np

from cellplan.adaptive.adapt import TaskResult, derive_seed
from cellplan.adaptive.counters import CheckCounter
from cellplan.adaptive.runner import (
    TaskPath,
    choose_goal,
    describe_change,
    settings_for,
    task_count,
)
from cellplan.adaptive.solve import PRMSession, SolveInfo, solve_rrtconnect
from cellplan.adaptive.space import PlanSpace
from cellplan.adaptive.world import make_world, preflight
from cellplan.core import Progress
from cellplan.scenario import Scenario

PEERS = ("prm", "rrtconnect")


def run_peer(
    scenario: Scenario,
    peer: str,
    tasks: int | None = None,
    seed: int | None = None,
    paths: list[TaskPath] | None = None,
    progress: Progress | None = None,
) -> list[dict[str, float]]:
    """Per-task checks of a peer planner over the scenario's task sequence.

    With ``paths``, each task's executed path (Solve's waypoints) is appended to it.
    """
    if peer not in PEERS:
        raise ValueError(f"unknown peer {peer!r}; known: {PEERS}")
    assert scenario.adaptive is not None
    sec = scenario.adaptive
    settings = settings_for(scenario, None, seed)
    n = task_count(scenario, tasks)
    preflight(scenario, settings.resolution, settings.seed)
    world = make_world(scenario, settings.resolution)
    counter = CheckCounter()
    space = PlanSpace(
        world.is_free,
        world.robot.lower,
        world.robot.upper,
        settings.resolution,
        counter,
        tuple(world.robot.periodic),
    )
    stages = sec.stages()
    u = np.asarray(world.robot.start, float)
    current: str | None = None
    prm: PRMSession | None = None
    rows = []
    try:
        for t in range(n):
            changed = []
            for _, change in stages.get(t, []):
                world.apply(change)
                changed.append(describe_change(change))
            if changed and prm is not None:
                prm.close()
                prm = None
            goal = choose_goal(sec, list(world.goals), t, current, settings.seed)
            w = world.goal_config(goal)
            assert w is not None
            before = counter.total
            t0 = time.perf_counter()
            u_before = u.copy()
            info = SolveInfo()
            if peer == "prm":
                if prm is None:
                    prm = PRMSession(space, derive_seed(settings.seed, t, 77))
                path = prm.query(u, w)
                note = "" if path is not None else "PRM found no path within its time limit"
            else:
                path = solve_rrtconnect(
                    space,
                    u,
                    w,
                    derive_seed(settings.seed, t, 1_000_003),
                    settings.max_solve_checks,
                    info=info,
                )
                note = "" if path is not None else _why(info, settings.max_solve_checks)
            if path is not None:
                u, current = w, goal
                path = space.unwrap(path)
            if paths is not None:
                res = TaskResult(goal, path is not None, path=path, note=note)
                paths.append(TaskPath(t + 1, goal, u_before, res, changed))
            if progress is not None:
                progress(t + 1, n, goal)
            rows.append(
                {
                    "task": t + 1,
                    "checks": int(counter.total - before),
                    "success": int(path is not None),
                    "seconds": time.perf_counter() - t0,
                }
            )
    finally:
        if prm is not None:
            prm.close()
    return rows


def _why(info: SolveInfo, budget: int) -> str:
    """Why a Solve call failed, in words."""
    if info.outcome == "endpoint":
        return "an end of the task is in collision"
    if info.outcome == "time":
        return f"Solve stopped at its wall-time guard after {info.checks} checks"
    return f"Solve found no path within its budget of {budget} checks"

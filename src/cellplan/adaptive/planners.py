"""The adaptive package's planners behind :func:`cellplan.plan` (light to import).

* ``adaptive``: Adapt (Chen 1994, Figure 1) over the scenario's task list, driving an
  :class:`~.experience.ExperiencePlanner` task by task, with the scheduled workcell
  changes and repair A0-A3 (Section 2.5), and optionally Solve alone on the same tasks
  for the cumulative cost ratio of Figure 5.
* ``adaptive.rrtconnect``: Solve alone (OMPL RRTConnect from scratch per task), the
  denominator of Figure 5's ratio.
* ``adaptive.prm``: OMPL PRM with its roadmap kept across tasks (rebuilt after a change),
  the modern multi-query peer.

The ``adaptive`` planner's ``solution`` is the :class:`~.experience.ExperiencePlanner`
the task list drove (query it further with ``plan(start, goal)``); the peers' is the
list of per-task rows (``task``, ``checks``, ``success``).

Every run returns the common :class:`~cellplan.core.Result`: ``solved`` when every task
reached its goal, ``failed`` with the failed tasks named otherwise; the trajectory is the
executed paths of all tasks end to end (``t`` = cumulative joint-space path length, mode =
the task's goal, events ``task``, ``arrive``, ``fail``, ``change``).
"""

from __future__ import annotations

import gc
from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field

from cellplan.core import Options, Progress, Result, Stat, Status

if TYPE_CHECKING:
    from cellplan.adaptive.runner import TaskPath
    from cellplan.setup import Setup
    from cellplan.trajectory import Trajectory

Repair = Literal["A0", "A1", "A2", "A3"]
TaskCount = Annotated[int, Field(ge=1, le=1_000_000)]


class AdaptiveOptions(Options):
    """Options of the ``adaptive`` planner (``None``: the scenario section's value)."""

    repair: Repair | None = Field(
        None,
        description="repair strategy after a workcell change: A0 forget, A1 verify all, "
        "A2 repair actively, A3 on demand (Section 2.5)",
    )
    tasks: TaskCount | None = Field(
        None, description="number of tasks (of a listed sequence: its first ones)"
    )
    seed: int | None = Field(
        None, description="seed of the random task sequence and of Solve (OMPL's RNG)"
    )
    db: str | None = Field(
        None,
        description="SQLite experience database; a run continues from it if it exists "
        "(None: in memory)",
    )
    baseline: bool = Field(
        True, description="also run Solve alone on every task (for the cost ratio of Fig. 5)"
    )


class PeerOptions(Options):
    """Options of the Solve-only peers (``None``: the scenario section's value)."""

    tasks: TaskCount | None = Field(
        None, description="number of tasks (of a listed sequence: its first ones)"
    )
    seed: int | None = Field(None, description="seed of the random task sequence and of OMPL")


def run_adaptive_planner(
    setup: Setup, options: AdaptiveOptions, progress: Progress | None = None
) -> Result:
    """Adapt over the scenario's tasks (see the module docstring)."""
    from cellplan.adaptive.runner import cumulative_ratio, run_adaptive, settings_for, task_count
    from cellplan.adaptive.store import ExperienceStore
    from cellplan.adaptive.world import preflight

    sc = setup.scenario
    n_tasks = task_count(sc, options.tasks)
    # Every check first: a scenario that fails them must not leave a database file
    # behind (it would then refuse the corrected scenario).
    settings = settings_for(sc, options.repair, options.seed)
    preflight(sc, settings.resolution, settings.seed)
    store = ExperienceStore(options.db, sc) if options.db is not None else None

    def on_task(done: int, total: int, row: dict[str, Any]) -> None:
        if progress is not None:
            progress(done, total, f"{row['goal']} |V|={row['vertices']}")

    sec = setup.section("adaptive")
    change_tasks = sorted({c.after_task for c in sec.changes})
    marks = {0, n_tasks, *change_tasks, *(t + 1 for t in change_tasks)}

    def snapshot_at(t: int) -> bool:
        # Figure 3's frames: the first tasks, around each change, the last.
        return t in marks or t <= 4

    try:
        out = run_adaptive(
            sc,
            options.repair,
            options.tasks,
            options.seed,
            store,
            options.baseline,
            on_task,
            snapshot_at=snapshot_at,
            checked=True,
        )
    finally:
        if store is not None:
            store.close()
    rows = out.rows
    planner = out.planner
    assert planner is not None
    traj = paths_trajectory(
        out.paths,
        planner.world.robot.axis_names,
        _meta(setup, planner),
        planner.position,
        planner.world.robot,
        sc.robot,
    )
    # Counts are ints, measures floats (core.Stat): they keep their type in --json.
    stats: dict[str, Stat] = {
        "tasks": len(rows),
        "solved": sum(int(r["success"]) for r in rows),
        "paths_ok": sum(int(r["path_ok"]) for r in rows),
        "checks": sum(int(r["adapt"]) for r in rows),
        "solve_calls": sum(int(r["solve_calls"]) for r in rows),
        "vertices": len(planner.graph),
        "edges": len(planner.graph.usable_edges()),
        "generation": int(planner.world.gen),
        "path_length": float(traj.duration),
        "seconds": float(sum(float(r["seconds"]) for r in rows)),
    }
    if options.baseline:
        solve_only = sum(int(r["baseline"]) for r in rows)
        stats["solve_only_checks"] = solve_only
        if solve_only > 0:
            stats["ratio"] = float(cumulative_ratio(rows)[-1])
    stats["s_fallbacks"] = sum(int(r.get("s_fallbacks") or 0) for r in rows)
    failed = [(int(r["task"]), str(r["goal"])) for r in rows if not (r["success"] and r["path_ok"])]
    gc.collect()
    ratio = f", cumulative cost ratio {stats['ratio']:.3f}" if "ratio" in stats else ""
    if failed:
        first = next(r for r in rows if not (r["success"] and r["path_ok"]))
        why = str(first.get("note") or "no reason recorded (a database from before reasons)")
        return Result(
            Status.FAILED,
            f"{len(failed)} of {len(rows)} tasks failed: {_task_list(failed)}; "
            f"task {int(first['task'])}: {why}",
            stats=stats,
            solution=planner,
            trajectory=traj,
        )
    return Result(
        Status.SOLVED,
        f"{len(rows)} of {n_tasks} tasks solved with {int(stats['checks'])} collision checks, "
        f"G has {len(planner.graph)} vertices{ratio}",
        stats=stats,
        solution=planner,
        trajectory=traj,
    )


def _run_peer(setup: Setup, options: PeerOptions, progress: Progress | None, peer: str) -> Result:
    from cellplan.adaptive.peers import run_peer

    paths: list[TaskPath] = []
    rows = run_peer(setup.scenario, peer, options.tasks, options.seed, paths, progress)
    gc.collect()
    robot = setup.workcell.robot
    traj = paths_trajectory(
        paths, robot.axis_names, {"scenario": setup.name}, robot.start, robot, setup.scenario.robot
    )
    # PRM's counts depend on its threads' timing, so they carry the timing marker.
    key = "checks_time_dependent" if peer == "prm" else "checks"
    stats: dict[str, Stat] = {
        "tasks": len(rows),
        "solved": sum(int(r["success"]) for r in rows),
        key: sum(int(r["checks"]) for r in rows),
        "path_length": float(traj.duration),
    }
    failed = [
        (int(r["task"]), p.goal) for r, p in zip(rows, paths, strict=True) if not r["success"]
    ]
    if failed:
        why = next(p.result.note for r, p in zip(rows, paths, strict=True) if not r["success"])
        return Result(
            Status.FAILED,
            f"{len(failed)} of {len(rows)} tasks failed: {_task_list(failed)}; "
            f"task {failed[0][0]}: {why}",
            stats=stats,
            solution=rows,
            trajectory=traj,
        )
    return Result(
        Status.SOLVED,
        f"{len(rows)} tasks solved by {peer} with {int(stats[key])} collision checks",
        stats=stats,
        solution=rows,
        trajectory=traj,
    )


def run_rrtconnect(setup: Setup, options: PeerOptions, progress: Progress | None = None) -> Result:
    """Solve alone: OMPL RRTConnect from scratch on every task."""
    return _run_peer(setup, options, progress, "rrtconnect")


def run_prm(setup: Setup, options: PeerOptions, progress: Progress | None = None) -> Result:
    """OMPL PRM with its roadmap kept across the tasks (rebuilt after a change)."""
    return _run_peer(setup, options, progress, "prm")


def paths_trajectory(
    paths: Sequence[TaskPath],
    axis_names: Sequence[str],
    meta: dict[str, Any],
    position: Any,
    robot: Any = None,
    robot_spec: Any = None,
) -> Trajectory:
    """The tasks' executed paths end to end, one mode per goal (see the module docstring).

    With no task run in this call (a database that already holds every task), the
    trajectory is one sample at the robot's ``position`` in mode ``idle``. ``robot`` and
    ``robot_spec`` (the scenario's robot section) give periodic axes and speeds.
    """
    import numpy as np

    from cellplan import units
    from cellplan.adaptive.experience import task_trajectory
    from cellplan.trajectory import Trajectory

    if not paths:
        q = np.asarray(position, dtype=float)[None, :]
        return Trajectory(
            np.zeros(1),
            q,
            np.zeros(1, dtype=np.int64),
            ("idle",),
            tuple(axis_names),
            units.axis_units(axis_names),
            "path",
            (),
            meta,
            periodic=getattr(robot, "periodic", ()),
        )
    parts = [
        task_trajectory(axis_names, p.u, p.result, p.goal, p.changes, meta, robot, robot_spec)
        for p in paths
    ]
    return Trajectory.concatenate(parts)


def _meta(setup: Setup, planner: Any) -> dict[str, Any]:
    return {
        "scenario": setup.name,
        "repair": planner.settings.repair,
        "seed": int(planner.settings.seed),
    }


def _task_list(failed: Sequence[tuple[int, str]], shown: int = 8) -> str:
    """``12 (g4), 40 (g7) ...``: the first failed tasks with their goals."""
    text = ", ".join(f"{t} ({g})" for t, g in failed[:shown])
    return text + (" ..." if len(failed) > shown else "")

"""A whole adaptive run: tasks, environment changes, repair, the Solve-only baseline, persistence.

:func:`run_adaptive` drives :class:`~.adapt.Adapter` through the scenario's
task sequence. Before task ``t + 1`` it applies the changes scheduled
``after_task: t`` (object-attached subgoals follow their objects), runs
Repair(G) for the chosen strategy, then the task. The baseline ("Solve only",
Section 4) plans the same goal from its own position with Solve alone, in the
same environment, with its checks counted separately. With a store, each task
(changes, repair, task, baseline) is committed in one transaction, and a run
continues from the saved state.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cellplan import budget, units
from cellplan.adaptive.adapt import Adapter, Hook, Settings, TaskResult, derive_seed
from cellplan.adaptive.experience import ExperiencePlanner, failure_state, saved_failures
from cellplan.adaptive.graph import ExperienceGraph
from cellplan.adaptive.repair import STRATEGIES
from cellplan.adaptive.section import AdaptiveSection, Change, RandomTasks, stage_words
from cellplan.adaptive.solve import (
    check_planner_name,
    ompl_planner_name,
    solve_rrtconnect,
    solve_two_segment,
)
from cellplan.adaptive.store import ExperienceStore
from cellplan.adaptive.world import AnyWorld, preflight
from cellplan.errors import ArgumentError, PersistenceError, Problem, ScenarioError
from cellplan.scenario import Scenario
from cellplan.workcell import Workcell

Row = dict[str, Any]
TaskCallback = Callable[[int, int, Row], None]


def settings_for(scenario: Scenario, repair: str | None, seed: int | None) -> Settings:
    """Planner settings from the scenario section (radians for arms), with overrides."""
    sec = _section(scenario)
    if repair is not None and repair not in STRATEGIES:
        raise ArgumentError(
            f"unknown repair strategy {repair!r}; choose one of {', '.join(STRATEGIES)}", "repair"
        )
    why = check_planner_name(sec.solve)
    if why:
        raise ScenarioError([Problem("adaptive.solve", why)])
    return Settings(
        repair=repair or sec.repair,
        solve=sec.solve,
        reach=sec.reach,
        resolution=resolution_in_code(scenario, sec.resolution),
        corner_cutting=sec.corner_cutting,
        max_chain=sec.max_chain,
        max_solve_checks=sec.max_solve_checks,
        seed=_task_seed(sec) if seed is None else seed,
    )


def resolution_in_code(scenario: Scenario, resolution: float) -> float:
    """The section's Reach step in code units: degrees become radians for an arm."""
    if scenario.robot is not None and scenario.robot.type in ("arm", "urdf"):
        return float(units.radians(resolution))
    return float(resolution)


def _section(scenario: Scenario) -> AdaptiveSection:
    if scenario.adaptive is None:
        raise ScenarioError([Problem("adaptive", "the scenario has no adaptive section")])
    return scenario.adaptive


def _task_seed(sec: AdaptiveSection) -> int:
    return sec.tasks.seed if isinstance(sec.tasks, RandomTasks) else 0


SECONDS_PER_TASK = 0.1
"""Seconds per task, its Solve-only baseline included, for the time estimate: 55 ms
measured (``cellplan adapt adaptive_fig4``, 10 and 80 tasks, on the shared 2-core machine
at load about 4), rounded up."""


def listed_count(sec: AdaptiveSection) -> int:
    """Number of tasks the section asks for (listed, or ``tasks.count`` random ones), with
    no time check: what ``validate`` prints after :func:`task_count` has checked it."""
    return len(sec.tasks) if isinstance(sec.tasks, list) else sec.tasks.count


def task_count(scenario: Scenario, tasks: int | None) -> int:
    """Number of tasks of the run (``tasks`` overrides the section's), refused when their
    estimated time passes the time limit (:func:`cellplan.budget.require_time`)."""
    sec = _section(scenario)
    if tasks is not None:
        if tasks < 1:
            raise ArgumentError("must be at least 1", "tasks")
        if isinstance(sec.tasks, list) and tasks > len(sec.tasks):
            raise ArgumentError(f"the scenario lists only {len(sec.tasks)} tasks", "tasks")
        budget.require_time(tasks * SECONDS_PER_TASK, "tasks", f"for {tasks} tasks")
        return tasks
    n = listed_count(sec)
    budget.require_time(
        n * SECONDS_PER_TASK, "adaptive.tasks.count", f"for {n} tasks", ScenarioError
    )
    return n


def choose_goal(
    sec: AdaptiveSection, goals: list[str], t: int, current: str | None, seed: int
) -> str:
    """Goal of task ``t + 1``: the listed one, or uniform over the goal set minus the current."""
    if isinstance(sec.tasks, list):
        return sec.tasks[t]
    candidates = sorted(g for g in goals if g != current) or sorted(goals)
    rng = np.random.default_rng([seed & 0xFFFFFFFF, t])
    return candidates[int(rng.integers(len(candidates)))]


@dataclass
class TaskPath:
    """What the robot did in one task: from ``u``, the executed path (``None``: failed)."""

    task: int
    goal: str
    u: np.ndarray
    result: TaskResult
    changes: list[str] = field(default_factory=list)


@dataclass
class RunOutcome:
    """Rows of every task (saved ones included when continuing) and the final planner.

    ``paths`` holds the tasks run in this call (not those of a continued database).
    """

    rows: list[Row] = field(default_factory=list)
    planner: ExperiencePlanner | None = None
    snapshots: list[Snapshot] = field(default_factory=list)
    paths: list[TaskPath] = field(default_factory=list)

    @property
    def adapter(self) -> Adapter | None:
        """Adapt's final state (``planner.adapter``)."""
        return None if self.planner is None else self.planner.adapter


def run_adaptive(
    scenario: Scenario,
    repair_strategy: str | None = None,
    tasks: int | None = None,
    seed: int | None = None,
    store: ExperienceStore | None = None,
    baseline: bool = True,
    on_task: TaskCallback | None = None,
    hook: Hook | None = None,
    snapshot_at: Callable[[int], bool] | None = None,
    checked: bool = False,
) -> RunOutcome:
    """Run Adapt over the scenario's tasks; see the module docstring.

    The tasks drive an :class:`~.experience.ExperiencePlanner`: each is a query from
    where the robot stands to the task's named goal, after the changes scheduled
    before it.

    Parameters
    ----------
    snapshot_at
        ``snapshot_at(t)`` true: keep a copy of G (and the world's object poses)
        after task ``t`` in the outcome, for pictures.
    checked
        The caller has already run :func:`~.world.preflight` on the scenario (it
        does so before creating the database file, so that a scenario that fails its
        checks leaves no file behind).
    """
    sec = _section(scenario)
    settings = settings_for(scenario, repair_strategy, seed)
    n_tasks = task_count(scenario, tasks)
    if not checked:
        preflight(scenario, settings.resolution, settings.seed)
    planner = ExperiencePlanner(scenario, settings.repair, seed=settings.seed, hook=hook)
    world, adapter, counter = planner.world, planner.adapter, planner.counter
    stages = sec.stages()
    outcome = RunOutcome(planner=planner)
    u_base = adapter.u.copy()
    start_t = 0
    if store is not None:
        if store.planner_state() is not None:
            raise PersistenceError(
                [
                    Problem(
                        str(store.path),
                        "was continued by an ExperiencePlanner (its workcell no longer follows "
                        "the scenario's schedule); use a new --db file",
                    )
                ]
            )
        outcome.rows = store.task_rows()
        saved = store.state()
        if saved is not None:
            _check_resume(saved, settings)
            restore_run(planner, store, saved)
            start_t = int(saved["tasks_done"])
            u_base = np.array(saved["u_base"], float)
    for t in range(start_t, n_tasks):
        applied = []
        stage = stages.get(t, [])
        moved: set[str] = set()
        for _, change in stage:
            moved |= world.apply(change)
            applied.append(describe_change(change))
        if stage:
            # After the stage's last change, as the preflight checks: subgoals follow their
            # objects' final poses, one inverse-kinematics solve each however many moves.
            if not adapter.space.free(adapter.u[None, :])[0]:
                field, what = stage_words(stage)
                verb = "puts" if len(stage) == 1 else f"{what} put"
                raise ScenarioError(
                    [Problem(field, f"{verb} an obstacle on the robot at task {t + 1}")]
                )
            adapter.follow_objects(moved)
        goal = choose_goal(sec, list(world.goals), t, adapter.current_goal, settings.seed)
        w = world.goal_config(goal)
        assert w is not None  # preflight checked every goal at every stage
        u = adapter.u.copy()
        res = planner.run_task(goal, w)  # changes and repair included in its costs
        adapter.tasks_done = t + 1
        outcome.paths.append(TaskPath(t + 1, goal, u, res, applied))
        base_cost = 0
        if baseline:
            base_cost, ok = _baseline(adapter, settings, u_base, w, t)
            if ok:
                u_base = w.copy()
        planner._mark = counter.snapshot()
        row = _row(t, res, base_cost, world.gen)
        outcome.rows.append(row)
        cell = world.workcell()
        # Snapshots are pictures of G over a planar cell (Figure 3).
        if snapshot_at is not None and snapshot_at(t + 1) and isinstance(cell, Workcell):
            outcome.snapshots.append(
                Snapshot(
                    t + 1,
                    adapter.graph.copy(),
                    cell,
                    adapter.u.copy(),
                    _goal_points(world),
                    res.path,
                )
            )
        if store is not None:
            state = {
                "tasks_done": t + 1,
                "generation": world.gen,
                "u": [float(x) for x in adapter.u],
                "u_hat": adapter.u_hat,
                "link_gen": adapter.link_gen,
                "repaired_gen": adapter.repaired_gen,
                "current_goal": adapter.current_goal,
                "solve_calls": adapter._solve_calls,
                **failure_state(adapter),
                "u_base": [float(x) for x in u_base],
                "repair": settings.repair,
                "seed": settings.seed,
            }
            store.commit_task(adapter.graph, state, row, adapter.links())
        if on_task is not None:
            on_task(t + 1, n_tasks, row)
    planner.queries = n_tasks
    planner.tasks = outcome.rows
    planner.snapshots = outcome.snapshots
    return outcome


def restore_run(planner: ExperiencePlanner, store: ExperienceStore, saved: dict[str, Any]) -> None:
    """Bring a planner to the state a run saved: the scheduled changes up to the last task
    done, then G, the remembered Reach answers and the pointers from the database."""
    assert planner.scenario is not None
    sec = _section(planner.scenario)
    world, adapter = planner.world, planner.adapter
    done = int(saved["tasks_done"])
    for _, change in sec.ordered_changes():
        if change.after_task < done:
            world.apply(change)
    if world.gen != int(saved["generation"]):
        raise PersistenceError(
            [Problem(str(store.path), "generation does not match the scenario's changes")]
        )
    adapter.graph = store.load_graph()
    store.check_state(adapter.graph, saved, adapter.u.size)
    links, links_gen = store.load_links()
    if links_gen is not None:
        adapter.goal_links, adapter._links_gen = links, links_gen
    adapter.u = np.array(saved["u"], float)
    adapter.u_hat = int(saved["u_hat"])
    adapter.link_gen = int(saved["link_gen"])
    adapter.repaired_gen = int(saved["repaired_gen"])
    adapter.current_goal = saved["current_goal"]
    adapter.tasks_done = done
    adapter._solve_calls = int(saved["solve_calls"])
    # S's remembered failures of this generation (none in a run saved before they were kept)
    adapter.s_failed, adapter.s_failed_gen = saved_failures(saved, world.gen)
    planner.queries = done


def describe_change(change: Change) -> str:
    """``add_object O6``, ``move_object B``, ``remove_goal w3`` ... (an event's detail)."""
    target = getattr(change, "object", None) or getattr(change, "goal", "")
    return f"{change.type} {target}"


def _goal_points(world: AnyWorld) -> dict[str, tuple[float, float]]:
    out = {}
    for n, tag in world.goals.items():
        p = world.tool_pose_of(tag)
        out[n] = (float(p[0]), float(p[1]))
    return out


@dataclass
class Snapshot:
    """G after a task, with the workcell of that moment (for pictures)."""

    task: int
    graph: ExperienceGraph
    cell: Workcell
    u: np.ndarray
    goals: dict[str, tuple[float, float]]
    path: np.ndarray | None


def _check_resume(saved: dict[str, Any], settings: Settings) -> None:
    problems = []
    if saved.get("repair") != settings.repair:
        problems.append(
            Problem(
                "repair",
                f"the database was built with {saved.get('repair')}, not {settings.repair}",
            )
        )
    if saved.get("seed") != settings.seed:
        problems.append(
            Problem(
                "seed",
                f"the database was built with seed {saved.get('seed')}, not {settings.seed}",
            )
        )
    if problems:
        raise ArgumentError(problems)


def _baseline(
    adapter: Adapter, settings: Settings, u: np.ndarray, w: np.ndarray, t: int
) -> tuple[int, bool]:
    """Solve alone from ``u`` to ``w``: (checks, success)."""
    counter = adapter.counter
    before = counter.counts["baseline"]
    with counter.charge("baseline"):
        if settings.solve == "two_segment":
            path = solve_two_segment(adapter.space, u, w)
        else:
            path = solve_rrtconnect(
                adapter.space,
                u,
                w,
                derive_seed(settings.seed, t, 1_000_003),
                settings.max_solve_checks,
                planner_name=ompl_planner_name(settings.solve),
            )
    return counter.counts["baseline"] - before, path is not None


def _row(t: int, res: TaskResult, base_cost: int, gen: int) -> Row:
    c = res.costs
    adapt = sum(v for k, v in c.items() if k != "baseline")
    return {
        "task": t + 1,
        "goal": res.goal,
        "success": int(res.success),
        "solve_calls": res.solve_calls,
        **{k: c.get(k, 0) for k in ("reach", "trace", "solve", "abstract", "cut", "repair")},
        "adapt": adapt,
        "baseline": base_cost,
        "seconds": round(res.seconds, 6),
        "vertices": res.vertices,
        "edges": res.edges,
        "path_ok": int(res.path_ok),
        "generation": gen,
        "s_fallbacks": res.s_fallbacks,
        "note": res.note,
    }


def cumulative_ratio(rows: list[Row]) -> np.ndarray:
    """Cumulative Adapt cost over cumulative Solve-only cost, per task (Figure 5's ordinate)."""
    adapt = np.cumsum([float(r["adapt"]) for r in rows])
    base = np.cumsum([float(r["baseline"]) for r in rows])
    return np.divide(adapt, base, out=np.full_like(adapt, np.nan), where=base > 0)

"""Plan once, query cheaply: Adapt (Chen 1994, Figure 1) as a query planner.

:class:`ExperiencePlanner` keeps the experience graph G of one workcell and answers
``plan(start, goal)`` against it, in the spirit of OMPL's Lightning and Thunder
frameworks (which the pip bindings of OMPL do not offer):

1. the robot is put at ``start``: if it is not where the last query ended, the first
   vertex of G by h that Reach connects to ``start`` becomes the pointer û, or
   ``start`` becomes a new vertex (T's step 2 then connects it with Solve);
2. Repair(G) for the chosen strategy (A0-A3, Section 2.5) if the workcell changed;
3. one pass of Figure 1's loop: R(u, w), else S(u, w) with Solve, Abstract and
   Augment, then T(u, w) and corner cutting (Section 2.6);
4. the executed path ``u, û, Γ, ŵ, w`` comes back as the Result's trajectory.

Environment changes (:meth:`~ExperiencePlanner.add`, :meth:`~ExperiencePlanner.remove`,
:meth:`~ExperiencePlanner.move`, :meth:`~ExperiencePlanner.turn`) go through the same
:class:`~.world.World` primitives as a scenario's scheduled ``changes:``; subgoals
attached to a moved or turned object follow it (Section 2.3) and the next query repairs
G. With ``db`` the graph, the pointers and the changed world are written to the SQLite
experience database after every query and change (one transaction each), so a later
session continues with the same graph.

The scenario task list (:func:`~.runner.run_adaptive`) drives the same object: each
task is a query from where the robot stands to a named goal.

A query may hold a part (``plan(..., carrying=name)``): the world's validity attaches it
to the tool for every check of the query (:meth:`~.worldbase.ChangingWorld.hold`; Chen
is silent on held parts: a different part is treated as an environment change, a new
generation, so G is verified again before it is used with the new shape).
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from cellplan import timing, units
from cellplan.adaptive.adapt import Adapter, Hook, Settings, TaskResult
from cellplan.adaptive.counters import CheckCounter
from cellplan.adaptive.graph import ExperienceGraph
from cellplan.adaptive.repair import STRATEGIES, repair
from cellplan.adaptive.section import AdaptiveSection
from cellplan.adaptive.space import FloatArray, IsFree, and_validity
from cellplan.adaptive.store import (
    ExperienceStore,
    signatures,
    workcell_signatures,
)
from cellplan.adaptive.world import AnyWorld, World, make_world
from cellplan.core import Result, Stat, Status
from cellplan.errors import ArgumentError, PersistenceError, Problem
from cellplan.robots import PlanarArm, Robot
from cellplan.scenario import Scenario
from cellplan.setup import Setup, as_setup
from cellplan.trajectory import Event, Trajectory
from cellplan.workcell import Workcell
from cellplan.workcell3d import UrdfRobot

if TYPE_CHECKING:
    from cellplan.adaptive.runner import Snapshot

PLANNER_STATE = "planner"


def default_settings(is_arm: bool, repair_strategy: str, seed: int) -> Settings:
    """Settings for a problem without an ``adaptive:`` section: the section's defaults."""
    fields = AdaptiveSection.model_fields

    def default(name: str) -> Any:
        return fields[name].default

    resolution = float(default("resolution"))
    return Settings(
        repair=repair_strategy,
        solve=default("solve"),
        reach=default("reach"),
        resolution=float(units.radians(resolution)) if is_arm else resolution,
        corner_cutting=default("corner_cutting"),
        max_chain=default("max_chain"),
        max_solve_checks=default("max_solve_checks"),
        seed=seed,
    )


class ExperiencePlanner:
    """Adapt's experience graph as a multi-query planner (Chen 1994, Figure 1).

    Parameters
    ----------
    problem
        A :class:`~cellplan.setup.Setup` (what :func:`cellplan.load` returns), a
        scenario, a scenario path or bundled name, or a bare
        :class:`~cellplan.workcell.Workcell`. The scenario's ``adaptive:`` section, if
        any, supplies the named goals, ``attach_radius`` and the planner settings;
        otherwise the section's defaults apply.
    repair
        Repair strategy after a workcell change: ``A0`` forget, ``A1`` verify every
        edge, ``A2`` repair actively, ``A3`` repair on demand (Section 2.5).
    db
        Path of the SQLite experience database; continued if it exists (see
        :mod:`.store` for what it is keyed on). ``None``: in memory.
    resolution
        Reach step in code units (radians for an arm, workcell units for a point
        robot); ``None``: the section's value (its ``resolution`` is in degrees for an
        arm and converted here).
    seed
        Seed of Solve (OMPL's RNG is reseeded from it before every call); ``None``:
        the section's task seed.
    validity
        A validity test of your own, ``validity(Q) -> bool[N]`` for ``Q`` of shape
        ``(N, dim)`` (radians for angles), AND-ed with the workcell's in every check
        (as OMPL's ``SimpleSetup.setStateValidityChecker``; a configuration is counted
        once), in the exact re-check of executed paths and in the start and goal checks.
        It must be a pure function of ``Q``: G keeps what it verified. A database
        reopened with one starts a new environment generation, so T verifies G's edges
        again before using them.
    hook
        Called with the phase names ``augment``, ``trace_solve`` and ``executed`` as a
        query passes them (used to test that a killed run leaves its database intact).

    Attributes
    ----------
    world
        The current workcell: objects with poses, named goals, generation.
    adapter
        Adapt's state: G (``adapter.graph``), the robot position, the pointers.
    counter
        Collision checks per category (the paper's cost measure).
    tasks
        When a scenario run drove the planner (the ``adaptive`` planner, ``cellplan
        adapt``): one row per task (goal, success, the cost split, the Solve-only
        baseline, |V| ...); empty otherwise.
    snapshots
        Copies of G with the workcell after selected tasks of such a run (for pictures).
    """

    def __init__(
        self,
        problem: Setup | Scenario | Workcell | str | Path,
        repair: str = "A3",
        db: str | Path | None = None,
        resolution: float | None = None,
        seed: int | None = 0,
        *,
        validity: IsFree | None = None,
        hook: Hook | None = None,
    ) -> None:
        from cellplan.adaptive.runner import settings_for

        if validity is not None and not callable(validity):
            raise ArgumentError(
                f"must be a callable Q (N, dim) -> bool[N], got {validity!r}", "validity"
            )
        if repair not in STRATEGIES:
            raise ArgumentError(
                f"unknown repair strategy {repair!r}; choose one of {', '.join(STRATEGIES)}",
                "repair",
            )
        if resolution is not None and not (np.isfinite(resolution) and resolution > 0):
            raise ArgumentError(f"must be a positive number, got {resolution!r}", "resolution")
        if isinstance(problem, Workcell):
            self.scenario: Scenario | None = None
            is_arm = problem.robot.kind == "arm"
            settings = default_settings(is_arm, repair, seed or 0)
            if resolution is not None:
                settings.resolution = float(resolution)
            self.world: AnyWorld = World.from_workcell(problem, settings.resolution)
            sig = workcell_signatures(problem)
            self.name = problem.name
        else:
            setup = as_setup(problem)
            sc = setup.scenario
            self.scenario = sc
            if sc.adaptive is not None:
                settings = settings_for(sc, repair, seed)
            else:
                settings = default_settings(
                    sc.robot is not None and sc.robot.type in ("arm", "urdf"), repair, seed or 0
                )
            if resolution is not None:
                settings.resolution = float(resolution)
            self.world = make_world(setup, settings.resolution)
            sig = signatures(sc)
            self.name = setup.name
        _check_robot(self.world.robot)
        if validity is not None:
            # Its answer's type and shape, once, before any work (the start's row).
            and_validity(lambda Q: np.ones(len(Q), bool), validity)(
                np.asarray(self.world.robot.start, float)[None, :]
            )
        self.validity = validity
        self.settings = settings
        self.counter = CheckCounter()
        self.adapter = Adapter(self.world, settings, self.counter, hook, validity)
        self.queries = 0
        self.tasks: list[dict[str, Any]] = []
        self.snapshots: list[Snapshot] = []
        self._mark = self.counter.snapshot()
        self.store: ExperienceStore | None = None
        if db is not None:
            self.store = ExperienceStore(db, sig)
            try:
                self._restore()
            except BaseException:
                self.store.close()
                raise

    # --- the graph -------------------------------------------------------------------------

    @property
    def graph(self) -> ExperienceGraph:
        """The experience graph G (vertices: subgoals; edges: verified Reach segments)."""
        return self.adapter.graph

    @property
    def position(self) -> FloatArray:
        """Where the robot is: the end of the last successful query (radians for angles)."""
        return self.adapter.u.copy()

    @property
    def goals(self) -> dict[str, FloatArray]:
        """The named goals' configurations in the current workcell (radians for angles).

        A goal whose object has moved out of the arm's reach (no inverse-kinematics
        solution on its elbow branch now) is left out.
        """
        out = {}
        for name in sorted(self.world.goals):
            q = self.world.goal_config(name)
            if q is not None:
                out[name] = q
        return out

    def stats(self) -> dict[str, int]:
        """G's size, the checks made so far, Solve calls, queries and the generation."""
        return {**self.adapter.stats(), "queries": int(self.queries)}

    def __repr__(self) -> str:
        g = self.graph
        return (
            f"ExperiencePlanner({self.name!r}, repair={self.settings.repair!r}, "
            f"|V|={len(g)}, |E|={len(g.usable_edges())}, queries={self.queries})"
        )

    # --- queries ---------------------------------------------------------------------------

    def plan(
        self,
        start: ArrayLike | None,
        goal: ArrayLike | str,
        time_limit: float | None = None,
        carrying: str | None = None,
    ) -> Result:
        """A path from ``start`` to ``goal`` through the experience graph.

        Parameters
        ----------
        start
            Configuration (radians for angles), or ``None`` for :attr:`position` (refused
            like any start if a change has put an object there).
        goal
            Configuration, the name of a goal of the scenario's ``adaptive:``
            section (then it follows its object, Section 2.3), or, for a URDF arm, a
            ``(4, 4)`` world pose of the tool frame (inverse kinematics from where the
            robot stands picks the configuration).
        time_limit
            Wall-clock seconds this query may take (OMPL's ``solve(time)``); ``None``: no
            limit beyond Solve's check budget. R, S and T stop at their next step past it
            (Solve within the call) and the query returns ``timeout``, G keeping what it
            verified. A limited query depends on the machine's speed: use the check
            budget (``max_solve_checks``) for results that repeat.
        carrying
            The part the robot holds during this query (a part of the scenario's
            ``parts:``, its shape in the tool frame), or ``None``. Every check of the
            query is made with it attached: the start and goal checks, the goal's IK,
            Reach's segments, Solve, the repair and the exact re-check of the executed
            path. A query holding another part than the last one is an environment change
            (Section 2.5: a new generation, G's edges verified again before use). A 3-D
            cell only: the planar world refuses it in one line.

        Returns
        -------
        Result
            ``solved`` with the executed path as the trajectory (``t`` the cumulative
            joint-space path length), ``failed`` (Solve found no path within its
            check budget) or ``timeout`` (``time_limit`` reached) with a one-sample
            trajectory at ``start``. ``stats`` counts
            this query's collision checks (changes and repair since the last query
            included), Solve calls, G's size and the wall time.

        Raises
        ------
        ArgumentError
            A malformed configuration, an angle in degrees, a configuration outside
            the joint limits or in collision (naming the obstacle), an unknown goal,
            an unknown part (or one the world cannot hold).
        """
        if carrying is not None and not isinstance(carrying, str):
            raise ArgumentError(f"must be a part's name or None, got {carrying!r}", "carrying")
        if time_limit is not None and not (
            isinstance(time_limit, int | float)
            and not isinstance(time_limit, bool)
            and math.isfinite(time_limit)
            and time_limit > 0
        ):
            raise ArgumentError(
                f"must be a positive number of seconds, got {time_limit!r}", "time_limit"
            )
        # Held before the goal and the start are checked: both must be free with the part.
        self.world.hold(carrying)
        w, key, label = self._goal(goal)
        # The robot's own position is checked too: a change may have put an object on it.
        u = self._configuration(self.position if start is None else start, "start")
        ad = self.adapter
        ad.deadline = None if time_limit is None else time.perf_counter() + float(time_limit)
        ad.timed_out = False
        try:
            res = self.run_task(key, w, start=u)
        finally:
            ad.deadline, ad.timed_out = None, False
        self.adapter.tasks_done += 1  # Solve's seeds derive from (seed, task, call)
        result = self._result(res, u, label)
        self.save()
        if res.solve_calls:
            gc.collect()  # OMPL's objects of the Solve calls go now, not at exit
        return result

    def run_task(self, key: str, w: FloatArray, start: FloatArray | None = None) -> TaskResult:
        """One task of Figure 1's loop: robot to ``start``, Repair(G), R / S, T, execute.

        ``key`` names the goal for R's memory of Reach(v, goal) answers within a
        generation (a goal name, or the exact configuration). The costs of the
        returned :class:`~.adapt.TaskResult` include the changes and the repair made
        since the previous task.
        """
        t0 = time.perf_counter()
        if start is not None:
            self._put_robot(start)
        repair(self.adapter, self.settings.repair)
        res = self.adapter.task(key, w)
        after = self.counter.snapshot()
        res.costs = {k: after[k] - self._mark[k] for k in after}
        res.seconds = time.perf_counter() - t0
        self._mark = after
        self.queries += 1
        return res

    def _put_robot(self, q: FloatArray) -> None:
        """Move the robot to ``q``; û becomes a vertex Reach connects to it, or ``q`` itself."""
        ad = self.adapter
        if np.array_equal(q, ad.u):
            return
        ad.u = q.copy()
        found = ad.plan_r(q)
        ad.u_hat = found if found is not None else ad.new_vertex(q)
        ad.link_gen = ad.gen

    def _result(self, res: TaskResult, u: FloatArray, label: str) -> Result:
        ok = res.success and res.path_ok
        traj = task_trajectory(
            self.world.robot.axis_names,
            u,
            res,
            label,
            meta=self._meta(),
            robot=self.world.robot,
            robot_spec=self.scenario.robot if self.scenario is not None else None,
        )
        checks = sum(v for k, v in res.costs.items() if k != "baseline")
        # Counts are ints, measures floats (core.Stat): they keep their type in JSON.
        stats: dict[str, Stat] = {
            "checks": int(checks),
            **{f"{k}_checks": int(v) for k, v in res.costs.items() if k != "baseline"},
            "solve_calls": int(res.solve_calls),
            "s_fallbacks": int(res.s_fallbacks),
            "vertices": int(res.vertices),
            "edges": int(res.edges),
            "path_length": float(traj.t[-1] - traj.t[0]),
            "generation": int(self.world.gen),
            "seconds": float(res.seconds),
            "timed_out": bool(res.timed_out),
        }
        cost = f"({checks} collision checks, {res.solve_calls} Solve calls, |V|={res.vertices})"
        if ok and len(traj) == 1:
            message = f"already at {label} {cost}"
            status = Status.SOLVED
        elif ok:
            segments = f"{len(traj) - 1} straight segment{'' if len(traj) == 2 else 's'}"
            message = f"reached {label} along {segments} {cost}"
            status = Status.SOLVED
        elif res.timed_out:
            message = f"time limit reached before a path to {label} was found {cost}"
            status = Status.TIMEOUT
        elif res.success:
            message = (
                f"reached {label}, but the executed path touches an obstacle at the 4x finer "
                f"re-check (exact contact test) {cost}"
            )
            status = Status.FAILED
        else:
            message = f"no path to {label}: {res.note} {cost}"
            status = Status.FAILED
        options = {
            "repair": self.settings.repair,
            "resolution": self.settings.resolution,
            "seed": self.settings.seed,
        }
        return Result(status, message, "ExperiencePlanner", stats, self, traj, options)

    def _meta(self) -> dict[str, str | int | float | bool]:
        return {
            "scenario": self.name,
            "repair": self.settings.repair,
            "seed": int(self.settings.seed),
        }

    # --- configurations ---------------------------------------------------------------------

    def _goal(self, goal: ArrayLike | str) -> tuple[FloatArray, str, str]:
        if isinstance(goal, str):
            if goal not in self.world.goals:
                known = ", ".join(sorted(self.world.goals)) or "none"
                raise ArgumentError(f"unknown goal {goal!r} (goals: {known})", "goal")
            w = self.world.goal_config(goal)
            if w is None:
                raise ArgumentError(
                    f"goal {goal!r} has no inverse-kinematics solution on its elbow branch now",
                    "goal",
                )
            self._check_free(w, "goal")
            return w, goal, goal
        if np.shape(goal) == (4, 4):
            # A tool pose: IK from where the robot stands (3-D arms), refused in one line
            # when no collision-free solution reaches it.
            w = self.world.pose_goal(np.asarray(goal, float), self.adapter.u)
            self._check_free(w, "goal")
            key = "q=" + ",".join(repr(float(x)) for x in w)
            return w, key, "the tool pose"
        w = self._configuration(goal, "goal")
        # Reach(v, w) answers are remembered per goal key; the exact bytes make a sound key.
        key = "q=" + ",".join(repr(float(x)) for x in w)
        return w, key, "the goal"

    def _configuration(self, q: ArrayLike, name: str) -> FloatArray:
        arr = units.check_configurations(q, self.world.robot.axis_names, name)
        if arr.shape[0] != 1:
            raise ArgumentError(f"expected one configuration, got {arr.shape[0]}", name)
        # a periodic joint's angle is a point on the circle: 3.5 rad is -2.78 rad
        out = np.asarray(self.world.robot.wrap(arr[0]), dtype=float)
        self._check_free(out, name)
        return out

    def _check_free(self, q: FloatArray, name: str) -> None:
        """One clear line when ``q`` is outside the limits, the bounds, or in collision."""
        self.world.check_free(q, name)
        if self.validity is not None and not self.adapter.space.free_uncounted(q[None, :])[0]:
            shown = "(" + ", ".join(f"{v:.4g}" for v in q) + ")"
            raise ArgumentError(f"configuration {shown} is refused by the validity checker", name)

    # --- environment changes ----------------------------------------------------------------

    def add(self, name: str, shape: Any, pose: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """Add an object: ``shape`` as in a scenario file (``{"type": "box", "min": ...,
        "max": ...}``, a polygon or a disc) or a :class:`~cellplan.geometry.ShapeSet`,
        placed at ``pose = (x, y, theta)`` (theta in radians) from its own coordinates.
        In a 3-D cell: a solid (``{"type": "box", "size": [...], "pose": {...}}``, or a
        :class:`~cellplan.solids.Solid`) shifted by ``pose = (x, y, z)`` metres."""
        if name in self.world.objects:
            raise ArgumentError(f"object {name!r} already exists", "name")
        solid = self.world.shape(shape)
        self.world.add_object(name, solid, self.world.pose_of(pose))  # type: ignore[arg-type]
        self._changed(set())

    def remove(self, name: str) -> None:
        """Remove an object (subgoals attached to it stay where they are, in the world)."""
        self._known_object(name)
        attached = sorted(g for g, tag in self.world.goals.items() if tag.obj == name)
        if attached:
            raise ArgumentError(
                f"goals {', '.join(attached)} are attached to {name!r}; it cannot be removed",
                "name",
            )
        self.world.remove_object(name)
        self._changed(set())

    def move(self, name: str, pose: Sequence[float]) -> None:
        """Place object ``name`` at ``pose = (x, y, theta)`` relative to its original
        coordinates (``(0, 0, 0)``: where the scenario put it); theta in radians.
        Subgoals and goals attached to it move with it (Section 2.3). In a 3-D cell
        objects translate: ``pose = (x, y, z)`` metres from where the scenario put it,
        and the attached subgoals come back by IK from their old configuration."""
        self._known_object(name)
        moved = self.world.set_pose(name, self.world.pose_of(pose))
        self._changed(moved)

    def turn(
        self, name: str, angle: float | Sequence[float], about: Sequence[float] | None = None
    ) -> None:
        """Turn object ``name`` from where it is now, as a scheduled ``rotate_object``
        change does and through the same primitive (:meth:`~.worldbase.ChangingWorld.turn`).

        Planar cell: ``angle`` is one angle ``theta`` in radians, counter-clockwise, about
        ``about = (x, y)`` (default: the object's centroid now). 3-D cell: ``angle`` is
        ``(roll, pitch, yaw)`` in radians about fixed world axes (``R = Rz Ry Rx``) about
        ``about = (x, y, z)`` metres (default: the object's centre now). Subgoals and goals
        attached to it turn with it and come back by IK (Section 2.3); a new environment
        generation, so the next query repairs G; the database records the new pose.
        An unknown object, an angle of the wrong count, not finite or beyond two turns
        (degrees given where radians are expected) and a bad centre are refused, one
        line each, before anything changes."""
        problems = []
        if name not in self.world.objects:
            known = ", ".join(sorted(self.world.objects)) or "none"
            problems.append(Problem("name", f"unknown object {name!r} (objects: {known})"))
        try:
            rad, centre = self.world.checked_turn(angle, about)
        except ArgumentError as exc:
            problems.extend(exc.problems)
        if problems:
            raise ArgumentError(problems)
        self._changed(self.world.turn(name, rad, centre))

    def pose(self, name: str) -> tuple[float, float, float]:
        """The current pose of an object (relative to its original coordinates)."""
        self._known_object(name)
        return self.world.objects[name].pose

    def _known_object(self, name: str) -> None:
        if name not in self.world.objects:
            known = ", ".join(sorted(self.world.objects)) or "none"
            raise ArgumentError(f"unknown object {name!r} (objects: {known})", "name")

    def _changed(self, moved: set[str]) -> None:
        self.adapter.follow_objects(moved)
        self.save()

    # --- persistence ------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        """The session state written to the database (JSON values)."""
        ad, world = self.adapter, self.world
        return {
            "tasks_done": self.queries,
            "generation": world.gen,
            "u": [float(x) for x in ad.u],
            "u_hat": ad.u_hat,
            "link_gen": ad.link_gen,
            "repaired_gen": ad.repaired_gen,
            "current_goal": ad.current_goal,
            **failure_state(ad),
            "solve_calls": ad._solve_calls,
            "resolution": self.settings.resolution,
            "counts": dict(self.counter.counts),
            "objects": world.objects_json(),
            "goals": world.goals_json(),
        }

    def save(self) -> None:
        """Write G and the session state to the database (no-op without ``db``)."""
        if self.store is not None:
            self.store.commit_task(
                self.graph, self.state(), None, self.adapter.links(), key=PLANNER_STATE
            )

    def close(self) -> None:
        """Save and close the database (idempotent)."""
        if self.store is not None:
            try:
                self.save()
            finally:  # release the database's lock even when the last write fails
                self.store.close()
                self.store = None

    def __enter__(self) -> ExperiencePlanner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _restore(self) -> None:
        from cellplan.adaptive.runner import restore_run

        store = self.store
        assert store is not None
        saved = store.planner_state()
        if saved is None:
            run = store.state()
            if run is not None and self.scenario is not None:
                restore_run(self, store, run)
            return
        if not np.isclose(float(saved["resolution"]), self.settings.resolution, rtol=1e-12):
            raise ArgumentError(
                f"the database was built with resolution {saved['resolution']:g}, "
                f"not {self.settings.resolution:g}",
                "resolution",
            )
        world, ad = self.world, self.adapter
        world.restore_json(saved["objects"], saved["goals"], int(saved["generation"]))
        ad.graph = store.load_graph()
        store.check_state(ad.graph, saved, ad.u.size)
        links, links_gen = store.load_links()
        if links_gen is not None:
            ad.goal_links, ad._links_gen = links, links_gen
        else:
            ad.goal_links, ad._links_gen = {}, world.gen
        ad.u = np.array(saved["u"], float)
        ad.u_hat = int(saved["u_hat"])
        ad.link_gen = int(saved["link_gen"])
        ad.repaired_gen = int(saved["repaired_gen"])
        ad.current_goal = saved["current_goal"]
        ad.s_failed, ad.s_failed_gen = saved_failures(saved, world.gen)
        ad._solve_calls = int(saved["solve_calls"])
        self.queries = int(saved["tasks_done"])
        ad.tasks_done = self.queries
        self.counter.counts.update({k: int(v) for k, v in saved["counts"].items()})
        self._mark = self.counter.snapshot()
        if ad.u_hat not in ad.graph.vertices:
            raise PersistenceError([Problem(str(store.path), "is damaged: û is not a vertex")])
        if self.validity is not None:
            # The checker is part of the environment and not in the database: a new
            # generation, so T verifies G's edges again before using them.
            world.gen += 1


def task_trajectory(
    axis_names: Sequence[str],
    u: FloatArray,
    res: TaskResult,
    label: str,
    changes: Sequence[str] = (),
    meta: Mapping[str, str | int | float | bool] | None = None,
    robot: Any = None,
    robot_spec: Any = None,
) -> Trajectory:
    """One task's executed path as a trajectory (mode = the goal).

    ``t`` is the cumulative joint-space path length; events: ``change`` (the workcell
    changes applied before the task), ``task`` at the start, ``arrive`` at the end, or
    ``fail`` (then the robot stays at ``u``: one sample); the goal is their ``region``.
    ``robot`` (the robot model) and ``robot_spec`` (the scenario's robot section) give
    the periodic axes and speeds (:func:`cellplan.timing.robot_motion`) of ``seconds``.
    """
    path = res.path if res.success and res.path is not None else np.asarray(u, float)[None, :]
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1) if len(path) > 1 else np.zeros(0)
    t = np.concatenate([[0.0], np.cumsum(steps)])
    events = [Event(0, "change", c) for c in changes]
    events.append(Event(0, "task", label, region=label))
    events.append(Event(len(path) - 1, "arrive" if res.success else "fail", label, region=label))
    axis_units = units.axis_units(axis_names)
    periodic, vlim, alim = timing.robot_motion(robot_spec, robot, axis_names, axis_units)
    return Trajectory(
        t,
        path,
        np.zeros(len(path), dtype=np.int64),
        (label,),
        tuple(axis_names),
        axis_units,
        "path",
        tuple(events),
        dict(meta or {}),
        periodic=periodic,
        velocity_limits=vlim,
        acceleration_limits=alim,
    )


def failure_state(ad: Adapter) -> dict[str, Any]:
    """S's failures of the current generation (issue 35) as JSON values, kept with G in
    both database states (an ``ExperiencePlanner``'s and a ``cellplan adapt --db`` run's)
    so a continued session does not pay a remembered failure again."""
    return {
        "s_failed_gen": ad.s_failed_gen,
        "s_failed": {g: [list(v), why] for g, (v, why) in sorted(ad.s_failed.items())},
    }


def saved_failures(
    saved: Mapping[str, Any], gen: int
) -> tuple[dict[str, tuple[tuple[int, ...], str]], int]:
    """S's remembered failures from a saved state (none in a database written before
    they were kept, or one whose entries are not well formed)."""
    raw = saved.get("s_failed")
    failed_gen = saved.get("s_failed_gen")
    if not isinstance(raw, dict) or failed_gen != gen:
        return {}, gen
    out: dict[str, tuple[tuple[int, ...], str]] = {}
    for goal, entry in raw.items():
        if (
            isinstance(entry, list)
            and len(entry) == 2
            and isinstance(entry[0], list)
            and all(isinstance(v, int) and not isinstance(v, bool) for v in entry[0])
            and isinstance(entry[1], str)
        ):
            out[str(goal)] = (tuple(entry[0]), entry[1])
    return out, gen


def _check_robot(robot: Robot | UrdfRobot) -> None:
    """Object-attached subgoals (Section 2.3) need IK: a rigid robot, or a 2- or 3-link arm."""
    if isinstance(robot, PlanarArm) and robot.n_links not in (2, 3):
        raise ArgumentError(
            f"the experience planner needs a rigid robot or a 2- or 3-link arm, not a "
            f"{robot.n_links}-link arm (attached subgoals need inverse kinematics)",
            "robot",
        )

"""Solve, the global planner (Section 2), and the point-robot toy Solve of Section 3.

:func:`solve_rrtconnect` runs OMPL's RRTConnect on a ``RealVectorStateSpace``
with the bounds of the :class:`~.space.PlanSpace`, or, when some coordinate is
periodic, on a compound space with one ``SO2StateSpace`` per periodic coordinate
and a one-dimensional real interval per other one (OMPL then interpolates and
measures periodic coordinates the short way round, like Reach). Its validity
checker is the counted ``space.free``, and OMPL's discrete motion validator is set
to the same resolution as Reach (``longest valid segment = resolution``; on the
compound space OMPL's distance is the sum over coordinates, never shorter than
Reach's Euclidean one, so its steps are no longer). Seeding goes through
``ompl.util.RNG.setSeed`` immediately before the planner is built, so a call
repeats exactly for a given seed.

Budget: the planner stops after ``max_checks`` collision checks, a deterministic,
load-independent budget (the default, :data:`DEFAULT_MAX_CHECKS`); the wall-time
limit ``max_seconds`` (:data:`TIME_GUARD_SECONDS`) is only a guard against a
runaway call, far above what the check budget takes on a loaded machine, and a
call it stops says so in its :class:`SolveInfo` (its result then depends on the
machine's speed).

:func:`solve_two_segment` is the paper's toy Solve: success iff the two points
are joined by at most two straight segments; it returns the shortest such path
among bend points on a lattice of the resolution.

:class:`PRMSession` keeps one OMPL PRM roadmap across queries (the modern peer
of the experiments).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from cellplan.adaptive.reach import reach
from cellplan.adaptive.space import FloatArray, PlanSpace
from cellplan.geometry import wrap_angle

THREADED_PLANNERS = frozenset(
    {"PRM", "PRMstar", "LazyPRM", "LazyPRMstar", "SPARS", "SPARStwo", "AnytimePathShortening"}
)
"""OMPL planners that evaluate the termination condition in a second thread: a Python
condition (the check budget) deadlocks there on the GIL, so Solve refuses them."""

DEFAULT_MAX_CHECKS = 200_000
TIME_GUARD_SECONDS = 600.0
"""Wall-time guard of one Solve call: 200,000 checks take 4-15 s on the 2-core
development machine, loaded or not; the guard only stops a runaway call."""
BEND_LATTICE = 40


@dataclass
class SolveInfo:
    """How one Solve call ended: ``outcome`` is ``solved``, ``endpoint`` (an end is not
    free), ``budget`` (``max_checks`` spent), ``time`` (the wall-time guard fired) or
    ``no_path`` (the planner gave up); ``checks`` it made, ``seconds`` it took."""

    outcome: str = "no_path"
    checks: int = 0
    seconds: float = 0.0


def _ompl() -> tuple[Any, Any, Any]:
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_NONE)
    return ob, og, ou


def ompl_planner_name(solve: str) -> str:
    """The OMPL geometric planner class a ``solve`` setting names: ``rrtconnect`` is
    ``RRTConnect``; ``ompl.<Name>`` is ``ompl.geometric.<Name>``."""
    return "RRTConnect" if solve == "rrtconnect" else solve.removeprefix("ompl.")


def check_planner_name(solve: str) -> str:
    """``""`` when ``solve`` names a usable OMPL geometric planner (or ``two_segment``),
    else why not, in one line."""
    if solve == "two_segment":
        return ""
    ob, og, _ = _ompl()
    name = ompl_planner_name(solve)
    cls = getattr(og, name, None)
    if not (isinstance(cls, type) and issubclass(cls, ob.Planner)):
        return (
            f"ompl.geometric has no planner {name!r} (e.g. ompl.RRTConnect, ompl.RRT, ompl.KPIECE1)"
        )
    if name in THREADED_PLANNERS:
        return (
            f"{name} checks its termination in a second thread, where the check budget "
            "cannot run; choose a single-threaded planner (e.g. ompl.RRTConnect)"
        )
    return ""


def _state_space(space: PlanSpace) -> Any:
    """OMPL's state space for ``space``: real vectors, or SO2 x intervals if some axis wraps."""
    ob, _, _ = _ompl()
    dim = space.dim
    if not space.any_periodic:
        state_space = ob.RealVectorStateSpace(dim)
        bounds = ob.RealVectorBounds(dim)
        for i in range(dim):
            bounds.setLow(i, float(space.lower[i]))
            bounds.setHigh(i, float(space.upper[i]))
        state_space.setBounds(bounds)
        return state_space
    state_space = ob.CompoundStateSpace()
    for i, per in enumerate(space.periodic):
        if per:
            state_space.addSubspace(ob.SO2StateSpace(), 1.0)
        else:
            sub = ob.RealVectorStateSpace(1)
            bounds = ob.RealVectorBounds(1)
            bounds.setLow(float(space.lower[i]))
            bounds.setHigh(float(space.upper[i]))
            sub.setBounds(bounds)
            state_space.addSubspace(sub, 1.0)
    return state_space


def _read_state(state: Any, periodic: tuple[bool, ...]) -> FloatArray:
    """The floats of an OMPL state, copied out (the state object is OMPL's)."""
    if not any(periodic):
        return np.array([state[i] for i in range(len(periodic))], dtype=float)
    return np.array(
        [state[i].value if per else state[i][0] for i, per in enumerate(periodic)], dtype=float
    )


def _space_information(space: PlanSpace) -> tuple[Any, Any]:
    """OMPL space information over ``space`` with a counted validity checker."""
    ob, _, _ = _ompl()
    state_space = _state_space(space)
    si = ob.SpaceInformation(state_space)
    periodic = space.periodic

    def valid(state: Any) -> bool:
        # Copy the floats out at once: the state object is OMPL's and may be reused.
        q = _read_state(state, periodic)
        return bool(space.free(q[None, :])[0])

    si.setStateValidityChecker(valid)
    si.setStateValidityCheckingResolution(space.resolution / state_space.getMaximumExtent())
    si.setup()
    return si, state_space


def _state(state_space: Any, q: FloatArray, periodic: tuple[bool, ...]) -> Any:
    st = state_space.allocState()
    for i, v in enumerate(q):
        if not any(periodic):
            st[i] = float(v)
        elif periodic[i]:
            st[i].value = float(wrap_angle(float(v)))
        else:
            st[i][0] = float(v)
    return st


def _path_array(path: Any, periodic: tuple[bool, ...]) -> FloatArray:
    n = path.getStateCount()
    return np.array([_read_state(path.getState(k), periodic) for k in range(n)], dtype=float)


def solve_rrtconnect(
    space: PlanSpace,
    a: FloatArray,
    b: FloatArray,
    seed: int,
    max_checks: int = DEFAULT_MAX_CHECKS,
    max_seconds: float = TIME_GUARD_SECONDS,
    planner_range: float | None = None,
    info: SolveInfo | None = None,
    planner_name: str = "RRTConnect",
) -> FloatArray | None:
    """Solve(a, b) with OMPL RRTConnect: waypoints ``(m, dim)`` from ``a`` to ``b``, or ``None``.

    ``planner_name`` picks another OMPL geometric planner by class name (checked by
    :func:`check_planner_name`; an optimising planner spends its whole budget).

    The endpoints are checked first (counted); a colliding endpoint fails at once.
    The call stops after ``max_checks`` checks (the budget) or, as a guard only, after
    ``max_seconds``; ``info``, if given, receives how it ended. On periodic coordinates
    consecutive waypoints are joined the short way round (they are wrapped to (-pi, pi]).
    """
    info = SolveInfo() if info is None else info
    t0 = time.perf_counter()
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if not np.all(space.free(np.stack([a, b]))):
        info.outcome, info.checks = "endpoint", 2
        return None
    ob, og, ou = _ompl()
    ou.RNG.setSeed(int(seed) % (2**31 - 1) + 1)
    si, state_space = _space_information(space)
    periodic = space.periodic
    pdef = ob.ProblemDefinition(si)
    pdef.setStartAndGoalStates(_state(state_space, a, periodic), _state(state_space, b, periodic))
    planner = getattr(og, planner_name)(si)
    if planner_range is not None:
        planner.setRange(planner_range)
    planner.setProblemDefinition(pdef)
    planner.setup()
    start_count = space.counter.total + space.counter.counts["baseline"]
    deadline = time.perf_counter() + max_seconds

    def used() -> int:
        return int(space.counter.total + space.counter.counts["baseline"] - start_count)

    def stop() -> bool:
        return used() >= max_checks or time.perf_counter() > deadline

    status = planner.solve(ob.PlannerTerminationCondition(stop))
    info.checks = used() + 2
    info.seconds = time.perf_counter() - t0
    if not pdef.hasExactSolution() or "Exact" not in str(status):
        if used() >= max_checks:
            info.outcome = "budget"
        elif time.perf_counter() > deadline:
            info.outcome = "time"
        else:
            info.outcome = "no_path"
        return None
    info.outcome = "solved"
    path = _path_array(pdef.getSolutionPath(), periodic)
    path[0], path[-1] = a, b
    return path


def solve_two_segment(space: PlanSpace, a: FloatArray, b: FloatArray) -> FloatArray | None:
    """The toy Solve of Section 3: the shortest path of at most two straight segments.

    Bend points are a lattice over the bounds (``BEND_LATTICE`` points along the
    longest side, never finer than the resolution), tried
    in order of path length, so the first success is the shortest on the lattice.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if reach(space, a, b):
        return np.stack([a, b])
    spacing = max(space.resolution, float(np.max(space.upper - space.lower)) / BEND_LATTICE)
    axes = [
        np.linspace(lo, hi, max(2, int(math.floor((hi - lo) / spacing)) + 1))
        for lo, hi in zip(space.lower, space.upper, strict=True)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, space.dim)
    length = np.linalg.norm(grid - a, axis=1) + np.linalg.norm(grid - b, axis=1)
    for k in np.argsort(length, kind="stable"):
        p = grid[k]
        if reach(space, a, p) and reach(space, p, b):
            return np.stack([a, p, b])
    return None


class PRMSession:
    """An OMPL PRM whose roadmap is kept across queries (the multi-query peer).

    Checks are counted in ``space.counter`` like every other planner, but PRM
    grows its roadmap in one thread while another looks for a solution, so the
    number of checks (not the answer) varies from run to run. Call
    :meth:`close` (or let it go out of scope) before the interpreter exits.
    """

    def __init__(self, space: PlanSpace, seed: int) -> None:
        _, og, ou = _ompl()
        ou.RNG.setSeed(int(seed) % (2**31 - 1) + 1)
        self.space = space
        self._si, self._state_space = _space_information(space)
        self._planner = og.PRM(self._si)
        self._pdef: Any = None

    def query(self, a: FloatArray, b: FloatArray, max_seconds: float = 10.0) -> FloatArray | None:
        """Plan from ``a`` to ``b`` reusing (and growing) the roadmap."""
        ob, _, _ = _ompl()
        a = np.asarray(a, dtype=float)
        b = np.asarray(b, dtype=float)
        if not np.all(self.space.free(np.stack([a, b]))):
            return None
        periodic = self.space.periodic
        pdef = ob.ProblemDefinition(self._si)
        pdef.setStartAndGoalStates(
            _state(self._state_space, a, periodic), _state(self._state_space, b, periodic)
        )
        self._pdef = pdef
        self._planner.clearQuery()
        self._planner.setProblemDefinition(pdef)
        self._planner.setup()
        # PRM checks for a solution in a second thread that evaluates the termination
        # condition; a Python condition there deadlocks on the GIL, so this peer stops
        # on OMPL's own timer. Its check counts therefore depend on thread timing.
        self._planner.solve(ob.timedPlannerTerminationCondition(max_seconds))
        if not pdef.hasExactSolution():
            return None
        path = _path_array(pdef.getSolutionPath(), periodic)
        path[0], path[-1] = a, b
        return path

    def close(self) -> None:
        """Drop the OMPL objects."""
        self._planner = None
        self._pdef = None
        self._si = None
        self._state_space = None

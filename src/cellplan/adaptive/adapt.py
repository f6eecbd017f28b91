"""Algorithm Adapt (Figure 1): the planners R and S, Augment, the trace procedure T.

One :class:`Adapter` holds the experience graph G, the robot position ``u``,
the pointer ``u_hat`` (a vertex known reachable from ``u`` with one Reach, in
generation ``link_gen``) and the world. :meth:`Adapter.task` runs one pass of
the ``do forever`` loop of Figure 1 for a goal:

1. Repair(G) for A0-A2 when the environment changed (:mod:`.repair`);
2. R(u, w): the vertices of G by heuristic h (nearest to ``w`` first); the
   first ``v`` with Reach(v, w) becomes ``w_hat``;
3. otherwise S(u, w): ``w_hat`` = the best vertex by h (the nearest one whose
   configuration is free now), Solve(w_hat, w), Abstract, Augment; ``w_hat``
   becomes the last vertex of the chain. Solve runs in rounds of growing budget
   from up to :data:`S_STARTS` starts (the best vertex, û, the next by h), so a best
   vertex sealed in a pocket by a change costs a small bounded Solve before S plans
   from the others; all of S stays within ``max_solve_checks`` (recorded per task);
4. T(u, w) (Section 2.4, steps 1(a), 1(b), 2, 3), then Execute the path
   ``u, u_hat, Gamma, w_hat, w`` after corner cutting (Section 2.6); the path is
   re-checked, uncounted and without clearance, at a quarter of the resolution.

Edges carry the generation they were verified in; T skips edges verified in
the current generation (they cannot have changed), which is the only departure
from re-checking the whole chain each task and changes no outcome.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from cellplan.adaptive.abstract import abstract
from cellplan.adaptive.counters import CheckCounter
from cellplan.adaptive.graph import BLOCKED, FREE, ExperienceGraph
from cellplan.adaptive.reach import path_is_free, reach, reach_potential, segment_points
from cellplan.adaptive.solve import (
    TIME_GUARD_SECONDS,
    SolveInfo,
    ompl_planner_name,
    solve_rrtconnect,
    solve_two_segment,
)
from cellplan.adaptive.space import FloatArray, IsFree, PlanSpace, and_validity
from cellplan.adaptive.tags import Tag
from cellplan.adaptive.world import AnyWorld

Hook = Callable[[str], None]

S_STARTS = 4
"""Start vertices S tries Solve from; they share ``max_solve_checks``."""
S_FIRST_SHARE = 64
"""S's first Solve call gets ``max_solve_checks / S_FIRST_SHARE`` checks (3,125 of the
default 200,000; every Solve of the Figure 5 experiment needs at most 795)."""


TOY_ADVICE = (
    "the real planner is OMPL's RRTConnect (solve: rrtconnect, the default, or ompl.RRTConnect)"
)
"""What a failure under the toy Solve (``solve: two_segment``) says to do instead."""


def derive_seed(*parts: int) -> int:
    """A 31-bit seed from integers (run seed, task, call)."""
    return int(
        np.random.SeedSequence([int(p) & 0xFFFFFFFF for p in parts]).generate_state(1)[0] >> 1
    )


@dataclass
class Settings:
    """Planner settings (from the scenario section, overridable from the CLI)."""

    repair: str = "A3"
    solve: str = "rrtconnect"
    reach: str = "straight"
    resolution: float = 0.02
    corner_cutting: bool = True
    max_chain: int | None = None
    max_solve_checks: int = 200_000
    seed: int = 0


@dataclass
class TaskResult:
    """What one task did: success, cost split, graph size, the executed path."""

    goal: str
    success: bool
    solve_calls: int = 0
    costs: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    vertices: int = 0
    edges: int = 0
    path: FloatArray | None = None
    path_ok: bool = True
    note: str = ""
    s_fallbacks: int = 0
    """Start vertices S tried after Solve from the best one failed."""
    timed_out: bool = False
    """The query's time limit (:attr:`Adapter.deadline`) stopped it before a path."""


class Adapter:
    """The state of Adapt between tasks and the procedures of Figure 1."""

    def __init__(
        self,
        world: AnyWorld,
        settings: Settings,
        counter: CheckCounter | None = None,
        hook: Hook | None = None,
        validity: IsFree | None = None,
    ) -> None:
        self.world = world
        # A user's validity test, AND-ed with the workcell's in every check (counted
        # once per configuration, like the workcell's) and in the exact re-check.
        self.validity = validity
        self.settings = settings
        self.counter = counter or CheckCounter()
        self.hook = hook
        robot = world.robot
        self.space = PlanSpace(
            world.is_free if validity is None else and_validity(world.is_free, validity),
            robot.lower,
            robot.upper,
            settings.resolution,
            self.counter,
            tuple(robot.periodic),
        )
        self._graph = ExperienceGraph(periodic=self.space.periodic)
        self.u = np.asarray(robot.start, dtype=float).copy()
        self.u_hat = self.new_vertex(self.u)
        self.link_gen = world.gen
        self.repaired_gen = world.gen
        self.tasks_done = 0
        self.current_goal: str | None = None
        self._solve_calls = 0
        self._vertex_free: dict[int, tuple[int, bool]] = {}
        # Reach(v, goal) results of the current generation, by (vertex id, goal name).
        self.goal_links: dict[tuple[int, str], bool] = {}
        self._links_gen = world.gen
        self.last_solve = SolveInfo()
        self.s_fallbacks = 0
        self.s_failure = ""
        # S's failures of this generation by goal: the start vertices Solve failed from,
        # and why (issue 35: a sealed goal is not asked again at full price).
        self.s_failed: dict[str, tuple[tuple[int, ...], str]] = {}
        self.s_failed_gen = world.gen
        self._s_tried: list[int] = []
        # Segments of executed paths that passed the 4x re-check, and in which generation.
        self._rechecked: set[tuple[bytes, bytes]] = set()
        self._rechecked_gen = world.gen
        # A query's wall-clock deadline (``time.perf_counter()`` value; None: no limit)
        # and whether it fired: R, S and T stop at their next step past it.
        self.deadline: float | None = None
        self.timed_out = False

    @property
    def graph(self) -> ExperienceGraph:
        """G; a graph assigned here (Repair's A0, a database) measures with this space."""
        return self._graph

    @graph.setter
    def graph(self, graph: ExperienceGraph) -> None:
        graph.periodic = self.space.periodic
        self._graph = graph

    # --- primitives ------------------------------------------------------------------------

    @property
    def gen(self) -> int:
        return self.world.gen

    def late(self) -> bool:
        """Whether the query's deadline has passed (and remember that it did)."""
        if self.deadline is not None and time.perf_counter() > self.deadline:
            self.timed_out = True
        return self.timed_out

    def _emit(self, phase: str) -> None:
        if self.hook is not None:
            self.hook(phase)

    def reach(self, a: FloatArray, b: FloatArray) -> bool:
        """Reach(a, b), the variant chosen in the settings (counted)."""
        if self.settings.reach == "potential":
            return reach_potential(self.space, a, b) is not None
        return reach(self.space, a, b)

    def local_path(self, a: FloatArray, b: FloatArray) -> FloatArray:
        """Reach[a, b]: the polyline Reach follows (uncounted; Reach(a, b) already succeeded)."""
        if self.settings.reach == "potential":
            saved = self.counter.snapshot()
            path = reach_potential(self.space, a, b)
            self.counter.counts.update(saved)
            if path is not None:
                return path
        return np.stack([np.asarray(a, float), np.asarray(b, float)])

    def solve(self, a: FloatArray, b: FloatArray, budget: int | None = None) -> FloatArray | None:
        """Solve(a, b) with the configured global planner, seeded per call (counted).

        ``budget``: collision checks this call may make (default ``max_solve_checks``);
        how the call ended is left in :attr:`last_solve`.
        """
        self._solve_calls += 1
        info = SolveInfo()
        self.last_solve = info
        if self.settings.solve == "two_segment":
            before = self.counter.total
            path = solve_two_segment(self.space, a, b)
            info.outcome, info.checks = (
                "solved" if path is not None else "no_path",
                self.counter.total - before,
            )
            return path
        seed = derive_seed(self.settings.seed, self.tasks_done, self._solve_calls)
        limit = self.settings.max_solve_checks if budget is None else budget
        seconds = TIME_GUARD_SECONDS
        if self.deadline is not None:
            seconds = min(seconds, max(0.0, self.deadline - time.perf_counter()))
        path = solve_rrtconnect(
            self.space,
            a,
            b,
            seed,
            limit,
            seconds,
            info=info,
            planner_name=ompl_planner_name(self.settings.solve),
        )
        if info.outcome == "time" and self.deadline is not None:
            self.timed_out = True
        return path

    def vertex_free(self, vid: int) -> bool:
        """Is a vertex's configuration free in this generation? (one counted check, cached)."""
        cached = self._vertex_free.get(vid)
        if cached is not None and cached[0] == self.gen:
            return cached[1]
        ok = bool(self.space.free(self.graph.vertices[vid].q[None, :])[0])
        self._vertex_free[vid] = (self.gen, ok)
        return ok

    def new_vertex(self, q: FloatArray) -> int:
        """Add a vertex for configuration ``q`` with its object-attached tag (Section 2.3)."""
        tag = self.world.tag_of(q)
        return self.graph.add_vertex(q, tag.obj, tag.rel, tag.branch)

    def augment(self, first: int, configs: FloatArray, last: int | None = None) -> list[int]:
        """Augment(G, rho): chain ``first -> configs (-> last)``, edges free in this generation."""
        ids = [first]
        for q in configs:
            ids.append(self.new_vertex(q))
        if last is not None:
            ids.append(last)
        for a, b in itertools.pairwise(ids):
            self.graph.set_edge(a, b, FREE, self.gen)
        return ids

    def abstract(self, path: FloatArray) -> FloatArray | None:
        """Abstract(Solve[...]): the chain's configurations after the first (counted)."""
        with self.counter.charge("abstract"):
            idx = abstract(path, self.reach, self.settings.max_chain)
        return None if idx is None else path[idx[1:]]

    # --- R, S, T ---------------------------------------------------------------------------

    def plan_r(self, w: FloatArray, goal: str | None = None) -> int | None:
        """R(u, w): the first vertex by h with Reach(v, w); ``None`` if there is none.

        Reach(v, w) is a pure function of the two configurations and the
        environment, so its answers for a named goal are remembered within a
        generation (vertex ids are never reused, and a vertex or an attached
        goal only moves when the generation changes).
        """
        links = self.links()
        with self.counter.charge("reach"):
            for vid in self.graph.by_heuristic(w):
                if self.late():
                    return None
                known = links.get((vid, goal)) if goal is not None else None
                if known is None:
                    known = self.reach(self.graph.vertices[vid].q, w)
                    if goal is not None:
                        links[(vid, goal)] = known
                if known:
                    return vid
        return None

    def links(self) -> dict[tuple[int, str], bool]:
        """The remembered Reach(vertex, goal) answers of the current generation."""
        if self._links_gen != self.gen:
            self.goal_links = {}
            self._links_gen = self.gen
        return self.goal_links

    def s_starts(self, w: FloatArray) -> Iterator[int]:
        """S's start vertices: the best free vertex by h, then û, then the next free ones.

        Lazy, so that a first Solve that succeeds costs exactly one free-vertex scan.
        """
        tried: set[int] = set()
        order = self.graph.by_heuristic(w)
        first = next((v for v in order if self.vertex_free(v)), None)
        if first is None:
            return
        tried.add(first)
        yield first
        if self.u_hat in self.graph.vertices and self.u_hat not in tried:
            if self.vertex_free(self.u_hat):
                tried.add(self.u_hat)
                yield self.u_hat
        for v in order:
            if v not in tried and self.vertex_free(v):
                tried.add(v)
                yield v

    def plan_s(self, w: FloatArray) -> int | None:
        """S(u, w): Solve from the best free vertex by h, Abstract, Augment; the new w_hat.

        Solve runs in rounds of growing budget: in round r each of up to
        :data:`S_STARTS` starts (the best free vertex by h, then û, then the next
        free vertices by h; :meth:`s_starts`) gets ``max_solve_checks / S_FIRST_SHARE
        * 4**r`` checks, until one succeeds or S has spent ``max_solve_checks`` in all.
        A best vertex sealed in a pocket by a change thus costs a small bounded Solve
        before S plans from the others. The Solve calls after the first failed one are
        counted in :attr:`s_fallbacks`; :attr:`s_failure` says why S failed.
        """
        self.s_failure = ""
        total = self.settings.max_solve_checks
        left = total
        share = max(1, total // S_FIRST_SHARE)
        path: FloatArray | None = None
        start: int | None = None
        starts: list[int] = []
        pending = self.s_starts(w)
        outcomes: list[str] = []
        calls = 0
        # the toy Solve is deterministic and unbudgeted: one round, each start once
        toy = self.settings.solve == "two_segment"
        with self.counter.charge("solve"):
            while path is None and left > 0:
                for k in range(S_STARTS):
                    if k == len(starts):
                        nxt = next(pending, None)
                        if nxt is None:
                            break
                        starts.append(nxt)
                    if calls:
                        self.s_fallbacks += 1
                    calls += 1
                    path = self.solve(self.graph.vertices[starts[k]].q, w, min(share, left))
                    outcomes.append(self.last_solve.outcome)
                    left -= self.last_solve.checks
                    if path is not None:
                        start = starts[k]
                        break
                    if left <= 0 or self.timed_out:
                        break
                if toy or not starts or self.timed_out:
                    break
                share *= 4
        if not starts:
            self.s_failure = "no vertex of G is free in the changed workcell"
            return None
        self._s_tried = list(starts)
        if (path is None or start is None) and toy:
            # The toy planner is complete only for two-segment paths (Fig. 3); say so and
            # name the real one, so nobody mistakes its failure for a sealed goal.
            self.s_failure = (
                f"Solve found no path from {len(starts)} start vertex"
                f"{'' if len(starts) == 1 else 'es'} of G: the toy Solve of the paper's "
                f"Fig. 3 (solve: two_segment) joins two points with at most two straight "
                f"segments only; {TOY_ADVICE}"
            )
            return None
        if path is None or start is None:
            why = "wall-time guard" if "time" in outcomes else "check budget"
            self.s_failure = (
                f"Solve found no path from {len(starts)} start vertex"
                f"{'' if len(starts) == 1 else 'es'} of G in {calls} calls within its {why} "
                f"({total - left} checks; budget {total}); the goal may be sealed off by "
                f"passages narrower than the certified clearance ({self.world.margin:.3g} at "
                f"resolution {self.settings.resolution:.3g}): a finer resolution shrinks the "
                "clearance, a larger max_solve_checks searches longer"
            )
            return None
        chain = self.abstract(path)
        if chain is None:
            self.s_failure = "Abstract could not cut Solve's path into Reach segments"
            return None
        self._emit("augment")
        return self.augment(start, chain)[-1]

    def plan_s_remembered(self, goal: str, w: FloatArray) -> int | None:
        """S(u, w) unless S already failed toward ``goal`` in this generation from every
        start it would try now (then it fails at once, saying so).

        Solve is a pure function of its ends, its seed and the workcell; within a
        generation the vertices do not move, so a failure from the same start vertices
        would be asked again at full price for nothing. A new generation (any workcell
        change) or a new free vertex among the starts asks Solve again.
        """
        if self.s_failed_gen != self.gen:
            self.s_failed, self.s_failed_gen = {}, self.gen
        known = self.s_failed.get(goal)
        if known is not None:
            with self.counter.charge("solve"):
                starts = list(itertools.islice(self.s_starts(w), S_STARTS))
            if starts and set(starts) <= set(known[0]):
                self.s_failure = (
                    f"{known[1]} (remembered: S failed toward this goal from the same start "
                    "vertices earlier in this workcell generation; it is asked again after a "
                    "change of the workcell or when G gains a nearer free vertex)"
                )
                return None
        self._s_tried = []
        w_hat = self.plan_s(w)
        if (
            w_hat is None
            and self._s_tried
            and not self.timed_out
            and self.last_solve.outcome != "time"
        ):
            self.s_failed[goal] = (tuple(self._s_tried), self.s_failure)
        return w_hat

    def ensure_u_hat(self) -> None:
        """Re-establish the pointer u_hat after a change: Reach(u, u_hat) or a new vertex at u."""
        if self.u_hat in self.graph.vertices and self.link_gen == self.gen:
            return
        if self.u_hat not in self.graph.vertices or not self.reach(
            self.u, self.graph.vertices[self.u_hat].q
        ):
            self.u_hat = self.new_vertex(self.u)
        self.link_gen = self.gen

    def trace(self, w_hat: int) -> list[int] | None:
        """T(u, w): a verified vertex sequence from u_hat to w_hat, repairing G on demand.

        Step 1: while G connects u_hat to w_hat, verify the shortest sequence
        Gamma; (a) all edges pass Reach: success; (b) remove the first failing
        edge (kept as ``blocked``). Step 2: Solve(u_hat, w_hat) and augment G
        with its abstraction. Step 3: remove w_hat's component and fail.
        """
        g = self.graph
        with self.counter.charge("trace"):
            self.ensure_u_hat()
            while True:
                if self.late():
                    return None
                gamma = g.shortest_path(self.u_hat, w_hat)
                if gamma is None:
                    break
                broken = False
                for a, b in itertools.pairwise(gamma):
                    e = g.edge(a, b)
                    if e is not None and e.status == FREE and e.gen == self.gen:
                        continue
                    if self.reach(g.vertices[a].q, g.vertices[b].q):
                        g.set_edge(a, b, FREE, self.gen)
                    else:
                        g.set_edge(a, b, BLOCKED, self.gen)
                        broken = True
                        break
                if not broken:
                    return gamma
        self._emit("trace_solve")
        with self.counter.charge("solve"):
            path = self.solve(g.vertices[self.u_hat].q, g.vertices[w_hat].q)
        chain = self.abstract(path) if path is not None else None
        if chain is not None:
            return self.augment(self.u_hat, chain[:-1], last=w_hat)
        if not self.timed_out:  # a query's time limit says nothing about G: keep it
            g.remove_component(w_hat)
        return None

    def cut_corners(self, gamma: list[int]) -> list[int]:
        """Section 2.6: shortcut Gamma greedily (furthest vertex first), adding the new edges."""
        g = self.graph
        out = [gamma[0]]
        i = 0
        with self.counter.charge("cut"):
            while i < len(gamma) - 1:
                nxt = i + 1
                for j in range(len(gamma) - 1, i + 1, -1):
                    a, b = gamma[i], gamma[j]
                    e = g.edge(a, b)
                    if e is not None and e.gen == self.gen and e.status in (FREE, BLOCKED):
                        if e.status == FREE:
                            nxt = j
                            break
                        continue
                    if self.reach(g.vertices[a].q, g.vertices[b].q):
                        g.set_edge(a, b, FREE, self.gen)
                        nxt = j
                        break
                    g.set_edge(a, b, BLOCKED, self.gen)
                out.append(gamma[nxt])
                i = nxt
        return out

    # --- one task --------------------------------------------------------------------------

    def task(self, goal: str, w: FloatArray) -> TaskResult:
        """One pass of the loop of Figure 1 for goal ``w`` (Repair is the caller's: repair.py)."""
        t0 = time.perf_counter()
        before = self.counter.snapshot()
        calls0 = self._solve_calls
        w = np.asarray(w, dtype=float)
        res = TaskResult(goal, False)
        fallbacks0 = self.s_fallbacks
        w_hat = self.plan_r(w, goal)
        if w_hat is None and not self.late():
            w_hat = self.plan_s_remembered(goal, w)
            if w_hat is None:
                res.note = self.s_failure
        if w_hat is not None and not self.late():
            gamma = self.trace(w_hat)
            if gamma is None and self.timed_out:
                pass  # the note below says so
            elif gamma is None:
                res.note = (
                    "T could not join the robot's vertex to the goal's: G's sequences were "
                    f"blocked and Solve found no path within its {self.last_solve.checks} checks "
                    f"({self.last_solve.outcome})"
                )
                if self.settings.solve == "two_segment":
                    res.note += f"; Solve was the two-segment toy of Fig. 3: {TOY_ADVICE}"
            else:
                if self.settings.corner_cutting and len(gamma) > 2:
                    gamma = self.cut_corners(gamma)
                res.path = self.execute(gamma, w)
                # The re-check tests the claim (no contact anywhere on the path), so it
                # checks exactly, without the clearance Reach demands of its samples.
                res.path_ok = self.recheck(res.path)
                if not res.path_ok:
                    res.note = "the executed path touches an obstacle at the 4x finer re-check"
                res.success = True
                self.u = w.copy()
                self.u_hat = w_hat
                self.link_gen = self.gen
                self.current_goal = goal
                self._emit("executed")
        if self.timed_out and not res.success:
            res.timed_out = True
            res.note = "the query's time limit was reached before a path was found"
        after = self.counter.snapshot()
        res.costs = {k: after[k] - before[k] for k in after}
        res.solve_calls = self._solve_calls - calls0
        res.s_fallbacks = self.s_fallbacks - fallbacks0
        res.seconds = time.perf_counter() - t0
        res.vertices = len(self.graph)
        res.edges = len(self.graph.usable_edges())
        return res

    def recheck(self, path: FloatArray) -> bool:
        """The executed path re-checked, uncounted and exactly (no clearance), at a quarter
        of the resolution (:func:`~.reach.path_is_free`).

        A segment that passed in the current generation is not checked again: the
        workcell has not changed since, so its answer cannot have (a repeated task then
        costs no re-check, only its new segments do).
        """
        is_exact: IsFree = self.world.is_free_exact
        if self.validity is not None:
            is_exact = and_validity(is_exact, self.validity)
        exact = self.space.with_is_free(is_exact)
        if len(path) < 2:
            return path_is_free(exact, path, refine=4)
        if self._rechecked_gen != self.gen:
            self._rechecked, self._rechecked_gen = set(), self.gen
        todo = [
            (a, b, (a.tobytes(), b.tobytes()))
            for a, b in itertools.pairwise(np.asarray(path, float))
            if (a.tobytes(), b.tobytes()) not in self._rechecked
        ]
        if not todo:
            return True
        step = self.space.resolution / 4
        points = np.concatenate([segment_points(a, b, step, self.space) for a, b, _ in todo])
        if not bool(np.all(exact.free_uncounted(points))):
            return False
        self._rechecked.update(key for _, _, key in todo)
        return True

    def execute(self, gamma: list[int], w: FloatArray) -> FloatArray:
        """R[u, w]: the polyline u, Gamma..., w through Reach's local paths.

        On periodic coordinates the polyline is unwrapped (each step the short way
        round, as Reach checked it), so its angles are continuous from ``u``.
        """
        points = [self.u] + [self.graph.vertices[v].q for v in gamma] + [w]
        pieces = [points[0][None, :]]
        for a, b in itertools.pairwise(points):
            if float(np.linalg.norm(self.space.difference(a, b))) <= 0.0:
                continue
            pieces.append(self.local_path(a, b)[1:])
        return self.space.unwrap(np.concatenate(pieces))

    # --- environment changes ---------------------------------------------------------------

    def follow_objects(self, moved: set[str]) -> int:
        """Move the subgoals attached to moved objects (Section 2.3); drop those without IK or free.

        Returns the number of dropped vertices. Vertices attached to objects that
        no longer exist stay where they are, attached to the world.
        """
        dropped = 0
        with self.counter.charge("repair"):
            for vid in list(self.graph.vertices):
                v = self.graph.vertices[vid]
                if v.obj is not None and v.obj not in self.world.objects:
                    v.rel, v.obj = self.world.tool(v.q), None
                    continue
                if v.obj not in moved:
                    continue
                # IK seeded from the subgoal's old configuration (its branch, in 3-D).
                q = self.world.config_of(Tag(v.obj, v.rel, v.branch), v.q)
                if q is None or not self.space.free(q[None, :])[0]:
                    self.graph.remove_vertex(vid)
                    dropped += 1
                    continue
                self.graph.set_q(vid, q)
        return dropped

    def stats(self) -> dict[str, int]:
        """G's size and the counts so far (all counts: ints)."""
        return {
            "vertices": len(self.graph),
            "edges": len(self.graph.usable_edges()),
            "checks": int(self.counter.total),
            "solve_calls": int(self._solve_calls),
            "s_fallbacks": int(self.s_fallbacks),
            "generation": int(self.gen),
        }

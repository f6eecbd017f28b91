"""Sequential assembly (Section 4.2): one disc moves at a time.

Low level (equations (10)-(12)): ``b' = f_i(b) = -S_i grad phi`` moves disc i alone along
its block of the gradient until it is "blocked" (its block of ``grad phi`` vanishes: the
limit point ``Omega_i`` of equation (15)).

High level, two rules selectable by name:

``paper``
    ``x_{n+1} = T(x_n) = Omega_{C(x_n)}(x_n)`` with ``C(x)`` the disc of largest
    ``||f_i(x)||`` (equations (13)-(16)); stops when ``||x - d|| < tol``. Optionally
    (``escapes > 0``) a stuck T map continues at a smaller k (Section 3.2), see below.
``place``
    Ours, to cut switches (the paper sees about three per disc; a person needs one or
    two). A disc put exactly on its goal is *placed* and is not chosen again while
    others can move. Goals are filled from the inside out (only discs whose goal lies
    within one radius of the innermost open goal's distance from the pattern centre are
    eligible), so placed discs never wall in an open goal. Each grasp, in order:

    1. an eligible disc with a collision-free polygonal route to its goal (the
       shortest in a visibility graph around the standing discs, see
       :func:`routes.placement_route`; the others stand still) is put there;
    2. otherwise the unplaced disc nearest the innermost open goal that can leave is
       parked on a circle around the pattern (at most once between two placements);
    3. otherwise the paper's ``C(x)`` over unplaced, non-stalled discs moves along its
       low-level flow until blocked, and continues to its goal if a route opens.

    Every motion is a navigation flow (clearance-bounded steps) or a straight segment
    checked exactly against the standing discs with a small positive margin.

The output is a pick / move / release sequence that one robot can execute, with each
disc's path.

The finish (issue 35, :func:`finish_with_place`; the planner's ``finish="place"``): a run
of either rule that stopped short is finished by the place rule from where it stopped,
or, when that cannot unpack the discs in ``3 n`` grasps, after spreading them one at a
time (:func:`spread_moves`), as the gradient planner's escape. Spheres (3-D) use the
same rules with directions on the sphere (:mod:`cellplan.assembly.routes`).

When the paper's T map is stuck (rule ``paper``). Every low-level flow descends phi, so
``L = log alpha^(1/k)`` (:func:`navigation.log_w`, a monotone function of phi) decreases
along ``x_0, T(x_0), T^2(x_0), ...``. A stage of the T map at one k is *stuck* when

* every disc is blocked away from the goal: all blocks ``f_i`` of ``grad phi`` vanish
  (equation (11)), so ``x`` is a critical point of phi other than d. The Hessian of
  ``L`` says which (:func:`flows.critical_point_kind`): ``spurious minimum`` or
  ``saddle``. (Given 3,000 switches, four 7-disc runs at k=128 in a workspace of radius
  ``4 + 2.2 sqrt n`` end here, after about 1,400 switches, Hessian positive definite.)
* or it makes no progress: ``L`` fell by less than ``min_progress`` (default 0.01:
  ``alpha^(1/k)`` shrank by less than 1%) over the last ``window`` grasps (default
  ``2 n``: two rounds, each of which normally shrinks it by a good factor). This is
  what every budget-exhausted run of our experiments was doing: two (sometimes three
  or four) discs pressed together hand the turn back and forth (``2626...``), far from
  any critical point of phi (``||v|| / ||x - d||`` 0.005-0.5), each grasp moving its
  disc by 0.002-0.03 radii: the disc moves "until blocked" by the other, whose own flow
  then retreats by about as much. This is block coordinate descent of ``L`` in a
  narrow, stiff valley (two-block Gauss-Seidel with strong coupling along the contact
  normal): taken literally, the T map does get out (given 3,000 switches every such run
  at our default workspace solved, after 159-1,075 switches instead of 20 n = 140),
  but at a rate that makes the switch count meaningless for a robot.

We read "a disc moves until blocked" literally (``Omega_i`` unchanged, ``C(x)``
unchanged) and treat a stuck T map the way :func:`flows.gradient_flow` treats a stuck
gradient flow (Section 3.2: k "will be adjusted ... to eliminate local minima"): with
``escapes > 0`` the run continues from where it stopped with the T map of the same
construction at ``k * escape_factor``, at most ``escapes`` times, each stage with its
own switch budget. Every stage is the paper's T map at one k; ``stages`` records them
(:class:`flows.Stage`, ``steps`` = grasps), so a report can say whether the T map at the
stated k alone finished (``solved_at_k``). With ``escapes=0`` (default) the T map runs
at k alone exactly as before, until solved, every disc blocked, or the budget is spent
(no-progress is then only named in the reason). Every switch of every stage is counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.flows import FlowSettings, Stage, critical_point_kind, integrate
from cellplan.assembly.navigation import NavEval, clearances, evaluate, hessian_log_w, log_w
from cellplan.assembly.problems import DiscProblem, workspace_center
from cellplan.assembly.routes import (
    SPHERE_DIRECTIONS,
    placement_route,
    route_margin,
    segment_clearance,
    segment_is_free,
    segments_clearance,
    unit_directions,
)
from cellplan.core import Status

__all__ = [
    "FINISH_SPREAD",
    "FINISH_STAGE",
    "RULES",
    "Grasp",
    "Rule",
    "SequentialResult",
    "finish_with_place",
    "parking_route",
    "path_clearance",
    "placement_route",
    "segment_clearance",
    "segment_is_free",
    "segments_clearance",
    "sequential_assembly",
    "spread_moves",
]

Array = NDArray[np.float64]
Rule = Literal["paper", "place"]
RULES: tuple[str, ...] = ("paper", "place")


@dataclass
class Grasp:
    """One pick / move / release of a single disc: its path (m, 2) from pick to release."""

    disc: int
    path: Array
    kinds: list[str] = field(default_factory=list)  # "flow" and/or "straight"

    def length(self) -> float:
        return float(np.sum(np.linalg.norm(np.diff(self.path, axis=0), axis=1)))


@dataclass
class SequentialResult:
    """The sequence of grasps, the configuration path, and how the run ended."""

    status: Status
    grasps: list[Grasp]
    path: Array  # (m, n, 2) configurations, one disc changing between rows
    min_clearance: float
    evaluations: int
    reason: str = ""
    stages: list[Stage] = field(default_factory=list)
    problem: DiscProblem | None = None  # the problem solved
    #: stages of the place-rule finish at the end of ``stages`` (:func:`finish_with_place`)
    finished: int = 0
    #: grasps of that finish (spreading moves included)
    placed: int = 0

    @property
    def switches(self) -> int:
        """Number of grasps (pick, move, release), the paper's switch count (Fig. 9)."""
        return len(self.grasps)

    @property
    def escapes(self) -> int:
        """Number of times k was lowered after a stuck stage of the T map."""
        return max(len(self.stages) - 1 - self.finished, 0)

    @property
    def k_final(self) -> float:
        """The k of the T map's last stage (the k asked for when k was never lowered)."""
        return self.stages[len(self.stages) - 1 - self.finished].k

    @property
    def solved_at_k(self) -> bool:
        """True when the first stage (the rule at the stated k alone) solved the problem."""
        return self.stages[0].status is Status.SOLVED

    def disc_lengths(self) -> Array:
        seg = np.diff(self.path, axis=0)
        return np.sum(np.linalg.norm(seg, axis=2), axis=0)

    def switches_within(self, goal: Array, tol: float) -> int:
        """Grasps until the configuration first lies within ``tol`` of ``goal`` in R^2n.

        The paper does not state when its sequential runs end; this shows how much of
        the switch count (Fig. 9) the last approach to the goal costs. A run that never
        got that close gives its whole grasp count.
        """
        ends = np.cumsum([len(g.path) - 1 for g in self.grasps], dtype=np.int64)
        if not len(ends):
            return 0
        err = np.linalg.norm((self.path[ends] - goal).reshape(len(ends), -1), axis=1)
        hit = np.flatnonzero(err < tol)
        return int(hit[0]) + 1 if len(hit) else len(self.grasps)

    def actions(self) -> list[dict[str, object]]:
        """The plan as pick / move / release actions for one robot (``metrics.json``).

        ``disc`` is the disc's number as a person counts, from 1 (as in the pictures,
        the CSV columns ``disc1.x`` and the events); disc ``d`` is index ``d - 1`` of the
        problem's arrays.
        """
        out: list[dict[str, object]] = []
        for g in self.grasps:
            d = g.disc + 1
            out.append({"action": "pick", "disc": d, "at": g.path[0].tolist()})
            out.append(
                {"action": "move", "disc": d, "path": g.path.tolist(), "kinds": list(g.kinds)}
            )
            out.append({"action": "release", "disc": d, "at": g.path[-1].tolist()})
        return out


def parking_route(
    problem: DiscProblem, x: Array, i: int, directions: int = 24
) -> list[Array] | None:
    """A route of one or two straight segments taking disc i to a parking spot.

    Spots lie on a circle (spheres: a sphere, ``SPHERE_DIRECTIONS`` points) around the
    goal pattern, clear of every goal and every standing disc; the route goes straight
    or via an exit point ``x_i + a u``.
    """
    centre = problem.goal.mean(axis=0)
    reach = 2.0 * (problem.radii[i] + float(np.max(problem.radii)))
    far = float(np.max(np.linalg.norm(problem.goal - centre, axis=1) + problem.radii))
    if problem.dim == 3:
        directions = SPHERE_DIRECTIONS
    unit = unit_directions(problem.dim, directions, 0.5)
    spots = np.concatenate(
        [
            centre + (far + problem.radii[i] + 0.25 * reach) * unit,
            centre + (far + problem.radii[i] + reach) * unit,
        ]
    )
    # clear of the goals and the other discs (with a margin), inside the workspace
    others = np.concatenate([problem.goal, np.delete(x, i, axis=0)])
    r_others = np.concatenate([problem.radii, np.delete(problem.radii, i)])
    gap = np.linalg.norm(spots[:, None] - others[None], axis=2) - r_others - problem.radii[i]
    ok = np.min(gap, axis=1) > 0.05 * problem.radii[i]
    ok &= segments_clearance(problem, x, i, spots, spots) > route_margin(problem)
    spots = spots[ok]
    if not len(spots):
        return None
    here = x[i]
    m = len(spots)
    margin = route_margin(problem)
    straight = segments_clearance(problem, x, i, np.repeat(here[None], m, 0), spots) > margin
    if np.any(straight):
        cost = np.where(straight, np.linalg.norm(spots - here, axis=1), np.inf)
        return [spots[int(np.argmin(cost))].copy()]
    exits = here + np.concatenate([0.5 * reach * unit, reach * unit])
    from_here = np.repeat(here[None], len(exits), 0)
    e_ok = segments_clearance(problem, x, i, from_here, exits) > margin
    pairs = np.argwhere(e_ok[:, None] & np.ones((1, m), dtype=bool))
    if not len(pairs):
        return None
    P, Q = exits[pairs[:, 0]], spots[pairs[:, 1]]
    good = segments_clearance(problem, x, i, P, Q) > route_margin(problem)
    if not np.any(good):
        return None
    cost = np.where(good, np.linalg.norm(P - here, axis=1) + np.linalg.norm(Q - P, axis=1), np.inf)
    j = int(np.argmin(cost))
    return [P[j].copy(), Q[j].copy()]


def path_clearance(problem: DiscProblem, rows: Array) -> float:
    """Smallest gap over configurations ``rows`` (m, n, 2)."""
    best = np.inf
    for row in rows:
        gaps, bgap = clearances(row, problem.radii, problem.workspace)
        best = min(best, float(min(np.min(gaps), np.min(bgap))))
    return float(best)


def sequential_assembly(
    problem: DiscProblem,
    k: float,
    rule: Rule = "paper",
    *,
    epsilon: float = 1e-3,
    tol: float = 1e-2,
    block_tol: float | None = None,
    max_switches: int | None = None,
    settings: FlowSettings | None = None,
    low_steps: int = 1500,
    escapes: int = 0,
    escape_factor: float = 0.5,
    window: int | None = None,
    min_progress: float = 1e-2,
) -> SequentialResult:
    """Plan a sequential assembly with the named high-level rule (Section 4.2).

    Parameters
    ----------
    problem, k, epsilon
        The problem, the exponent k (equation (2)), the normalisation epsilon.
    rule
        ``paper`` (equations (13)-(16)) or ``place`` (ours, fewer switches).
    tol
        ``paper`` ends when ``||x - d|| < tol`` in R^2n (the limit is only reached
        asymptotically); ``place`` puts discs exactly on their goals.
    block_tol
        A low-level flow is blocked when ``||v_i|| < block_tol`` (``v`` is ``grad phi``
        rescaled to length units; default ``tol / (4 sqrt(n))``).
    max_switches
        Budget of grasps per stage of the T map (default ``20 n``).
    low_steps
        Step budget of one low-level flow; a disc still creeping then is released.
    escapes
        ``paper`` only: how many times a stuck T map (every disc blocked away from the
        goal, or no progress) continues from where it stopped with k multiplied by
        ``escape_factor`` (Section 3.2, as :func:`flows.gradient_flow`). 0 (default):
        the T map at k alone.
    escape_factor
        Factor applied to k at each escape, in (0, 1).
    window, min_progress
        ``paper`` with an escape left: the stage is stuck when ``L = log alpha^(1/k)``
        fell by less than ``min_progress`` over the last ``window`` grasps (default
        ``window = 2 n``).

    Returns
    -------
    SequentialResult
        The grasps, the configuration path, the outcome and the stages (one per k).
    """
    if rule not in RULES:
        raise ValueError(f"unknown rule {rule!r}; known: {', '.join(RULES)}")
    if not 0.0 < escape_factor < 1.0:
        raise ValueError(f"escape_factor must be in (0, 1), got {escape_factor}")
    if escapes < 0:
        raise ValueError(f"escapes must be >= 0, got {escapes}")
    n = problem.n
    span = 2 * n if window is None else window
    block = tol / (4.0 * np.sqrt(n)) if block_tol is None else block_tol
    budget = 20 * n if max_switches is None else max_switches
    base = settings or FlowSettings()
    # A low-level flow ends when blocked (||v_i|| < block) or after ``low_steps`` steps:
    # near a contact the flow is stiff and creeps towards its limit point Omega_i
    # (equation (15)); we release the disc where it is then (a legal configuration).
    low_settings = FlowSettings(
        dt_max=base.dt_max,
        euler_fraction=base.euler_fraction,
        max_steps=low_steps,
        stall_ratio=0.0,
        window=base.window,
        min_progress=0.0,
        stiff_bound=False,
        method=base.method,
        step_max=base.step_max,
        goal_fraction=base.goal_fraction,
    )
    x = np.array(problem.start, dtype=float)
    rows = [x.copy()]
    grasps: list[Grasp] = []
    placed = np.zeros(n, dtype=bool)
    stalled = np.zeros(n, dtype=bool)
    parked_already = np.zeros(n, dtype=bool)
    gaps, bgap = clearances(x, problem.radii, problem.workspace)
    min_clear = float(min(np.min(gaps), np.min(bgap)))
    evals = 0
    # inner discs first: order goals by distance from the pattern's centre
    centre = problem.goal.mean(axis=0) if n > 1 else workspace_center(problem.workspace)
    goal_depth = np.linalg.norm(problem.goal - centre, axis=1)
    inner_rank = np.argsort(np.argsort(goal_depth))
    free: list[int] = []

    def _open_layer(done: NDArray[np.bool_]) -> float:
        """Depth up to which goals may be filled now (the innermost open goal's, plus
        the smallest radius)."""
        open_ = np.flatnonzero(~done)
        return float(goal_depth[open_].min() + problem.radii[open_].min())

    def low_level(i: int, x0: Array) -> tuple[Array, Status]:
        nonlocal evals

        def stop(b: Array, ev: NavEval) -> Status | None:
            return Status.SOLVED if float(np.linalg.norm(ev.v[i])) < block else None

        res = integrate(problem, x0, k_now, epsilon, moving=i, stop=stop, settings=low_settings)
        evals += res.evaluations
        return res.path, res.status

    k_now = float(k)
    stages: list[Stage] = []
    first = 0  # index of the first grasp of the current stage
    progress: list[float] = []  # L = log alpha^(1/k_now) before each grasp of the stage
    while True:
        if len(grasps) - first >= budget:
            status, reason = Status.BUDGET_EXHAUSTED, f"{budget} switches"
            if rule == "paper" and _no_progress(progress, span, min_progress):
                reason += "; " + _no_progress_reason(grasps[len(grasps) - span :], span)
            break
        if rule == "paper" and float(np.linalg.norm(x - problem.goal)) < tol:
            status, reason = Status.SOLVED, ""
            break
        if rule == "place" and bool(np.all(placed)):
            status, reason = Status.SOLVED, ""
            break
        ev = evaluate(x, problem, k_now)
        evals += 1
        norms = np.linalg.norm(ev.v, axis=1)
        if rule == "paper":
            progress.append(log_w(ev, k_now))
            stuck = ""
            if float(np.max(norms)) < block:
                # every f_i vanishes, hence grad phi: a critical point other than d
                stuck = critical_point_kind(hessian_log_w(x, problem, k_now))
            elif len(stages) < escapes and _no_progress(progress, span, min_progress):
                stuck = _no_progress_reason(grasps[len(grasps) - span :], span)
            if stuck:
                if len(stages) >= escapes:
                    status, reason = Status.STUCK, stuck
                    break
                stages.append(Stage(k_now, Status.STUCK, stuck, len(grasps) - first))
                # Section 3.2: continue from here with the T map of phi at a smaller k
                k_now *= escape_factor
                first = len(grasps)
                progress = []
                continue
        kinds: list[str] = []
        disc_path: list[Array] = []
        if rule == "place":
            # inner layers first: only discs whose goal is within one radius of the
            # innermost open goal's distance from the centre may be placed now
            open_ = np.flatnonzero(~placed)
            layer = goal_depth[open_].min() + problem.radii[open_].min()
            # the first eligible disc (inner goals first) with a route is placed
            found: tuple[int, list[Array]] | None = None
            for j in sorted(open_, key=lambda j: inner_rank[j]):
                if goal_depth[j] <= layer:
                    candidate = placement_route(problem, x, int(j))
                    if candidate is not None:
                        found = (int(j), candidate)
                        break
            free = [] if found is None else [found[0]]
            if found is not None:
                i, route = found
                disc_path = [x[i].copy(), *route]
                kinds.extend(["straight"] * len(route))
            else:
                parked = _park_blocker(problem, x, placed, parked_already, inner_rank)
                if parked is not None:
                    i, route = parked
                    disc_path = [x[i].copy(), *route]
                    kinds.extend(["park"] * len(route))
                    parked_already[i] = True
            if not kinds and not free:
                # the paper's C(x) over unplaced discs that still make progress; placed
                # discs only when nothing else can move
                candidates = np.where(placed | stalled, -1.0, norms)
                if float(np.max(candidates)) < block:
                    candidates = np.where(stalled, -1.0, norms)
                i = int(np.argmax(candidates))
        else:
            i = int(np.argmax(norms))  # C(x), equation (16)
        if not kinds:
            if float(norms[i]) < block:  # place rule: nothing left that can move
                status, reason = Status.STUCK, "every disc is blocked away from the goal"
                break
            # a low-level flow that cannot step on any more (its descent step collapses at
            # the limit point) has reached Omega_i as closely as floating point allows
            cpath, _ = low_level(i, x)
            disc_path = list(cpath[:, i, :])
            kinds.append("flow")
            end = cpath[-1]
            # spheres: only a disc of the open layer goes on to its goal (in 3-D an outer
            # shell placed early walls the inner goals in for good; docs/assembly.md)
            in_layer = problem.dim == 2 or bool(goal_depth[i] <= _open_layer(placed))
            if rule == "place" and not placed[i] and in_layer:
                onward = placement_route(problem, end, i)
                if onward is not None:
                    disc_path.extend(onward)
                    kinds.extend(["straight"] * len(onward))
            stalled[i] = bool(np.linalg.norm(end[i] - x[i]) < tol)
        pts = np.array(disc_path)
        for p in pts[1:]:
            x = x.copy()
            x[i] = p
            rows.append(x)
        now_placed = bool(np.array_equal(x[i], problem.goal[i]))
        if now_placed and not placed[i]:
            parked_already[:] = False
            stalled[:] = False  # the scene changed: blocked discs may move again
        placed[i] = now_placed
        grasps.append(Grasp(i, pts, kinds))
        new_rows = np.array(rows[len(rows) - len(pts) :])  # from pick to release
        n_straight = sum(1 for kind in kinds if kind != "flow")
        n_flow = len(pts) - n_straight
        if n_flow > 1:
            min_clear = min(min_clear, path_clearance(problem, new_rows[:n_flow]))
        for s_idx in range(n_flow - 1 if n_flow else 0, len(pts) - 1):
            min_clear = min(
                min_clear, segment_clearance(problem, new_rows[s_idx], i, pts[s_idx + 1])
            )
    stages.append(Stage(k_now, status, reason, len(grasps) - first))
    return SequentialResult(
        status, grasps, np.array(rows), min_clear, evals, reason, stages, problem
    )


#: The stage names of the paper rule's finish (:func:`finish_with_place`) in ``stages``.
FINISH_STAGE = "place rule"
FINISH_SPREAD = "place rule after spreading the discs"
#: Grasp budget of the finish from where the T map stopped, per disc (as the gradient
#: planner's escape, :data:`flows.PLACE_GRASPS_PER_DISC`); then the spread and the place
#: rule's own budget (20 n).
FINISH_GRASPS_PER_DISC = 3


def spread_moves(problem: DiscProblem, x: Array, factor: float) -> list[tuple[int, Array]] | None:
    """The spreading move of :func:`flows.expand_cluster` one disc at a time.

    Each disc goes straight from ``x_i`` to ``c + f (x_i - c)`` (``c`` the goals'
    centroid), the disc farthest from ``c`` first, so that a disc moves out into room
    its outer neighbours have already left; each move is checked exactly against the
    standing discs (:func:`segment_is_free`). ``None`` when a move is blocked.
    """
    centre = problem.goal.mean(axis=0)
    target = centre + factor * (x - centre)
    order = np.argsort(-np.linalg.norm(x - centre, axis=1), kind="stable")
    cur = x.copy()
    moves: list[tuple[int, Array]] = []
    for i in order:
        if not segment_is_free(problem, cur, int(i), target[i]):
            return None
        moves.append((int(i), target[i].copy()))
        cur[i] = target[i]
    return moves


def finish_with_place(
    problem: DiscProblem,
    stopped: SequentialResult,
    k: float,
    *,
    epsilon: float = 1e-3,
    settings: FlowSettings | None = None,
) -> SequentialResult:
    """Finish a paper-rule run that stopped short (stuck, or budget spent) with the place rule.

    Issue 35: the paper's T map only lowers k (Section 3.2) and on tight packings ends
    far from the goal; the gradient planner's escape (:func:`flows.gradient_flow`,
    ``escape="place"``) is given to it too. The place rule runs from where the T map
    stopped with ``FINISH_GRASPS_PER_DISC n`` grasps; when it cannot unpack the
    configuration, its partial run is dropped, the discs are spread one at a time
    (:func:`spread_moves`, factors 2.5 down to 1.1) and the place rule runs from there
    with its own budget. Every grasp (the T map's, the spread's, the place rule's) is
    kept and counted, so ``switches`` is the robot's whole work; ``stages`` records the
    T map's stages and the finish's (:data:`FINISH_STAGE`, :data:`FINISH_SPREAD`).
    """
    from cellplan.assembly.flows import SPREAD_FACTOR

    def place(start: Array, budget: int | None) -> SequentialResult:
        return sequential_assembly(
            problem.with_start(start),
            k,
            "place",
            epsilon=epsilon,
            settings=settings,
            max_switches=budget,
        )

    end = stopped.path[-1]
    stages = list(stopped.stages)
    run = place(end, FINISH_GRASPS_PER_DISC * problem.n)
    stages.append(Stage(k, run.status, _finish_reason(run, FINISH_STAGE), run.switches))
    grasps, rows = list(stopped.grasps), [stopped.path]
    evals = stopped.evaluations + run.evaluations
    clear = stopped.min_clearance
    if run.status is not Status.SOLVED:
        moves = None
        for f in np.linspace(SPREAD_FACTOR, 1.1, 15):
            moves = spread_moves(problem, end, float(f))
            if moves is not None:
                break
        x = end.copy()
        for i, target in moves or []:
            clear = min(clear, segment_clearance(problem, x, i, target))
            grasps.append(Grasp(i, np.array([x[i].copy(), target]), ["spread"]))
            x = x.copy()
            x[i] = target
            rows.append(x[None])
        spread = len(moves or [])
        run = place(x, None)
        evals += run.evaluations
        # the stage's steps are its grasps, the spreading moves included
        reason = _finish_reason(run, FINISH_SPREAD)
        stages.append(Stage(k, run.status, reason, spread + run.switches))
    grasps.extend(run.grasps)
    rows.append(run.path[1:])
    return SequentialResult(
        run.status,
        grasps,
        np.concatenate(rows),
        min(clear, run.min_clearance),
        evals,
        stages[-1].reason,
        stages,
        problem,
        len(stages) - len(stopped.stages),
        len(grasps) - len(stopped.grasps),
    )


def _finish_reason(run: SequentialResult, name: str) -> str:
    return name if run.status is Status.SOLVED else f"{name}: {run.reason or run.status.value}"


def _no_progress(progress: list[float], window: int, min_progress: float) -> bool:
    """True when ``L`` fell by less than ``min_progress`` over the last ``window`` grasps."""
    return len(progress) > window and progress[-window - 1] - progress[-1] < min_progress


def _no_progress_reason(recent: list[Grasp], window: int) -> str:
    """Name the stall; a pair of discs that hand the turn back and forth is named."""
    discs = sorted({g.disc for g in recent})
    if len(discs) == 2:
        return (
            f"no progress over {window} switches (discs {discs[0]} and {discs[1]} "
            "hand the turn back and forth)"
        )
    return f"no progress over {window} switches"


def _park_blocker(
    problem: DiscProblem,
    x: Array,
    placed: NDArray[np.bool_],
    parked_already: NDArray[np.bool_],
    inner_rank: NDArray[np.int64],
) -> tuple[int, list[Array]] | None:
    """Move aside the unplaced disc nearest the innermost open goal, if it can leave.

    Discs are tried by distance from that goal; each disc is parked at most once
    between two placements (so parking cannot cycle).
    """
    open_goals = np.flatnonzero(~placed)
    target = open_goals[np.argmin(inner_rank[open_goals])]
    dist = np.linalg.norm(x - problem.goal[target], axis=1)
    for j in np.argsort(dist):
        if placed[j] or parked_already[j]:
            continue
        route = parking_route(problem, x, int(j))
        if route is not None:
            return int(j), route
    return None

"""Sequential assembly (Section 4.2): one disc moves at a time.

Low level (equations (10)-(12)): ``b' = f_i(b) = -S_i grad phi`` moves disc i alone along
its block of the gradient until it is "blocked" (its block of ``grad phi`` vanishes: the
limit point ``Omega_i`` of equation (15)).

High level, two rules selectable by name:

``paper``
    ``x_{n+1} = T(x_n) = Omega_{C(x_n)}(x_n)`` with ``C(x)`` the disc of largest
    ``||f_i(x)||`` (equations (13)-(16)); stops when ``||x - d|| < tol``.
``place``
    Ours, to cut switches (the paper sees about three per disc; a person needs one or
    two). A disc put exactly on its goal is *placed* and is not chosen again while
    others can move. Goals are filled from the inside out (only discs whose goal lies
    within one radius of the innermost open goal's distance from the pattern centre are
    eligible), so placed discs never wall in an open goal. Each grasp, in order:

    1. an eligible disc with a collision-free polygonal route to its goal (the
       shortest in a visibility graph around the standing discs, see
       :func:`placement_route`; the others stand still) is put there;
    2. otherwise the unplaced disc nearest the innermost open goal that can leave is
       parked on a circle around the pattern (at most once between two placements);
    3. otherwise the paper's ``C(x)`` over unplaced, non-stalled discs moves along its
       low-level flow until blocked, and continues to its goal if a route opens.

    Every motion is a navigation flow (clearance-bounded steps) or a straight segment
    checked exactly against the standing discs with a small positive margin.

The output is a pick / move / release sequence that one robot can execute, with each
disc's path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.flows import FlowSettings, integrate
from cellplan.assembly.navigation import NavEval, clearances, evaluate
from cellplan.assembly.problems import CircleWorkspace, DiscProblem, workspace_center
from cellplan.core import Status

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

    @property
    def switches(self) -> int:
        """Number of grasps (pick, move, release), the paper's switch count (Fig. 9)."""
        return len(self.grasps)

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
        """The plan as pick / move / release actions for one robot."""
        out: list[dict[str, object]] = []
        for g in self.grasps:
            out.append({"action": "pick", "disc": g.disc, "at": g.path[0].tolist()})
            out.append({"action": "move", "disc": g.disc, "path": g.path.tolist(),
                        "kinds": list(g.kinds)})
            out.append({"action": "release", "disc": g.disc, "at": g.path[-1].tolist()})
        return out


def segments_clearance(problem: DiscProblem, x: Array, i: int, P: Array, Q: Array) -> Array:
    """Smallest gap while disc i moves straight from each ``P[s]`` to ``Q[s]`` (S,).

    The other discs stand at ``x``. Exact: the distance from each other centre to the
    segment minus the radii; the workspace is convex, so the boundary gap is smallest
    at an end point.
    """
    seg = Q - P  # (S, 2)
    length2 = np.einsum("sk,sk->s", seg, seg)
    rel = x[None, :, :] - P[:, None, :]  # (S, n, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("snk,sk->sn", rel, seg) / length2[:, None]
    t = np.clip(np.nan_to_num(t), 0.0, 1.0)
    closest = P[:, None, :] + t[..., None] * seg[:, None, :]
    gap = np.linalg.norm(x[None] - closest, axis=2) - problem.radii[None] - problem.radii[i]
    gap[:, i] = np.inf
    ends = np.concatenate([P, Q])
    ws = problem.workspace
    if isinstance(ws, CircleWorkspace):
        bgap = ws.radius - problem.radii[i] - np.linalg.norm(ends - ws.center, axis=1)
    else:
        walls = np.concatenate([ends - ws.lo, ws.hi - ends], axis=1)
        bgap = np.min(walls, axis=1) - problem.radii[i]
    bgap = np.minimum(bgap[: len(P)], bgap[len(P):])
    return np.minimum(np.min(gap, axis=1), bgap)


def segment_clearance(problem: DiscProblem, x: Array, i: int, target: Array) -> float:
    """Smallest gap while disc i moves straight from ``x[i]`` to ``target``, others still."""
    return float(segments_clearance(problem, x, i, x[i][None], np.asarray(target)[None])[0])


def segment_is_free(problem: DiscProblem, x: Array, i: int, target: Array) -> bool:
    """True when disc i can move straight to ``target`` without touching anything."""
    return segment_clearance(problem, x, i, target) > _margin(problem)


def _margin(problem: DiscProblem) -> float:
    # straight moves keep a small positive clearance, never a touching contact: 1e-3 of
    # the smallest radius, or a quarter of the tightest goal gap if the pattern is tighter
    gaps, _ = clearances(problem.goal, problem.radii, problem.workspace)
    return float(min(1e-3 * float(np.min(problem.radii)), 0.25 * float(np.min(gaps))))


def placement_route(problem: DiscProblem, x: Array, i: int, directions: int = 24,
                    corners: int = 12) -> list[Array] | None:
    """A short collision-free polygonal route for disc i to its goal, others standing.

    The shortest path (Dijkstra) in a visibility graph whose nodes are the disc, its
    goal, ``corners`` points around each standing disc (a polygon circumscribing the
    circle of centre distances ``rho_i + rho_j`` plus twice the margin, so that the
    paths hug the obstacles as a shortest path among discs does) and the candidates
    of the former three-segment search (approach points ``d_i + a u`` and exit points
    ``x_i + a u``, ``u`` one of ``directions`` unit vectors, ``a`` one or two times
    ``2 (rho_i + max rho)``), so no route is longer than that search's. An edge is a
    straight segment whose exact clearance (:func:`segments_clearance`) exceeds the
    margin. Returns the points after ``x[i]`` (ending at the goal), or ``None``.
    """
    from scipy.sparse.csgraph import dijkstra

    goal = problem.goal[i]
    here = x[i]
    if segment_is_free(problem, x, i, goal):
        return [goal.copy()]
    margin = _margin(problem)
    reach = 2.0 * (problem.radii[i] + float(np.max(problem.radii)))
    ang = 2.0 * np.pi * np.arange(directions) / directions
    unit = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    rays = np.concatenate([reach * unit, 2.0 * reach * unit])
    others = np.delete(np.arange(problem.n), i)
    cang = 2.0 * np.pi * (np.arange(corners) + 0.5) / corners
    cunit = np.stack([np.cos(cang), np.sin(cang)], axis=1)
    ring = (problem.radii[i] + problem.radii[others] + 2.0 * margin) / np.cos(np.pi / corners)
    around = (x[others][:, None, :] + ring[:, None, None] * cunit[None]).reshape(-1, 2)
    nodes = np.concatenate([here[None], goal[None], goal + rays, here + rays, around])
    nodes = nodes[np.r_[True, True, segments_clearance(problem, x, i, nodes[2:], nodes[2:])
                        > margin]]
    m = len(nodes)
    a, b = np.triu_indices(m, 1)
    free = np.zeros(len(a), dtype=bool)
    chunk = max(1, 400_000 // max(problem.n, 1))
    for lo in range(0, len(a), chunk):
        sl = slice(lo, lo + chunk)
        free[sl] = segments_clearance(problem, x, i, nodes[a[sl]], nodes[b[sl]]) > margin
    weight = np.zeros((m, m))
    length = np.linalg.norm(nodes[a[free]] - nodes[b[free]], axis=1)
    weight[a[free], b[free]] = length
    weight[b[free], a[free]] = length
    dist, pred = dijkstra(weight, directed=False, indices=0, return_predecessors=True)
    if not np.isfinite(dist[1]):
        return None
    route: list[Array] = []
    node = 1
    while node != 0:
        route.append(nodes[node].copy())
        node = int(pred[node])
    route.reverse()
    route[-1] = goal.copy()
    return route


def parking_route(problem: DiscProblem, x: Array, i: int, directions: int = 24
                  ) -> list[Array] | None:
    """A route of one or two straight segments taking disc i to a parking spot.

    Spots lie on a circle around the goal pattern, clear of every goal and every
    standing disc; the route goes straight or via an exit point ``x_i + a u``.
    """
    centre = problem.goal.mean(axis=0)
    reach = 2.0 * (problem.radii[i] + float(np.max(problem.radii)))
    far = float(np.max(np.linalg.norm(problem.goal - centre, axis=1) + problem.radii))
    ang = 2.0 * np.pi * (np.arange(directions) + 0.5) / directions
    unit = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    spots = np.concatenate([centre + (far + problem.radii[i] + 0.25 * reach) * unit,
                            centre + (far + problem.radii[i] + reach) * unit])
    # clear of the goals and the other discs (with a margin), inside the workspace
    others = np.concatenate([problem.goal, np.delete(x, i, axis=0)])
    r_others = np.concatenate([problem.radii, np.delete(problem.radii, i)])
    gap = np.linalg.norm(spots[:, None] - others[None], axis=2) - r_others - problem.radii[i]
    ok = np.min(gap, axis=1) > 0.05 * problem.radii[i]
    ok &= segments_clearance(problem, x, i, spots, spots) > _margin(problem)
    spots = spots[ok]
    if not len(spots):
        return None
    here = x[i]
    m = len(spots)
    margin = _margin(problem)
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
    good = segments_clearance(problem, x, i, P, Q) > _margin(problem)
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
) -> SequentialResult:
    """Plan a sequential assembly with the named high-level rule.

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
        Budget of grasps (default ``20 n``).
    low_steps
        Step budget of one low-level flow; a disc still creeping then is released.
    """
    if rule not in RULES:
        raise ValueError(f"unknown rule {rule!r}; known: {', '.join(RULES)}")
    n = problem.n
    block = tol / (4.0 * np.sqrt(n)) if block_tol is None else block_tol
    budget = 20 * n if max_switches is None else max_switches
    base = settings or FlowSettings()
    # A low-level flow ends when blocked (||v_i|| < block) or after ``low_steps`` steps:
    # near a contact the flow is stiff and creeps towards its limit point Omega_i
    # (equation (15)); we release the disc where it is then (a legal configuration).
    low_settings = FlowSettings(dt_max=base.dt_max, euler_fraction=base.euler_fraction,
                                max_steps=low_steps, stall_ratio=0.0,
                                window=base.window, min_progress=0.0, stiff_bound=False,
                                method=base.method, step_max=base.step_max,
                                goal_fraction=base.goal_fraction)
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

    def low_level(i: int, x0: Array) -> tuple[Array, Status]:
        nonlocal evals

        def stop(b: Array, ev: NavEval) -> Status | None:
            return Status.SOLVED if float(np.linalg.norm(ev.v[i])) < block else None

        res = integrate(problem, x0, k, epsilon, moving=i, stop=stop, settings=low_settings)
        evals += res.evaluations
        return res.path, res.status

    status, reason = Status.BUDGET_EXHAUSTED, f"{budget} switches"
    while len(grasps) < budget:
        if rule == "paper" and float(np.linalg.norm(x - problem.goal)) < tol:
            status, reason = Status.SOLVED, ""
            break
        if rule == "place" and bool(np.all(placed)):
            status, reason = Status.SOLVED, ""
            break
        ev = evaluate(x, problem, k)
        evals += 1
        norms = np.linalg.norm(ev.v, axis=1)
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
            if float(norms[i]) < block:
                status, reason = Status.STUCK, "every disc is blocked away from the goal"
                break
            # a low-level flow that cannot step on any more (its descent step collapses at
            # the limit point) has reached Omega_i as closely as floating point allows
            cpath, _ = low_level(i, x)
            disc_path = list(cpath[:, i, :])
            kinds.append("flow")
            end = cpath[-1]
            if rule == "place" and not placed[i]:
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
        new_rows = np.array(rows[len(rows) - len(pts):])  # from pick to release
        n_straight = sum(1 for kind in kinds if kind != "flow")
        n_flow = len(pts) - n_straight
        if n_flow > 1:
            min_clear = min(min_clear, path_clearance(problem, new_rows[:n_flow]))
        for s_idx in range(n_flow - 1 if n_flow else 0, len(pts) - 1):
            min_clear = min(min_clear, segment_clearance(problem, new_rows[s_idx], i,
                                                         pts[s_idx + 1]))
    return SequentialResult(status, grasps, np.array(rows), min_clear, evals, reason)


def _park_blocker(problem: DiscProblem, x: Array, placed: NDArray[np.bool_],
                  parked_already: NDArray[np.bool_], inner_rank: NDArray[np.int64]
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

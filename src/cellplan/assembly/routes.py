"""Straight-segment routes for one disc among standing discs (the ``place`` rule's moves).

Not in the paper: our ``place`` rule (:mod:`cellplan.assembly.sequential`) moves a
grasped disc along a polygonal route while the other discs stand still (one robot,
Section 4.2's setting). Every segment is checked exactly (:func:`segments_clearance`)
and must keep a small positive margin (:func:`route_margin`).

The route is the shortest path in a visibility graph (:func:`route_nodes`): the disc,
its goal, points around every standing disc and fixed approach / exit points; an edge
is a segment that keeps the margin. Two searches return the same shortest length:

* :func:`shortest_route_full` (baseline): every one of the ``N (N - 1) / 2`` edges is
  tested (``O(N^2 n)`` for ``N = 12 (n - 1) + 98`` nodes), then Dijkstra.
* :func:`shortest_route` (default): A* with lazy edge evaluation. The heuristic is the
  straight distance to the goal (admissible and consistent, so the first time the goal
  is selected its distance is the graph's shortest); the edges out of a node are
  tested only when the node is expanded, all of them in one vectorised call, and only
  towards nodes that could still improve the goal's distance (``g(u) + |uv| + |v d|``
  below the best distance found so far). Expanded nodes are never re-tested.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.kernels import segments_gap_kernel
from cellplan.assembly.problems import CircleWorkspace, DiscProblem

Array = NDArray[np.float64]


#: Directions of the 3-D route nodes, approach points and parking spots: ours (the planar
#: code's 24 directions and 12 corners become points on the sphere; docs/assembly.md).
SPHERE_DIRECTIONS = 48
SPHERE_CORNERS = 26
#: Covering angle of the 26 corner directions (rad): every direction lies within it of a
#: corner (0.534 measured on 200,000 random directions), so the convex hull of the corner
#: points at ``r / cos`` of it contains the ball of radius r, as the planar polygon does.
CORNER_HALF_ANGLE_3D = 0.54


def unit_directions(dim: int, count: int, offset: float = 0.0) -> Array:
    """``count`` unit vectors spread evenly: ``dim`` 2 on the circle at angles
    ``2 pi (j + offset) / count``; ``dim`` 3 on the sphere (a Fibonacci lattice, ``offset``
    turning it about the z axis), nearly uniform for any count."""
    if dim == 2:
        ang = 2.0 * np.pi * (np.arange(count) + offset) / count
        return np.stack([np.cos(ang), np.sin(ang)], axis=1)
    j = np.arange(count) + 0.5
    z = 1.0 - 2.0 * j / count
    rho = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * j + 2.0 * np.pi * offset / count
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def segments_clearance(problem: DiscProblem, x: Array, i: int, P: Array, Q: Array) -> Array:
    """Smallest gap while disc i moves straight from each ``P[s]`` to ``Q[s]`` (S,).

    The other discs stand at ``x``. Exact: the distance from each other centre to the
    segment minus the radii (one numba pass over segments and discs,
    :func:`kernels.segments_gap_kernel`); the workspace is convex, so the boundary gap
    is smallest at an end point. :func:`segments_clearance_numpy` is the reference.
    """
    gap = segments_gap_kernel(
        np.ascontiguousarray(P, dtype=np.float64),
        np.ascontiguousarray(Q, dtype=np.float64),
        np.ascontiguousarray(x, dtype=np.float64),
        problem.radii,
        int(i),
    )
    return np.minimum(gap, _boundary_gap(problem, i, P, Q))


def _boundary_gap(problem: DiscProblem, i: int, P: Array, Q: Array) -> Array:
    """Smallest boundary gap of disc i at the segments' end points (S,)."""
    ends = np.concatenate([P, Q])
    ws = problem.workspace
    if isinstance(ws, CircleWorkspace):
        bgap = ws.radius - problem.radii[i] - np.linalg.norm(ends - ws.center, axis=1)
    else:
        walls = np.concatenate([ends - ws.lo, ws.hi - ends], axis=1)
        bgap = np.min(walls, axis=1) - problem.radii[i]
    out: Array = np.minimum(bgap[: len(P)], bgap[len(P) :])
    return out


def segments_clearance_numpy(problem: DiscProblem, x: Array, i: int, P: Array, Q: Array) -> Array:
    """:func:`segments_clearance` on ``(S, n)`` numpy arrays (the reference of its kernel)."""
    # components as (S, n) arrays: no (S, n, d) temporaries, no norm calls; sums over
    # the axes in axis order, as the kernel
    dim = x.shape[1]
    sv = [Q[:, a] - P[:, a] for a in range(dim)]
    rv = [x[None, :, a] - P[:, a, None] for a in range(dim)]
    length2 = np.zeros(len(P))
    dot = np.zeros((len(P), len(x)))
    for a in range(dim):
        length2 = length2 + sv[a] * sv[a]
        dot = dot + rv[a] * sv[a][:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = dot / length2[:, None]
    t = np.clip(np.nan_to_num(t), 0.0, 1.0)
    sq = np.zeros((len(P), len(x)))
    for a in range(dim):
        da = rv[a] - t * sv[a][:, None]
        sq = sq + da * da
    gap = np.sqrt(sq) - problem.radii[None] - problem.radii[i]
    gap[:, i] = np.inf
    return np.minimum(np.min(gap, axis=1), _boundary_gap(problem, i, P, Q))


def segment_clearance(problem: DiscProblem, x: Array, i: int, target: Array) -> float:
    """Smallest gap while disc i moves straight from ``x[i]`` to ``target``, others still."""
    return float(segments_clearance(problem, x, i, x[i][None], np.asarray(target)[None])[0])


def route_margin(problem: DiscProblem) -> float:
    """Clearance every straight move keeps: never a touching contact.

    1e-3 of the smallest radius, or a quarter of the tightest goal gap if the pattern
    is tighter (Fig. 5(e) has gaps of about 1e-4 radii).
    """
    return float(min(1e-3 * float(np.min(problem.radii)), 0.25 * problem.goal_gap))


def segment_is_free(problem: DiscProblem, x: Array, i: int, target: Array) -> bool:
    """True when disc i can move straight to ``target`` keeping :func:`route_margin`."""
    return segment_clearance(problem, x, i, target) > route_margin(problem)


def route_nodes(
    problem: DiscProblem, x: Array, i: int, directions: int = 24, corners: int = 12
) -> Array:
    """Nodes of the visibility graph for disc i: ``[x_i, d_i, ...]`` (N, d).

    ``corners`` points around each standing disc (a polygon circumscribing the circle
    of centre distances ``rho_i + rho_j`` plus twice the margin, so that routes hug the
    obstacles as a shortest path among discs does) and the approach points ``d_i + a u``
    and exit points ``x_i + a u`` (``u`` one of ``directions`` unit vectors, ``a`` one or
    two times ``2 (rho_i + max rho)``). Nodes where the disc itself would not keep the
    margin are dropped (the first two are always kept).

    Spheres (3-D): ``SPHERE_DIRECTIONS`` and ``SPHERE_CORNERS`` points on the sphere
    (:func:`unit_directions`) instead of the planar ``directions`` and ``corners``; the
    corner points lie at ``(rho_i + rho_j + 2 margin) / cos(theta)``, ``theta`` the
    covering angle of the corner directions (``CORNER_HALF_ANGLE_3D``), so that their
    convex hull contains the grown sphere as the planar polygon does.
    """
    goal, here = problem.goal[i], x[i]
    dim = problem.dim
    margin = route_margin(problem)
    reach = 2.0 * (problem.radii[i] + float(np.max(problem.radii)))
    if dim == 3:
        directions, corners = SPHERE_DIRECTIONS, SPHERE_CORNERS
    unit = unit_directions(dim, directions)
    rays = np.concatenate([reach * unit, 2.0 * reach * unit])
    others = np.delete(np.arange(problem.n), i)
    cunit = unit_directions(dim, corners, 0.5)
    half = np.pi / corners if dim == 2 else CORNER_HALF_ANGLE_3D
    ring = (problem.radii[i] + problem.radii[others] + 2.0 * margin) / np.cos(half)
    around = (x[others][:, None, :] + ring[:, None, None] * cunit[None]).reshape(-1, dim)
    nodes = np.concatenate([here[None], goal[None], goal + rays, here + rays, around])
    keep = segments_clearance(problem, x, i, nodes[2:], nodes[2:]) > margin
    return nodes[np.r_[True, True, keep]]


def _walk_back(nodes: Array, pred: NDArray[np.int64]) -> list[Array]:
    route: list[Array] = []
    node = 1
    while node != 0:
        route.append(nodes[node].copy())
        node = int(pred[node])
    route.reverse()
    return route


def _edges_free(
    problem: DiscProblem,
    x: Array,
    i: int,
    nodes: Array,
    u: int,
    others: NDArray[np.int64],
    margin: float,
) -> NDArray[np.bool_]:
    """Edges ``u - others`` that keep the margin, one vectorised test.

    Each segment runs from the lower to the higher node index, as in the baseline, so
    both searches test exactly the same floating-point segments.
    """
    lo, hi = np.minimum(u, others), np.maximum(u, others)
    return segments_clearance(problem, x, i, nodes[lo], nodes[hi]) > margin


def shortest_route(
    problem: DiscProblem, x: Array, i: int, nodes: Array
) -> tuple[list[Array], float] | None:
    """Shortest path from ``nodes[0]`` to ``nodes[1]``: A* with lazy edge tests.

    Same graph and edge test as :func:`shortest_route_full`, hence the same shortest
    length (the route may differ only between paths of equal length). Returns the
    points after ``nodes[0]`` and the length, or ``None`` when the goal is unreachable.
    """
    margin = route_margin(problem)
    m = len(nodes)
    goal = nodes[1]
    h = np.linalg.norm(nodes - goal, axis=1)  # admissible, consistent
    g = np.full(m, np.inf)
    g[0] = 0.0
    pred = np.full(m, -1, dtype=np.int64)
    done = np.zeros(m, dtype=bool)
    # the goal's own edges first: an unreachable goal (occupied, walled in) fails at once
    # instead of after a search of the whole reachable graph
    into_goal = _edges_free(problem, x, i, nodes, 1, np.arange(m), margin)
    into_goal[1] = False
    if not np.any(into_goal):
        return None
    while True:
        f = np.where(done, np.inf, g + h)
        u = int(np.argmin(f))
        if not np.isfinite(f[u]):
            return None
        if u == 1:
            return _walk_back(nodes, pred), float(g[1])
        done[u] = True
        cand = np.flatnonzero(~done)
        step = np.linalg.norm(nodes[cand] - nodes[u], axis=1)
        via = g[u] + step
        # only edges that improve the node and could still beat the best goal distance
        useful = (via < g[cand]) & (via + h[cand] < g[1])
        cand, via = cand[useful], via[useful]
        if not len(cand):
            continue
        ok = np.empty(len(cand), dtype=bool)
        is_goal = cand == 1
        ok[is_goal] = into_goal[u]
        ok[~is_goal] = _edges_free(problem, x, i, nodes, u, cand[~is_goal], margin)
        g[cand[ok]] = via[ok]
        pred[cand[ok]] = u


def shortest_route_full(
    problem: DiscProblem, x: Array, i: int, nodes: Array
) -> tuple[list[Array], float] | None:
    """Baseline of :func:`shortest_route`: test every edge, then Dijkstra (scipy)."""
    from scipy.sparse.csgraph import dijkstra

    margin = route_margin(problem)
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
    return _walk_back(nodes, pred.astype(np.int64)), float(dist[1])


def placement_route(
    problem: DiscProblem,
    x: Array,
    i: int,
    directions: int = 24,
    corners: int = 12,
    full: bool = False,
) -> list[Array] | None:
    """A short collision-free polygonal route for disc i to its goal, others standing.

    The straight segment when it is free; otherwise the shortest path in the visibility
    graph of :func:`route_nodes` (no longer than the former three-segment search, whose
    candidates are among the nodes). An edge is a straight segment whose exact
    clearance (:func:`segments_clearance`) exceeds :func:`route_margin`. ``full``
    selects the baseline search (:func:`shortest_route_full`); both give the same
    length. Returns the points after ``x[i]`` (ending exactly at the goal), or ``None``.
    """
    goal = problem.goal[i]
    if segment_is_free(problem, x, i, goal):
        return [goal.copy()]
    nodes = route_nodes(problem, x, i, directions, corners)
    search = shortest_route_full if full else shortest_route
    found = search(problem, x, i, nodes)
    if found is None:
        return None
    route = found[0]
    route[-1] = goal.copy()
    return route

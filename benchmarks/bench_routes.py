"""Benchmark of the place rule's route search: lazy A* against the full visibility graph.

Run: ``.venv/bin/python benchmarks/bench_routes.py`` (``--quick``:
7 and 15 discs only; ``--sizes 7 15 30 50`` to choose).

For n discs (``cellplan assemble --random n --seed 0`` problems: random legal starts,
hexagonal goals, the default workspace) the place rule is run once; before every grasp
the route of every disc not on its goal (at most 120 of these searches, evenly spaced)
is searched in the same process, on the same state and the same nodes
(:func:`routes.route_nodes`), three ways:

* ``v0``: the previous code, kept here as the baseline: every edge tested with the
  previous segment test (``(S, n, 2)`` einsum arrays, :func:`segments_clearance_v0`),
  then Dijkstra;
* ``full``: the same full graph with the current segment test
  (:func:`routes.shortest_route_full`), which isolates the gain of the search;
* ``lazy``: :func:`routes.shortest_route` (A*, edges tested lazily, one vectorised call
  per expanded node).

It checks that all three find a route in the same cases and that the lengths agree,
and prints the time of each and the ratios. Then the whole place-rule run with the
previous search patched in and with the current one: time, grasps, ratio.
"""

from __future__ import annotations

import argparse
import functools
import time
from unittest import mock

import numpy as np

from cellplan.assembly import routes
from cellplan.assembly.problems import (
    CircleWorkspace,
    DiscProblem,
    default_workspace,
    generate_problem,
)
from cellplan.assembly.section import GeneratorSpec
from cellplan.assembly.sequential import sequential_assembly


def segments_clearance_v0(
    problem: DiscProblem, x: np.ndarray, i: int, P: np.ndarray, Q: np.ndarray
) -> np.ndarray:
    """The previous :func:`routes.segments_clearance` (same formula, (S, n, 2) arrays)."""
    seg = Q - P
    length2 = np.einsum("sk,sk->s", seg, seg)
    rel = x[None, :, :] - P[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("snk,sk->sn", rel, seg) / length2[:, None]
    t = np.clip(np.nan_to_num(t), 0.0, 1.0)
    closest = P[:, None, :] + t[..., None] * seg[:, None, :]
    gap = np.linalg.norm(x[None] - closest, axis=2) - problem.radii[None] - problem.radii[i]
    gap[:, i] = np.inf
    ends = np.concatenate([P, Q])
    ws = problem.workspace
    assert isinstance(ws, CircleWorkspace)
    bgap = ws.radius - problem.radii[i] - np.linalg.norm(ends - ws.center, axis=1)
    bgap = np.minimum(bgap[: len(P)], bgap[len(P) :])
    return np.minimum(np.min(gap, axis=1), bgap)


def full_graph_v0(
    problem: DiscProblem, x: np.ndarray, i: int, nodes: np.ndarray
) -> tuple[list[np.ndarray], float] | None:
    """The previous search: :func:`routes.shortest_route_full` with the previous test."""
    with mock.patch.object(routes, "segments_clearance", segments_clearance_v0):
        return routes.shortest_route_full(problem, x, i, nodes)


def queries(n: int, seed: int = 0) -> tuple[list[tuple[np.ndarray, int]], DiscProblem]:
    """(state, disc) pairs: before each grasp of a place run, every disc off its goal."""
    p = generate_problem(GeneratorSpec(n=n, seed=seed), default_workspace(n))
    res = sequential_assembly(p, 2000.0, "place")
    ends = np.concatenate([[0], np.cumsum([len(g.path) - 1 for g in res.grasps])[:-1]])
    out: list[tuple[np.ndarray, int]] = []
    for e in ends:
        x = res.path[e]
        off = np.flatnonzero(np.linalg.norm(x - p.goal, axis=1) > 0)
        out.extend((x, int(i)) for i in off)
    return out, p


def compare(n: int, most: int = 120) -> None:
    qs, p = queries(n)
    qs = qs[:: -(-len(qs) // most)]  # evenly spaced, at most ``most`` searches
    searches = {
        "v0": full_graph_v0,
        "full": routes.shortest_route_full,
        "lazy": routes.shortest_route,
    }
    spent = dict.fromkeys(searches, 0.0)
    found = 0
    for x, i in qs:
        nodes = routes.route_nodes(p, x, i)
        out: dict[str, tuple[list[np.ndarray], float] | None] = {}
        for name, search in searches.items():
            t0 = time.perf_counter()
            out[name] = search(p, x, i, nodes)
            spent[name] += time.perf_counter() - t0
        lengths = [r[1] for r in out.values() if r is not None]
        assert len(lengths) in (0, len(out)), (n, i)  # all find a route or none does
        if lengths:
            found += 1
            assert max(lengths) - min(lengths) <= 1e-9 * max(1.0, lengths[0]), (n, i)
    m = len(routes.route_nodes(p, qs[0][0], qs[0][1]))
    per = {name: 1e3 * t / len(qs) for name, t in spent.items()}
    print(
        f"n={n:3d}  {len(qs):4d} searches ({found} routes, ~{m} nodes), ms/search: "
        f"v0 {per['v0']:.2f}, full {per['full']:.2f}, lazy {per['lazy']:.2f}; "
        f"v0/lazy {spent['v0'] / spent['lazy']:.1f}x, full/lazy "
        f"{spent['full'] / spent['lazy']:.1f}x; equal lengths"
    )


def whole_run(n: int, seed: int = 0) -> None:
    p = generate_problem(GeneratorSpec(n=n, seed=seed), default_workspace(n))
    straight = float(np.sum(np.linalg.norm(p.start - p.goal, axis=1)))
    times = {}
    v0 = functools.partial(routes.placement_route, full=True)
    for name in ("v0", "lazy"):
        with (
            mock.patch.object(
                routes,
                "segments_clearance",
                segments_clearance_v0 if name == "v0" else routes.segments_clearance,
            ),
            mock.patch(
                "cellplan.assembly.sequential.placement_route",
                v0 if name == "v0" else routes.placement_route,
            ),
        ):
            t0 = time.perf_counter()
            res = sequential_assembly(p, 2000.0, "place")
            times[name] = time.perf_counter() - t0
        ratio = float(np.sum(res.disc_lengths())) / straight
        print(
            f"   whole place run, {name:4s}: {times[name]:7.2f} s, {res.status.value}, "
            f"{res.switches} grasps, ratio {ratio:.4f}"
        )
    print(f"   whole-run v0/lazy {times['v0'] / times['lazy']:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--sizes", type=int, nargs="*")
    args = parser.parse_args()
    sizes = args.sizes or ([7, 15] if args.quick else [7, 15, 30, 50])
    for n in sizes:
        compare(n)
        whole_run(n)


if __name__ == "__main__":
    main()

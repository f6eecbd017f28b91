"""Repair strategies A0-A3 (Section 2.5), applied once after each environment change.

* A0 forgets: G is reinitialised to the single vertex at the robot's position.
* A1 verifies every edge of G with Reach, removes the broken ones, and keeps
  the home component (the one of ``u_hat``, the vertex the robot reaches).
* A2 repairs actively: it applies T from home to every vertex of G, nearest to
  the robot first, before taking on a new task (Solve reconnects components;
  components that cannot be reconnected are removed, as in T step 3).
* A3 repairs on demand: nothing here; T does it when a path is needed.

All checks made here are charged to the ``repair`` category.
"""

from __future__ import annotations

from cellplan.adaptive.adapt import Adapter
from cellplan.adaptive.graph import BLOCKED, FREE, ExperienceGraph

STRATEGIES = ("A0", "A1", "A2", "A3")


def repair(adapter: Adapter, strategy: str) -> None:
    """Repair(G) for ``strategy`` if the environment changed since the last repair."""
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown repair strategy {strategy!r}; known: {', '.join(STRATEGIES)}")
    if adapter.repaired_gen == adapter.gen:
        return
    adapter.repaired_gen = adapter.gen
    if strategy == "A3":
        return
    with adapter.counter.charge("repair"):
        if strategy == "A0":
            forget(adapter)
        elif strategy == "A1":
            verify_all(adapter)
        else:
            repair_all(adapter)


def forget(adapter: Adapter) -> None:
    """A0: G <- ({u}, {})."""
    adapter.graph = ExperienceGraph(next_id=adapter.graph.next_id)  # ids are never reused
    adapter.u_hat = adapter.new_vertex(adapter.u)
    adapter.link_gen = adapter.gen


def verify_all(adapter: Adapter) -> None:
    """A1: verify every edge, then keep only the home component."""
    g = adapter.graph
    for a, b in list(g.usable_edges()):
        e = g.edge(a, b)
        if e is not None and e.status == FREE and e.gen == adapter.gen:
            continue
        ok = adapter.reach(g.vertices[a].q, g.vertices[b].q)
        g.set_edge(a, b, FREE if ok else BLOCKED, adapter.gen)
    adapter.ensure_u_hat()
    home = g.component(adapter.u_hat)
    for vid in list(g.vertices):
        if vid not in home:
            g.remove_vertex(vid)


def repair_all(adapter: Adapter) -> None:
    """A2: T(home, v) for every vertex v of G, nearest to the robot first."""
    g = adapter.graph
    adapter.ensure_u_hat()
    for vid in g.by_heuristic(adapter.u):
        if vid in g.vertices and vid != adapter.u_hat:
            adapter.trace(vid)

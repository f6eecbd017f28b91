"""The experience graph G = (V, E) of Section 2.

Vertices are subgoals: a configuration ``q`` plus the object-attached tag that
regenerates it (Section 2.3: the attached object's name or ``None`` for the
world, the tool-point pose relative to that object, and the IK branch). Edges
join subgoals that Reach connects; each edge has a status (``unknown``,
``free`` or ``blocked``) and the environment generation in which it was last
checked, so that T (Section 2.4) never re-verifies an edge already verified in
the current generation. Blocked edges are kept for inspection but are not part
of G for any search.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from cellplan.adaptive.space import FloatArray
from cellplan.geometry import wrap_angle

UNKNOWN = "unknown"
FREE = "free"
BLOCKED = "blocked"
EDGE_STATUSES = (UNKNOWN, FREE, BLOCKED)


@dataclass
class Vertex:
    """A subgoal: configuration and object-attached tag."""

    id: int
    q: FloatArray
    obj: str | None = None
    rel: tuple[float, float, float] = (0.0, 0.0, 0.0)
    branch: int | None = None


@dataclass
class Edge:
    """Status of the pair ``(a, b)`` with ``a < b`` and the generation it was checked in."""

    status: str = UNKNOWN
    gen: int = -1


def edge_key(a: int, b: int) -> tuple[int, int]:
    """The canonical key of an undirected edge."""
    return (a, b) if a < b else (b, a)


@dataclass
class ExperienceGraph:
    """Vertices and edges of G, with the searches Adapt needs."""

    vertices: dict[int, Vertex] = field(default_factory=dict)
    edges: dict[tuple[int, int], Edge] = field(default_factory=dict)
    next_id: int = 0
    periodic: tuple[bool, ...] = ()
    """Which coordinates wrap round (distances take the short way there); empty: none."""
    _adj: dict[int, set[int]] = field(default_factory=dict)
    _cache: tuple[list[int], FloatArray] | None = None

    # --- construction ----------------------------------------------------------------------

    def add_vertex(
        self,
        q: FloatArray,
        obj: str | None = None,
        rel: tuple[float, float, float] = (0.0, 0.0, 0.0),
        branch: int | None = None,
        vid: int | None = None,
    ) -> int:
        """Add a vertex and return its id."""
        if vid is None:
            vid = self.next_id
        if vid in self.vertices:
            raise ValueError(f"vertex {vid} exists")
        self.next_id = max(self.next_id, vid + 1)
        self.vertices[vid] = Vertex(vid, np.array(q, dtype=float), obj, tuple(rel), branch)  # type: ignore[arg-type]
        self._adj[vid] = set()
        self._cache = None
        return vid

    def set_q(self, vid: int, q: FloatArray) -> None:
        """Move a vertex; its usable edges become unknown (they must be re-verified)."""
        self.vertices[vid].q = np.array(q, dtype=float)
        for n in self._adj[vid]:
            e = self.edges[edge_key(vid, n)]
            if e.status == FREE:
                e.status, e.gen = UNKNOWN, -1
        self._cache = None

    def remove_vertex(self, vid: int) -> None:
        """Remove a vertex and every edge at it."""
        for n in list(self._adj[vid]):
            self.remove_edge(vid, n)
        for key in [k for k in self.edges if vid in k]:
            del self.edges[key]
        del self._adj[vid]
        del self.vertices[vid]
        self._cache = None

    def set_edge(self, a: int, b: int, status: str, gen: int) -> None:
        """Record the edge ``(a, b)``; a blocked edge leaves the searchable graph."""
        if a == b:
            return
        if status not in EDGE_STATUSES:
            raise ValueError(f"bad edge status {status!r}")
        self.edges[edge_key(a, b)] = Edge(status, gen)
        if status == BLOCKED:
            self._adj[a].discard(b)
            self._adj[b].discard(a)
        else:
            self._adj[a].add(b)
            self._adj[b].add(a)

    def remove_edge(self, a: int, b: int) -> None:
        """Delete the edge (T steps 1(b))."""
        self.edges.pop(edge_key(a, b), None)
        self._adj[a].discard(b)
        self._adj[b].discard(a)

    def edge(self, a: int, b: int) -> Edge | None:
        return self.edges.get(edge_key(a, b))

    # --- queries ---------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.vertices)

    def neighbours(self, vid: int) -> set[int]:
        return self._adj[vid]

    def usable_edges(self) -> list[tuple[int, int]]:
        """Edges that are part of G (not blocked)."""
        return [k for k, e in self.edges.items() if e.status != BLOCKED]

    def arrays(self) -> tuple[list[int], FloatArray]:
        """Vertex ids and their configurations as one ``(|V|, dim)`` array (cached)."""
        if self._cache is None:
            ids = sorted(self.vertices)
            Q = np.array([self.vertices[i].q for i in ids], dtype=float)
            self._cache = (ids, Q)
        return self._cache

    def difference(self, a: FloatArray, B: FloatArray) -> FloatArray:
        """``B - a``, the short way round on periodic coordinates."""
        D = np.asarray(B, dtype=float) - np.asarray(a, dtype=float)
        if any(self.periodic):
            mask = np.array(self.periodic, dtype=bool)
            D[..., mask] = wrap_angle(D[..., mask])
        return D

    def by_heuristic(self, q: FloatArray) -> list[int]:
        """Vertex ids nearest to ``q`` first: the heuristic h = h1 of Section 3."""
        ids, Q = self.arrays()
        if not ids:
            return []
        d = np.linalg.norm(self.difference(np.asarray(q, dtype=float), Q), axis=1)
        return [ids[k] for k in np.argsort(d, kind="stable")]

    def component(self, vid: int) -> set[int]:
        """The connected component of ``vid`` over usable edges."""
        seen = {vid}
        stack = [vid]
        while stack:
            v = stack.pop()
            for n in self._adj[v]:
                if n not in seen:
                    seen.add(n)
                    stack.append(n)
        return seen

    def remove_component(self, vid: int) -> None:
        """Remove the component of ``vid`` (T step 3)."""
        for v in self.component(vid):
            self.remove_vertex(v)

    def shortest_path(self, a: int, b: int) -> list[int] | None:
        """Shortest vertex sequence from ``a`` to ``b`` by configuration-space length (Dijkstra)."""
        if a not in self.vertices or b not in self.vertices:
            return None
        if a == b:
            return [a]
        dist = {a: 0.0}
        prev: dict[int, int] = {}
        heap = [(0.0, a)]
        while heap:
            d, v = heapq.heappop(heap)
            if v == b:
                break
            if d > dist[v]:
                continue
            qv = self.vertices[v].q
            for n in self._adj[v]:
                nd = d + float(np.linalg.norm(self.difference(qv, self.vertices[n].q)))
                if nd < dist.get(n, np.inf):
                    dist[n] = nd
                    prev[n] = v
                    heapq.heappush(heap, (nd, n))
        if b not in prev:
            return None
        path = [b]
        while path[-1] != a:
            path.append(prev[path[-1]])
        return path[::-1]

    def copy(self) -> ExperienceGraph:
        """A deep copy (vertices, edges and adjacency)."""
        g = ExperienceGraph(next_id=self.next_id, periodic=self.periodic)
        for v in self.vertices.values():
            g.add_vertex(v.q, v.obj, v.rel, v.branch, vid=v.id)
        for (a, b), e in self.edges.items():
            g.set_edge(a, b, e.status, e.gen)
        g.next_id = self.next_id
        return g

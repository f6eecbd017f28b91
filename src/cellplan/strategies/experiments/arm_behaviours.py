"""The behaviours of Section V measured through the validity interface (any workcell).

:mod:`cellplan.strategies.experiments.behaviours` measures the planar problems with the planar
geometry (shapely distances to region polygons, the wall's corners). The functions here
ask the workcell only what :class:`cellplan.validity.ValiditySpace` answers (the tool's
position, region tests per component, collision tests with a held part) and the solved
model (where each mode's fine motion is allowed), so they measure the same behaviours
on a 3-D arm (``strategies_ur5``, the first three joints of a UR5) without asking which
workcell they have:

* :func:`idle_near_pick_points` — while no request waits, the arm moves to wait near the
  sources (P1, P3): the tool ends nearer the places where a pick can start;
* :func:`component_by_destination` — with a request from a two-component source, the
  arm picks from the component nearer the request's destination (P6);
* :func:`detour_where_empty_fits` — the empty arm crosses a joint-space line (the gate)
  at configurations where the arm holding the part would collide, and carrying it takes
  a longer route (P1's narrow opening and detour).

Each follows the optimal actions without random transitions, as the paper's figures do
between mode changes, from starts drawn with the caller's generator among the live cells.
They follow them as the simulator does (:func:`execute`: the executor's lookahead and
LRTA* correction, FMP only where the exact region test allows it), not by plain rule (9):
on the UR5's grid the plain rule falls into a 2-cycle between two cells from most starts
of a W mode (docs/strategies.md, "Following a strategy at real states").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from cellplan.strategies.experiments.behaviours import (
    FOLLOW_LIMIT,
    fraction,
    idle_moves,
    live_starts,
)
from cellplan.strategies.policy.decisions import FMP, STAY
from cellplan.strategies.policy.execution import Executor
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.sim.simulate import region_test


def execute(
    strategy: Strategy, cell: Any, q: np.ndarray, mode: int, limit: int = FOLLOW_LIMIT
) -> tuple[np.ndarray, int | None]:
    """Drive the robot in ``mode`` from ``q`` as the simulator does, until it stays or
    performs an FMP (the exact region test of ``cell`` agreeing).

    A fresh :class:`~cellplan.strategies.policy.execution.Executor` per call (its corrections
    belong to this one path). Returns the ``(K, dim)`` configurations visited and the
    last action (``STAY`` or ``FMP``), or ``None`` when ``limit`` stages pass first.
    """
    test = region_test(strategy, cell, str(strategy.meta.get("regions", "contact")))
    executor = Executor(strategy, fmp_test=test)
    can_fmp = strategy.mdp.fmp_next[mode] >= 0
    path = [np.asarray(q, float)]
    for _ in range(limit):
        here = path[-1]
        allowed = bool(test(here[None], mode)[0]) if can_fmp else None
        u = executor.action(here, mode, allowed)
        if u == STAY or (u == FMP and allowed):
            return np.array(path), u
        if u == FMP:  # refused by the exact test: the executor plans again
            continue
        path.append(strategy.next_configuration(here, mode, u))
    return np.array(path), None


def _cell_centres(strategy: Strategy, cells: np.ndarray) -> np.ndarray:
    """``(K, dim)`` centres of the flat cell indices ``cells`` of the strategy's grid."""
    mdp = strategy.mdp
    idx = np.array(np.unravel_index(cells, tuple(mdp.shape))).T
    return np.asarray(mdp.lower + (idx + 0.5) * mdp.spacing)


def pick_points(strategy: Strategy, cell: Any, source: str | None = None) -> np.ndarray:
    """``(K, 3)`` (or ``(K, 2)`` in a planar cell) tool positions of the cells where a
    pick may start: the cells of the W modes (of ``source``, or of every source) whose
    fine motion the model allows (finite ``t_f``, Section III-C)."""
    mdp = strategy.mdp
    rows = [
        m for m, mode in enumerate(mdp.modes) if mode.kind == "W" and source in (None, mode.source)
    ]
    cells = np.flatnonzero(np.any(np.isfinite(mdp.tf[rows]), axis=0))
    return np.asarray(cell.tool_position(_cell_centres(strategy, cells)))


def drop_points(strategy: Strategy, cell: Any, destination: str) -> np.ndarray:
    """Tool positions of the cells where a delivery to ``destination`` may start."""
    mdp = strategy.mdp
    rows = [
        m
        for m, mode in enumerate(mdp.modes)
        if mode.kind == "C" and mode.destination == destination
    ]
    cells = np.flatnonzero(np.any(np.isfinite(mdp.tf[rows]), axis=0))
    return np.asarray(cell.tool_position(_cell_centres(strategy, cells)))


def _nearest(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Distance from each of ``points`` to the nearest of ``targets``."""
    d = np.linalg.norm(points[:, None, :] - targets[None, :, :], axis=-1)
    return np.asarray(d.min(axis=1))


def idle_near_pick_points(
    strategy: Strategy, cell: Any, rng: np.random.Generator, count: int = 40
) -> float:
    """Fraction of random starts from which the no-request policy stops with the tool
    nearer the sources (P1, P3 of Section V-A).

    "Near the sources" is measured in the workspace, from the tool's position to the
    nearest tool position of a cell where a pick may start (:func:`pick_points`). Starts
    already within one cell of where the policy stops are not counted (there is no motion
    to judge); a start from which the policy does not settle counts as a miss. NaN when
    every start is left out.
    """
    targets = pick_points(strategy, cell)
    hits = []
    for q, stop in idle_moves(strategy, lambda q, m: execute(strategy, cell, q, m), count, rng):
        if stop is None:  # a policy that does not settle is a miss
            hits.append(False)
            continue
        near = _nearest(np.asarray(cell.tool_position(np.stack([q, stop]))), targets)
        hits.append(bool(near[1] < near[0]))
    return fraction(hits)


def component_by_destination(
    strategy: Strategy,
    cell: Any,
    rng: np.random.Generator,
    count: int = 40,
    source: str = "S2",
) -> float:
    """Fraction of (random start, destination) pairs where the arm picks from the
    component of ``source`` nearer the request's destination (P6, Fig. 15).

    For each start drawn among the cells live in every W mode of (the first part of)
    ``source``, the W policy of each destination is followed to its pick. The component
    picked is the one whose region test (:meth:`in_region` per component) holds at the
    pick; a pick in both, or no pick, is a miss. A component is nearer a destination when
    the mean tool position of its pick cells is nearer the mean tool position of the
    destination's delivery cells. NaN when the source has one component.
    """
    mdp = strategy.mdp
    part = next(m.part for m in mdp.modes if m.kind == "W" and m.source == source)
    modes = [
        m
        for m, mode in enumerate(mdp.modes)
        if mode.kind == "W" and mode.source == source and mode.part == part
    ]
    components = len(cell.sources[source].components)
    if components < 2:
        return float("nan")
    picks = pick_points_by_component(strategy, cell, source)
    hits = []
    for q in live_starts(strategy, modes, count, rng):
        for m in modes:
            target = drop_points(strategy, cell, mdp.modes[m].destination).mean(axis=0)
            nearer = int(np.argmin([np.linalg.norm(p.mean(axis=0) - target) for p in picks]))
            path, u = execute(strategy, cell, q, m)
            if u != FMP:
                hits.append(False)
                continue
            inside = [
                bool(cell.in_region(path[-1][None], source, "contact", k, None)[0])
                for k in range(components)
            ]
            hits.append(inside[nearer] and sum(inside) == 1)
    return fraction(hits)


def pick_points_by_component(strategy: Strategy, cell: Any, source: str) -> list[np.ndarray]:
    """Per component of ``source``, the tool positions of the pick cells in it."""
    mdp = strategy.mdp
    rows = [m for m, mode in enumerate(mdp.modes) if mode.kind == "W" and mode.source == source]
    centres = _cell_centres(strategy, np.flatnonzero(np.any(np.isfinite(mdp.tf[rows]), axis=0)))
    out = []
    for k in range(len(cell.sources[source].components)):
        inside = cell.in_region(centres, source, "contact", k, None)
        out.append(np.asarray(cell.tool_position(centres[inside])))
    return out


@dataclass(frozen=True)
class Detour:
    """What :func:`detour_where_empty_fits` saw from one start."""

    shown: bool
    """The empty arm crossed where the loaded one would collide, and carrying took more
    stages than the empty approach."""
    empty_stages: int
    loaded_stages: int


def _cells_of(strategy: Strategy, q: np.ndarray) -> np.ndarray:
    """Flat indices of the grid cells holding the configurations ``q`` ``(K, dim)``."""
    mdp = strategy.mdp
    idx = np.floor((q - mdp.lower) / mdp.spacing).astype(np.int64)
    idx = np.where(mdp.periodic, idx % mdp.shape, np.clip(idx, 0, mdp.shape - 1))
    return np.asarray(np.ravel_multi_index(tuple(idx.T), tuple(mdp.shape)))


def _crossings(path: np.ndarray, axis: int, value: float) -> list[int]:
    """Indices ``k`` where the segment ``path[k] -> path[k + 1]`` crosses ``value`` on
    ``axis``."""
    return [
        k
        for k, (a, b) in enumerate(pairwise(path[:, axis]))
        if (a - value) * (b - value) <= 0 and a != b
    ]


def detour_where_empty_fits(
    strategy: Strategy,
    cell: Any,
    rng: np.random.Generator,
    count: int = 40,
    request: tuple[str, str, str] = ("P1", "S1", "D2"),
    gate: tuple[int, float] = (0, 0.0),
) -> list[Detour]:
    """From random starts on the destination's side of a gate, the empty arm's way to
    the source and the loaded arm's way back (P1, Fig. 9(b)-(d)).

    ``gate`` is ``(axis, value)``: a joint-space line between the source and the
    destination (the first joint's angle in radians, for the UR5 of
    ``strategies_ur5``). Each start is drawn among the cells live in the request's W mode
    on the side of the gate where the destination's delivery cells lie (by their mean).
    The empty arm follows the W policy to its pick, the loaded arm the C policy from there
    to the delivery. The behaviour is shown from that start when both paths cross the
    gate, the empty one at a step one of whose ends lies in a cell that is not free for
    the arm holding the part (the C mode's conservative bitmap, :func:`cellplan.cspace.
    free_bitmap` through the interface, the other sources as obstacles: the loaded arm
    has no certified room where the empty one went), and the loaded path takes more
    stages than the empty one. A start whose request is not finished counts as not
    shown.
    """
    mdp = strategy.mdp
    part, source, destination = request
    waiting = strategy.mode_index(f"{part},{source},{destination},W")
    carrying = strategy.mode_index(f"{part},{source},{destination},C")
    axis, value = gate
    drops = np.flatnonzero(np.isfinite(mdp.tf[carrying]))
    side = np.sign(_cell_centres(strategy, drops)[:, axis].mean() - value)
    out: list[Detour] = []
    for q in live_starts(strategy, [waiting], 4 * count, rng):
        if np.sign(q[axis] - value) != side:
            continue
        empty, u = execute(strategy, cell, q, waiting)
        loaded, v = execute(strategy, cell, empty[-1], carrying) if u == FMP else (empty[-1:], None)
        if u != FMP or v != FMP:
            out.append(Detour(False, len(empty) - 1, len(loaded) - 1))
        else:
            loaded_free = mdp.free[mdp.vcls[carrying]]
            through = [
                not loaded_free[_cells_of(strategy, empty[k : k + 2])].all()
                for k in _crossings(empty, axis, value)
            ]
            shown = (
                any(through) and bool(_crossings(loaded, axis, value)) and len(loaded) > len(empty)
            )
            out.append(Detour(shown, len(empty) - 1, len(loaded) - 1))
        if len(out) == count:
            break
    return out


def detour_fraction(
    strategy: Strategy,
    cell: Any,
    rng: np.random.Generator,
    count: int = 40,
    request: Sequence[str] = ("P1", "S1", "D2"),
    gate: tuple[int, float] = (0, 0.0),
) -> float:
    """Fraction of starts of :func:`detour_where_empty_fits` showing the behaviour; NaN
    when no start lies on the destination's side."""
    p, s, d = request
    seen = detour_where_empty_fits(strategy, cell, rng, count, (p, s, d), gate)
    return fraction([x.shown for x in seen])

"""The behaviours Section V of the strategies paper reports, measured on a solved strategy.

The paper shows its results as pictures of sample paths (Figs. 9-15) and states what they
show in words. Each function here turns one of those sentences into a number measured
from starts drawn at random (with the caller's generator) among the live cells of the
strategy, so that the experiment :mod:`cellplan.strategies.experiments.paper` can put an
interval on it over seeds and the behaviour tests can assert it:

* :func:`idle_near_sources` — while no request waits, the robot moves to wait near the
  sources (P1, P3);
* :func:`opening_and_detour` — it passes a narrow opening when empty and detours through
  the wide passage when carrying (P1);
* :func:`nearer_component` — it delivers to the nearer component of a split destination
  (P2);
* :func:`turns_to_changed_destination` — its first move after the destination changes
  heads toward the new destination (P4);
* :func:`component_for_destination` — with a request from a two-component source, the
  destination decides which component it picks from (P6);
* :func:`move_clearances` — how far from obstacles a simulated run's moves land (noisy
  motion, Section VI-4).

Each follows the optimal actions without random transitions (:func:`follow`), as the
paper's figures do between mode changes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from itertools import pairwise
from typing import Any

import numpy as np
from shapely.geometry import Point

from cellplan.strategies.policy.decisions import FMP, STAY, Action
from cellplan.strategies.policy.strategy import Strategy

FOLLOW_LIMIT = 400
"""Stages :func:`follow` takes at most before giving up (no policy here needs 200)."""


def follow(
    strategy: Strategy, q: np.ndarray, mode: int, limit: int = FOLLOW_LIMIT
) -> tuple[np.ndarray, int | None]:
    """Follow the optimal actions in ``mode`` from ``q`` until they stay or perform an FMP.

    Returns the ``(K, dim)`` configurations visited and the last action (``STAY`` or
    ``FMP``), or ``None`` when ``limit`` stages pass first.
    """
    path = [np.asarray(q, float)]
    for _ in range(limit):
        u = strategy.action_code(path[-1], mode)
        if u in (FMP, STAY):
            return np.array(path), u
        path.append(strategy.next_configuration(path[-1], mode, u))
    return np.array(path), None


def fraction(hits: Sequence[bool]) -> float:
    """The fraction of ``hits`` that hold: a behaviour's measure over the starts judged
    (NaN when none was, so that the interval over seeds drops it)."""
    return float(np.mean(hits)) if len(hits) else float("nan")


def live_starts(
    strategy: Strategy, modes: Sequence[int], count: int, rng: np.random.Generator
) -> np.ndarray:
    """``(count, dim)`` centres of cells drawn without replacement among the cells live in
    every one of ``modes`` (fewer when there are fewer such cells)."""
    mdp = strategy.mdp
    live = np.logical_and.reduce([mdp.live[m] for m in modes])
    cells = np.flatnonzero(live)
    chosen = rng.choice(cells, min(count, len(cells)), replace=False)
    idx = np.array(np.unravel_index(chosen, tuple(mdp.shape))).T
    return np.asarray(mdp.lower + (idx + 0.5) * mdp.spacing)


Drive = Callable[[np.ndarray, int], tuple[np.ndarray, "int | None"]]
"""Follows a mode's policy from a configuration: ``(path, last action)`` as :func:`follow`."""


def idle_moves(
    strategy: Strategy, drive: Drive, count: int, rng: np.random.Generator
) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """``(start, stop)`` for each random start from which the no-request policy, followed
    by ``drive``, moves: starts it stops within one cell of are left out (there is no
    motion to judge), and ``stop`` is None where it does not settle within the limit (the
    caller says whether that is a miss)."""
    out: list[tuple[np.ndarray, np.ndarray | None]] = []
    for q in live_starts(strategy, [0], count, rng):
        path, u = drive(q, 0)
        if u is None:
            out.append((q, None))
        elif u == STAY and not np.all(np.abs(path[-1] - q) <= strategy.mdp.spacing):
            out.append((q, path[-1]))
    return out


def _point(cell: Any, q: np.ndarray) -> np.ndarray:
    """The robot's reference point in the plane (its tool point for arms)."""
    return np.asarray(cell.robot.tool_pose(np.asarray(q, float)[None])[0, :2])


def _distance(cell: Any, q: np.ndarray, geometries: Sequence[Any]) -> float:
    p = Point(*_point(cell, q))
    return float(min(g.distance(p) for g in geometries))


def idle_near_sources(
    strategy: Strategy, cell: Any, rng: np.random.Generator, count: int = 40
) -> float:
    """Fraction of random starts from which the no-request policy stops nearer the sources.

    Distances are from the robot's reference point to the nearest source component.
    Starts already within one cell of where the policy stops are not counted (there is
    no motion to judge). NaN when every start is.
    """
    sources = [g for r in cell.sources.values() for g in r.geometries]
    moves = idle_moves(strategy, lambda q, m: follow(strategy, q, m), count, rng)
    return fraction(
        [
            _distance(cell, stop, sources) < _distance(cell, q, sources)
            for q, stop in moves
            if stop is not None  # not settling within the limit is not judged here
        ]
    )


def _crossing(path: np.ndarray, y: float) -> float | None:
    """x where the path first crosses the horizontal line at ``y``."""
    for a, b in pairwise(path):
        if (a[1] - y) * (b[1] - y) <= 0 and a[1] != b[1]:
            return float(a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0]))
    return None


def opening_and_detour(
    strategy: Strategy,
    cell: Any,
    rng: np.random.Generator,
    count: int = 40,
    walls: tuple[str, str] = ("wall_left", "wall_right"),
) -> float:
    """Fraction of random starts above the wall from which the empty robot goes down
    through the narrow opening to its source and then, carrying, back up through the wide
    passage to its destination (problem 1).

    The wall is the two obstacles named in ``walls`` (left, right): the narrow opening is
    the gap between them, the wide passage the gap right of the right one, and the line
    crossed is the wall's middle. Each start gets a request (part, the left source, the
    left destination) with the part drawn at random. NaN when no start is above the wall.
    """
    left = cell.obstacle_geometries[walls[0]].bounds  # (xmin, ymin, xmax, ymax)
    right = cell.obstacle_geometries[walls[1]].bounds
    y_line = 0.5 * (left[1] + left[3])
    narrow = (left[2], right[0])
    wide = right[2]
    parts = list(dict.fromkeys(m.part for m in strategy.modes[1:]))
    source = next(m.source for m in strategy.modes[1:])
    dest = next(m.destination for m in strategy.modes[1:])
    hits = []
    for q in live_starts(strategy, [0], 4 * count, rng):
        if _point(cell, q)[1] <= left[3]:
            continue
        part = parts[int(rng.integers(len(parts)))]
        waiting = strategy.mode_index(f"{part},{source},{dest},W")
        empty, u = follow(strategy, q, waiting)
        if u != FMP:
            hits.append(False)
        else:
            carrying = strategy.mode_index(f"{part},{source},{dest},C")
            loaded, v = follow(strategy, empty[-1], carrying)
            x_down, x_up = _crossing(empty, y_line), _crossing(loaded, y_line)
            hits.append(
                v == FMP
                and x_down is not None
                and narrow[0] < x_down < narrow[1]
                and x_up is not None
                and x_up > wide
            )
        if len(hits) == count:
            break
    return fraction(hits)


def nearer_component(
    strategy: Strategy,
    cell: Any,
    rng: np.random.Generator,
    count: int = 40,
    destination: str = "D1",
) -> float:
    """Fraction of random carrying starts from which the robot delivers to the component
    of ``destination`` nearer its start (straight-line distance from its reference point).

    Each start carries a part from a source drawn at random among the requests to
    ``destination``. Starts from which no delivery happens count as misses.
    """
    comps = cell.region(destination).geometries
    modes = [
        i for i, m in enumerate(strategy.modes) if m.kind == "C" and m.destination == destination
    ]
    hits = []
    for q in live_starts(strategy, modes, count, rng):
        mode = modes[int(rng.integers(len(modes)))]
        path, u = follow(strategy, q, mode)
        if u != FMP:
            hits.append(False)
            continue
        part = strategy.modes[mode].part
        reached = [
            bool(cell.in_region(path[-1][None], destination, "contact", k, part)[0])
            for k in range(len(comps))
        ]
        p = Point(*_point(cell, q))
        nearest = int(np.argmin([g.distance(p) for g in comps]))
        hits.append(reached[nearest] and sum(reached) == 1)
    return fraction(hits)


def turns_to_changed_destination(
    strategy: Strategy,
    cell: Any,
    rng: np.random.Generator,
    count: int = 40,
    pair: tuple[str, str] = ("D1", "D3"),
) -> float:
    """Fraction of (random carrying start, change) pairs where the first move after the
    destination changes (between the two of ``pair``, either way) heads toward the new
    destination (positive component toward its nearest point) and differs from the move
    toward the old one (problem 4).

    The part and source are those of the first request to ``pair[0]``. Starts where
    either policy stays or performs an FMP at once are not counted.
    """
    first = next(m for m in strategy.modes if m.kind == "C" and m.destination == pair[0])
    modes = [strategy.mode_index(f"{first.part},{first.source},{d},C") for d in pair]
    targets = [cell.region(d).geometries for d in pair]
    hits = []
    for q in live_starts(strategy, modes, count, rng):
        actions = [strategy.action(q, m) for m in modes]
        moves = [a for a in actions if isinstance(a, Action) and a.kind == "move"]
        if len(moves) < len(actions):
            continue
        steps = [strategy.move_vector(q, m, a) for m, a in zip(modes, moves, strict=True)]
        here = _point(cell, q)
        for new, old in ((1, 0), (0, 1)):
            p = Point(*here)
            goal = min(targets[new], key=lambda g: g.distance(p))
            nearest = np.asarray(goal.exterior.interpolate(goal.exterior.project(p)).coords[0])
            moved = _point(cell, q + steps[new]) - here
            hits.append(
                float(moved @ (nearest - here)) > 0 and not np.allclose(steps[new], steps[old])
            )
    return fraction(hits)


def component_for_destination(
    strategy: Strategy,
    cell: Any,
    rng: np.random.Generator,
    count: int = 40,
    source: str = "S1",
    destinations: tuple[str, str] = ("D1", "D2"),
) -> float:
    """How much more often the arm picks from the upper component of ``source`` when the
    destination is the upper one of ``destinations`` than when it is the lower one
    (problem 6, Fig. 15): the fraction of random starts picking the upper component with
    ``destinations[0]`` minus that with ``destinations[1]``, over starts from which both
    requests are picked. The component picked is the one nearest the tool at the FMP.
    NaN when no start picks both.
    """
    comps = cell.region(source).geometries
    upper = int(np.argmax([g.bounds[1] for g in comps]))
    part = next(m.part for m in strategy.modes[1:] if m.source == source)
    modes = [strategy.mode_index(f"{part},{source},{d},W") for d in destinations]
    picks: list[list[bool]] = [[], []]
    for q in live_starts(strategy, modes, count, rng):
        ends = [follow(strategy, q, m) for m in modes]
        if any(u != FMP for _, u in ends):
            continue
        for k, (path, _) in enumerate(ends):
            p = Point(*_point(cell, path[-1]))
            picks[k].append(int(np.argmin([g.distance(p) for g in comps])) == upper)
    if not picks[0]:
        return float("nan")
    return float(np.mean(picks[0]) - np.mean(picks[1]))


def move_clearances(strategy: Strategy, cell: Any, sim: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(configurations, clearances)`` after every move of a simulated run.

    The clearance (workcell units, :meth:`~cellplan.workcell.Workcell.clearance`) is that
    of the robot and what it carries to the obstacles of its mode: the other sources
    while a request is served, every source in NR. Used to show that with noisy motion
    (Section VI-4) the strategy keeps away from obstacles in narrow passages.
    """
    mdp = strategy.mdp
    moved = np.flatnonzero(sim.actions >= 0)
    out = np.empty(len(moved))
    for m in np.unique(sim.modes[moved]):
        sel = sim.modes[moved] == m
        mode = mdp.modes[int(m)]
        carrying = mode.part if mode.kind in ("C", "X") else None
        avoid = "all" if mode.kind == "NR" else cell.sources_except(mode.source)
        out[sel] = cell.clearance(sim.q[moved[sel] + 1], carrying, avoid)
    return sim.q[moved + 1], out

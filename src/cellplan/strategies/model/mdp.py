"""The layered MDP of the strategies paper (Sections III-IV) on a C-space grid.

State space ``X = C x M`` (Section III-A): the modes are NR plus ``<p,s,d,W>`` and
``<p,s,d,C>`` for every requestable (part, source, destination), ``2R + 1`` in all, plus
with failure modes (Section VI-3) the ``<p,s,d,X:R>`` modes of a rejected part carried to
a reject region ``R`` (:func:`_failure_outcomes`).
Each mode is a *layer*: a copy of the grid restricted to that mode's free space,
equations (1)-(3) (:func:`cellplan.cspace.free_bitmap` with ``avoid_sources``):

* NR: the robot alone, every source an obstacle (3);
* ``<p,s,d,W>``: the robot alone, the sources other than ``s`` obstacles (1);
* ``<p,s,d,C>``: robot plus part ``p``, the sources other than ``s`` obstacles (2).

Transitions (Section III-B): from NR a request arrives with probability ``P`` per stage
and is ``(p,s,d)`` with probability ``pi_r`` (type 1); in ``<p,s,d,C>`` the destination
changes to another of the same part and source (type 2); in ``<p,s,d,W>`` the source
changes to another of the same part and destination (type 3). FMP moves
``<p,s,d,W> -> <p,s,d,C>`` inside source ``s`` and ``<p,s,d,C> -> NR`` inside destination
``d`` with probability one. The loss is equation (7).

A layer's *live* states are the free cells from which its request can be finished
(computed by :func:`cellplan.strategies.model.domain.live_layer`); the MDP is defined on live
states only, which keeps it unichain-friendly and lets the input checks name a request
that can never be served.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from cellplan.cspace import Grid as CSpaceGrid
from cellplan.cspace import free_bitmap, region_bitmap
from cellplan.errors import Problem, ScenarioError
from cellplan.strategies.model.actions import ActionSet, action_set
from cellplan.strategies.model.bundles import Grid, Outcomes
from cellplan.strategies.model.layered import (
    NR,
    Failure,
    Failures,
    Geometry,
    LayeredMDP,
    Mode,
    MoveClasses,
)
from cellplan.strategies.model.live import compute_live, live_problems, start_problems
from cellplan.strategies.model.motion import valid_moves
from cellplan.strategies.model.spec import (
    Build,
    ModeTables,
    Motions,
    ProblemSpec,
    Process,
    compiled,
)
from cellplan.strategies.model.tables import corner_tables, stencil_tables, table_rows

#: Re-exported: the model's types and checks are reached through this module.
__all__ = [
    "NR",
    "Failure",
    "Failures",
    "Geometry",
    "LayeredMDP",
    "Mode",
    "MoveClasses",
    "assemble",
    "build_model",
    "compute_live",
    "finish_model",
    "live_problems",
    "start_problems",
]


def request_fields(
    geometry: Geometry, requests: Sequence[tuple[str, str, str, float]]
) -> np.ndarray:
    """``(2R + 1, N)``: the fine-motion time ``t_f`` of the FMP of NR (none), of each W
    mode (the pick) and of each C mode (the delivery), ``inf`` where it is not allowed.

    A pick needs a configuration in the source region that is free both while waiting
    and while carrying the part; a delivery one in the destination region free both
    while carrying and in NR (equations (1)-(3)).
    """
    R = len(requests)
    tf = np.full((1 + 2 * R, geometry.free_nr.size), np.inf)
    for r, (p, s, d, _) in enumerate(requests):
        pick = (
            geometry.pick[(p, s)].ravel()
            & geometry.free_w[s].ravel()
            & geometry.free_c[(p, s)].ravel()
        )
        tf[1 + r, pick] = geometry.tf_pick[(p, s)].ravel()[pick]
        drop = (
            geometry.drop[(p, d)].ravel()
            & geometry.free_c[(p, s)].ravel()
            & geometry.free_nr.ravel()
        )
        tf[1 + R + r, drop] = geometry.tf_drop[(p, d)].ravel()[drop]
    return tf


def grid_box(
    shape: Sequence[int],
    lower: Sequence[float] | np.ndarray,
    upper: Sequence[float] | np.ndarray,
    periodic: Sequence[bool],
) -> Grid:
    """The kernels' grid bundle of a box split into ``shape`` cells per axis."""
    shape_a = np.asarray(shape, np.int64)
    lower_a = np.asarray(lower, float)
    upper_a = np.asarray(upper, float)
    return Grid(
        shape_a, lower_a, upper_a, (upper_a - lower_a) / shape_a, np.asarray(periodic, bool)
    )


def assemble(
    grid: Grid,
    requests: Sequence[tuple[str, str, str, float]],
    geometry: Geometry,
    motions: Motions,
    process: Process,
    failures: Failures | None = None,
) -> LayeredMDP:
    """Build the layered MDP from bitmaps (the part that does not need a workcell).

    Layer order: NR, then ``W`` of each request, then ``C`` of each request, then the
    ``X`` modes of failures that reject a part (one per request, reject region and what
    follows the rejection). ``motions`` are the action sets while empty and while carrying
    each part, ``process`` the per-stage probabilities of Section III-B.
    """
    R = len(requests)
    modes = [Mode(NR)]
    modes += [Mode("W", p, s, d) for p, s, d, _ in requests]
    modes += [Mode("C", p, s, d) for p, s, d, _ in requests]
    # X modes (Section VI-3): carrying a rejected part of request r to a reject region.
    x_index: dict[tuple[int, str, str], int] = {}
    if failures is not None:
        for r in range(R):
            for f in (failures.pick[r], failures.drop[r]):
                if f is not None and f.reject and (r, f.reject, f.after) not in x_index:
                    x_index[(r, f.reject, f.after)] = len(modes)
                    p, s, d, _ = requests[r]
                    modes.append(Mode("X", p, s, d, f.reject, f.after))
    M = len(modes)
    classes = MoveClasses()
    vcls = np.zeros(M, np.int64)
    cost = np.full(M, process.stage_time)
    cost[0] = 0.0  # equation (7): no loss while no request waits
    fmp_next = np.full(M, -1, np.int64)
    tf = np.full((M, int(np.prod(grid.shape))), np.inf)
    vcls[0] = classes.add(geometry.free_nr.ravel(), motions.empty)
    for r, (p, s, _d, _) in enumerate(requests):
        w, c = 1 + r, 1 + R + r
        vcls[w] = classes.add(geometry.free_w[s].ravel(), motions.empty)
        vcls[c] = classes.add(geometry.free_c[(p, s)].ravel(), motions.carrying[p])
        fmp_next[w] = c
        fmp_next[c] = 0
    tf[: 1 + 2 * R] = request_fields(geometry, requests)
    for (r, reject, _after), x in x_index.items():
        assert failures is not None
        p, s, d, _ = requests[r]
        vcls[x] = classes.add(geometry.free_c[(p, s)].ravel(), motions.carrying[p])
        into = geometry.free_c[(p, s)].ravel() & failures.reject_drop[(p, reject)].ravel()
        tf[x, into] = failures.tf_reject[reject].ravel()[into]
        fmp_next[x] = 1 + r
    probs = np.array([q for *_, q in requests], float)
    outcomes = None
    if failures is not None:
        outcomes = _failure_outcomes(requests, probs, x_index, failures)
        for x in x_index.values():
            fmp_next[x] = outcomes.layer[outcomes.ptr[x]]
    branches = section_v_branches(requests, process, list(x_index.values()))
    tables = ModeTables(modes, classes, vcls, cost, fmp_next, tf, branches, outcomes)
    return finish_model(grid, tables, motions.empty, process, probs)


def section_v_branches(
    requests: Sequence[tuple[str, str, str, float]], process: Process, x_modes: Sequence[int]
) -> tuple[list[int], list[int], list[float]]:
    """The branches ``(ptr, layer, prob)`` of Section III-B: arrivals in NR (type 1),
    source changes in W (type 3) and destination changes in C (type 2), each to the
    requests of the same part and destination (source) with equal probability; an X mode
    (Section VI-3) stays itself."""
    R = len(requests)
    arrival = process.arrival
    ptr, layers, bprob = [0], [0], [1.0 - arrival]
    for r, (*_, q) in enumerate(requests):
        if arrival * q > 0.0:
            layers.append(1 + r)
            bprob.append(arrival * q)
    ptr.append(len(layers))
    for kind, change in (("W", process.source_change), ("C", process.destination_change)):
        first = 1 if kind == "W" else 1 + R
        for r, (p, s, d, _) in enumerate(requests):
            others = []
            if change > 0.0:
                others = [
                    i
                    for i, (p2, s2, d2, _) in enumerate(requests)
                    if p2 == p and (d2 == d and s2 != s if kind == "W" else s2 == s and d2 != d)
                ]
            layers.append(first + r)
            bprob.append(1.0 - (change if others else 0.0))
            for i in others:
                layers.append(first + i)
                bprob.append(change / len(others))
            ptr.append(len(layers))
    for x in x_modes:
        layers.append(x)
        bprob.append(1.0)
        ptr.append(len(layers))
    return ptr, layers, bprob


def finish_model(
    grid: Grid,
    tables: ModeTables,
    empty: ActionSet,
    process: Process,
    request_prob: np.ndarray,
) -> LayeredMDP:
    """The move tables (valid moves, stencils) and the live states of a layered MDP whose
    modes, classes, FMP options and branches are given (``tables``); ``empty``, the
    action set while empty, gives the heading axis and the noisy landings' probabilities."""
    shape_a, lower_a, upper_a, spacing, periodic_a = grid
    ncell = int(np.prod(shape_a))
    cls_free, cls_actions = tables.classes.free, tables.classes.actions
    K = len(cls_free)
    A = max(a.disp.shape[0] for a in cls_actions)
    disp = np.zeros((K, A, len(shape_a)))
    nact = np.zeros(K, np.int64)
    for k, acts in enumerate(cls_actions):
        disp[k, : acts.disp.shape[0]] = acts.disp
        nact[k] = acts.commanded
    heading_axis, noise_prob = empty.heading_axis, np.asarray(empty.noise_prob, float)
    J = len(noise_prob)
    free = np.stack(cls_free).astype(np.bool_)
    valid = np.zeros((K, ncell), np.int64)
    for k in range(K):
        na = int(nact[k])
        if J == 1:
            valid[k] = valid_moves(free[k], disp[k, :na], heading_axis, grid)
            continue
        # A noisy move is allowed where every outcome's swept motion is free (Section VI-4).
        valid[k] = (1 << na) - 1
        for j in range(J):
            rows = na + np.arange(na) * J + j
            valid[k] &= valid_moves(
                free[k], np.ascontiguousarray(disp[k, rows]), heading_axis, grid
            )
    offs, fr = stencil_tables(disp, heading_axis, shape_a, lower_a, spacing)
    coff, cw, interior = corner_tables(offs, fr, table_rows(nact, J), shape_a)
    ptr, layers, bprob = tables.branches
    mdp = LayeredMDP(
        shape=shape_a,
        lower=lower_a,
        upper=upper_a,
        spacing=spacing,
        periodic=periodic_a,
        modes=tables.modes,
        cost=tables.cost,
        vcls=tables.vcls,
        fmp_next=tables.fmp_next,
        tf=tables.tf,
        branch_ptr=np.asarray(ptr, np.int64),
        branch_layer=np.asarray(layers, np.int64),
        branch_prob=np.asarray(bprob, float),
        free=free,
        disp=disp,
        nact=nact,
        heading_axis=heading_axis,
        valid=valid,
        offs=offs,
        fr=fr,
        coff=coff,
        cw=cw,
        interior=interior,
        live=free[tables.vcls].copy(),
        stage_time=process.stage_time,
        arrival=process.arrival,
        request_prob=request_prob,
        labels=[a.labels for a in cls_actions],
        outcomes=tables.outcomes,
        noise_prob=noise_prob,
        opt_ptr=tables.opt_ptr,
    )
    compute_live(mdp)
    return mdp


def _failure_outcomes(
    requests: Sequence[tuple[str, str, str, float]],
    probs: np.ndarray,
    x_index: Mapping[tuple[int, str, str], int],
    failures: Failures,
) -> Outcomes:
    """The FMP outcomes of every mode with failures (Section VI-3), in mode order.

    A failure with probability ``f`` splits the FMP's certain outcome: success with
    ``1 - f``, and with ``f`` either the same state again at the rework cost (retry in
    place) or the X mode of the rejected part. An X mode's FMP (the drop in the reject
    region) leads to the request's W mode (fetch a replacement), or to the W modes of the
    requests for the same part and destination, by their request probabilities.
    """
    R = len(requests)
    ptr = [0]
    layer: list[int] = []
    prob: list[float] = []
    cost: list[float] = []

    def add(succ: int, m: int, r: int, f: Failure | None) -> None:
        if f is None or f.probability <= 0.0:
            layer.append(succ)
            prob.append(1.0)
            cost.append(0.0)
            return
        layer.extend([succ, x_index[(r, f.reject, f.after)] if f.reject else m])
        prob.extend([1.0 - f.probability, f.probability])
        cost.extend([0.0, 0.0 if f.reject else f.rework])

    ptr.append(0)  # NR: no FMP
    for r in range(R):
        add(1 + R + r, 1 + r, r, failures.pick[r])
        ptr.append(len(layer))
    for r in range(R):
        add(0, 1 + R + r, r, failures.drop[r])
        ptr.append(len(layer))
    for r, _, after in x_index:
        p, _, d, _ = requests[r]
        same = [i for i, (p2, _, d2, _) in enumerate(requests) if p2 == p and d2 == d]
        weights = probs[same]
        if after == "request" and weights.sum() > 0:
            for i, w in zip(same, weights / weights.sum(), strict=True):
                if w > 0:
                    layer.append(1 + i)
                    prob.append(float(w))
                    cost.append(0.0)
        else:
            layer.append(1 + r)
            prob.append(1.0)
            cost.append(0.0)
        ptr.append(len(layer))
    return Outcomes(
        np.asarray(ptr, np.int64),
        np.asarray(layer, np.int64),
        np.asarray(prob, float),
        np.asarray(cost, float),
    )


def fine_motion_field(spec: Any, tool_xy: np.ndarray) -> np.ndarray:
    """``t_f`` per cell from a :class:`~cellplan.strategies.section.FineMotionSpec` (Fig. 5)."""
    time = float(spec.time)
    point = spec.point
    rate = float(spec.rate)
    out = np.full(len(tool_xy), time)
    if point is not None and rate > 0:
        out += rate * np.hypot(tool_xy[:, 0] - point[0], tool_xy[:, 1] - point[1])
    return out


def build_model(
    problem: Any,
    cell: Any,
    cells: Sequence[int] | None = None,
    start: Sequence[float] | np.ndarray | None = None,
) -> LayeredMDP:
    """The layered MDP of a scenario with a ``strategy:`` section.

    ``problem`` is the scenario or its compiled section (a
    :class:`~cellplan.strategies.model.spec.ProblemSpec`, :func:`~.spec.compiled`: a
    caller that compiled it already hands it on); the model is the Section V one
    unless an active variant of the specification assembles its own or extends it
    (:class:`~cellplan.strategies.variants.base.Variant`). With ``start`` (the robot's
    start, as the planner passes it), also checks that a run can begin there
    (:func:`start_problems`). ``cellplan validate`` runs this same function, so it refuses
    exactly what ``cellplan solve`` refuses before solving.

    Raises
    ------
    ScenarioError
        When a request can never be served (a region no configuration reaches, a part
        that cannot be carried anywhere, an unreachable destination), one problem each,
        or the start is outside the strategy's domain.
    """
    spec = compiled(problem)
    scenario = spec.scenario
    robot = cell.robot
    shape = grid_shape(scenario, cell, cells)
    if len(shape) != robot.dim:
        raise ScenarioError([Problem("strategy.cells", f"needs {robot.dim} entries")])
    build = _build(spec, scenario, cell, CSpaceGrid.for_robot(robot, shape))
    mdp = None
    for variant in spec.variants:
        mdp = variant.assemble(build)
        if mdp is not None:
            break
    if mdp is None:
        mdp = section_v_model(build)
    for variant in spec.variants:
        mdp = variant.extend(build, mdp)
    mdp.variants = spec.variants
    problems = None
    for variant in spec.variants:
        problems = variant.build_problems(build, mdp)
        if problems is not None:
            break
    if problems is None:
        problems = live_problems(mdp)
    return _checked(mdp, problems, start, cell, _obstacles(spec, cell, None))


def _obstacles(spec: ProblemSpec, cell: Any, source: str | None) -> list[str]:
    """The sources that are obstacles while the robot waits at ``source`` (equations
    (1)-(3)), less those an active variant exempts (a region on a belt)."""
    exempt: set[str] = set()
    for variant in spec.variants:
        exempt |= variant.obstacle_exempt(spec.section)
    return [s for s in cell.sources_except(source) if s not in exempt]


def _build(spec: ProblemSpec, scenario: Any, cell: Any, grid: Any) -> Build:
    """The bitmaps of equations (1)-(3), the regions and the action sets of ``spec``."""
    sec, requests = spec.section, spec.requests
    parts, sources = spec.parts, spec.sources
    free_nr = free_bitmap(cell, grid, None, _obstacles(spec, cell, None))
    free_w = {s: free_bitmap(cell, grid, None, _obstacles(spec, cell, s)) for s in sources}
    free_c = {
        (p, s): free_bitmap(cell, grid, p, _obstacles(spec, cell, s))
        for p in parts
        for s in sources
        if any(r[0] == p and r[1] == s for r in requests)
    }
    tool = cell.tool_position(grid.points())[:, :2]

    def tf_of(region: str) -> np.ndarray:
        return fine_motion_field(sec.fine_motion_regions.get(region, sec.fine_motion), tool)

    # Regions written twice (a YAML alias, a copied block) are tested once: each test
    # poses the robot at every grid cell.
    tested: dict[tuple[str, str | None], np.ndarray] = {}

    def in_region(name: str, carrying: str | None) -> np.ndarray:
        key = ((scenario.sources | scenario.destinations)[name].model_dump_json(), carrying)
        if key not in tested:
            tested[key] = region_bitmap(cell, grid, name, sec.regions, None, carrying)
        return tested[key]

    pick = {(p, s): in_region(s, None) for p, s in free_c}
    tf_pick = {(p, s): tf_of(s) for p, s in free_c}
    drop: dict[tuple[str, str], np.ndarray] = {}
    tf_drop: dict[tuple[str, str], np.ndarray] = {}
    for p, _, d, _ in requests:
        if (p, d) not in drop:
            drop[(p, d)] = in_region(d, p)
            tf_drop[(p, d)] = tf_of(d)
    geometry = Geometry(free_nr, free_w, free_c, pick, drop, tf_pick, tf_drop)
    empty, carrying = action_sets(spec, cell.robot, parts)
    return Build(spec, scenario, cell, grid, geometry, empty, carrying, in_region, tf_of)


def section_v_model(build: Build, failures: Failures | None = None) -> LayeredMDP:
    """The model of Sections III-IV (:func:`assemble`) on ``build``'s pieces; with
    ``failures``, the X modes and FMP outcomes of Section VI-3 as well."""
    spec, grid = build.spec, build.grid
    return assemble(
        grid_box(grid.shape, grid.lower, grid.upper, grid.periodic),
        spec.requests,
        build.geometry,
        Motions(build.empty, build.carrying),
        spec.process,
        failures,
    )


def _checked(
    mdp: LayeredMDP,
    problems: list[Problem],
    start: Sequence[float] | np.ndarray | None,
    cell: Any = None,
    sources: Sequence[str] = (),
) -> LayeredMDP:
    """``mdp``, unless a request can never be served or the start is outside its domain
    (naming the ``sources`` the empty robot touches there, by ``cell``'s exact test)."""
    if not problems and start is not None:
        problems = start_problems(mdp, start)
        if problems and cell is not None:
            q = np.asarray(start, float)[None, :]
            # A start clear of the fixed obstacles but touching a source (an obstacle
            # while the robot is empty) gets a line naming the source.
            clear = not bool(cell.collides(q, None, [])[0])
            blocking = [s for s in sources if clear and bool(cell.collides(q, None, [s])[0])]
            problems = start_problems(mdp, start, blocking)
    if problems:
        raise ScenarioError(problems)
    return mdp


def grid_shape(scenario: Any, cell: Any, cells: Sequence[int] | None = None) -> tuple[int, ...]:
    """Cells per axis of the model: ``cells``, else ``strategy.cells``, else
    ``cspace.cells``, else the robot kind's default."""
    sec = scenario.strategy
    return tuple(
        int(n) for n in (cells or sec.cells or scenario.cspace.cells or cell.default_cells)
    )


def action_sets(
    spec: ProblemSpec, robot: Any, parts: Sequence[str]
) -> tuple[ActionSet, dict[str, ActionSet]]:
    """The motion actions while empty, and while carrying each part (speed factor), as
    each active variant changes them (noisy landings, Section VI-4)."""
    sec = spec.section
    kind = robot.kind if robot.kind in ("point", "translating", "rotating") else "arm"
    common = dict(
        speed=sec.speed,
        stage_time=sec.stage_time,
        headings=sec.actions.headings,
        turn_speed_deg=sec.turn_speed,
    )
    empty = action_set(kind, robot.dim, **common)
    carrying = {
        p: action_set(kind, robot.dim, factor=sec.carry_speed_factor.get(p, 1.0), **common)
        for p in parts
    }
    for variant in spec.variants:
        empty, carrying = variant.actions(sec, robot, empty, carrying)
    return empty, carrying

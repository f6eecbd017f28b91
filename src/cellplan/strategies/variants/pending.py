"""Simultaneous requests (Section VI-2 of the strategies paper): the layered MDP.

Section V lets a request arrive only while none is open. Section VI-2 suggests the
general case: requests keep arriving while the robot serves one, and the loss counts the
requests open per stage. With up to ``k = max_pending`` requests open at once, a mode is

* the multiset ``Q`` of open requests not yet picked up (their types: two requests of
  one type are interchangeable in the model), and
* the request ``r`` whose part the robot carries, or none,

with ``|Q| + [r carried] <= k``. The mode ``(empty, none)`` is NR (layer 0). Choices the
paper leaves open, and the ones made here (docs/strategies.md, "Simultaneous requests"):

* **Arrivals.** Each stage of motion or waiting, a request arrives with probability
  ``P`` and is of type ``r`` with probability ``pi_r`` (as in Section III-B). It joins
  ``Q`` unless ``k`` requests are open already: then it is turned away (the simulator
  counts these; ``k`` is a modelling bound, chosen so that this is rare). As in Section
  V, no request arrives during an FMP (a fine motion is one decision step of the model).
* **Loss.** The weighted number of open requests per unit of time: each open request
  (waiting or carried) adds its part's ``urgency`` (default 1) times the stage time per
  stage, and times ``t_f`` during an FMP. With one type of weight 1 and ``k = 1`` this is
  equation (7), and the model is exactly the Section V model (tested).
* **The order of service is chosen.** FMP in ``(Q, none)`` has one *option* per
  request type in ``Q`` (:class:`~cellplan.strategies.model.bundles.Layers`: ``opt_ptr``): picking
  up its part at its source, leading to ``(Q - r, r)``. Two requests for the same part
  and source are different options at the same configurations: the pick decides which
  destination the part goes to. FMP in ``(Q, r)`` is the delivery of ``r``, leading to
  ``(Q, none)``.
* **Free space.** While empty, the robot may enter the sources of the waiting requests
  (the other sources are obstacles, equations (1)-(3)); the union of the Section V
  bitmaps of those sources is used, which is exact unless the robot can touch two
  sources at once (then it is conservative). While carrying, the carrying bitmap of
  Section V (2).

The move classes are shared by every mode with the same bitmap and action set (a
handful: NR, one per set of sources of the waiting requests, one per carried (part,
source)), so the layers cost one bitmap each only in ``live`` and ``tf``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from cellplan.errors import Problem
from cellplan.strategies.model.bundles import Grid, Outcomes
from cellplan.strategies.model.mdp import NR, Geometry, LayeredMDP, Mode, MoveClasses, finish_model
from cellplan.strategies.model.spec import ModeTables, Motions, Process
from cellplan.strategies.variants.request_sets import (
    MAX_PENDING,
    mode_counts,
    option_count,
    pending_modes,
)

#: Re-exported: the modes of simultaneous requests are reached through this module too.
__all__ = ["MAX_PENDING", "assemble_pending", "mode_counts", "option_count", "pending_modes"]

ModeKey = tuple[tuple[str, ...], str, str, str]


def mode_keys(mdp: LayeredMDP) -> dict[ModeKey, int]:
    """Each mode's index by ``(waiting, part, source, destination)``: the waiting requests
    as ``"part,source,destination"`` in the model's order, then the carried request (``""``
    when none); NR is ``((), "", "", "")``."""
    return {(m.waiting, m.part, m.source, m.destination): i for i, m in enumerate(mdp.modes)}


def assemble_pending(
    grid: Grid,
    requests: Sequence[tuple[str, str, str, float]],
    geometry: Geometry,
    motions: Motions,
    process: Process,
    max_pending: int,
    urgency: Mapping[str, float],
) -> LayeredMDP:
    """The layered MDP of simultaneous requests (module docstring) on a grid.

    ``urgency`` weighs each part's open requests in the loss (default 1); ``process``
    gives the stage time and the arrival probability (no changes with this model).
    """
    names = [f"{p},{s},{d}" for p, s, d, _ in requests]
    weight = np.array([float(urgency.get(p, 1.0)) for p, *_ in requests])
    keys = pending_modes(len(requests), max_pending)
    modes: list[Mode] = []
    for q, r in keys:
        if not q and r < 0:
            modes.append(Mode(NR))
            continue
        p, s, d, _ = requests[r] if r >= 0 else ("", "", "", 0.0)
        modes.append(Mode("Q", p, s, d, waiting=tuple(names[i] for i in q)))
    classes = MoveClasses()
    vcls = np.zeros(len(keys), np.int64)
    cost = np.zeros(len(keys))
    free_of: dict[tuple[str, ...], np.ndarray] = {}
    for m, (q, r) in enumerate(keys):
        cost[m] = process.stage_time * (weight[list(q)].sum() + (weight[r] if r >= 0 else 0.0))
        if r >= 0:
            p, s, _, _ = requests[r]
            vcls[m] = classes.add(geometry.free_c[(p, s)].ravel(), motions.carrying[p])
            continue
        sources = tuple(sorted({requests[i][1] for i in q}))
        if sources not in free_of:
            free = geometry.free_nr.ravel().copy()
            for s in sources:
                free |= geometry.free_w[s].ravel()
            free_of[sources] = free
        vcls[m] = classes.add(free_of[sources], motions.empty)
    free_mode = [classes.free[k] for k in vcls]
    opt, tf, outcomes = _fmp_options(keys, requests, geometry, free_mode, cost, process.stage_time)
    fmp_next = np.array(
        [outcomes.layer[opt[m]] if opt[m + 1] > opt[m] else -1 for m in range(len(keys))],
        np.int64,
    )
    probs = np.array([q for *_, q in requests], float)
    branches = _arrivals(keys, probs * process.arrival, max_pending)
    tables = ModeTables(modes, classes, vcls, cost, fmp_next, tf, branches, outcomes, opt)
    return finish_model(grid, tables, motions.empty, process, probs)


def _fmp_options(
    keys: list[tuple[tuple[int, ...], int]],
    requests: Sequence[tuple[str, str, str, float]],
    geometry: Geometry,
    free_mode: list[np.ndarray],
    cost: np.ndarray,
    stage_time: float,
) -> tuple[np.ndarray, np.ndarray, Outcomes]:
    """The FMP options ``(opt_ptr, tf, outcomes)`` of every mode, each with one certain
    outcome (no failures with simultaneous requests): the pick of each waiting request
    type in an empty mode, the delivery in a carrying one. An FMP's time field is weighed
    by the mode's loss per stage (``cost``, in stage times): every open request waits."""
    index = {key: m for m, key in enumerate(keys)}
    opt_ptr = [0]
    opt_tf: list[np.ndarray] = []
    out_layer: list[int] = []
    for m, (q, r) in enumerate(keys):
        if r >= 0:
            p, s, d, _ = requests[r]
            nxt = index[(q, -1)]
            where = geometry.drop[(p, d)].ravel() & free_mode[m] & geometry.free_nr.ravel()
            field = np.where(where, geometry.tf_drop[(p, d)].ravel(), np.inf)
            opt_tf.append(field * cost[m] / stage_time)
            out_layer.append(nxt)
        else:
            for i in sorted(set(q)):
                p, s, _, _ = requests[i]
                rest = list(q)
                rest.remove(i)
                nxt = index[(tuple(rest), i)]
                where = geometry.pick[(p, s)].ravel() & free_mode[m] & free_mode[nxt]
                field = np.where(where, geometry.tf_pick[(p, s)].ravel(), np.inf)
                opt_tf.append(field * cost[m] / stage_time)
                out_layer.append(nxt)
        opt_ptr.append(len(opt_tf))
    n_opt = len(opt_tf)
    tf = np.stack(opt_tf) if n_opt else np.zeros((0, geometry.free_nr.size))
    outcomes = Outcomes(
        np.arange(n_opt + 1, dtype=np.int64),
        np.asarray(out_layer, np.int64),
        np.ones(n_opt),
        np.zeros(n_opt),
    )
    return np.asarray(opt_ptr, np.int64), tf, outcomes


def _arrivals(
    keys: list[tuple[tuple[int, ...], int]], p_arrive: np.ndarray, max_pending: int
) -> tuple[list[int], list[int], list[float]]:
    """The branches ``(ptr, layer, prob)``: arrivals (Section III-B, type 1, ``p_arrive``
    per request type) in every mode with room for one more request."""
    index = {key: m for m, key in enumerate(keys)}
    ptr = [0]
    layers: list[int] = []
    bprob: list[float] = []
    for m, (q, r) in enumerate(keys):
        stay = 1.0
        if len(q) + (r >= 0) < max_pending:
            for i, p_i in enumerate(p_arrive):
                if p_i <= 0.0:
                    continue
                layers.append(index[(tuple(sorted((*q, i))), r)])
                bprob.append(float(p_i))
                stay -= p_i
        layers.append(m)
        bprob.append(stay)
        ptr.append(len(layers))
    return ptr, layers, bprob


def pending_problems(
    mdp: LayeredMDP, requests: Sequence[tuple[str, str, str, float]]
) -> list[Problem]:
    """One problem per request that can never be served (checked before solving).

    Request ``r`` alone is served through the modes ``({r}, none)`` and ``(empty, r)``,
    the Section V modes ``W`` and ``C`` of ``r``; the messages are those of
    :func:`cellplan.strategies.model.live.live_problems`.
    """
    index = mode_keys(mdp)
    problems = []
    if not mdp.live[0].any():
        problems.append(Problem("strategy", "no configuration in NR can serve every request"))
    for p, s, d, _ in requests:
        where = f"strategy.requests <{p},{s},{d}>"
        w = index[((f"{p},{s},{d}",), "", "", "")]
        c = index[((), p, s, d)]
        if not mdp.fmp_allowed(c).any():
            message = (
                f"part {p!r} cannot be delivered anywhere in destination {d!r} (no free "
                "configuration in the region)"
            )
        elif not mdp.fmp_allowed(w).any():
            message = (
                f"part {p!r} cannot be picked up anywhere in source {s!r} (no free "
                "configuration in the region)"
            )
        elif not mdp.live[c].any():
            message = f"destination {d!r} is unreachable while carrying {p!r}"
        elif not mdp.live[w].any():
            message = (
                f"source {s!r} is unreachable, or its part cannot reach destination {d!r} "
                "from there"
            )
        else:
            continue
        problems.append(Problem(where, message))
    return problems

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
from itertools import combinations_with_replacement

import numpy as np

from cellplan.errors import Problem
from cellplan.strategies.model.actions import ActionSet
from cellplan.strategies.model.bundles import Grid, Outcomes
from cellplan.strategies.model.mdp import NR, Geometry, LayeredMDP, Mode, MoveClasses, finish_model


def pending_modes(R: int, k: int) -> list[tuple[tuple[int, ...], int]]:
    """Every mode ``(Q, r)`` for ``R`` request types and at most ``k`` open requests.

    ``Q`` is a sorted tuple of request indices (a multiset: an index may repeat), ``r``
    the carried request or -1. Order:
    NR (``((), -1)``) first, then the empty modes by the size of ``Q``, then the
    carrying modes by ``r`` and the size of ``Q``.
    """
    out: list[tuple[tuple[int, ...], int]] = []
    for n in range(k + 1):
        out += [(q, -1) for q in combinations_with_replacement(range(R), n)]
    for r in range(R):
        for n in range(k):
            out += [(q, r) for q in combinations_with_replacement(range(R), n)]
    return out


ModeKey = tuple[tuple[str, ...], str, str, str]


def mode_keys(mdp: LayeredMDP) -> dict[ModeKey, int]:
    """Each mode's index by ``(waiting, part, source, destination)``: the waiting requests
    as ``"part,source,destination"`` in the model's order, then the carried request (``""``
    when none); NR is ``((), "", "", "")``."""
    return {(m.waiting, m.part, m.source, m.destination): i for i, m in enumerate(mdp.modes)}


def option_count(R: int, k: int) -> int:
    """FMP options: one per waiting request type in each empty mode, one per carrying mode."""
    return sum(len(set(q)) if r < 0 else 1 for q, r in pending_modes(R, k))


def assemble_pending(
    *,
    grid: Grid,
    requests: Sequence[tuple[str, str, str, float]],
    geometry: Geometry,
    actions_empty: ActionSet,
    actions_carrying: Mapping[str, ActionSet],
    stage_time: float,
    arrival: float,
    max_pending: int,
    urgency: Mapping[str, float],
) -> LayeredMDP:
    """The layered MDP of simultaneous requests (module docstring) on a grid.

    ``urgency`` weighs each part's open requests in the loss (default 1).
    """
    R = len(requests)
    ncell = int(np.prod(grid.shape))
    probs = np.array([q for *_, q in requests], float)
    names = [f"{p},{s},{d}" for p, s, d, _ in requests]
    weight = np.array([float(urgency.get(p, 1.0)) for p, *_ in requests])
    keys = pending_modes(R, max_pending)
    index = {key: m for m, key in enumerate(keys)}
    M = len(keys)
    modes: list[Mode] = []
    for q, r in keys:
        if not q and r < 0:
            modes.append(Mode(NR))
            continue
        p, s, d, _ = requests[r] if r >= 0 else ("", "", "", 0.0)
        modes.append(Mode("Q", p, s, d, waiting=tuple(names[i] for i in q)))

    classes = MoveClasses()
    vcls = np.zeros(M, np.int64)
    cost = np.zeros(M)
    free_of: dict[tuple[str, ...], np.ndarray] = {}
    for m, (q, r) in enumerate(keys):
        cost[m] = stage_time * (weight[list(q)].sum() + (weight[r] if r >= 0 else 0.0))
        if r >= 0:
            p, s, _, _ = requests[r]
            vcls[m] = classes.add(geometry.free_c[(p, s)].ravel(), actions_carrying[p])
            continue
        sources = tuple(sorted({requests[i][1] for i in q}))
        if sources not in free_of:
            free = geometry.free_nr.ravel().copy()
            for s in sources:
                free |= geometry.free_w[s].ravel()
            free_of[sources] = free
        vcls[m] = classes.add(free_of[sources], actions_empty)
    free_mode = [classes.free[k] for k in vcls]

    # FMP options, each with one certain outcome (no failures with simultaneous requests).
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
    tf = np.stack(opt_tf) if n_opt else np.zeros((0, ncell))
    opt = np.asarray(opt_ptr, np.int64)
    fmp_next = np.array(
        [out_layer[opt[m]] if opt[m + 1] > opt[m] else -1 for m in range(M)], np.int64
    )
    outcomes = Outcomes(
        np.arange(n_opt + 1, dtype=np.int64),
        np.asarray(out_layer, np.int64),
        np.ones(n_opt),
        np.zeros(n_opt),
    )

    # Arrivals (Section III-B, type 1) in every mode with room for one more request.
    ptr = [0]
    layers: list[int] = []
    bprob: list[float] = []
    for m, (q, r) in enumerate(keys):
        stay = 1.0
        if len(q) + (r >= 0) < max_pending:
            for i in range(R):
                p_i = arrival * probs[i]
                if p_i <= 0.0:
                    continue
                layers.append(index[(tuple(sorted((*q, i))), r)])
                bprob.append(p_i)
                stay -= p_i
        layers.append(m)
        bprob.append(stay)
        ptr.append(len(layers))

    return finish_model(
        grid=grid,
        modes=modes,
        classes=classes,
        vcls=vcls,
        cost=cost,
        fmp_next=fmp_next,
        tf=tf,
        branches=(ptr, layers, bprob),
        outcomes=outcomes,
        noise_prob=actions_empty.noise_prob,
        heading_axis=actions_empty.heading_axis,
        stage_time=stage_time,
        arrival=arrival,
        request_prob=probs,
        opt_ptr=opt,
    )


def pending_problems(
    mdp: LayeredMDP, requests: Sequence[tuple[str, str, str, float]]
) -> list[Problem]:
    """One problem per request that can never be served (checked before solving).

    Request ``r`` alone is served through the modes ``({r}, none)`` and ``(empty, r)``,
    the Section V modes ``W`` and ``C`` of ``r``; the messages are those of
    :func:`cellplan.strategies.model.mdp.live_problems`.
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

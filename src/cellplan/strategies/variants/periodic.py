"""Time-varying models and conveyors (Section VI-1 of the strategies paper).

Section V's strategy is stationary: the transition law does not depend on the stage.
Section VI-1 lets it vary: arrivals that follow the cycle of an upstream machine or a
shift, and sources or destinations that ride on a conveyor belt (Fig. 16), which the
robot must "intercept" as the terminating condition of its gross motion. With a period
of ``T`` stages the stage index matters only modulo ``T``, so the process is a stationary
MDP on the product (mode, phase). The choices where the paper is silent
(docs/strategies.md, "Time-varying models and conveyors"):

* **Layers.** Mode ``m`` at phase ``t`` is layer ``t * M + m`` (``M`` the Section V modes,
  NR first), so phase 0 holds the Section V layout and ``mdp.layer(m, t)`` finds a layer.
  Every stage (a move or a stay) leads to phase ``t + 1 mod T``; every branch of the
  Section V model (arrivals in NR) is drawn with the probabilities of the phase it leaves.
* **Arrivals by phase.** In NR at phase ``t`` a request arrives with probability
  ``P_t`` (``arrival`` times ``arrival_profile[t]``), of type ``r`` with ``pi_r``.
* **Belts.** A region on a belt lies at phase ``t`` at its scenario position plus
  ``v * t * stage_time``; at the end of each period the next part comes in at the start
  (a part every ``T`` stages). The FMP of a W mode at phase ``t`` picks from the region
  where it is at phase ``t``: its fine-motion field ``t_f`` is that of the moved region.
  So the gross motion ends where the part *will be* when the robot gets there. A region
  on a belt is not an obstacle in any mode (the belt runs under the robot's working
  plane); the stationary sources stay obstacles as in equations (1)-(3).
* **Fine motions take time.** An FMP with fine-motion time ``t_f`` advances the phase by
  ``t_f / stage_time`` stages rounded half up, and costs ``t_f`` as in equation (7) (the
  scenario checks refuse a fine-motion time that varies over a region in a time-varying
  model).
* **Memory.** The values of every phase are stored: ``T`` times the stationary model's
  ``(2R + 1) N`` values (and its fine-motion fields and live states); the move classes
  and their tables are shared by every phase. The scenario checks refuse more than
  :data:`~cellplan.strategies.section.MAX_PERIODIC_LAYERS` layers.
* **Live states** are computed on the product (:func:`periodic_live`): a W or C state is
  live when its request can be finished from it, the least fixed point over the phases
  (a waiting robot that idles for ever is not finishing its request), and NR keeps the
  states with an action every branch of which lands on live states (the greatest one).

The product is solved by policy iteration (the structured solver needs Section V's
stationary shape), and :meth:`~cellplan.strategies.policy.strategy.Strategy.action` queries
it at ``mdp.layer(mode, phase)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from cellplan.errors import Problem
from cellplan.strategies.model.domain import live_layer
from cellplan.strategies.model.mdp import LayeredMDP, request_fields
from cellplan.strategies.model.spec import Build

#: Passes of :func:`periodic_live` before it gives up (each carries reachability at
#: least one period further back, so this is far beyond any grid).
MAX_LIVE_PASSES = 10_000


def belt_offset(
    velocity: Sequence[float] | None, phase: int, stage_time: float
) -> tuple[float, float]:
    """How far a region on a belt has moved at ``phase`` (zero without a belt)."""
    if velocity is None:
        return (0.0, 0.0)
    return (float(velocity[0]) * phase * stage_time, float(velocity[1]) * phase * stage_time)


def region_offset(mdp: LayeredMDP, region: str, layer: int) -> tuple[float, float] | None:
    """The offset of ``region`` in ``layer``'s phase, or None when it is not on a belt."""
    velocity = mdp.belts.get(region)
    if velocity is None:
        return None
    return belt_offset(velocity, layer // mdp.modes_per_phase, mdp.stage_time)


def assemble_periodic(
    base: LayeredMDP,
    *,
    fields: np.ndarray,
    arrival: Sequence[float],
    fmp_stages: Sequence[int],
    belts: Mapping[str, tuple[float, float]],
) -> LayeredMDP:
    """The product of a Section V model ``base`` with the phase of a period (module
    docstring).

    Parameters
    ----------
    base
        The stationary model (its move classes and tables are shared by every phase;
        its branches other than NR's arrivals are copied to every phase).
    fields
        ``(T, M, N)``: the fine-motion time of each mode's FMP at each phase (``inf``
        where it is not allowed), the moved regions' fields for a belt.
    arrival
        ``(T,)``: the arrival probability per stage in NR at each phase.
    fmp_stages
        ``(M,)``: the stages each mode's FMP advances the phase.
    belts
        The velocity of each region on a belt (kept for the simulator and the plots).
    """
    T, M, N = fields.shape
    if M != base.n_modes or len(arrival) != T or len(fmp_stages) != M:
        raise ValueError("fields, arrival and fmp_stages must match the base model and period")
    probs = base.request_prob
    R = base.n_requests
    modes = [replace(mode, phase=t) for t in range(T) for mode in base.modes]
    fmp_next = np.full(T * M, -1, np.int64)
    ptr = [0]
    layers: list[int] = []
    bprob: list[float] = []
    for t in range(T):
        nxt = ((t + 1) % T) * M
        for m in range(M):
            if base.fmp_next[m] >= 0:
                fmp_next[t * M + m] = ((t + int(fmp_stages[m])) % T) * M + base.fmp_next[m]
            if m == 0:
                # NR: arrivals of this phase (Section III-B, type 1).
                stay = 1.0
                for r in range(R):
                    p_r = float(arrival[t]) * float(probs[r])
                    if p_r > 0.0:
                        layers.append(nxt + base.w_layer(r))
                        bprob.append(p_r)
                        stay -= p_r
                if stay > 0.0:
                    layers.append(nxt)
                    bprob.append(stay)
            else:
                lo, hi = base.branch_ptr[m], base.branch_ptr[m + 1]
                for L, q in zip(base.branch_layer[lo:hi], base.branch_prob[lo:hi], strict=True):
                    if q > 0.0:
                        layers.append(nxt + int(L))
                        bprob.append(float(q))
            ptr.append(len(layers))
    vcls = np.tile(base.vcls, T)
    mdp = replace(
        base,
        modes=modes,
        cost=np.tile(base.cost, T),
        vcls=vcls,
        fmp_next=fmp_next,
        tf=np.ascontiguousarray(fields.reshape(T * M, N)),
        branch_ptr=np.asarray(ptr, np.int64),
        branch_layer=np.asarray(layers, np.int64),
        branch_prob=np.asarray(bprob, float),
        live=base.free[vcls].copy(),
        arrival=float(np.mean(arrival)),  # a summary: NR's branches hold each phase's
        outcomes=None,
        opt_ptr=None,
        period=T,
        belts=dict(belts),
    )
    periodic_live(mdp)
    return mdp


def periodic_live(mdp: LayeredMDP) -> None:
    """Restrict ``mdp.live`` to the states from which every request can be finished.

    In a stationary layer :func:`~cellplan.strategies.model.domain.live_layer` grows the states
    that reach an FMP within the layer. Here a layer's moves lead to the next phase, so the
    growth runs over the phases: the W and C layers start empty and, pass after pass (phases
    backwards, C before W), take the candidates that reach a live state of the next phase
    or an FMP whose outcome is live, until nothing grows (the least fixed point). NR then
    shrinks to the states with an action whose every branch lands on live states (the
    greatest fixed point), and the two repeat until NR settles.
    """
    model = mdp.kernel_args()
    fmp_ok = mdp.tf < np.inf
    cand = mdp.free[mdp.vcls].astype(np.bool_)
    live = cand.copy()
    M = mdp.modes_per_phase
    has_fmp = mdp.fmp_next >= 0
    # Phases backwards; in each, the C layers (their FMP reads NR) before the W layers.
    grow = [
        t * M + m
        for t in reversed(range(mdp.period))
        for m in sorted(range(M), key=lambda m: mdp.modes[m].kind != "C")
        if has_fmp[t * M + m]
    ]
    idle = [ell for ell in range(mdp.n_modes) if not has_fmp[ell]]
    for _ in range(MAX_LIVE_PASSES):
        live[grow] = False
        for _ in range(MAX_LIVE_PASSES):
            grew = False
            for ell in grow:
                before = live[ell].copy()
                live[ell] = cand[ell]
                live_layer(live, fmp_ok, model, ell)
                grew |= not np.array_equal(live[ell], before)
            if not grew:
                break
        shrunk = False
        while any([live_layer(live, fmp_ok, model, ell) for ell in idle]):
            shrunk = True
        if not shrunk:
            mdp.live[:] = live
            return
    raise RuntimeError("live-state computation did not settle")  # pragma: no cover


def periodic_problems(mdp: LayeredMDP) -> list[Problem]:
    """One problem per request that can never be served at any phase (checked before
    solving); the messages are those of :func:`cellplan.strategies.model.live.live_problems`."""
    problems = []
    T = mdp.period
    if not mdp.live[[mdp.layer(0, t) for t in range(T)]].any():
        problems.append(Problem("strategy", "no configuration in NR can serve every request"))
    for r in range(mdp.n_requests):
        mode = mdp.modes[mdp.w_layer(r)]
        where = f"strategy.requests <{mode.part},{mode.source},{mode.destination}>"
        w = [mdp.layer(mdp.w_layer(r), t) for t in range(T)]
        c = [mdp.layer(mdp.c_layer(r), t) for t in range(T)]
        if not (mdp.tf[c] < np.inf).any():
            message = (
                f"part {mode.part!r} cannot be delivered anywhere in destination "
                f"{mode.destination!r} at any phase (no free configuration in the region)"
            )
        elif not (mdp.tf[w] < np.inf).any():
            message = (
                f"part {mode.part!r} cannot be picked up anywhere in source {mode.source!r} "
                "at any phase (no free configuration in the region)"
            )
        elif not mdp.live[c].any():
            message = (
                f"destination {mode.destination!r} is unreachable while carrying {mode.part!r}"
            )
        elif not mdp.live[w].any():
            message = (
                f"source {mode.source!r} is unreachable, or its part cannot reach destination "
                f"{mode.destination!r} from there"
            )
        else:
            continue
        problems.append(Problem(where, message))
    return problems


def periodic_model(build: Build, base: LayeredMDP) -> LayeredMDP:
    """The time-varying model of a scenario (Section VI-1, :mod:`.periodic`): the Section
    V model ``base`` on ``geometry`` (phase 0), and the pick and delivery regions at every
    phase."""
    sec, requests, cell, geometry = (
        build.spec.section,
        build.spec.requests,
        build.cell,
        build.geometry,
    )
    T = sec.period
    velocity = {name: (float(b.velocity[0]), float(b.velocity[1])) for name, b in sec.belts.items()}
    pts = build.grid.points()
    kind = sec.regions

    def moved(name: str, carrying: str | None, t: int) -> np.ndarray:
        offset = belt_offset(velocity[name], t, sec.stage_time)
        return cell.in_region(pts, name, kind, None, carrying, offset)

    fields = np.empty((T, base.n_modes, base.n_cells))
    for t in range(T):
        pick = dict(geometry.pick)
        drop = dict(geometry.drop)
        if t > 0:
            for p, s in pick:
                if s in velocity:
                    pick[(p, s)] = moved(s, None, t)
            for p, d in drop:
                if d in velocity:
                    drop[(p, d)] = moved(d, p, t)
        fields[t] = request_fields(replace(geometry, pick=pick, drop=drop), requests)

    def stages(region: str) -> int:
        spec = sec.fine_motion_regions.get(region, sec.fine_motion)
        return int(np.floor(float(spec.time) / sec.stage_time + 0.5))  # half up

    fmp_stages = [0] + [stages(s) for _, s, _, _ in requests] + [stages(d) for *_, d, _ in requests]
    return assemble_periodic(
        base,
        fields=fields,
        arrival=sec.arrival_by_phase(),
        fmp_stages=fmp_stages,
        belts=velocity,
    )

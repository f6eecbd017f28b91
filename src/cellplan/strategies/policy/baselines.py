"""Baseline strategies for the anticipation claim of Section V-C.

* *reactive*: stay still while no request waits; serve each request as fast as possible
  (minimum waiting time of that request alone, ignoring where the delivery leaves the
  robot);
* *return-home*: the same per request, but while no request waits move to a fixed home
  configuration (by the shortest path in the NR layer) and wait there.

Both use the value layers computed here with the same kernels as the optimal strategy,
so the three run in the same simulator on the same discretisation.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cellplan.strategies.model.mdp import LayeredMDP
from cellplan.strategies.solve import kernels


def motions_leave_layers(mdp: LayeredMDP) -> bool:
    """Whether a motion in a layer with a request to finish never stays in that layer (no
    such layer is among its own branches): then no layer can be solved, or searched ahead,
    on its own. So it is in a time-varying model (Section VI-1), whose every motion leads
    to the next phase's layer; the model's branch table says so, whichever variant built
    it."""
    ptr, layers = mdp.branch_ptr, mdp.branch_layer
    return not any(
        m in layers[ptr[m] : ptr[m + 1]] for m in range(mdp.n_modes) if mdp.fmp_next[m] >= 0
    )


def success_only(mdp: LayeredMDP) -> LayeredMDP:
    """The model with every FMP certain to succeed (its FMP leads to ``fmp_next``): the
    layer sweeps of the per-request values follow each FMP's success, and
    :func:`_with_failures` folds the other outcomes (Section VI-3) into ``t_f`` (the
    kernels' transition law would otherwise count them twice, or, before a layer is
    solved, value a retry at the layer's own ``+inf``)."""
    return mdp if mdp.outcomes is None else replace(mdp, outcomes=None)


def per_request_values(mdp: LayeredMDP, tol: float = 1e-9, max_sweeps: int = 10000) -> np.ndarray:
    """``(M, N)`` time-to-finish of the current request alone (g = 0, nothing after delivery).

    Layer NR is 0 (a delivery ends the cost); each C layer is the expected time to deliver
    (stages plus t_f), each W layer the time to pick up and then deliver.
    """
    if motions_leave_layers(mdp):
        return _over_phases(mdp, tol, max_sweeps)
    h = np.where(mdp.live, 0.0, np.nan)
    D = np.zeros(h.shape)
    work = np.where(mdp.live, 0.0, 0.0)
    args = success_only(mdp).kernel_args()
    d = len(mdp.shape)
    for m in _request_layers(mdp):
        work[m][mdp.live[m]] = np.inf
        for s in range(max_sweeps):
            if kernels.sweep_layer(m, s % (1 << d), work, D, 0.0, False, False, args) < tol:
                break
        h[m] = np.where(mdp.live[m], work[m], np.nan)
    return _with_failures(mdp, h, tol, max_sweeps)


def _over_phases(mdp: LayeredMDP, tol: float, max_passes: int) -> np.ndarray:
    """:func:`per_request_values` of a time-varying model (Section VI-1).

    A W or C layer's moves lead to the next phase, so no layer is solved on its own:
    Gauss-Seidel passes sweep every request layer once, phases backwards (C before W),
    until a pass changes no value by more than ``tol``; each pass carries the time to
    finish one period further back.
    """
    M = mdp.modes_per_phase
    request = [m for m in range(M) if mdp.fmp_next[m] >= 0]
    order = [
        t * M + m
        for t in reversed(range(mdp.period))
        for m in sorted(request, key=lambda m: mdp.modes[m].kind != "C")
    ]
    work = np.where(mdp.live, 0.0, 0.0)
    for m in order:
        work[m][mdp.live[m]] = np.inf
    D = np.zeros(work.shape)
    args = mdp.kernel_args()
    d = len(mdp.shape)
    for s in range(max_passes):
        change = max(
            kernels.sweep_layer(m, s % (1 << d), work, D, 0.0, False, False, args) for m in order
        )
        if change < tol:
            break
    return np.where(mdp.live, work, np.nan)


def _request_layers(mdp: LayeredMDP) -> list[int]:
    """The layers of a request, each after those its FMP leads to: C, W, then the X modes."""
    R = mdp.n_requests
    rejects = [m for m, mode in enumerate(mdp.modes) if mode.kind == "X"]
    return [mdp.c_layer(r) for r in range(R)] + [mdp.w_layer(r) for r in range(R)] + rejects


def _with_failures(mdp: LayeredMDP, h: np.ndarray, tol: float, max_sweeps: int) -> np.ndarray:
    """The time-to-finish values when FMPs can fail (Section VI-3); ``h`` itself where
    every FMP has one outcome (the model's outcome table says so, whichever variant built it).

    The layer sweeps above follow each FMP's success only. Passes then re-solve every
    layer with its FMP's other outcomes (a retry, a rejection) valued at the last pass's
    values, folded into the fine-motion time: ``t_f + sum_o P_o (c_o + h(L_o)) - h(next)``
    makes the kernels' ``t_f + h(next)`` the expected FMP value. The error shrinks by the
    failure probability per pass (a failure is the only way back into a solved layer).
    """
    out = mdp.fmp_outcomes()
    order = _request_layers(mdp)
    failing = [m for m in order if out.ptr[m + 1] - out.ptr[m] > 1]
    if not failing:  # every FMP has its one certain outcome: the layer sweeps were exact
        return h
    args_of = success_only(mdp).kernel_args  # the other outcomes are folded into t_f
    d = len(mdp.shape)
    D = np.zeros(h.shape)
    work = np.where(mdp.live, h, 0.0)
    for _ in range(max_sweeps):
        tf = mdp.tf.copy()
        for m in failing:
            expected = np.zeros(mdp.n_cells)
            fmp = np.isfinite(tf[m])
            for o in range(out.ptr[m], out.ptr[m + 1]):
                expected += out.prob[o] * (out.cost[o] + work[out.layer[o]])
                if out.prob[o] > 0:
                    fmp &= mdp.live[out.layer[o]]  # as the Bellman operator requires
            tf[m, ~fmp] = np.inf
            tf[m, fmp] += expected[fmp] - work[mdp.fmp_next[m], fmp]
        args = args_of()._replace(layers=args_of().layers._replace(tf=tf))
        before = work.copy()
        for m in order:
            for s in range(max_sweeps):
                if kernels.sweep_layer(m, s % (1 << d), work, D, 0.0, False, False, args) < tol:
                    break
        change = np.max(np.abs(work - before)[mdp.live])
        if change <= tol * max(1.0, float(np.max(np.abs(work[mdp.live])))):
            break
    return np.where(mdp.live, work, np.nan)


def home_values(
    mdp: LayeredMDP, home_cell: int, tol: float = 1e-9, max_sweeps: int = 10000
) -> np.ndarray:
    """``(N,)`` stages to reach the home cell from each NR state (NaN where it cannot).

    Solved as a one-request shortest path on the NR layer's move class: FMP (cost 0) is
    allowed only at the home cell and leads to a layer of zeros.
    """
    N = mdp.n_cells
    live_nr = mdp.live[0]
    live = np.stack([live_nr, np.zeros(N, np.bool_)])
    live[1, home_cell] = True
    tf = np.full((2, N), np.inf)
    tf[0, home_cell] = 0.0
    aux = replace(
        mdp,
        modes=mdp.modes[:2],
        cost=np.array([1.0, 1.0]),
        vcls=np.array([mdp.vcls[0], mdp.vcls[0]], np.int64),
        fmp_next=np.array([1, -1], np.int64),
        tf=tf,
        branch_ptr=np.array([0, 1, 2], np.int64),
        branch_layer=np.array([0, 1], np.int64),
        branch_prob=np.array([1.0, 1.0]),
        live=live,
        outcomes=None,  # the home's FMP is certain (and the model's are of other modes)
    )
    h = np.zeros((2, N))
    h[0][live_nr] = np.inf
    D = np.zeros((2, N))
    d = len(mdp.shape)
    args = aux.kernel_args()
    for s in range(max_sweeps):
        if kernels.sweep_layer(0, s % (1 << d), h, D, 0.0, False, False, args) < tol:
            break
    out = np.where(live_nr & np.isfinite(h[0]), h[0], np.nan)
    return out

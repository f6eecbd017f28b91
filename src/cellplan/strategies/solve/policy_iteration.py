"""Average-cost policy iteration over every live state (Howard; Puterman 1994, Sec. 8.6).

The structured solver (:func:`cellplan.strategies.solve.solver.solve_structured`) needs the
Section V shape of the model: a carrying layer's FMP ends in NR, a waiting layer's in its
carrying layer, with certainty, and a move lands where it is commanded. With failure
modes (Section VI-3 of the strategies paper) an FMP has several outcomes (a retry in
place, a rejected part carried elsewhere), with noisy motion (Section VI-4) a move has
several landings, and relative value iteration
(:func:`~cellplan.strategies.solve.certify.solve_general`) needs thousands of sweeps because the
request cycle mixes slowly. Policy iteration needs a handful of iterations, each

1. *assembly*: the policy's transition matrix ``P`` over the live states in CSR and its
   cost ``c`` (the numba kernel :func:`policy_rows`, with the transition law of
   :func:`cellplan.strategies.solve.bellman.bellman_rows`: moves land on the live corners of
   their stencil, renormalised, in every branch, at every landing of a noisy move; stay
   keeps the cell in every branch; FMP takes its outcomes);
2. *unichain check* (:func:`unichain`): the strongly connected components of the chain;
   if more than one is closed, the one of lowest gain is kept and the states that do not
   reach it take actions one hop nearer to it;
3. *evaluation* (:func:`evaluate`): ``h + g = c + P h`` exactly, by one sparse LU
   (SuperLU) on the recurrent class and back-substitution of the transient components in
   their order (:func:`back_substitute`);
4. *improvement*: a few value iteration sweeps from ``h`` (modified policy iteration,
   :data:`LOOKAHEAD_SWEEPS`), then the Jacobi Bellman operator
   (:func:`cellplan.strategies.solve.certify.bellman`); a state changes its action only where the
   best action beats the current one by more than a small relative margin. Once a
   policy repeats (the look-ahead and the unichain repair breaking ties opposite ways),
   the look-ahead is switched off and Howard's improvement alone goes on.

The first policy is proper by construction: NR stays where it is, and every other state
takes an action with a successor one hop nearer to NR (hop distances through the union of
every action's successors, Gauss-Seidel sweeps of ``d(s) = 1 + min_a min_{s'} d(s')`` by
:func:`hop_sweep`, layers in the order they read each other), so every request is
finished with probability one. If a factorisation fails anyway, or its solution does not
satisfy its equations, relative value iteration sweeps from the last values stand in for
the evaluation. The answer is certified like every solve (:func:`.certify.finish`).
docs/strategies.md ("Policy iteration") has the choices and the measurements.
"""

from __future__ import annotations

import hashlib
import logging
import time
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph
from scipy.sparse.linalg import splu

from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.mdp import NR, LayeredMDP
from cellplan.strategies.solve.bellman import residual_range
from cellplan.strategies.solve.certify import (
    INNER_FACTOR,
    Certificate,
    Progress,
    SolveResult,
    Tally,
    bellman,
    finish,
    solve_general,
)
from cellplan.strategies.solve.law import OUTSIDE
from cellplan.strategies.solve.pi_kernels import PolicyRows, back_substitute, hop_sweep, policy_rows
from cellplan.strategies.solve.threads import Workers, workers_for

log = logging.getLogger(__name__)

# An action replaces the current one only if it is better by this much (relative to the
# size of the value): ties and rounding never make the policy cycle.
IMPROVE_MARGIN = 1e-10
# Residual of an evaluation above which it is not trusted (relative to max |h| + 1).
EVAL_RESIDUAL = 1e-7
# Cap of the Gauss-Seidel sweeps of the hop distances (each at least one more hop).
MAX_HOP_SWEEPS = 100_000
# Relative value iteration sweeps per recovery from a failed evaluation.
RECOVERY_SWEEPS = 200
# Value iteration sweeps between an evaluation and the next improvement.
LOOKAHEAD_SWEEPS = 4
# Strongly connected components larger than this are evaluated by sparse LU, smaller ones
# by Gauss-Seidel on the component.
DIRECT_ABOVE = 64


class _Chain:
    """The live states of a model as one index ``0..S-1`` (flat ``m * N + c`` order)."""

    def __init__(self, mdp: LayeredMDP) -> None:
        live = mdp.live
        self.shape = live.shape
        self.states = np.flatnonzero(live.ravel()).astype(np.int64)
        self.size = len(self.states)
        self.index = np.full(live.shape, -1, np.int64)
        self.index.ravel()[self.states] = np.arange(self.size)
        # Room for each state's row of a policy's matrix (:func:`assemble`): from
        # ``starts[k]``; ``slot`` is each place's position in its row, ``slot_row`` its row.
        room = row_room(mdp)[self.states // live.shape[1]]
        self.starts = np.zeros(self.size + 1, np.int64)
        np.cumsum(room, out=self.starts[1:])
        self.slot_row = np.repeat(np.arange(self.size), room)
        self.slot = np.arange(int(self.starts[-1])) - self.starts[self.slot_row]

    def spread(self, x: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """A per-state vector as an ``(M, N)`` array (``fill`` outside the live states)."""
        out = np.full(self.shape, fill)
        out.ravel()[self.states] = x
        return out


def layer_order(mdp: LayeredMDP) -> np.ndarray:
    """Layers in the order in which hop distances from NR reach them (NR first).

    A layer follows the layers it reads (its branches and FMP outcomes), so one
    Gauss-Seidel sweep carries the distances round the request cycle
    (NR <- C <- W <- NR in the Section V model).
    """
    out = mdp.fmp_outcomes()
    options = mdp.options
    M = mdp.n_modes
    readers: list[set[int]] = [set() for _ in range(M)]
    for m in range(M):
        for b in range(mdp.branch_ptr[m], mdp.branch_ptr[m + 1]):
            readers[int(mdp.branch_layer[b])].add(m)
        for o in range(out.ptr[options[m]], out.ptr[options[m + 1]]):
            readers[int(out.layer[o])].add(m)
    order = [0]
    seen = {0}
    for L in order:  # grows while it is walked: a breadth-first order
        for m in sorted(readers[L] - seen):
            seen.add(m)
            order.append(m)
    order += [m for m in range(M) if m not in seen]
    return np.array(order, np.int64)


def hop_policy(
    mdp: LayeredMDP, chain: _Chain, targets: np.ndarray, actions: np.ndarray, model: Model
) -> tuple[np.ndarray, np.ndarray, int]:
    """Actions that reach ``targets`` (bool per state) with probability one.

    Returns ``(actions, hop distances, sweeps)``: every other state takes an action with a
    successor one hop nearer to the targets (hop distances through the union of every
    action's successors, Gauss-Seidel sweeps in alternating cell orders, layers in
    :func:`layer_order`); the targets keep their ``actions`` (or take an available one
    where it is ``-3``). Distances stay at ``S`` (the number of states) where no target
    can be reached.
    """
    S = chain.size
    dist = np.where(targets, 0.0, float(S))
    act = np.where(targets, actions, OUTSIDE).astype(np.int64)
    order = layer_order(mdp)
    d = len(mdp.shape)
    usable = np.full(S, -1, np.int64)  # per state, the moves a policy may take (bitmask)
    sweeps = 0
    while sweeps < MAX_HOP_SWEEPS:
        flips = sweeps % (1 << d)
        changed = hop_sweep(dist, act, targets, chain.index, order, flips, usable, model)
        sweeps += 1
        if not changed:
            break
    return act, dist, sweeps


def row_room(mdp: LayeredMDP) -> np.ndarray:
    """The most successors a state of each mode can have under one action (per mode)."""
    out = mdp.fmp_outcomes()
    corners = (1 << len(mdp.shape)) * len(mdp.noise_prob)  # per landing of a noisy move
    branches = np.diff(mdp.branch_ptr)
    options = mdp.options
    per_option = np.diff(out.ptr)
    fmp = np.array(
        [per_option[options[m] : options[m + 1]].max(initial=0) for m in range(mdp.n_modes)],
        np.int64,
    )
    return np.maximum(branches * corners, fmp).astype(np.int64)


def assemble(
    chain: _Chain, actions: np.ndarray, model: Model, workers: Workers
) -> tuple[sp.csr_matrix, np.ndarray, int]:
    """The policy's transition matrix over the live states (CSR), its cost vector, and the
    number of states whose action is not available (their rows are empty).

    One pass of :func:`policy_rows` writes each row into the room its mode may need
    (:func:`row_room`); the rows are then packed.
    """
    S = chain.size
    starts = chain.starts
    cols = np.empty(int(starts[-1]), np.int64)
    vals = np.empty(int(starts[-1]))
    counts = np.zeros(S, np.int64)
    cost = np.zeros(S)

    out = PolicyRows(chain.states, actions, chain.index, starts, cols, vals, counts, cost)

    def rows(r: tuple[int, int]) -> int:
        return int(policy_rows(out, r[0], r[1], model))

    bad = sum(workers.map(rows, workers.ranges(S)))
    keep = chain.slot < counts[chain.slot_row]
    indptr = np.zeros(S + 1, np.int64)
    np.cumsum(counts, out=indptr[1:])
    P = sp.csr_matrix(
        (vals[keep], cols[keep].astype(np.int32), indptr.astype(np.int32)), shape=(S, S)
    )
    P.sum_duplicates()
    return P, cost, bad


def evaluate(
    P: sp.csr_matrix,
    cost: np.ndarray,
    labels: np.ndarray,
    actions: np.ndarray,
    memo: dict[str, Any],
) -> tuple[float, np.ndarray, int]:
    """``(g, h, nnz of the LU factors)`` of a unichain policy: ``h + g = c + P h``.

    ``labels`` are the strongly connected components of the chain, sinks first (as
    :func:`scipy.sparse.csgraph.connected_components` numbers them); the first closed one
    is the recurrent class. Its equations, with ``h = 0`` at its first state, give ``g``:
    ``(I - P)`` on the class with that state's column replaced by ones (its unknown is
    ``g``), one sparse LU (SuperLU). The transient states follow in the components'
    order, each known once the components it leads to are (:func:`back_substitute`);
    components larger than :data:`DIRECT_ABOVE` states are solved by LU too. ``memo``
    keeps the recurrent class's solution: while the class and its ``actions`` stay the
    same (the late iterations improve transient states only), it is not factorised
    again. Raises
    ``RuntimeError`` (SuperLU) when a system is singular.
    """
    S = P.shape[0]
    order = np.argsort(labels, kind="stable")
    n = int(labels.max()) + 1
    starts = np.searchsorted(labels[order], np.arange(n + 1)).astype(np.int64)
    sizes = np.diff(starts)
    h = np.zeros(S)
    # Component 0 is closed (a sink is numbered before whatever leads to it); in a
    # unichain policy it is the recurrent class.
    members = order[starts[0] : starts[1]]
    key = (members.tobytes(), actions[members].tobytes())
    if memo.get("key") != key:
        # The recurrent class changed (or its actions did): factorise its system again.
        _, x, fill = _class_system(P, cost, members)
        memo.update(key=key, x=x, fill=fill)
    x = memo["x"].copy()
    g = float(x[0])
    x[0] = 0.0
    h[members] = x
    fill = int(memo["fill"])
    first = 1
    for k in [*(int(k) for k in np.flatnonzero(sizes > DIRECT_ABOVE) if k > 0), n]:
        back_substitute((P.indptr, P.indices, P.data), cost, g, h, (order, starts), first, k)
        if k == n:
            break
        idx = order[starts[k] : starts[k + 1]]
        rest = cost[idx] - g + P[idx] @ h  # h is still 0 on the component itself
        lub = splu((sp.identity(len(idx), format="csc") - P[idx][:, idx]).tocsc())
        h[idx] = lub.solve(rest)
        fill = max(fill, int(lub.nnz))
        first = k + 1
    return g, h, fill


def closed_classes(P: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """``(labels, closed)``: the strongly connected components of a chain, numbered sinks
    first (:func:`scipy.sparse.csgraph.connected_components`), and the labels of the
    closed ones (no transition leaves them): its recurrent classes."""
    _, labels = csgraph.connected_components(P, directed=True, connection="strong")
    rows = np.repeat(np.arange(P.shape[0]), np.diff(P.indptr))
    cross = labels[rows] != labels[P.indices]
    leaves = np.zeros(int(labels.max()) + 1, np.bool_)
    leaves[labels[rows[cross]]] = True
    return labels, np.flatnonzero(~leaves)


def stranded_modes(mdp: LayeredMDP, policy: np.ndarray) -> np.ndarray:
    """The modes in which ``policy`` (``(M, N)``, as :class:`.certify.SolveResult` holds
    it) can keep requests open for ever: those of its recurrent classes that contain no
    NR state.

    A recurrent class is never left once entered; without an NR state in it, the
    requests open in its modes are never all finished. A Section V model's optimal
    policy has none (a request held open costs at least as much per stage as serving
    it), but where a request can be turned away at no cost (simultaneous requests with
    ``max_pending`` open, Section VI-2) and parts differ in urgency, holding cheap
    requests open so that urgent ones are turned away can be optimal. Empty when every
    recurrent class passes through NR.
    """
    chain = _Chain(mdp)
    # int64 like the iteration's own actions (a solve's policy is int16): one compile of
    # the row kernels serves both.
    actions = policy.ravel()[chain.states].astype(np.int64)
    P, _, _ = assemble(chain, actions, mdp.kernel_args(), Workers(1))
    labels, closed = closed_classes(P)
    mode = chain.states // mdp.live.shape[1]
    idle = np.array([m.kind == NR for m in mdp.modes])[mode]
    held = np.setdiff1d(closed, labels[idle])
    return np.unique(mode[np.isin(labels, held)])


def closed_class_gains(
    P: sp.csr_matrix, cost: np.ndarray, labels: np.ndarray, closed: np.ndarray
) -> np.ndarray:
    """The gain of each closed class ``closed`` (component labels) of a policy's chain.

    A closed class is a recurrent class of its own: its gain solves ``h + g = c + P h``
    on the class with ``h = 0`` at its first state (the system :func:`evaluate` solves,
    one sparse LU per class; a single state's gain is its cost, it stays put).
    """
    gains = np.empty(len(closed))
    for j, k in enumerate(closed):
        members = np.flatnonzero(labels == k)
        if len(members) == 1:
            gains[j] = cost[members[0]]
            continue
        gains[j] = _class_system(P, cost, members)[0]
    return gains


def _class_system(
    P: sp.csr_matrix, cost: np.ndarray, members: np.ndarray
) -> tuple[float, np.ndarray, int]:
    """``(g, x, nnz of the LU factors)`` of the closed class ``members``: ``(I - P)`` on the
    class with its first state's column replaced by ones (its unknown is ``g``; ``x[0]``
    holds it, the other entries are ``h`` with ``h = 0`` at the first state)."""
    sub = P[members][:, members].tocoo()
    off = sub.col != 0
    size = len(members)
    rows = np.concatenate([sub.row[off], np.arange(1, size), np.arange(size)])
    cols = np.concatenate([sub.col[off], np.arange(1, size), np.zeros(size, np.int64)])
    vals = np.concatenate([-sub.data[off], np.ones(size - 1), np.ones(size)])
    lu = splu(sp.csc_matrix((vals, (rows, cols)), shape=(size, size)))
    x = lu.solve(cost[members])
    # SuperLU's own count: reading lu.L and lu.U would copy the factors.
    return float(x[0]), x, int(lu.nnz)


def unichain(
    mdp: LayeredMDP,
    chain: _Chain,
    P: sp.csr_matrix,
    cost: np.ndarray,
    actions: np.ndarray,
    model: Model,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Make the policy unichain; returns ``(actions, component labels, states changed)``.

    The recurrent classes of the policy are the closed strongly connected components of
    its chain. With several, the one of lowest gain (:func:`closed_class_gains`; the
    first of equal ones) is kept, and the states that do not reach it take actions one
    hop nearer to it (:func:`hop_policy`; the class keeps its actions): the others
    still reach it, and these now do too. Keeping the lowest gain matters: after an
    improvement every recurrent class of the new policy has a gain no higher than the
    old policy's (Puterman 1994, Sec. 9.2), and routing every state to the best of them
    keeps the gains of the iterations non-increasing; an arbitrary class can undo the
    improvement and make the iteration cycle. The labels returned are those of the
    policy returned (recomputed after a repair), numbered sinks first
    (:func:`scipy.sparse.csgraph.connected_components`), so the one closed class is
    component 0.
    """
    changed = 0
    for _ in range(2):
        labels, closed = closed_classes(P)
        if len(closed) == 1:
            return actions, labels, changed
        best = int(closed[np.argmin(closed_class_gains(P, cost, labels, closed))])
        start = int(np.flatnonzero(labels == best)[0])
        reach = csgraph.breadth_first_order(P.T, start, directed=True, return_predecessors=False)
        ok = np.zeros(chain.size, np.bool_)
        ok[reach] = True
        hop, _, _ = hop_policy(mdp, chain, labels == best, actions, model)
        actions = np.where(ok, actions, hop)
        changed += int(np.count_nonzero(~ok))
        P, cost, _ = assemble(chain, actions, model, Workers(1))
    raise RuntimeError("policy iteration: the repaired policy is not unichain (a bug)")


class _Repeats:
    """The policies evaluated so far (16-byte digests of their actions), and whether the
    improvement still looks ahead.

    A policy evaluated twice means the iteration cycles: ties that the look-ahead breaks
    one way and the unichain repair the other. From then on the improvement is Howard's
    alone (strict, on the evaluated values), which cannot cycle on a unichain model;
    should a policy still repeat, the iteration stops.
    """

    def __init__(self) -> None:
        self.seen: set[bytes] = set()
        self.lookahead = True

    def stop(self, actions: np.ndarray, it: int) -> bool:
        """Record the policy ``actions`` of iteration ``it``; whether to stop."""
        digest = hashlib.blake2b(actions.tobytes(), digest_size=16).digest()
        if digest in self.seen:
            if not self.lookahead:
                log.warning("policy iteration: the policy repeats; stopping at %d", it)
                return True
            log.debug("iteration %d: the policy repeats; no more look-ahead", it)
            self.lookahead = False
        self.seen.add(digest)
        return False


def solve_policy_iteration(
    mdp: LayeredMDP,
    tol: float = 1e-6,
    max_iterations: int = 500,
    progress: Progress | None = None,
    threads: int | None = None,
) -> SolveResult:
    """Average-cost policy iteration over every live state (module docstring).

    Stops when an improvement changes no action, or when the Bellman bracket of the
    evaluated policy is already narrower than ``tol / 100``; gives up (``NOT_CONVERGED``)
    after ``max_iterations`` iterations. The result is certified by
    :func:`cellplan.strategies.solve.certify.finish` (``SOLVED`` only when the span test
    passes). ``sweeps`` and ``full_sweeps`` count the Jacobi Bellman sweeps over every
    state (per iteration one plus :data:`LOOKAHEAD_SWEEPS`, plus any recovery sweeps;
    the certificate's two are added to ``full_sweeps``), ``eval_sweeps`` the exact
    evaluations, ``outer_iterations`` the iterations. ``threads``: as in
    :func:`cellplan.strategies.solve.solver.solve`.
    """
    t0 = time.perf_counter()
    live = mdp.live
    chain = _Chain(mdp)
    model = mdp.kernel_args()
    ref_cell = int(np.flatnonzero(live[0])[0])
    # The first policy: NR waits where it is (stay, the reactive robot), every other state
    # heads for NR by the fewest stages (hop distances to the NR states).
    nr = chain.states < live.shape[1]
    actions, dist, hops = hop_policy(mdp, chain, nr, np.full(chain.size, OUTSIDE), model)
    unreachable = int(np.count_nonzero(dist >= chain.size))
    log.debug("first policy: %d hop sweeps, %d states unreachable", hops, unreachable)
    if unreachable:
        log.warning(
            "policy iteration: %d live states cannot reach NR; solving by relative value iteration",
            unreachable,
        )
        return solve_general(mdp, tol, progress=progress, threads=threads)
    h, g, sweeps, evaluations, it = np.zeros(chain.size), 0.0, 0, 0, 0
    cert: Certificate | None = None
    memo: dict[str, Any] = {}
    repeats = _Repeats()
    with workers_for(chain.size, threads) as workers:
        for it in range(1, max_iterations + 1):
            P, cost, bad = assemble(chain, actions, model, workers)
            if bad:
                raise RuntimeError(
                    f"policy iteration: {bad} states have an unavailable action (a bug)"
                )
            repaired, labels, fixed = unichain(mdp, chain, P, cost, actions, model)
            if fixed:
                log.debug("iteration %d: %d states did not reach the recurrent class", it, fixed)
                actions = repaired
                P, cost, _ = assemble(chain, actions, model, workers)
            solved = _trusted_evaluation(P, cost, labels, actions, memo)
            evaluations += solved is not None
            hfull = chain.spread(h)
            if solved is not None:
                g = solved[0]
            if solved is not None and solved[2]:
                h = solved[1]
                hfull = chain.spread(h)
            else:
                hfull, n = _recover(mdp, hfull, ref_cell, workers)
                sweeps += n
                h = hfull.ravel()[chain.states]
            th, pol, gap = bellman(mdp, hfull, workers=workers)
            sweeps += 1
            lo, hi = (float(v) for v in residual_range(th, hfull, live))
            cert = (lo, hi, th, pol, gap)
            cert_pol = pol
            if progress is not None:
                progress(it, hi - lo, 0.5 * (lo + hi))
            q = cost + P @ h
            thv = th.ravel()[chain.states]
            better = thv < q - IMPROVE_MARGIN * np.maximum(1.0, np.abs(q))
            changes = int(np.count_nonzero(better))
            log.debug(
                "iteration %d: g %.10f bracket [%.10f, %.10f] changes %d", it, g, lo, hi, changes
            )
            if changes == 0 or hi - lo < tol * INNER_FACTOR:
                break
            if repeats.stop(actions, it):
                break
            cert = None
            better, pol, n = _improvement(
                mdp, (P, cost, chain), (g, better, cert_pol), th, repeats.lookahead, workers
            )
            sweeps += n
            actions = np.where(better, pol.ravel()[chain.states], actions)
        tally = Tally("policy", t0, sweeps, sweeps, it, ref_cell)
        result = finish(mdp, chain.spread(h), g, tol, tally, cert, workers)
    result.eval_sweeps = evaluations
    return result


def _trusted_evaluation(
    P: sp.csr_matrix,
    cost: np.ndarray,
    labels: np.ndarray,
    actions: np.ndarray,
    memo: dict[str, Any],
) -> tuple[float, np.ndarray, bool] | None:
    """``(g, h, trusted)`` of the policy (:func:`evaluate`), or None where the
    factorisation failed; ``trusted`` whether the solution satisfies its equations (to
    :data:`EVAL_RESIDUAL`)."""
    try:
        g, h, _ = evaluate(P, cost, labels, actions, memo)
    except RuntimeError as err:  # a singular factor
        log.debug("evaluation failed (%s)", err)
        return None
    res = cost - g + P @ h - h
    trusted = bool(
        np.all(np.isfinite(h)) and np.max(np.abs(res)) <= EVAL_RESIDUAL * (1.0 + np.max(np.abs(h)))
    )
    return g, h, trusted


def _improvement(
    mdp: LayeredMDP,
    policy: tuple[sp.csr_matrix, np.ndarray, _Chain],
    greedy: tuple[float, np.ndarray, np.ndarray],
    th: np.ndarray,
    lookahead: bool,
    workers: Workers,
) -> tuple[np.ndarray, np.ndarray, int]:
    """``(states that change, their new actions (M, N), sweeps)`` of one improvement.

    ``policy`` is the evaluated policy's ``(P, c, chain)``; ``greedy`` is ``(g, the
    states whose greedy action beats the policy's on the evaluated values, that greedy
    policy)``, and ``th`` its Bellman values. With ``lookahead``, modified policy
    iteration: a few value iteration sweeps from the policy's values carry an
    improvement several states further up the paths before the next (greedy) policy is
    taken; late iterations otherwise move it by one state each, along every path whose
    better route is found at its end. Without, or when the look-ahead finds nothing,
    Howard's improvement.
    """
    P, cost, chain = policy
    g, better, pol = greedy
    if not lookahead:
        return better, pol, 0
    h2, th2, pol2 = _lookahead(mdp, th, g, workers)
    q2 = cost + P @ h2.ravel()[chain.states]
    thv = th2.ravel()[chain.states]
    better2 = thv < q2 - IMPROVE_MARGIN * np.maximum(1.0, np.abs(q2))
    if np.any(better2):
        return better2, pol2, LOOKAHEAD_SWEEPS
    return better, pol, LOOKAHEAD_SWEEPS


def _lookahead(
    mdp: LayeredMDP, th: np.ndarray, g: float, workers: Workers
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:data:`LOOKAHEAD_SWEEPS` value iteration sweeps from ``T h - g``: ``(h', T h', its
    policy)`` (modified policy iteration)."""
    h2 = np.where(mdp.live, th - g, 0.0)
    th2, pol, _ = bellman(mdp, h2, workers=workers)
    for _ in range(LOOKAHEAD_SWEEPS - 1):
        h2 = np.where(mdp.live, th2 - g, 0.0)
        th2, pol, _ = bellman(mdp, h2, workers=workers)
    return h2, th2, pol


def _recover(
    mdp: LayeredMDP, h: np.ndarray, ref_cell: int, workers: Workers
) -> tuple[np.ndarray, int]:
    """Relative value iteration sweeps from ``h`` (after an evaluation that failed)."""
    live = mdp.live
    for _ in range(RECOVERY_SWEEPS):
        th, _, _ = bellman(mdp, h, workers=workers)
        h = np.where(live, th, 0.0)
        h -= h[0, ref_cell]
    return h, RECOVERY_SWEEPS

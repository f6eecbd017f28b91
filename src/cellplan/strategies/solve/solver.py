"""Average-cost dynamic programming for the layered MDP (Section IV of the strategies paper).

The paper iterates equation (9) backwards over a long horizon until the actions stop
changing. Over an infinite horizon the cost-to-go grows without bound, so we solve the
equivalent average-cost problem

    h(x) + g = min_u [ l(x, u) + sum_x' P(x' | x, u) h(x') ]

where ``g`` is the long-run expected loss per stage (the expected waiting time of parts per
stage) and ``h`` the relative cost-to-go; the optimal actions of (9) for a long horizon are
the minimisers of the right-hand side. Two solvers share the kernels:

* :func:`solve_general` - relative value iteration (Jacobi sweeps over all states, optional
  damping ``h <- (1-tau) h + tau T h`` for periodic chains), stopping when
  ``span(T h - h) < epsilon``; ``min`` and ``max`` of ``T h - h`` bracket ``g``.
* :func:`solve_structured` - exploits the structure: for a fixed ``g`` and NR layer, every
  carrying layer and then every waiting layer is a deterministic shortest path with
  terminal cost (FMP into the next mode), solved by policy iteration: alternating-direction
  Gauss-Seidel sweeps over every action choose the actions, and between them the chosen
  policy is evaluated exactly in one pass, in the dependency order of its strongly
  connected components (:mod:`cellplan.strategies.solve.evaluation`); a layer is done when a
  *full* sweep changes it by less than the inner accuracy. The independent C layers run in
  parallel threads, each request's W layer as soon as its C layer is done (layers coupled
  by destination or source changes are
  swept together as a group, started from their uncoupled solutions). NR is then solved
  with its stay self-loop eliminated exactly (``h = H_W - g/P``), removing the slow
  ``(1 - P)`` mode; its request branches (into the fixed W layers) are summed once per
  pass, so its sweeps interpolate NR alone. From the second pass on every layer starts by
  evaluating last pass's policy. An outer loop takes the NR layer round the
  request cycle and moves ``g`` by Newton steps on the drift ``h_NR(ref)`` (the
  derivative, minus the expected cycle length, is tracked along the minimising actions
  as ``D = dh/dg``, which also moves the other layers with ``g``); the NR shape is
  Anderson-accelerated over the last passes. On the first pass and while the NR shape
  still changes a lot from pass to pass, each C and W layer gets only a few sweeps (an
  inexact inner solve); such a pass never ends the loop. Layers with identical data are solved once.
  The answer is certified by one Jacobi Bellman sweep over every state, which must pass
  the same span test.
"""

from __future__ import annotations

import hashlib
import itertools
import logging
import time
import typing
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellplan.core import Status
from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.mdp import LayeredMDP
from cellplan.strategies.model.section import SolverMethod
from cellplan.strategies.solve import bellman as bellman_kernels
from cellplan.strategies.solve import evaluation, sweeps
from cellplan.strategies.solve.improvement import improvable
from cellplan.strategies.solve.threads import Workers, workers_for

log = logging.getLogger(__name__)
# The solver methods (their one list is the scenario schema's).
METHODS: tuple[str, ...] = typing.get_args(SolverMethod)
# Inner solves need only be accurate relative to the outer progress (drift, NR shape change).
ACCURACY_FACTOR = 0.05
# Inner accuracy of the first passes (cold start, g still far from the gain).
FIRST_ACCURACY = 1e-2
# On the first pass (g still at its initial guess) and while the NR shape changes by more
# than EARLY_SHAPE * tol per pass, the C and W layers get at most EARLY_SWEEPS full sweeps
# plus evaluations each: solving them exactly against terminal values that will move
# again is wasted (P6 at 64^3: 18 -> 11.3 s).
EARLY_SWEEPS = 5
EARLY_SHAPE = 1e4
# Once the passes are no longer capped, the C and W layers of a model without source or
# destination changes are solved to the final inner accuracy: policy iteration with its
# residual check gets there for little more, and exact layers let the certificate succeed
# a pass earlier (fitted on problems 2, 4, 5 and 1 at 141 x 141: 3.52-3.66 -> 3.42-3.45 s
# in all; benchmarks/fit_solver_rules.py). Layers coupled by changes are solved by
# Gauss-Seidel, for which that costs sweeps.
# The certificate is tried with every layer moved along the Newton step on g once the NR
# shape changes by less than ATTEMPT_SHAPE * tol, and the drift is below tol, or below
# NEWTON_DRIFT * tol with the layers solved to NEWTON_ACCURACY * tol.
ATTEMPT_SHAPE = 0.5
NEWTON_DRIFT = 1e3
NEWTON_ACCURACY = 0.1
# Passes mixed by the Anderson acceleration of the NR shape.
ANDERSON_DEPTH = 4
# Warm passes start each layer with an exact evaluation of last pass's policy.
EVAL_FIRST = True
# Final inner accuracy relative to the span tolerance.
INNER_FACTOR = 1e-2
# NR, the one layer solved alone, is swept in this many slabs of rows on the pool's
# threads. A fixed number rather than the thread count, so that the answer does not
# depend on the threads (two threads: one NR sweep 4.75 -> 2.74 ms on P1 at 200 x 200,
# 14.2 -> 8.65 ms on P6; docs/benchmarks.md, seventh session).
NR_SLABS = 2
Progress = Callable[[int, float, float], None]  # (sweep, residual span, gain)


@dataclass
class SolveResult:
    """Outcome of a solve.

    Attributes
    ----------
    values
        ``(M, N)`` relative cost-to-go ``h`` (NaN outside the live states).
    gain
        ``g``, the long-run expected loss per stage.
    gain_lower, gain_upper
        ``min`` and ``max`` of ``T h - h`` over all live states: ``g`` lies between them.
    span
        ``gain_upper - gain_lower`` of the final (certifying) sweep.
    sweeps
        Layer sweeps over every action (structured) or full sweeps (general) performed.
    full_sweeps
        Full Jacobi Bellman sweeps over all states.
    status
        ``SOLVED`` when the span test passed, ``NOT_CONVERGED`` otherwise.
    stable
        Whether one more Bellman sweep leaves every optimal action unchanged.
    policy
        ``(M, N)`` optimal action per state (-2 FMP, -1 stay, ``a >= 0`` move; -3 outside).
    eval_sweeps
        Structured solver: cheap layer sweeps that evaluate only the current policy's action
        (modified policy iteration).
    """

    values: np.ndarray
    gain: float
    gain_lower: float
    gain_upper: float
    span: float
    sweeps: int
    full_sweeps: int
    outer_iterations: int
    status: Status
    stable: bool
    policy_changes: int
    policy: np.ndarray
    method: str
    seconds: float
    eval_sweeps: int = 0

    @property
    def converged(self) -> bool:
        return self.status is Status.SOLVED

    def stats(self) -> dict[str, int | float | bool]:
        """The figures of the solve for :attr:`cellplan.core.Result.stats`: counts as
        ``int``, the stability flag as ``bool``, measures as ``float`` (each keeps its
        type in JSON)."""
        return {
            "gain": float(self.gain),
            "gain_lower": float(self.gain_lower),
            "gain_upper": float(self.gain_upper),
            "span": float(self.span),
            "sweeps": int(self.sweeps),
            "full_sweeps": int(self.full_sweeps),
            "eval_sweeps": int(self.eval_sweeps),
            "outer_iterations": int(self.outer_iterations),
            "stable": bool(self.stable),
            "policy_changes": int(self.policy_changes),
            "seconds": float(self.seconds),
        }


def bellman(
    mdp: LayeredMDP,
    h: np.ndarray,
    subset: np.ndarray | None = None,
    workers: Workers | None = None,
    model: Model | None = None,
    out: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(T h, policy, gap)``: one Jacobi sweep of equation (9) over every state (no ``g``).

    ``gap`` is the second-best action value minus the best, per state. With ``subset``
    (boolean, like ``h``) only those states are swept; the outputs elsewhere are NaN / -3.
    ``workers`` runs ranges of states in parallel threads. ``model``: the kernel bundle
    (default ``mdp.kernel_args()``); with ``Layers.dense`` filled, as the structured solver
    has it, the layers :func:`.improvement.improvable` accepts are swept by
    :func:`.bellman.bellman_dense` (the same results, the moves vectorised). ``out``: an
    array like ``h`` to hold ``T h`` (overwritten; not ``h`` itself).
    """
    if out is None:
        out = np.full_like(h, np.nan)
    else:
        if np.may_share_memory(out, h) or out.shape != h.shape or out.dtype != h.dtype:
            raise ValueError("bellman: out must be a separate array shaped like h")
        out.fill(np.nan)
    policy = np.full(h.shape, -3, np.int64)
    gap = np.full_like(h, np.nan)
    mask = np.zeros((0, 0), np.bool_) if subset is None else subset
    model = mdp.kernel_args() if model is None else model
    pool = Workers(1) if workers is None else workers
    M, N = h.shape
    # (A subset is cheaper state by state: the stability check's is a quarter of them.)
    dense = [m for m in range(M) if subset is None and improvable(m, model)]
    # Tasks: a dense layer whole, the other layers in ranges of states.
    tasks: list[tuple[int, int, int]] = [(m, 0, 0) for m in dense]
    for m in sorted(set(range(M)) - set(dense)):
        tasks += [(-1, m * N + a, m * N + b) for a, b in pool.ranges(N)]

    def run(task: tuple[int, int, int]) -> None:
        m, start, stop = task
        if m >= 0:
            bellman_kernels.bellman_dense(m, h, out, policy, gap, mask, model)
        else:
            bellman_kernels.bellman_rows(h, out, policy, gap, mask, start, stop, model)

    pool.map(run, tasks)
    return out, policy, gap


Certificate = tuple[float, float, np.ndarray, np.ndarray, np.ndarray]


def _certify(
    mdp: LayeredMDP, h: np.ndarray, workers: Workers | None = None, model: Model | None = None
) -> Certificate:
    """The span test: ``min (T h - h) <= g <= max (T h - h)`` over the live states."""
    th, policy, gap = bellman(mdp, h, workers=workers, model=model)
    lo, hi = bellman_kernels.residual_range(th, h, mdp.live)
    return float(lo), float(hi), th, policy, gap


def _stability(
    mdp: LayeredMDP,
    cert: Certificate,
    g: float,
    workers: Workers | None = None,
    model: Model | None = None,
) -> int:
    """States whose action changes in one more Bellman sweep, ``T (T h - g)`` against ``T h``.

    ``T h - g = h + r`` with ``span(r)`` the certificate's span, so an action can change only
    where its margin over the second-best action is at most that span (ties included); the
    second sweep visits only those states.

    The certificate's ``T h`` and ``gap`` arrays are reused as the second sweep's input and
    output (the certificate is not read again): on problem 6 each full-size array is
    36 MB, and memory a process touches for the first time costs more there than the
    sweep's arithmetic.
    """
    lo, hi, th, policy, gap = cert
    near = bellman_kernels.near_ties(th, gap, mdp.live, hi - lo)
    if not np.any(near):
        return 0
    start = np.subtract(th, g, out=th)
    _, policy2, _ = bellman(mdp, start, near, workers, model, out=gap)
    return int(np.count_nonzero((policy2 != policy) & near))


def _finish(
    mdp: LayeredMDP,
    h: np.ndarray,
    g_hint: float,
    tol: float,
    sweeps: int,
    full: int,
    outer: int,
    method: str,
    t0: float,
    ref: int,
    cert: Certificate | None = None,
    workers: Workers | None = None,
    model: Model | None = None,
) -> SolveResult:
    # ``cert``: the certificate of this very ``h``, when the caller already computed it.
    cert = _certify(mdp, h, workers, model) if cert is None else cert
    lo, hi, _, policy, _ = cert
    full += 1
    span = hi - lo
    g = 0.5 * (lo + hi) if span < tol else g_hint
    changes = _stability(mdp, cert, g, workers, model)
    full += 1
    values = np.where(mdp.live, h - h[0, ref], np.nan)
    return SolveResult(
        values=values,
        gain=g,
        gain_lower=lo,
        gain_upper=hi,
        span=span,
        sweeps=sweeps,
        full_sweeps=full,
        outer_iterations=outer,
        status=Status.SOLVED if span < tol else Status.NOT_CONVERGED,
        stable=changes == 0,
        policy_changes=changes,
        policy=policy.astype(np.int16),
        method=method,
        seconds=time.perf_counter() - t0,
    )


def solve_general(
    mdp: LayeredMDP,
    tol: float = 1e-6,
    max_sweeps: int = 20000,
    damping: float = 1.0,
    progress: Progress | None = None,
    threads: int | None = None,
) -> SolveResult:
    """Relative value iteration over all states (works for every transition model).

    ``h_{k+1} = (1 - tau) h_k + tau T h_k``, renormalised at a reference NR state, until
    ``span(T h_k - h_k) < tol``.
    """
    t0 = time.perf_counter()
    live = mdp.live
    h = np.zeros(live.shape)
    ref = int(np.flatnonzero(live[0])[0])
    g = 0.0
    k = 0
    with workers_for(int(live.sum()), threads) as workers:
        for k in range(1, max_sweeps + 1):
            th, _, _ = bellman(mdp, h, workers=workers)
            diff = np.where(live, th - h, 0.0)
            r = diff[live]
            lo, hi = float(r.min()), float(r.max())
            g = 0.5 * (lo + hi)
            if progress is not None and (k % 25 == 0 or hi - lo < tol):
                progress(k, hi - lo, g)
            if hi - lo < tol:
                break
            h = h + damping * diff
            h -= h[0, ref]
        return _finish(mdp, h, g, tol, k, k, k, "general", t0, ref, workers=workers)


def _layer_key(mdp: LayeredMDP, m: int, groups: dict[int, int]) -> bytes:
    dig = hashlib.sha1()
    nxt = int(mdp.fmp_next[m])
    dig.update(np.array([mdp.vcls[m], groups.get(nxt, nxt), mdp.cost[m]]).tobytes())
    dig.update(mdp.tf[m].tobytes())
    dig.update(mdp.live[m].tobytes())
    return dig.digest()


class _Layers:
    """The state of a structured solve and its two inner steps (C/W layers, then NR).

    ``h`` and ``D = dh/dg`` are ``(M, N)``; ``pol`` the last recorded policy per state.
    """

    def __init__(self, mdp: LayeredMDP, max_sweeps: int, workers: Workers) -> None:
        self.mdp = mdp
        self.model = sweeps.with_dense(mdp.kernel_args())
        self.max_sweeps = max_sweeps
        self.workers = workers
        live = mdp.live
        self.live = live
        self.h = np.zeros(live.shape)
        self.D = np.zeros(live.shape)
        self.pol = np.full(live.shape, -3, np.int16)
        self.sweeps = 0  # full layer sweeps (every action)
        self.evaluations = 0  # exact policy evaluations
        self.coupled = mdp.has_changes()
        R = mdp.n_requests
        self.c_layers = [mdp.c_layer(r) for r in range(R)]
        self.w_layers = [mdp.w_layer(r) for r in range(R)]
        self.order = self.c_layers + self.w_layers
        # Layers with identical data (move class, successor, fine-motion field, live set)
        # are solved once and share values.
        self.groups: dict[int, int] = {}
        reps: dict[bytes, int] = {}
        for m in self.order:
            key = _layer_key(mdp, m, self.groups)
            self.groups[m] = m if self.coupled else reps.setdefault(key, m)
        self.c_reps = [m for m in self.c_layers if self.groups[m] == m]
        self.w_reps = [m for m in self.w_layers if self.groups[m] == m]
        self.copies = {
            m: [k for k in self.order if k != m and self.groups[k] == m] for m in self.order
        }
        # The W layers to solve once a C layer (a representative) is: those picking up
        # into it or into one of its copies (a W layer's FMP leads to its C layer).
        self.w_after: dict[int, list[int]] = {m: [] for m in self.order}
        for w in self.w_reps:
            self.w_after[self.groups[int(mdp.fmp_next[w])]].append(w)
        # The uncoupled model (every move keeps the request) starts coupled groups.
        ptr, lay, prob = mdp.branch_ptr, mdp.branch_layer, mdp.branch_prob
        solo_prob = prob.copy()
        for m in range(1, mdp.n_modes):
            for b in range(ptr[m], ptr[m + 1]):
                solo_prob[b] = 1.0 if lay[b] == m else 0.0
        self.solo_model = self.model._replace(
            layers=self.model.layers._replace(branch_prob=solo_prob)
        )
        # A Dijkstra first policy pays off where Gauss-Seidel from +inf is slow to cross
        # the layer: 3-D joint spaces (8 sweep orders). In the plane 4 orders suffice, and
        # for a robot-frame heading axis its predecessor search costs more than it saves.
        self.cold_dijkstra = len(mdp.shape) >= 3 and mdp.heading_axis < 0
        # NR: its request branches (into the W layers, fixed while NR is solved) are
        # summed once per pass into E (ED for D), per cell and action.
        n_act = int(mdp.nact[mdp.vcls[0]])
        self.E = np.empty((live.shape[1], n_act + 1))
        self.ED = np.empty_like(self.E)
        self.p_self = float(sum(prob[b] for b in range(ptr[0], ptr[1]) if lay[b] == 0))
        self._merge_request_branches()
        # NR is swept in NR_SLABS slabs of rows along the first axis (_nr_sweep).
        self.nr_cells = evaluation.live_cells(live[0])
        rows = int(mdp.shape[0])
        cuts = [rows * k // NR_SLABS for k in range(NR_SLABS + 1)]
        self.nr_slabs = [(a, b) for a, b in itertools.pairwise(cuts) if b > a]
        self.frozen_h = np.empty(live.shape[1])
        self.frozen_D = np.empty(live.shape[1])

    # --- step 1: the C and W layers ---------------------------------------------------------

    def start(self, m: int, warm: float | None, dg: float) -> None:
        """Starting values of a C or W layer (see :meth:`request_layers`)."""
        lm = self.live[m]
        if warm is None:
            self.h[m][lm] = np.inf
        else:
            self.h[m][lm] += dg * self.D[m][lm] + warm

    def request_layers(
        self, g: float, accuracy: float, warm: float | None, dg: float, cap: int
    ) -> None:
        """Solve every C layer, then every W layer, for the gain ``g`` and the current NR.

        A C or W layer is a deterministic shortest path with terminal cost (eq. (9) with
        the loss (7) of a stage, ``dt``, and of FMP, ``t_f``):

            h(m, x) = min( t_f(m, x) - g + h(next(m), x),  min_a  dt - g + H_m(x + dx_a) ).

        Gauss-Seidel on a shortest path converges fast from above and creeps up from below.
        The first pass starts from ``+inf`` (``warm`` None); later passes start from the
        last solution moved by the exact change of its old policy's cost under the new g
        (``dg * D``) plus ``warm``, the largest change of the terminal NR values beyond
        that: an upper bound within the spread of those changes. ``cap`` bounds the sweeps
        and evaluations per layer (an inexact solve on early passes).
        """
        if self.coupled:
            for ms in (self.c_layers, self.w_layers):
                self._coupled_group(ms, g, accuracy, warm, dg)
            return
        # C layers read only NR, and a W layer only its own C layer: each C layer is
        # solved in parallel with the others, and its W layers start as soon as it is
        # done (no barrier between the C and the W layers).
        warm_start = EVAL_FIRST and warm is not None

        def solve_one(m: int) -> tuple[int, int]:
            self.start(m, warm, dg)
            counts = sweeps.layer_iteration(
                m, self.h, self.D, g, accuracy, cap, self.max_sweeps, self.pol, warm_start,
                cap >= self.max_sweeps, self.cold_dijkstra, self.model,
            )  # fmt: skip
            # Layers with the same data share this solution (before a W layer reads it).
            for copy in self.copies[m]:
                self.h[copy] = self.h[m]
                self.D[copy] = self.D[m]
            return counts

        counts = self.workers.map_chains(solve_one, self.c_reps, self.w_after.__getitem__)
        self.sweeps += sum(c[0] for c in counts.values())
        self.evaluations += sum(c[1] for c in counts.values())
        log.debug("layers: (full sweeps, evaluations) %s", dict(sorted(counts.items())))

    def _gauss_seidel(self, m: int, g: float, accuracy: float, model: Model) -> None:
        d = len(self.mdp.shape)
        for s in range(max(1, self.max_sweeps)):
            change = sweeps.sweep_layer(m, s % (1 << d), self.h, self.D, g, False, True, model)
            self.sweeps += 1
            if change < accuracy:
                return

    def _coupled_group(
        self, ms: list[int], g: float, accuracy: float, warm: float | None, dg: float
    ) -> None:
        """Layers coupled by destination or source changes: Gauss-Seidel rounds over the
        group, started on the first pass from each layer's solution with the changes off."""
        d = len(self.mdp.shape)
        for m in ms:
            self.start(m, warm, dg)
            if warm is None:
                self._gauss_seidel(m, g, accuracy, self.solo_model)
        for s in range(max(1, self.max_sweeps)):
            change = 0.0
            for m in ms:
                flips = s % (1 << d)
                change = max(
                    change,
                    sweeps.sweep_layer(m, flips, self.h, self.D, g, False, True, self.model),
                )
            self.sweeps += len(ms)
            if change < accuracy:
                return

    # --- step 2: NR ---------------------------------------------------------------------------

    def _merge_request_branches(self) -> None:
        """Group NR's request branches whose W layers share one live set.

        A request ``r`` arrives in NR with probability ``P pi_r`` and leads to ``W_r``
        (Section III-B). The interpolation of Section IV-B renormalises a landing point's
        weights over the live corners of the layer it reads, so where the live sets agree
        the weights agree too and ``sum_b P_b H_{W_b}(x')`` is the interpolation of
        ``sum_b P_b h_{W_b}`` over that live set: one interpolation per group instead of
        one per request (problem 1: one group of 8, problem 6: two of 4). ``merged`` is a
        model whose layers are NR and one per group (only ``live`` and the branches of NR
        are read from it: :func:`.sweeps.other_branches` of layer 0), each group on one
        branch with its total probability; :meth:`_merged_values` fills ``hg`` and ``Dg``
        with the probability-weighted means of the group's values.
        """
        mdp = self.mdp
        ptr, lay, prob = mdp.branch_ptr, mdp.branch_layer, mdp.branch_prob
        groups: dict[bytes, list[int]] = {}
        for b in range(ptr[0], ptr[1]):
            if lay[b] != 0 and prob[b] > 0.0:
                groups.setdefault(self.live[lay[b]].tobytes(), []).append(b)
        self.nr_groups = list(groups.values())
        self.merged: Model | None = None
        if len(self.nr_groups) == sum(len(bs) for bs in self.nr_groups):
            return  # nothing to merge
        n_groups = len(self.nr_groups)
        live = np.empty((n_groups + 1, self.live.shape[1]), np.bool_)
        live[0] = self.live[0]
        for k, bs in enumerate(self.nr_groups):
            live[k + 1] = self.live[lay[bs[0]]]
        self.group_prob = np.array([float(prob[bs].sum()) for bs in self.nr_groups])
        layers = self.model.layers._replace(
            live=live,
            branch_ptr=np.array([0, n_groups + 1], np.int64),
            branch_layer=np.arange(n_groups + 1, dtype=np.int64),
            branch_prob=np.concatenate([[self.p_self], self.group_prob]),
            dense=np.zeros((0, 0), np.int64),
        )
        self.merged = self.model._replace(layers=layers)
        self.hg = np.zeros(live.shape)
        self.Dg = np.zeros(live.shape)

    def _merged_values(self) -> bool:
        """Fill the merged layers' values; False where a W layer still has an unreached
        live state (the groups then read differently, so the branches stay separate)."""
        if self.merged is None:
            return False
        lay, prob = self.mdp.branch_layer, self.mdp.branch_prob
        tmp = np.empty(self.live.shape[1])
        for k, bs in enumerate(self.nr_groups):
            for src, out in ((self.h, self.hg[k + 1]), (self.D, self.Dg[k + 1])):
                # Accumulated member by member, in place: the same sums, in the same order,
                # as a sum over a stacked copy, without the copy (P6: 10 -> 2 ms a group).
                np.multiply(src[lay[bs[0]]], prob[bs[0]], out=out)
                for b in bs[1:]:
                    out += np.multiply(src[lay[b]], prob[b], out=tmp)
                out /= self.group_prob[k]
            # A member at +inf (an unreached state: all probabilities are positive) makes
            # the mean +inf on the group's live set.
            if not np.all(np.isfinite(self.hg[k + 1]), where=self.live[lay[bs[0]]]):
                return False
        return True

    def nr_layer(self, g: float, accuracy: float, cold: bool) -> None:
        """Solve NR for the gain ``g`` with the W layers fixed.

        NR has no loss and a self-loop of probability ``1 - P`` (no request arrives); a
        request ``r`` arrives with probability ``P pi_r`` and leads to ``W_r``. Its stay
        self-loop is eliminated exactly,

            h(NR, x) = min( (-g + E_stay(x)) / P,  min_a  -g + E_a(x) + (1 - P) H_NR(x + dx_a) ),

        with ``E`` the request branches summed once per pass (:func:`sweeps.other_branches`).
        The first pass starts from ``+inf``; later ones evaluate last pass's NR policy first.
        Its sweeps run in slabs on the pool (:meth:`_nr_sweep`), its exact evaluations
        (:func:`.evaluation.self_system`, :func:`.evaluation.evaluate`) in this thread.
        """
        n = self.live.shape[1]

        h: np.ndarray = self.h
        D: np.ndarray = self.D
        model = self.model
        if self._merged_values():
            assert self.merged is not None
            h, D, model = self.hg, self.Dg, self.merged

        def branches(r: tuple[int, int]) -> None:
            sweeps.other_branches(0, h, D, self.E, self.ED, r[0], r[1], model)

        self.workers.map(branches, self.workers.ranges(n))
        if cold:
            self.h[0][self.live[0]] = np.inf
        # Policy iteration, as sweeps.layer_iteration does it for a C or W layer: full
        # sweeps until the minimiser has nearly settled, then an exact evaluation.
        cells, local = self.nr_cells
        full = evaluations = 0
        changed = 0
        evaluate_first = not cold  # last pass's policy, confirmed by a full sweep
        while full + evaluations < max(1, self.max_sweeps):
            if evaluate_first:
                evaluate_first = False
            else:
                change, changed = self._nr_sweep(g, full % (1 << len(self.mdp.shape)), accuracy)
                full += 1
                if change < accuracy:
                    break
            if changed <= sweeps.SETTLED_FRACTION * len(cells):
                system = evaluation.self_system(
                    0, self.h, self.D, g, self.E, self.ED, self.p_self, self.pol, cells, local,
                    self.model,
                )  # fmt: skip
                evaluation.evaluate(self.h[0], self.D[0], cells, *system)
                evaluations += 1
        self.sweeps += full
        self.evaluations += evaluations
        log.debug("NR: full sweeps %d, evaluations %d", full, evaluations)

    def _nr_sweep(self, g: float, flips: int, tie: float) -> tuple[float, int]:
        """One Gauss-Seidel sweep of NR, its slabs of rows on the pool (:func:`.sweeps.sweep_self`).

        Inside a slab the sweep is Gauss-Seidel; across slabs it reads the values from
        before the sweep, so the slabs can run in any order on any number of threads and
        give the same values. Returns the largest change and how many minimisers changed
        by more than ``tie``.
        """
        np.copyto(self.frozen_h, self.h[0])
        np.copyto(self.frozen_D, self.D[0])
        changed = np.zeros((len(self.nr_slabs), 1), np.int64)

        def run(k: int) -> float:
            rows = self.nr_slabs[k]
            return float(
                sweeps.sweep_self(
                    0, flips, self.h, self.D, g, self.E, self.ED, self.p_self, self.pol, 1,
                    changed[k], tie, self.model, rows, self.frozen_h, self.frozen_D,
                )
            )  # fmt: skip

        return max(self.workers.map(run, range(len(self.nr_slabs)))), int(changed.sum())


class _ShapeMixer:
    """Anderson acceleration of the NR shape over the last :data:`ANDERSON_DEPTH` passes.

    One pass maps the NR values the C layers see (``x``) to the NR values that come out
    (``f``); near the answer the map is affine, and the request cycle can have slow modes
    (the arms of problems 5 and 6 remember their joint configuration from one delivery to
    the next, so the shape error shrinks by only a factor 2-3 per pass). With residuals
    ``r_i = f_i - x_i`` the next input is ``f_k - dF gamma`` where ``gamma`` minimises
    ``|r_k - dR gamma|`` (``dR``, ``dF``: differences of successive residuals and
    outputs). Outputs are moved to the current ``g`` through ``D`` first.
    """

    def __init__(self, depth: int = ANDERSON_DEPTH) -> None:
        self.depth = depth
        self.x: list[np.ndarray] = []
        self.f: list[np.ndarray] = []
        self.d: list[np.ndarray] = []
        self.g: list[float] = []

    def push(self, x: np.ndarray, f: np.ndarray, d: np.ndarray, g: float) -> None:
        self.x.append(x)
        self.f.append(f)
        self.d.append(d)
        self.g.append(g)
        if len(self.g) > self.depth + 1:
            del self.x[0], self.f[0], self.d[0], self.g[0]

    def mix(self, g: float) -> np.ndarray:
        f_now = [f + (g - gi) * di for f, di, gi in zip(self.f, self.d, self.g, strict=True)]
        res = [f - x for f, x in zip(f_now, self.x, strict=True)]
        if len(res) == 1:
            return f_now[-1]
        dr = np.stack([res[i + 1] - res[i] for i in range(len(res) - 1)], 1)
        df = np.stack([f_now[i + 1] - f_now[i] for i in range(len(f_now) - 1)], 1)
        gamma = np.linalg.lstsq(dr, res[-1], rcond=None)[0]
        return np.asarray(f_now[-1] - df @ gamma)


@dataclass(frozen=True)
class _Drift:
    """What a pass did to NR at the reference state (steps 2-3 of :func:`solve_structured`).

    ``drift`` is how far ``h_NR(ref)`` moved in the pass (zero exactly at the optimal
    gain), ``deriv`` its derivative in ``g`` (minus the expected length of the request
    cycle, carried along the minimising actions as ``D``), ``shape`` the span of the
    change of NR over its live states (infinite on the first pass, whose old values are
    the initial zeros), and ``shift``, ``d_shift`` the values of ``h_NR(ref)`` and
    ``D_NR(ref)`` that NR was normalised by.
    """

    drift: float
    deriv: float
    shape: float
    shift: float
    d_shift: float

    def newton(self) -> float:
        """The Newton step on ``g``: ``-drift / (d drift / dg)`` (none without descent)."""
        return -self.drift / self.deriv if self.deriv < 0 else 0.0


def _normalise_nr(
    h: np.ndarray,
    D: np.ndarray,
    old: np.ndarray,
    old_d: np.ndarray,
    lnr: np.ndarray,
    ref: int,
    first: bool,
) -> _Drift:
    """Measure the pass at NR's reference state and normalise NR there (``h_NR(ref) = 0``).

    ``old`` and ``old_d``: NR's values and ``D`` before the pass. The C and W layers keep
    their raw values (they were solved against the un-normalised NR) and are shifted only
    at the end.
    """
    delta = (h[0] - old)[lnr]
    p = _Drift(
        drift=float(h[0, ref] - old[ref]),
        deriv=float(D[0, ref] - old_d[ref]),
        shape=np.inf if first else float(delta.max() - delta.min()),
        shift=float(h[0, ref]),
        d_shift=float(D[0, ref]),
    )
    h[0][lnr] -= p.shift
    D[0][lnr] -= p.d_shift
    return p


def _settled(p: _Drift, capped: bool, accuracy: float, tol: float, inner_tol: float) -> bool:
    """A full pass that moved neither ``h_NR(ref)`` nor the NR shape (by ``0.1 tol``)."""
    return not capped and abs(p.drift) < tol * 0.1 and p.shape < tol * 0.1 and accuracy <= inner_tol


def _certificate_due(p: _Drift, capped: bool, first: bool, accuracy: float, tol: float) -> bool:
    """Whether to try the certificate after this pass (step 5 of :func:`solve_structured`).

    Its span is about the larger of the drift (it shows up as the inconsistency at the
    FMP into NR), the NR shape change and the inner accuracy. The Newton step on ``g`` is
    exact while no action changes, so the certificate is tried with every layer moved
    along it (:func:`_moved_along_newton`): once the shape change is within
    :data:`ATTEMPT_SHAPE` times the tolerance, and either the drift is within the tolerance,
    or it is small and the layers were solved exactly (policy iteration makes that cheap).
    A failed attempt costs one Jacobi sweep.
    """
    return (
        not capped
        and not first
        and p.shape < ATTEMPT_SHAPE * tol
        and (
            abs(p.drift) < tol
            or (abs(p.drift) < NEWTON_DRIFT * tol and accuracy <= NEWTON_ACCURACY * tol)
        )
    )


def _moved_along_newton(run: _Layers, p: _Drift, newton: float) -> np.ndarray:
    """Every layer moved to ``g + newton`` along its policy (``h + newton D``, exact while no
    action changes); the C and W layers also shifted as NR was normalised."""
    live = run.live
    trial = run.h.copy()
    lnr = live[0]
    trial[0][lnr] += newton * run.D[0][lnr]
    for m in run.order:
        lm = live[m]
        trial[m][lm] += newton * (run.D[m][lm] - p.d_shift) - p.shift
    return trial


def _inner_accuracy(p: _Drift, first: bool, coupled: bool, inner_tol: float, tol: float) -> float:
    """The inner accuracy of the next pass: early passes need not be exact.

    It follows the outer progress (:data:`ACCURACY_FACTOR` times the smaller of the drift
    and the shape change) until the passes are no longer capped; from then on a model
    without source or destination changes is solved to the final ``inner_tol``.
    """
    if first:
        return FIRST_ACCURACY
    if p.shape <= EARLY_SHAPE * tol and not coupled:
        return inner_tol
    return min(FIRST_ACCURACY, max(inner_tol, ACCURACY_FACTOR * min(abs(p.drift), p.shape)))


def solve_structured(
    mdp: LayeredMDP,
    tol: float = 1e-6,
    max_sweeps: int = 20000,
    progress: Progress | None = None,
    max_outer: int = 200,
    predictor: bool = True,
    extrapolate: bool = True,
    threads: int | None = None,
    start: tuple[float, np.ndarray] | None = None,
) -> SolveResult:
    """The decomposed solver (see the module docstring and docs/strategies.md).

    Each outer pass, for the current gain ``g``:

    1. solve the C layers, then the W layers (:meth:`_Layers.request_layers`);
    2. solve NR (:meth:`_Layers.nr_layer`); its value at a reference state moved by the
       *drift* ``delta``, which is zero exactly at the optimal gain (NR is normalised
       there, the Bellman equation ``h + g = T h`` then holds round the request cycle;
       :func:`_normalise_nr`);
    3. a Newton step ``g <- g - delta / (d delta / dg)``, the derivative (minus the
       expected cycle length) carried along the minimising actions as ``D``
       (:meth:`_Drift.newton`);
    4. the next NR shape: Anderson-mixed over the last passes (:class:`_ShapeMixer`), or
       with ``extrapolate`` off and ``predictor`` on moved to first order with ``g``
       through ``D``;
    5. once the drift and the NR shape change are within the tolerance
       (:func:`_certificate_due`), the certificate: one Jacobi Bellman sweep over every
       layer moved along the Newton step (:func:`_moved_along_newton`), whose span must
       be below ``tol``.

    ``threads`` overrides the thread count (:mod:`cellplan.strategies.solve.threads`).

    ``start``: ``(g, h_NR)``, a gain and NR values (``(N,)``, finite on NR's live states,
    e.g. a finished solve's ``gain`` and ``values[0]``) to start from instead of
    ``g = dt / 2`` and NR at zero. Every pass then solves its layers to the final inner
    accuracy, uncapped: capped early passes would move away from a good start, after
    which the outer iteration needs as many passes as from scratch. Given the answer's
    own ``g`` and NR the solve takes two passes (one exact pass of the C and W layers
    from cold, one that confirms it): the floor of this solver, which a better start or
    outer iteration could lower by the confirming pass at most
    (``benchmarks/bench_strategies.py --oracle``; docs/benchmarks.md).
    """
    t0 = time.perf_counter()
    live = mdp.live
    lnr = live[0]
    inner_tol = tol * INNER_FACTOR
    exact = start is not None
    with workers_for(int(live.sum()), threads) as workers:
        run = _Layers(mdp, max_sweeps, workers)
        h, D = run.h, run.D
        g = 0.5 * mdp.stage_time
        accuracy = FIRST_ACCURACY
        if start is not None:
            g, nr_start = _checked_start(mdp, start)
            h[0][lnr] = nr_start
            accuracy = inner_tol
        ref = -1
        outer = 0
        prev_term = np.zeros(live.shape[1])  # the NR values the C layers were solved against
        prev_d0 = np.zeros(live.shape[1])
        g_solved = g  # the g the C and W layers were last solved with
        mixer = _ShapeMixer()
        shift = 0.0
        cert: Certificate | None = None
        last_shape = np.inf
        for outer in range(1, max_outer + 1):
            first = outer == 1
            # Warm start (later passes): the largest change of the NR values the C layers
            # read, beyond the change of the old policy's cost under the new g.
            warm: float | None = None
            dg = g - g_solved
            if not first:
                rest = h[0][lnr] - prev_term[lnr] - dg * prev_d0[lnr]
                warm = float(np.max(rest)) + 1e-12
            prev_term = h[0].copy()
            prev_d0 = D[0].copy()
            g_solved = g
            # Early passes (g at its first guess, or the NR shape still moving a lot) get an
            # inexact inner solve: it can neither stop the loop nor try the certificate.
            capped = not exact and last_shape > EARLY_SHAPE * tol
            # Steps 1 and 2: once round the request cycle.
            t_pass = time.perf_counter()
            run.request_layers(g, accuracy, warm, dg, EARLY_SWEEPS if capped else max_sweeps)
            t_layers = time.perf_counter()
            old = h[0].copy()
            old_d = D[0].copy()
            run.nr_layer(g, accuracy, first)
            t_nr = time.perf_counter()
            if ref < 0:
                ref = int(np.flatnonzero(lnr)[np.argmin(h[0][lnr])])
            p = _normalise_nr(h, D, old, old_d, lnr, ref, first)
            shift = p.shift
            last_shape = p.shape
            if progress is not None:
                progress(run.sweeps, p.shape, g)
            log.debug(
                "pass %d: g %.10f drift %.3e d(drift)/dg %.3f NR shape change %.3e accuracy "
                "%.1e%s; C and W layers %.3f s, NR %.3f s",
                outer, g, p.drift, p.deriv, p.shape, accuracy, " (capped)" if capped else "",
                t_layers - t_pass, t_nr - t_layers,
            )  # fmt: skip
            if _settled(p, capped, accuracy, tol, inner_tol):
                break
            # Step 3, and step 5 with it where due.
            newton = p.newton()
            if _certificate_due(p, capped, first, accuracy, tol):
                t_cert = time.perf_counter()
                trial = _moved_along_newton(run, p, newton)
                cert = _certify(mdp, trial, workers, run.model)
                log.debug(
                    "certificate at pass %d: span %.3e (g step %.3e); %.3f s",
                    outer, cert[1] - cert[0], newton, time.perf_counter() - t_cert,
                )  # fmt: skip
                if cert[1] - cert[0] < tol:
                    h[:] = trial
                    shift = 0.0
                    g = g + newton
                    break
                cert = None
            if not exact:
                accuracy = _inner_accuracy(p, first, run.coupled, inner_tol, tol)
            g_prev = g
            g = min(max(g + newton, 0.0), mdp.stage_time)
            # Step 4: the NR values the next pass's C layers read.
            if extrapolate and not first:
                mixer.push(old[lnr] - old[ref], h[0][lnr].copy(), D[0][lnr].copy(), g_prev)
                new_x = mixer.mix(g)
                h[0][lnr] = new_x - new_x[np.searchsorted(np.flatnonzero(lnr), ref)]
            elif predictor:
                h[0][lnr] += (g - g_prev) * D[0][lnr]
            if run.sweeps > max_sweeps:
                break
        for m in run.order:
            h[m][live[m]] -= shift
        result = _finish(
            mdp, h, g, tol, run.sweeps, 0, outer, "structured", t0, max(ref, 0), cert, workers,
            run.model,
        )  # fmt: skip
    result.eval_sweeps = run.evaluations
    return result


def _checked_start(mdp: LayeredMDP, start: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
    """``start``'s gain and NR values on NR's live states, or a ``ValueError`` naming the field."""
    g, nr = start
    values = np.asarray(nr, dtype=np.float64)
    if not (np.isfinite(g) and 0.0 <= g <= mdp.stage_time):
        raise ValueError(f"start: gain {g!r} is not a number in [0, {mdp.stage_time}]")
    if values.shape != (mdp.live.shape[1],):
        raise ValueError(f"start: NR values have shape {values.shape}, not ({mdp.live.shape[1]},)")
    on_live = values[mdp.live[0]]
    if not np.isfinite(on_live).all():
        raise ValueError("start: NR values are not finite on every live NR state")
    return float(g), on_live


def method_problem(mdp: LayeredMDP, method: str, damping: float = 1.0) -> str | None:
    """Why ``method`` (with ``damping``, for ``general``) cannot solve ``mdp`` (one line),
    or None when it can."""
    if method not in METHODS:
        return f"unknown solver method {method!r} (one of {', '.join(METHODS)})"
    if method == "structured" and not mdp.is_simple():
        return (
            "the structured solver needs the Section V model (every fine motion succeeds "
            "with certainty, every move lands where commanded, one FMP per mode, no "
            "period); this model has failure modes, noisy motion, simultaneous requests or "
            "a period: use auto or policy"
        )
    if method == "general" and mdp.period > 1 and damping >= 1.0:
        return (
            "relative value iteration (general) cycles with the period of a time-varying "
            "model (every stage advances the phase): set strategy.solver.damping below 1, "
            "or use auto or policy"
        )
    return None


def solve(
    mdp: LayeredMDP,
    method: str = "auto",
    tol: float = 1e-6,
    max_sweeps: int = 20000,
    damping: float = 1.0,
    progress: Progress | None = None,
    threads: int | None = None,
) -> SolveResult:
    """Solve with the structured method when the model allows it, else by policy iteration.

    ``method``: ``auto`` (structured when :meth:`LayeredMDP.is_simple`, else policy),
    ``structured`` (:func:`solve_structured`, Section V models only: a ``ValueError``
    otherwise), ``policy`` (:func:`~.policy_iteration.solve_policy_iteration`,
    at most ``max_sweeps`` iterations) or ``general`` (:func:`solve_general`).
    ``threads``: worker threads (default :func:`cellplan.strategies.solve.threads.default_threads`;
    problems below :data:`~cellplan.strategies.solve.threads.SERIAL_BELOW` states run serially).
    """
    problem = method_problem(mdp, method, damping)
    if problem is not None:
        raise ValueError(problem)
    if method == "auto":
        method = "structured" if mdp.is_simple() else "policy"
    if method == "structured":
        return solve_structured(mdp, tol, max_sweeps, progress, threads=threads)
    if method == "policy":
        from cellplan.strategies.solve.policy_iteration import solve_policy_iteration

        return solve_policy_iteration(mdp, tol, max_sweeps, progress, threads)
    return solve_general(mdp, tol, max_sweeps, damping, progress, threads)

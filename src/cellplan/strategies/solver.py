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
  connected components (:mod:`cellplan.strategies.evaluation`); a layer is done when a
  *full* sweep changes it by less than the inner accuracy. The independent C layers, then the
  W layers, run in parallel threads (layers coupled by destination or source changes are
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
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellplan.core import Status
from cellplan.strategies import kernels
from cellplan.strategies.model import LayeredMDP

log = logging.getLogger(__name__)
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
# Passes mixed by the Anderson acceleration of the NR shape.
ANDERSON_DEPTH = 4
# Warm passes start each layer with an exact evaluation of last pass's policy.
EVAL_FIRST = True
# Final inner accuracy relative to the span tolerance.
INNER_FACTOR = 1e-2
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

    def stats(self) -> dict[str, float]:
        return {
            "gain": self.gain,
            "gain_lower": self.gain_lower,
            "gain_upper": self.gain_upper,
            "span": self.span,
            "sweeps": float(self.sweeps),
            "full_sweeps": float(self.full_sweeps),
            "eval_sweeps": float(self.eval_sweeps),
            "outer_iterations": float(self.outer_iterations),
            "stable": float(self.stable),
            "policy_changes": float(self.policy_changes),
            "seconds": self.seconds,
        }


def bellman(
    mdp: LayeredMDP, h: np.ndarray, subset: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(T h, policy, gap)``: one Jacobi sweep of equation (9) over every state (no ``g``).

    ``gap`` is the second-best action value minus the best, per state. With ``subset``
    (boolean, like ``h``) only those states are swept; the outputs elsewhere are NaN / -3.
    """
    out = np.full_like(h, np.nan)
    policy = np.full(h.shape, -3, np.int64)
    gap = np.full_like(h, np.nan)
    mask = np.zeros((0, 0), np.bool_) if subset is None else subset
    kernels.bellman_all(h, out, policy, gap, mask, mdp.kernel_args())
    return out, policy, gap


Certificate = tuple[float, float, np.ndarray, np.ndarray, np.ndarray]


def _certify(mdp: LayeredMDP, h: np.ndarray) -> Certificate:
    th, policy, gap = bellman(mdp, h)
    r = (th - h)[mdp.live]
    return float(r.min()), float(r.max()), th, policy, gap


def _stability(mdp: LayeredMDP, cert: Certificate, g: float) -> int:
    """States whose action changes in one more Bellman sweep, ``T (T h - g)`` against ``T h``.

    ``T h - g = h + r`` with ``span(r)`` the certificate's span, so an action can change only
    where its margin over the second-best action is at most that span (ties included); the
    second sweep visits only those states.
    """
    lo, hi, th, policy, gap = cert
    live = mdp.live
    # Float slack: values are sums of tens of terms of size up to |T h|.
    slack = (hi - lo) + 1e-9 * np.maximum(1.0, np.abs(np.where(live, th, 0.0)))
    near = live & (gap <= slack)
    if not np.any(near):
        return 0
    _, policy2, _ = bellman(mdp, th - g, near)
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
) -> SolveResult:
    # ``cert``: the certificate of this very ``h``, when the caller already computed it.
    cert = _certify(mdp, h) if cert is None else cert
    lo, hi, _, policy, _ = cert
    full += 1
    span = hi - lo
    g = 0.5 * (lo + hi) if span < tol else g_hint
    changes = _stability(mdp, cert, g)
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
    for k in range(1, max_sweeps + 1):
        th, _, _ = bellman(mdp, h)
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
    return _finish(mdp, h, g, tol, k, k, k, "general", t0, ref)


def _layer_key(mdp: LayeredMDP, m: int, groups: dict[int, int]) -> bytes:
    dig = hashlib.sha1()
    nxt = int(mdp.fmp_next[m])
    dig.update(np.array([mdp.vcls[m], groups.get(nxt, nxt), mdp.cost[m]]).tobytes())
    dig.update(mdp.tf[m].tobytes())
    dig.update(mdp.live[m].tobytes())
    return dig.digest()


def solve_structured(
    mdp: LayeredMDP,
    tol: float = 1e-6,
    max_sweeps: int = 20000,
    progress: Progress | None = None,
    max_outer: int = 200,
    predictor: bool = True,
    extrapolate: bool = True,
) -> SolveResult:
    """The decomposed solver (see the module docstring).

    With destination or source changes the C (or W) layers are coupled; they are then
    solved together by Gauss-Seidel rounds over the group, started from the uncoupled
    solution (each layer as if its request never changed).

    ``extrapolate`` turns on the Anderson acceleration of the NR shape; without it,
    ``predictor`` moves the NR shape with ``g`` to first order through ``D``.
    """
    t0 = time.perf_counter()
    coupled = mdp.has_changes()
    live = mdp.live
    R = mdp.n_requests
    d = len(mdp.shape)
    h = np.zeros(live.shape)
    D = np.zeros(live.shape)
    args = mdp.kernel_args()
    inner_tol = tol * INNER_FACTOR
    # Layers with identical data (move class, successor, fine-motion field, live set) share values.
    groups: dict[int, int] = {}
    reps: dict[bytes, int] = {}
    order = [mdp.c_layer(r) for r in range(R)] + [mdp.w_layer(r) for r in range(R)]
    for m in order:
        key = _layer_key(mdp, m, groups)
        groups[m] = m if coupled else reps.setdefault(key, m)
    sweeps = 0
    eval_sweeps = 0
    pol = np.full(live.shape, -3, np.int16)
    layer_args = args
    c_reps = np.array([m for m in order[:R] if groups[m] == m], np.int64)
    w_reps = np.array([m for m in order[R:] if groups[m] == m], np.int64)
    # The uncoupled model: every move keeps the request (used to start coupled groups).
    ptr, lay, prob = mdp.branch_ptr, mdp.branch_layer, mdp.branch_prob
    solo_prob = prob.copy()
    for m in range(1, mdp.n_modes):
        for b in range(ptr[m], ptr[m + 1]):
            solo_prob[b] = 1.0 if lay[b] == m else 0.0
    solo_args = (*args[:-5], ptr, lay, solo_prob, *args[-2:])

    # A Dijkstra first policy pays off where Gauss-Seidel from +inf is slow to cross the
    # layer: 3-D joint spaces (8 sweep orders). In the plane 4 orders suffice, and for a
    # robot-frame heading axis its predecessor search costs more than it saves.
    cold_dijkstra = d >= 3 and mdp.heading_axis < 0

    def solve_layer(
        m: int, g: float, exact_stay: bool, accuracy: float, warm: float | None
    ) -> None:
        # Gauss-Seidel on a shortest path converges fast from above and creeps up from below.
        # The first pass starts from +inf; later passes start from the last solution moved by
        # the exact change of its old policy's cost under the new g (D is d h / d g along
        # it) plus the largest change of the terminal NR values beyond that - an upper bound
        # within the spread of those changes, which is tiny once the NR shape has settled.
        nonlocal sweeps
        lm = live[m]
        if warm is None:
            h[m][lm] = np.inf
        else:
            h[m][lm] += dg * D[m][lm] + warm
        for s in range(max(1, max_sweeps)):
            change = kernels.sweep_layer(m, s % (1 << d), h, D, g, exact_stay, True, layer_args)
            sweeps += 1
            if change < accuracy:
                return

    def start_layer(m: int, warm: float | None) -> None:
        lm = live[m]
        if warm is None:
            h[m][lm] = np.inf
        else:
            h[m][lm] += dg * D[m][lm] + warm

    # NR: its request branches lead to the W layers, fixed while NR is solved; their
    # expected values per (cell, action) are computed once per pass (kernels.other_branches)
    # so that each Gauss-Seidel sweep of NR interpolates only NR itself.
    n_act = int(mdp.nact[mdp.vcls[0]])
    E = np.empty((live.shape[1], n_act + 1))
    ED = np.empty_like(E)
    p_self = float(
        sum(
            mdp.branch_prob[b]
            for b in range(mdp.branch_ptr[0], mdp.branch_ptr[1])
            if mdp.branch_layer[b] == 0
        )
    )

    def solve_nr(g: float, accuracy: float, cold: bool) -> None:
        # The first pass starts from +inf (Gauss-Seidel then decreases monotonically);
        # later passes evaluate last pass's NR policy exactly first, then sweep.
        nonlocal sweeps, eval_sweeps
        kernels.other_branches(0, h, D, E, ED, args)
        if cold:
            h[0][live[0]] = np.inf
        counts = np.zeros(2, np.int64)
        kernels.solve_self(
            0, h, D, g, E, ED, p_self, accuracy, max_sweeps, pol, not cold, counts, args
        )
        sweeps += int(counts[0])
        eval_sweeps += int(counts[1])
        log.debug("NR: full sweeps %d, evaluations %d", counts[0], counts[1])

    def solve_group(ms: list[int], g: float, accuracy: float, warm: float | None) -> None:
        # Gauss-Seidel rounds over layers coupled by request changes.
        nonlocal sweeps, layer_args
        if warm is None:
            layer_args = solo_args
            for m in ms:
                solve_layer(m, g, False, accuracy, None)
            layer_args = args
        else:
            for m in ms:
                h[m][live[m]] += dg * D[m][live[m]] + warm
        for s in range(max(1, max_sweeps)):
            change = 0.0
            for m in ms:
                change = max(
                    change, kernels.sweep_layer(m, s % (1 << d), h, D, g, False, True, args)
                )
            sweeps += len(ms)
            if change < accuracy:
                return

    g = 0.5 * mdp.stage_time
    g_prev = g
    ref = -1
    outer = 0
    accuracy = FIRST_ACCURACY
    prev_term = np.zeros(live.shape[1])  # the NR values the C layers were last solved against
    prev_d0 = np.zeros(live.shape[1])
    g_solved = g  # the g the C and W layers were last solved with
    dg = 0.0
    hist_x: list[np.ndarray] = []
    hist_f: list[np.ndarray] = []
    hist_d: list[np.ndarray] = []
    hist_g: list[float] = []
    shift = 0.0
    cert: Certificate | None = None
    last_shape = np.inf
    for outer in range(1, max_outer + 1):
        warm: float | None = None
        if outer > 1:
            lnr = live[0]
            dg = g - g_solved
            rest = h[0][lnr] - prev_term[lnr] - dg * prev_d0[lnr]
            warm = float(np.max(rest)) + 1e-12
        prev_term = h[0].copy()
        prev_d0 = D[0].copy()
        g_solved = g
        # An early pass (see EARLY_SWEEPS) may end with the layers short of the accuracy, so
        # it can neither stop the loop nor try the certificate.
        capped = last_shape > EARLY_SHAPE * tol
        layer_cap = EARLY_SWEEPS if capped else max_sweeps
        if coupled:
            solve_group([mdp.c_layer(r) for r in range(R)], g, accuracy, warm)
            solve_group([mdp.w_layer(r) for r in range(R)], g, accuracy, warm)
        else:
            # C layers read only NR and W layers only C layers: each set is solved in parallel.
            for kind in (c_reps, w_reps):
                for m in kind:
                    start_layer(m, warm)
                counts = np.zeros((len(kind), 2), np.int64)
                kernels.solve_layers(
                    kind,
                    h,
                    D,
                    g,
                    accuracy,
                    layer_cap,
                    pol,
                    EVAL_FIRST and warm is not None,
                    cold_dijkstra,
                    counts,
                    args,
                )
                sweeps += int(counts[:, 0].sum())
                eval_sweeps += int(counts[:, 1].sum())
                log.debug(
                    "layers %s: full sweeps %s, evaluations %s",
                    kind.tolist(),
                    counts[:, 0].tolist(),
                    counts[:, 1].tolist(),
                )
            for m in order:
                if groups[m] != m:
                    h[m] = h[groups[m]]
                    D[m] = D[groups[m]]
        old = h[0].copy()
        old_d = D[0].copy()
        solve_nr(g, accuracy, outer == 1)
        if ref < 0:
            ref = int(np.flatnonzero(live[0])[np.argmin(h[0][live[0]])])
        delta = (h[0] - old)[live[0]]
        # On the first pass the old NR values are the initial zeros: a rough but useful drift.
        drift = float(h[0, ref] - old[ref])
        # d(drift)/dg with the NR layer's own dependence on g carried through D.
        deriv = float(D[0, ref] - old_d[ref])
        shape_span = float(delta.max() - delta.min()) if outer > 1 else np.inf
        last_shape = shape_span
        # Normalise NR at the reference state; C and W keep their raw values (they were
        # solved against prev_term) and are shifted only at the end.
        shift = float(h[0, ref])
        h[0][live[0]] -= shift
        D[0][live[0]] -= D[0, ref]
        if progress is not None:
            progress(sweeps, shape_span, g)
        log.debug(
            "pass %d: g %.10f drift %.3e d(drift)/dg %.3f NR shape change %.3e inner accuracy %.1e",
            outer,
            g,
            drift,
            deriv,
            shape_span,
            accuracy,
        )
        if (
            not capped
            and abs(drift) < tol * 0.1
            and shape_span < tol * 0.1
            and accuracy <= inner_tol
        ):
            break
        # The certificate's span is about the larger of the drift and the NR shape change
        # (the drift shows up as the inconsistency at the FMP into NR): try it once both are
        # within the tolerance; a failed attempt costs one Jacobi sweep.
        if not capped and outer > 1 and abs(drift) < tol and shape_span < tol * 0.5:
            # Close enough to try the certificate now rather than after another pass.
            trial = h.copy()
            for m in order:
                trial[m][live[m]] -= shift
            cert = _certify(mdp, trial)
            log.debug("certificate at pass %d: span %.3e", outer, cert[1] - cert[0])
            if cert[1] - cert[0] < tol:
                h[:] = trial
                shift = 0.0
                break
            cert = None
        # Inner accuracy follows the outer progress: early passes need not be exact.
        accuracy = (
            min(FIRST_ACCURACY, max(inner_tol, ACCURACY_FACTOR * min(abs(drift), shape_span)))
            if outer > 1
            else FIRST_ACCURACY
        )
        # Newton step on the drift; the NR shape follows g to first order through D (the
        # predictor below), so g can move every pass instead of waiting for the shape.
        step = -drift / deriv if deriv < 0 else 0.0
        g_prev = g
        g = min(max(g + step, 0.0), mdp.stage_time)
        if extrapolate and outer > 1:
            # Anderson acceleration of the NR shape: one pass maps the NR values the C layers
            # see (x) to the NR values that come out (f); near the answer the map is affine,
            # and the request cycle can have slow modes (the arms of problems 5 and 6
            # remember their joint configuration from one delivery to the next, so the shape
            # error shrinks by only a factor 2-3 per pass). Mixing the last few passes
            # removes those modes. Outputs are moved to the new g through D.
            lnr = live[0]
            hist_x.append(old[lnr] - old[ref])
            hist_f.append(h[0][lnr].copy())
            hist_d.append(D[0][lnr].copy())
            hist_g.append(g_prev)
            if len(hist_x) > ANDERSON_DEPTH + 1:
                del hist_x[0], hist_f[0], hist_d[0], hist_g[0]
            f_now = [f + (g - gi) * di for f, di, gi in zip(hist_f, hist_d, hist_g, strict=True)]
            res_now = [f - x for f, x in zip(f_now, hist_x, strict=True)]
            new_x = f_now[-1]
            if len(res_now) > 1:
                dr = np.stack([res_now[i + 1] - res_now[i] for i in range(len(res_now) - 1)], 1)
                df = np.stack([f_now[i + 1] - f_now[i] for i in range(len(f_now) - 1)], 1)
                gamma = np.linalg.lstsq(dr, res_now[-1], rcond=None)[0]
                new_x = f_now[-1] - df @ gamma
            h[0][lnr] = new_x - new_x[np.searchsorted(np.flatnonzero(lnr), ref)]
        elif predictor:
            h[0][live[0]] += (g - g_prev) * D[0][live[0]]
        if sweeps > max_sweeps:
            break
    for m in order:
        h[m][live[m]] -= shift
    result = _finish(mdp, h, g, tol, sweeps, 0, outer, "structured", t0, max(ref, 0), cert)
    result.eval_sweeps = eval_sweeps
    return result


def solve(
    mdp: LayeredMDP,
    method: str = "auto",
    tol: float = 1e-6,
    max_sweeps: int = 20000,
    damping: float = 1.0,
    progress: Progress | None = None,
) -> SolveResult:
    """Solve with the structured method when the model allows it, else the general one."""
    if method == "auto":
        method = "structured"
    if method == "structured":
        return solve_structured(mdp, tol, max_sweeps, progress)
    return solve_general(mdp, tol, max_sweeps, damping, progress)

"""The certificate every solve ends with, and relative value iteration (numba kernels in
:mod:`.bellman`).

One Jacobi Bellman sweep over every state (:func:`bellman`, the right-hand side of
equation (9) of the strategies paper, the transition law of :mod:`.law`) brackets the
optimal gain: ``min (T h - h) <= g <= max (T h - h)`` over the live states (the span
test of relative value iteration, :func:`certify`); a second sweep over the near ties
checks that the actions are stable (:func:`stability`). :func:`finish` turns a solver's
values into its :class:`SolveResult` so; :func:`solve_general` is relative value
iteration, which needs nothing else.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellplan.core import Status
from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.mdp import LayeredMDP
from cellplan.strategies.solve import bellman as bellman_kernels
from cellplan.strategies.solve.improvement import improvable
from cellplan.strategies.solve.threads import Workers, workers_for

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


def certify(
    mdp: LayeredMDP, h: np.ndarray, workers: Workers | None = None, model: Model | None = None
) -> Certificate:
    """The span test: ``min (T h - h) <= g <= max (T h - h)`` over the live states."""
    th, policy, gap = bellman(mdp, h, workers=workers, model=model)
    lo, hi = bellman_kernels.residual_range(th, h, mdp.live)
    return float(lo), float(hi), th, policy, gap


def stability(
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


@dataclass(frozen=True)
class Tally:
    """What a solve counted, for its :class:`SolveResult`: the method, its start time
    (``time.perf_counter``), the layer sweeps, full Bellman sweeps and outer iterations,
    and the reference state ``ref`` of NR at which the values are normalised."""

    method: str
    t0: float
    sweeps: int
    full: int
    outer: int
    ref: int


def finish(
    mdp: LayeredMDP,
    h: np.ndarray,
    g_hint: float,
    tol: float,
    tally: Tally,
    cert: Certificate | None = None,
    workers: Workers | None = None,
    model: Model | None = None,
) -> SolveResult:
    """Certify ``h`` (the span test, :func:`certify`; ``cert``: the certificate of this very
    ``h`` when the caller already computed it), check the stability of its actions
    (:func:`stability`) and return the :class:`SolveResult`. The gain is the middle of the
    bracket when the test passes, ``g_hint`` otherwise."""
    cert = certify(mdp, h, workers, model) if cert is None else cert
    lo, hi, _, policy, _ = cert
    full = tally.full + 1
    span = hi - lo
    g = 0.5 * (lo + hi) if span < tol else g_hint
    changes = stability(mdp, cert, g, workers, model)
    full += 1
    values = np.where(mdp.live, h - h[0, tally.ref], np.nan)
    return SolveResult(
        values=values,
        gain=g,
        gain_lower=lo,
        gain_upper=hi,
        span=span,
        sweeps=tally.sweeps,
        full_sweeps=full,
        outer_iterations=tally.outer,
        status=Status.SOLVED if span < tol else Status.NOT_CONVERGED,
        stable=changes == 0,
        policy_changes=changes,
        policy=policy.astype(np.int16),
        method=tally.method,
        seconds=time.perf_counter() - tally.t0,
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
        return finish(mdp, h, g, tol, Tally("general", t0, k, k, k, ref), workers=workers)

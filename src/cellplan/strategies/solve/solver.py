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

import logging
import time
import typing
from dataclasses import dataclass

import numpy as np

from cellplan.strategies.model.mdp import LayeredMDP
from cellplan.strategies.section import SolverMethod
from cellplan.strategies.solve.certify import (
    INNER_FACTOR,
    Certificate,
    Progress,
    SolveResult,
    Tally,
    bellman,
    certify,
    finish,
    solve_general,
    stability,
)
from cellplan.strategies.solve.layers import Layers
from cellplan.strategies.solve.policy_iteration import solve_policy_iteration
from cellplan.strategies.solve.threads import workers_for
from cellplan.strategies.variants.registry import model_variants

# The solver's public names, with those of the certificate it ends with (:mod:`.certify`).
__all__ = [
    "INNER_FACTOR",
    "METHODS",
    "Certificate",
    "Progress",
    "SolveResult",
    "bellman",
    "certify",
    "method_problem",
    "solve",
    "solve_general",
    "solve_structured",
    "stability",
]

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


def _moved_along_newton(run: Layers, p: _Drift, newton: float) -> np.ndarray:
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


@dataclass(frozen=True)
class OuterLoop:
    """The outer loop of :func:`solve_structured`: at most ``max_outer`` passes; the next
    NR shape Anderson-mixed over the last passes (``extrapolate``), else, with
    ``predictor``, moved to first order with ``g`` through ``D``."""

    max_outer: int = 200
    predictor: bool = True
    extrapolate: bool = True


def solve_structured(
    mdp: LayeredMDP,
    tol: float = 1e-6,
    max_sweeps: int = 20000,
    progress: Progress | None = None,
    loop: OuterLoop = OuterLoop(),
    threads: int | None = None,
    start: tuple[float, np.ndarray] | None = None,
) -> SolveResult:
    """The decomposed solver (see the module docstring and docs/strategies.md).

    Each outer pass, for the current gain ``g`` (``loop``: :class:`OuterLoop`):

    1. solve the C layers, then the W layers (:meth:`Layers.request_layers`);
    2. solve NR (:meth:`Layers.nr_layer`); its value at a reference state moved by the
       *drift* ``delta``, which is zero exactly at the optimal gain (NR is normalised
       there, the Bellman equation ``h + g = T h`` then holds round the request cycle;
       :func:`_normalise_nr`);
    3. a Newton step ``g <- g - delta / (d delta / dg)``, the derivative (minus the
       expected cycle length) carried along the minimising actions as ``D``
       (:meth:`_Drift.newton`);
    4. the next NR shape (:func:`_next_nr`);
    5. once the drift and the NR shape change are within the tolerance
       (:func:`_certificate_due`), the certificate: one Jacobi Bellman sweep over every
       layer moved along the Newton step (:func:`_moved_along_newton`), whose span must
       be below ``tol``.

    ``threads`` overrides the thread count (:mod:`cellplan.strategies.solve.threads`).
    ``start``: ``(g, h_NR)``, a gain and NR values to start from instead of ``g = dt / 2``
    and NR at zero (:func:`_checked_start`; every pass is then solved to the final inner
    accuracy, uncapped: the solver's floor, ``benchmarks/bench_strategies.py --oracle``).
    """
    t0 = time.perf_counter()
    live = mdp.live
    lnr = live[0]
    inner_tol = tol * INNER_FACTOR
    exact = start is not None
    with workers_for(int(live.sum()), threads) as workers:
        run = Layers(mdp, max_sweeps, workers)
        h, D = run.h, run.D
        g = 0.5 * mdp.stage_time
        accuracy = FIRST_ACCURACY
        if start is not None:
            g, nr_start = _checked_start(mdp, start)
            h[0][lnr] = nr_start
            accuracy = inner_tol
        ref, outer, shift, last_shape = -1, 0, 0.0, np.inf
        # The NR values (and D) the C layers were solved against, and the g they were.
        prev_term, prev_d0, g_solved = np.zeros(live.shape[1]), np.zeros(live.shape[1]), g
        mixer = _ShapeMixer()
        cert: Certificate | None = None
        for outer in range(1, loop.max_outer + 1):
            first = outer == 1
            dg = g - g_solved
            warm = None if first else _warm(h[0], lnr, prev_term, prev_d0, dg)
            prev_term, prev_d0, g_solved = h[0].copy(), D[0].copy(), g
            # Early passes (g at its first guess, or the NR shape still moving a lot) get an
            # inexact inner solve: it can neither stop the loop nor try the certificate.
            capped = not exact and last_shape > EARLY_SHAPE * tol
            cap = EARLY_SWEEPS if capped else max_sweeps
            old, old_d, secs = _round_trip(run, g, accuracy, warm, dg, cap, first)
            if ref < 0:
                ref = int(np.flatnonzero(lnr)[np.argmin(h[0][lnr])])
            p = _normalise_nr(h, D, old, old_d, lnr, ref, first)
            shift, last_shape = p.shift, p.shape
            if progress is not None:
                progress(run.sweeps, p.shape, g)
            log.debug(
                "pass %d: g %.10f drift %.3e d(drift)/dg %.3f NR shape change %.3e accuracy "
                "%.1e%s; C and W layers %.3f s, NR %.3f s", outer, g, p.drift, p.deriv,
                p.shape, accuracy, " (capped)" if capped else "", *secs,
            )  # fmt: skip
            if _settled(p, capped, accuracy, tol, inner_tol):
                break
            # Step 3, and step 5 with it where due.
            newton = p.newton()
            if _certificate_due(p, capped, first, accuracy, tol):
                cert = _attempt(run, p, newton, tol, outer)
                if cert is not None:
                    shift = 0.0
                    g = g + newton
                    break
            if not exact:
                accuracy = _inner_accuracy(p, first, run.coupled, inner_tol, tol)
            g_prev = g
            g = min(max(g + newton, 0.0), mdp.stage_time)
            # Step 4: the NR values the next pass's C layers read.
            if loop.extrapolate and not first:
                mixer.push(old[lnr] - old[ref], h[0][lnr].copy(), D[0][lnr].copy(), g_prev)
                _next_nr(h[0], lnr, mixer.mix(g), ref)
            elif loop.predictor:
                h[0][lnr] += (g - g_prev) * D[0][lnr]
            if run.sweeps > max_sweeps:
                break
        for m in run.order:
            h[m][live[m]] -= shift
        tally = Tally("structured", t0, run.sweeps, 0, outer, max(ref, 0))
        result = finish(mdp, h, g, tol, tally, cert, workers, run.model)
    result.eval_sweeps = run.evaluations
    return result


def _round_trip(
    run: Layers,
    g: float,
    accuracy: float,
    warm: float | None,
    dg: float,
    cap: int,
    first: bool,
) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Steps 1 and 2 of a pass of :func:`solve_structured`: once round the request cycle.

    Returns NR's values and ``D`` from before NR was solved, and the seconds the C and W
    layers and NR took."""
    t_pass = time.perf_counter()
    run.request_layers(g, accuracy, warm, dg, cap)
    t_layers = time.perf_counter()
    old = run.h[0].copy()
    old_d = run.D[0].copy()
    run.nr_layer(g, accuracy, first)
    return old, old_d, (t_layers - t_pass, time.perf_counter() - t_layers)


def _warm(
    nr: np.ndarray, lnr: np.ndarray, prev: np.ndarray, prev_d: np.ndarray, dg: float
) -> float:
    """The warm start of a later pass's C and W layers: the largest change of the NR
    values ``nr`` they read since ``prev`` (``prev_d`` its ``D``), beyond the change of
    the old policy's cost under the new ``g`` (``dg``)."""
    rest = nr[lnr] - prev[lnr] - dg * prev_d[lnr]
    return float(np.max(rest)) + 1e-12


def _attempt(run: Layers, p: _Drift, newton: float, tol: float, outer: int) -> Certificate | None:
    """Step 5: the certificate of every layer moved along the Newton step
    (:func:`_moved_along_newton`); where its span is below ``tol`` the layers take the
    moved values and the certificate is returned, else None."""
    t_cert = time.perf_counter()
    trial = _moved_along_newton(run, p, newton)
    cert = certify(run.mdp, trial, run.workers, run.model)
    log.debug(
        "certificate at pass %d: span %.3e (g step %.3e); %.3f s",
        outer, cert[1] - cert[0], newton, time.perf_counter() - t_cert,
    )  # fmt: skip
    if cert[1] - cert[0] < tol:
        run.h[:] = trial
        return cert
    return None


def _next_nr(nr: np.ndarray, lnr: np.ndarray, new_x: np.ndarray, ref: int) -> None:
    """Step 4: NR's live values set to the mixed shape ``new_x`` (Anderson,
    :class:`_ShapeMixer`), normalised to zero at the reference state ``ref``."""
    nr[lnr] = new_x - new_x[np.searchsorted(np.flatnonzero(lnr), ref)]


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
    for variant in model_variants(mdp):
        problems = variant.check_solver(method, damping)
        if problems:
            return problems[0]
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
        return solve_policy_iteration(mdp, tol, max_sweeps, progress, threads)
    return solve_general(mdp, tol, max_sweeps, damping, progress, threads)

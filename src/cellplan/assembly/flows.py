"""Integrating the gradient flows of the navigation function (Sections 3.3, 4.1, 4.2.1).

The paper integrates the normalised system ``b' = -lambda grad phi``,
``lambda = (epsilon + ||grad phi||)^-1`` (Section 3.3). Its trajectories are the
trajectories of ``b' = -v`` for any positive rescaling ``v`` of ``grad phi``; we integrate
``b' = -v`` with ``v = exp(-s) grad phi`` from :func:`navigation.evaluate` (well scaled:
``v ~ b - d`` near the goal, free of ``beta`` and ``gamma^k``), so the path and hence every
path-length figure is the paper's, and we recover the normalised system's own time
``T = int ds / ||lambda grad phi||`` in log space (``epsilon`` only enters there).

Two integrators, both with steps bounded by the current clearance:

* ``method="implicit"`` (default): the normalised flow by arc length, each step a
  linearly implicit (Rosenbrock-Euler) step on ``L = log alpha^(1/k)`` with the analytic
  Hessian (:func:`implicit_step`), which resolves the stiff repulsion near contacts
  without creeping; a step is accepted only if along the straight segment no gap falls
  below half its value (:func:`segment_is_safe`, exact) and ``L`` decreases, otherwise
  the trust radius halves.
* ``method="rk4"``: classical Runge-Kutta 4 on ``b' = -v``; with per-disc displacements
  ``delta_i`` the centre distance of discs i, j changes by at most ``||delta_i|| +
  ||delta_j||`` along the straight step, so requiring that sum to stay below a fraction
  of their gap (and ``||delta_i||`` below the boundary gap) means no step can jump into
  or through a collision. A step that violates the bound is halved and retried.

Outcomes: ``solved`` (goal tolerance reached), ``stuck`` (a critical point other than
the goal, classified ``spurious minimum`` or ``saddle`` by the Hessian, or no progress,
or a collapsed step), ``budget_exhausted`` (step budget spent).

Escaping spurious minima (:func:`gradient_flow`, ``escapes > 0``). The stuck points we
see are true minima of phi at that k (positive definite Hessian: two discs of a packed
cluster on each other's goals; perturbed points flow back), so no perturbation leaves
them. ``escape="halve-k"`` (Section 3.2: k "will be adjusted ... to eliminate local
minima"): the run continues from where it stopped with ``k * escape_factor``, as often
as ``escapes`` allows; every stage is the paper's gradient algorithm with one k and
:attr:`FlowResult.stages` records each. On packed clusters of 12 or more discs this
spreads the discs instead of assembling them (issue 13). ``escape="place"`` (the
planner's default): the place rule of :mod:`cellplan.assembly.sequential` finishes from
the stuck point, or, when it cannot unpack the cluster, after one collision-free
spreading move (:func:`expand_cluster`); docs/assembly.md, "Escaping spurious minima".
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.eigen import eigvalsh, one_blas_thread, shift_for_length
from cellplan.assembly.kernels import (
    max_dt_kernel,
    rk4_stages_kernel,
    segment_kernel,
    triangle_safe_kernel,
)
from cellplan.assembly.layout import legality_problems
from cellplan.assembly.navigation import (
    NavEval,
    clearances,
    evaluate,
    hessian_log_w,
    log_w,
    workspace_args,
)
from cellplan.assembly.options import STEP_MAX_FLOOR, STEP_MAX_PER_SQRT_DISC
from cellplan.assembly.problems import DiscProblem
from cellplan.core import Status

if TYPE_CHECKING:
    from cellplan.assembly.sequential import SequentialResult

Array = NDArray[np.float64]

#: fraction of a gap one step may use (checked exactly after each step)
STEP_FRACTION = 0.5


@dataclass(frozen=True)
class FlowSettings:
    """Integration settings shared by the gradient and the low-level flows.

    Attributes
    ----------
    dt_max
        Largest step of ``b' = -v`` (``v ~ b - d`` near the goal: the rate there is 1).
    euler_fraction
        Fraction of the gap the Euler estimate of a step may use when choosing ``dt``.
    max_steps
        Step budget; exceeding it ends the run with ``budget_exhausted``.
    stall_ratio
        ``||v|| < stall_ratio ||b - d||`` away from the goal means a critical point
        other than the goal (spurious minimum or saddle): the run is ``stuck``.
    window
        Steps over which progress is measured: the decrease of ``log alpha^(1/k) =
        log gamma - log(beta) / k``, a monotone function of ``phi`` (equation (6)).
    min_progress
        Decrease over ``window`` steps below which the run is ``stuck``.
    stiff_bound
        Bound ``dt`` by the repulsion stiffness (accurate paths; the gradient flow).
        Without it (the low-level flows of the sequential algorithm, where only the
        limit point matters) ``dt`` follows the net speed and a step is accepted only
        if it decreases ``log alpha^(1/k)`` (the flow is a descent flow), which stops
        the stiff overshoot at a fraction of the steps.
    normalize
        ``eta``: integrate ``b' = -v / (eta + ||v||)`` instead of ``b' = -v``: the
        normalisation of Section 3.3 applied to ``v`` (same trajectories). Speed is
        about 1 wherever ``||v|| >> eta`` (also near saddles, where ``b' = -v`` crawls)
        and about ``||v|| / eta`` near the goal. ``None``: no normalisation (RK4 only).
    method
        ``"implicit"`` (default): the normalised flow stepped by arc length with a
        linearly implicit (Rosenbrock-Euler) step on ``L = log alpha^(1/k)``, see
        :func:`implicit_step`; ``"rk4"``: classical Runge-Kutta 4 on ``b' = -v`` with the
        speed and stiffness step bounds (``dt_max``, ``euler_fraction``, ``stiff_bound``).
    step_max
        Implicit method: largest step length in R^2n (the trust radius never exceeds it).
    goal_fraction
        Implicit method: a step is at most this fraction of ``||b - d||``, so the run
        approaches the goal geometrically (the flow is radial there).
    """

    dt_max: float = 0.25
    euler_fraction: float = 0.3
    max_steps: int = 50000
    stall_ratio: float = 1e-4
    window: int = 200
    min_progress: float = 1e-7
    stiff_bound: bool = True
    normalize: float | None = None
    method: Literal["implicit", "rk4"] = "implicit"
    step_max: float = STEP_MAX_FLOOR
    goal_fraction: float = 0.5


@dataclass(frozen=True)
class Stage:
    """One stage of a gradient run: the k it used, how it ended, its steps."""

    k: float
    status: Status
    reason: str
    steps: int


@dataclass
class FlowResult:
    """A path of a flow and how it ended.

    ``stages`` lists the k-stages of :func:`gradient_flow` (one stage unless a stuck
    run was continued at a smaller k); empty for the low-level flows. ``problem`` is the
    problem :func:`gradient_flow` solved (``None`` for the low-level flows).
    """

    status: Status
    path: Array  # (m, n, 2) accepted configurations, the start first
    steps: int
    evaluations: int
    min_clearance: float
    log_time: float  # log of the normalised system's time (Section 3.3)
    reason: str = ""
    log_w: list[float] = field(default_factory=list)
    stages: list[Stage] = field(default_factory=list)
    problem: DiscProblem | None = None  # set by gradient_flow (the planners' solution)
    #: the place rule's run that finished a stuck flow (``escape="place"``), else None
    placement: SequentialResult | None = None
    #: where the flow was stuck when the place rule took over (``escape="place"``)
    stuck_at: Array | None = None

    @property
    def escapes(self) -> int:
        """Number of times k was lowered after a stuck stage."""
        return max(len(self.stages) - 1, 0)

    @property
    def end(self) -> Array:
        return self.path[-1]

    def length(self) -> float:
        """Path length in R^2n (Section 5.1)."""
        seg = np.diff(self.path, axis=0).reshape(len(self.path) - 1, self.path[0].size)
        return float(np.sum(np.linalg.norm(seg, axis=1)))

    def disc_lengths(self) -> Array:
        """Distance travelled by each disc (n,)."""
        seg = np.diff(self.path, axis=0)
        return np.sum(np.linalg.norm(seg, axis=2), axis=0)


def max_dt(
    w: Array, ev: NavEval, moving: Array, gaps: Array, bgap: Array, stiff: bool = True
) -> float:
    """Largest ``dt`` for which the Euler step stays within every gap.

    Per pair, ``dt (||w_i|| + ||w_j|| + 2 rep_ij) <= gap_ij`` (and per disc the same with
    the boundary): the speeds bound the motion, the repulsion magnitudes ``rep`` of
    :class:`NavEval` bound the stiffness, ``|d v / d gap| ~ rep / gap``, so that the
    stiff repulsion near a contact is resolved rather than overshot. ``moving`` (n,)
    is the field's scale factor (``lambda``) for the discs that move, 0 for the others.
    One pass over the pairs (:func:`kernels.max_dt_kernel`); :func:`max_dt_numpy` is
    its reference.
    """
    return float(
        max_dt_kernel(
            np.ascontiguousarray(w, dtype=np.float64),
            ev.rep,
            ev.rep_bnd,
            np.ascontiguousarray(moving, dtype=np.float64),
            gaps,
            bgap,
            bool(stiff),
        )
    )


def max_dt_numpy(
    w: Array, ev: NavEval, moving: Array, gaps: Array, bgap: Array, stiff: bool = True
) -> float:
    """:func:`max_dt` on ``(n, n)`` numpy arrays (the reference of its kernel)."""
    speed = np.sqrt(np.sum(w * w, axis=1))
    # ``moving`` carries the field's scale factor, so the stiffness is scaled with it
    pair_moves = np.maximum(moving[:, None], moving[None, :]) * (1.0 if stiff else 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        pair = gaps / (speed[:, None] + speed[None, :] + 2.0 * ev.rep * pair_moves)
        bnd = bgap / (speed + ev.rep_bnd * moving * (1.0 if stiff else 0.0))
    return float(min(np.min(pair), np.min(bnd)))


def step_is_safe(delta: Array, gaps: Array, bgap: Array, fraction: float) -> bool:
    """True when no disc pair or disc and boundary can meet along the straight step.

    Per pair the centre distance changes by at most ``||delta_i|| + ||delta_j||`` along
    the step; one pass over the pairs (:func:`kernels.triangle_safe_kernel`),
    :func:`step_is_safe_numpy` is its reference.
    """
    return bool(
        triangle_safe_kernel(
            np.ascontiguousarray(delta, dtype=np.float64), gaps, bgap, float(fraction)
        )
    )


def step_is_safe_numpy(delta: Array, gaps: Array, bgap: Array, fraction: float) -> bool:
    """:func:`step_is_safe` on ``(n, n)`` numpy arrays (the reference of its kernel)."""
    m = np.sqrt(np.sum(delta * delta, axis=1))
    return bool(np.all(m[:, None] + m[None, :] <= fraction * gaps) and np.all(m <= fraction * bgap))


Field = Callable[[Array], tuple[Array, NavEval]]


def integrate(
    problem: DiscProblem,
    b0: Array,
    k: float,
    epsilon: float,
    *,
    moving: int | None = None,
    stop: Callable[[Array, NavEval], Status | None],
    settings: FlowSettings = FlowSettings(),
    direction: Callable[[Array], Array] | None = None,
) -> FlowResult:
    """Integrate ``b' = -v`` (all discs, or disc ``moving`` alone: equations (10)-(12)).

    Parameters
    ----------
    problem, b0, k, epsilon
        The problem, the initial configuration (legal), the exponent k (eq. (2)) and
        the normalisation epsilon (Section 3.3; only the reported time depends on it).
    moving
        ``None`` for the gradient flow (9); a disc index for the low-level flow f_i.
    stop
        Called after every accepted step with the configuration and its evaluation;
        returns a final :class:`Status` or ``None`` to go on.
    settings
        Step size and stopping parameters.
    direction
        Baselines only: a replacement for the direction of ``-v`` (its speed is kept),
        e.g. ``-grad phi`` formed in linear space. A zero or non-finite direction ends
        the run as ``stuck``.
    """
    if settings.method == "implicit":
        if direction is not None or settings.normalize is not None:
            raise ValueError("direction and normalize need method='rk4'")
        with one_blas_thread():
            return _integrate_implicit(problem, b0, k, epsilon, moving, stop, settings)
    radii, ws = problem.radii, problem.workspace
    mask = np.zeros((problem.n, 1))
    if moving is None:
        mask[:] = 1.0
    else:
        mask[moving] = 1.0
    evals = 0

    def fld(b: Array) -> tuple[Array, NavEval]:
        nonlocal evals
        evals += 1
        ev = evaluate(b, problem, k)
        vm = ev.v * mask
        norm = float(np.sqrt(np.sum(vm * vm)))
        lam = 1.0 if settings.normalize is None else 1.0 / (settings.normalize + norm)
        if direction is None:
            return -vm * lam, ev
        u = direction(b)
        with np.errstate(all="ignore"):
            # numpy division: a zero (underflowed) direction gives inf, caught as non-finite
            scale = norm * lam / np.sqrt(np.sum(u * u))
            return u * scale * mask, ev

    def lam_of(ev: NavEval) -> float:
        if settings.normalize is None:
            return 1.0
        vm = ev.v * mask
        return 1.0 / (settings.normalize + float(np.sqrt(np.sum(vm * vm))))

    # the stages in one numba call where the field is the plain -v (bit-identical steps)
    fast = direction is None and settings.normalize is None
    # near the goal the normalised field has rate 1/eta: keep dt * rate <= 1
    dt_cap = (
        settings.dt_max if settings.normalize is None else min(settings.dt_max, settings.normalize)
    )
    b = np.array(b0, dtype=float)
    w, ev = fld(b)
    gaps, bgap = clearances(b, radii, ws)
    record = _Record.start(b, ev, k, epsilon, moving, settings)
    status = stop(b, ev)
    steps = 0
    reason = ""
    while status is None:
        if steps >= settings.max_steps:
            status, reason = Status.BUDGET_EXHAUSTED, f"{settings.max_steps} steps"
            break
        if not np.all(np.isfinite(w)):
            status, reason = Status.STUCK, "non-finite field"
            break
        dt = min(
            dt_cap,
            settings.euler_fraction
            * max_dt(w, ev, mask[:, 0] * lam_of(ev), gaps, bgap, settings.stiff_bound),
        )
        for _ in range(60):
            if fast:
                new, inner = _rk4_fast(fld, problem, k, mask, b, w, dt, gaps, bgap)
                evals += inner
            else:
                new = _rk4(fld, b, w, dt, gaps, bgap)
            if new is not None and (
                settings.stiff_bound or log_w(new[2], k) <= log_w(ev, k) + 1e-13
            ):
                break
            dt *= 0.5
        else:
            status, reason = Status.STUCK, "step size collapsed"
            break
        b_new, w_new, ev_new = new
        stalled = record.accept(b, ev, b_new, ev_new)
        b, w, ev = b_new, w_new, ev_new
        steps += 1
        gaps, bgap = ev.gaps, ev.bgap
        status = stop(b, ev)
        if status is None and stalled:
            status, reason = Status.STUCK, "no progress"
    return record.result(status, steps, evals, reason)


@dataclass
class _Record:
    """What both integrators keep of a run: the path, the progress of ``log w``, the
    smallest clearance, and the time of the normalised system (Section 3.3)."""

    k: float
    log_eps: float
    moving: int | None
    window: int
    min_progress: float
    path: list[Array]
    log_ws: list[float]
    min_clear: float
    log_time: float = -math.inf

    @classmethod
    def start(
        cls,
        b: Array,
        ev: NavEval,
        k: float,
        epsilon: float,
        moving: int | None,
        settings: FlowSettings,
    ) -> _Record:
        return cls(
            k,
            math.log(epsilon),
            moving,
            settings.window,
            settings.min_progress,
            [b.copy()],
            [log_w(ev, k)],
            float(min(np.min(ev.gaps), np.min(ev.bgap))),
        )

    def accept(self, b: Array, ev: NavEval, b_new: Array, ev_new: NavEval) -> bool:
        """Record an accepted step ``b -> b_new``; True when progress has stalled."""
        delta = b_new - b
        ds = float(np.sqrt(np.sum(delta * delta)))
        # time of the normalised system: ds / (||grad phi|| / (eps + ||grad phi||)),
        # in logs: log ds + log(1 + eps / ||grad phi||); grad phi of the moving block.
        if ds > 0:
            log_g = _log_field_norm(ev, self.moving)
            log_dt = math.log(ds) + float(np.logaddexp(0.0, self.log_eps - log_g))
            self.log_time = float(np.logaddexp(self.log_time, log_dt))
        self.min_clear = min(self.min_clear, float(min(np.min(ev_new.gaps), np.min(ev_new.bgap))))
        self.path.append(b_new.copy())
        self.log_ws.append(log_w(ev_new, self.k))
        lw = self.log_ws
        return len(lw) > self.window and lw[-self.window - 1] - lw[-1] < self.min_progress

    def result(self, status: Status, steps: int, evals: int, reason: str) -> FlowResult:
        return FlowResult(
            status,
            np.array(self.path),
            steps,
            evals,
            self.min_clear,
            self.log_time,
            reason,
            self.log_ws,
        )


# --- the normalised flow with a linearly implicit, clearance-bounded step ---------------------


def segment_is_safe(
    b: Array, delta: Array, radii: Array, gaps: Array, bgap: Array, bgap_new: Array, fraction: float
) -> bool:
    """True when along the straight step ``b -> b + delta`` no gap shrinks below
    ``fraction`` of its value at ``b`` (so no contact can occur inside the step).

    Exact: per pair, the smallest centre distance along the segment (a quadratic in
    the step parameter) minus the radii; for the boundary, the workspace is convex and
    the distance to its boundary concave, so the end points (``bgap``, ``bgap_new``)
    bound the whole segment. One pass over the pairs in a numba kernel
    (:func:`kernels.segment_kernel`); :func:`segment_is_safe_numpy` is its reference.
    """
    if not np.all(bgap_new >= fraction * bgap):
        return False
    return bool(
        segment_kernel(
            np.ascontiguousarray(b, dtype=np.float64),
            np.ascontiguousarray(delta, dtype=np.float64),
            radii,
            gaps,
            float(fraction),
        )
    )


def segment_is_safe_numpy(
    b: Array, delta: Array, radii: Array, gaps: Array, bgap: Array, bgap_new: Array, fraction: float
) -> bool:
    """:func:`segment_is_safe` in numpy over ``(n, n)`` arrays (the reference of its kernel)."""
    if not np.all(bgap_new >= fraction * bgap):
        return False
    x0 = b[:, None, :] - b[None, :, :]
    dx = delta[:, None, :] - delta[None, :, :]
    dd = np.einsum("ijk,ijk->ij", dx, dx)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.where(dd > 0, -np.einsum("ijk,ijk->ij", x0, dx) / dd, 0.0), 0.0, 1.0)
    closest = x0 + t[:, :, None] * dx
    dist = np.sqrt(np.einsum("ijk,ijk->ij", closest, closest))
    gap_min = dist - (radii[:, None] + radii[None, :])
    np.fill_diagonal(gap_min, np.inf)
    return bool(np.all(gap_min >= fraction * gaps))


def implicit_step(g: Array, hess: Array, length: float) -> Array:
    """Linearly implicit (Rosenbrock-Euler) step of ``x' = -g`` of about the given length.

    ``delta = -(I / h + H_+)^(-1) g`` with ``H_+`` the Hessian with its negative
    eigenvalues set to 0 (where the flow diverges an explicit step is accurate; a shift
    that keeps them would overshoot along them and cut corners) and ``h`` chosen so
    that ``||delta|| ~= length`` (at most it): ``mu = 1/h`` is the first point of the log
    grid ``10^-12 .. 10^12`` (49 points) whose step is short enough, refined once on 17
    geometric points below it (:func:`eigen.shift_for_length`). In the stiff directions
    (large positive curvature: the repulsion near a contact) this is a Newton step to the
    valley floor instead of an overshoot; along the valley it is a gradient step. The
    arc-length parametrisation is the normalisation of Section 3.3.

    The eigen-decomposition is LAPACK's ``eigh``; the integrators call this inside
    :func:`eigen.one_blas_thread` (OpenBLAS's threads cost more than they give on
    matrices of this size on a shared machine; docs/assembly.md).

    Parameters
    ----------
    g, hess
        Gradient ``(m,)`` and symmetric Hessian ``(m, m)`` of ``L`` at the point.
    length
        Target step length.
    """
    lam, q = np.linalg.eigh(hess)
    lam = np.maximum(lam, 0.0)
    gq = q.T @ g
    mu = shift_for_length(np.ascontiguousarray(gq), lam, float(length))
    return -(q @ (gq / (mu + lam)))


def _integrate_implicit(
    problem: DiscProblem,
    b0: Array,
    k: float,
    epsilon: float,
    moving: int | None,
    stop: Callable[[Array, NavEval], Status | None],
    settings: FlowSettings,
) -> FlowResult:
    """The normalised gradient flow (Section 3.3) by arc length; see :func:`integrate`.

    Each step has length at most ``min(r, goal_fraction ||b - d||)`` for a trust radius
    ``r <= step_max``, is a :func:`implicit_step` on ``L = log alpha^(1/k)`` (grad L =
    v / gamma), and is accepted only if no gap can shrink below half its value along it
    (:func:`segment_is_safe`) and ``L`` (hence ``phi``) decreases; otherwise the radius
    halves. Accepted steps let the radius double again.
    """
    radii = problem.radii
    n = problem.n
    dim = problem.dim
    sel = np.arange(dim * n) if moving is None else dim * moving + np.arange(dim)
    b = np.array(b0, dtype=float)
    ev = evaluate(b, problem, k)
    evals = 1
    gaps, bgap = ev.gaps, ev.bgap
    record = _Record.start(b, ev, k, epsilon, moving, settings)
    status = stop(b, ev)
    steps = 0
    reason = ""
    radius = settings.step_max
    while status is None:
        if steps >= settings.max_steps:
            status, reason = Status.BUDGET_EXHAUSTED, f"{settings.max_steps} steps"
            break
        gamma = math.exp(ev.log_gamma)
        g = (ev.v.reshape(-1) / gamma)[sel]
        if not np.all(np.isfinite(g)):
            status, reason = Status.STUCK, "non-finite field"
            break
        hess = _hessian(b, problem, k, sel, moving)
        err = float(np.linalg.norm((b - problem.goal).reshape(-1)[sel]))
        length = min(radius, settings.goal_fraction * max(err, 1e-300))
        lw = record.log_ws[-1]
        for _ in range(60):
            flat = np.zeros(dim * n)
            flat[sel] = implicit_step(g, hess, length)
            delta = flat.reshape(n, dim)
            b_new = b + delta
            ev_new = evaluate(b_new, problem, k)
            evals += 1
            if (
                np.isfinite(ev_new.log_beta)
                and log_w(ev_new, k) <= lw
                and segment_is_safe(b, delta, radii, gaps, bgap, ev_new.bgap, STEP_FRACTION)
            ):
                break
            length *= 0.5
            radius = length
        else:
            status, reason = Status.STUCK, "step size collapsed"
            break
        radius = min(settings.step_max, 2.0 * radius)
        stalled = record.accept(b, ev, b_new, ev_new)
        b, ev = b_new, ev_new
        steps += 1
        gaps, bgap = ev.gaps, ev.bgap
        status = stop(b, ev)
        if status is None and stalled:
            status, reason = Status.STUCK, "no progress"
        if status is Status.STUCK and not reason:
            reason = critical_point_kind(_hessian(b, problem, k, sel, moving))
    return record.result(status, steps, evals, reason)


def _hessian(
    b: Array, problem: DiscProblem, k: float, sel: NDArray[np.int_], moving: int | None
) -> Array:
    """The Hessian of ``L`` in the moving coordinates ``sel`` (all: ``moving`` None)."""
    hess = hessian_log_w(b, problem, k)
    return hess if moving is None else hess[np.ix_(sel, sel)]


def critical_point_kind(hess: Array) -> str:
    """``"spurious minimum"`` or ``"saddle"`` from the Hessian of ``L`` at a stall.

    ``L`` is a monotone function of ``phi``, so at a critical point its Hessian has the
    same inertia as that of ``phi`` (Sec. 3: phi is Morse; its only minimum should be d).
    """
    lam = eigvalsh(np.ascontiguousarray(hess, dtype=np.float64))
    return "spurious minimum" if float(lam[0]) > 0.0 else "saddle"


def _log_field_norm(ev: NavEval, moving: int | None) -> float:
    v = ev.v if moving is None else ev.v[moving]
    norm = float(np.sqrt(np.sum(v * v)))
    return ev.log_scale + math.log(norm) if norm > 0 else -math.inf


def _rk4(
    fld: Field, b: Array, w1: Array, dt: float, gaps: Array, bgap: Array
) -> tuple[Array, Array, NavEval] | None:
    # Each stage point is itself a straight step from b; all must pass the gap test.
    stages = [w1]
    for c in (0.5, 0.5, 1.0):
        delta = c * dt * stages[-1]
        if not step_is_safe(delta, gaps, bgap, STEP_FRACTION):
            return None
        w, _ = fld(b + delta)
        if not np.all(np.isfinite(w)):
            return None
        stages.append(w)
    delta = dt / 6.0 * (stages[0] + 2.0 * stages[1] + 2.0 * stages[2] + stages[3])
    if not step_is_safe(delta, gaps, bgap, STEP_FRACTION):
        return None
    b_new = b + delta
    w_new, ev_new = fld(b_new)
    if not (np.isfinite(ev_new.log_beta) and np.all(np.isfinite(w_new))):
        return None
    return b_new, w_new, ev_new


def _rk4_fast(
    fld: Field,
    problem: DiscProblem,
    k: float,
    mask: Array,
    b: Array,
    w1: Array,
    dt: float,
    gaps: Array,
    bgap: Array,
) -> tuple[tuple[Array, Array, NavEval] | None, int]:
    """:func:`_rk4` with its three inner stages in one numba call
    (:func:`kernels.rk4_stages_kernel`: the same operations, so the same step), for
    the field ``-v * mask`` (no ``direction``, no ``normalize``); also returns the
    number of stage evaluations (``fld`` counts its own call)."""
    circle, w0, w1ws = workspace_args(problem.workspace)
    ok, delta, evals = rk4_stages_kernel(
        b,
        w1,
        float(dt),
        gaps,
        bgap,
        problem.goal,
        problem.radii,
        circle,
        w0,
        w1ws,
        float(k),
        mask,
        STEP_FRACTION,
    )
    if not ok:
        return None, evals
    b_new = b + delta
    w_new, ev_new = fld(b_new)
    if not (np.isfinite(ev_new.log_beta) and np.all(np.isfinite(w_new))):
        return None, evals
    return (b_new, w_new, ev_new), evals


# --- the gradient assembly algorithm (Section 4.1) -------------------------------------------


#: What a stuck gradient stage does (``escape`` of :func:`gradient_flow`).
Escape = Literal["place", "halve-k"]


def gradient_flow(
    problem: DiscProblem,
    k: float,
    epsilon: float = 1e-3,
    tol: float = 1e-3,
    settings: FlowSettings = FlowSettings(),
    direction: Callable[[Array], Array] | None = None,
    escapes: int = 0,
    escape_factor: float = 0.5,
    escape: Escape = "halve-k",
) -> FlowResult:
    """All discs move together along ``-grad phi`` (equation (9)) until ``||b - d|| < tol``.

    Ends ``solved`` at the goal, ``stuck`` at another critical point or without
    progress, ``budget_exhausted`` after ``settings.max_steps`` steps (each stage).

    Parameters
    ----------
    problem, k, epsilon, tol
        The problem, the exponent k (equation (2)), the normalisation (Section 3.3)
        and the goal tolerance in R^2n.
    settings, direction
        Integration settings; ``direction`` replaces ``-v`` (baselines, RK4 only).
    escapes
        How many escape stages a ``stuck`` run may take. 0 (default): the flow at k
        alone.
    escape_factor
        ``halve-k``: factor applied to k at each escape, in (0, 1).
    escape
        ``"halve-k"``: a stuck stage continues from its end point with k multiplied by
        ``escape_factor`` (Section 3.2: k is adjusted to eliminate local minima), at most
        ``escapes`` times. ``"place"``: the stuck configuration is handed to the place
        rule (:func:`sequential.sequential_assembly` with ``rule="place"``: one disc at a
        time along checked routes onto its goal, blockers parked), which ends on the
        goal; one escape stage (docs/assembly.md, "Escaping spurious minima").
    """
    if not 0.0 < escape_factor < 1.0:
        raise ValueError(f"escape_factor must be in (0, 1), got {escape_factor}")
    if escape not in ("place", "halve-k"):
        raise ValueError(f"unknown escape {escape!r}; use 'place' or 'halve-k'")
    res = _gradient_stage(problem, problem.start, k, epsilon, tol, settings, direction)
    stages = [Stage(k, res.status, res.reason, res.steps)]
    if res.status is Status.STUCK and escapes > 0 and escape == "place":
        return _place_escape(problem, res, stages, k, epsilon, tol, settings)
    parts = [res]
    k_now = k
    while res.status is Status.STUCK and len(stages) <= escapes:
        k_now *= escape_factor
        res = _gradient_stage(problem, res.end, k_now, epsilon, tol, settings, direction)
        stages.append(Stage(k_now, res.status, res.reason, res.steps))
        parts.append(res)
    if len(parts) == 1:
        res.stages = stages
        res.problem = problem
        return res
    path = np.concatenate([parts[0].path] + [p.path[1:] for p in parts[1:]])
    log_time = float(np.logaddexp.reduce([p.log_time for p in parts]))
    return FlowResult(
        res.status,
        path,
        sum(p.steps for p in parts),
        sum(p.evaluations for p in parts),
        min(p.min_clearance for p in parts),
        log_time,
        res.reason,
        [w for p in parts for w in p.log_w],
        stages,
        problem,
    )


#: The stage names of the place rule in :attr:`FlowResult.stages`: from the stuck point,
#: and (when that fails) after the cluster was spread (:func:`expand_cluster`).
PLACE_STAGE = "place rule"
PLACE_SPREAD = "place rule after spreading the cluster"
#: Grasp budget of the place rule from a stuck point, per disc. On the fitting grid and
#: the reporting sets up to 50 discs a successful escape took at most 1.65 grasps per
#: disc; where the place rule cannot unpack a stuck cluster it cycles (1,000 grasps and
#: 40 s on a 50-disc cluster), so it is cut short and the fallback runs.
PLACE_GRASPS_PER_DISC = 3


def _place_escape(
    problem: DiscProblem,
    stuck: FlowResult,
    stages: list[Stage],
    k: float,
    epsilon: float,
    tol: float,
    settings: FlowSettings,
) -> FlowResult:
    """Finish a stuck flow with the place rule, from where it stopped or from the start.

    The flow's spurious minima are packed clusters with two or three discs on each
    other's goals (docs/assembly.md); the place rule moves one disc at a time along a
    checked route onto its goal (parking a blocker on a circle round the pattern), so
    it leaves such a configuration and ends exactly on the goal; the flow's path and the
    place rule's rows (one disc moving between rows) make one path. A disc walled in
    by its packed neighbours cannot be parked, though: when the place rule from the
    stuck point has not finished within ``PLACE_GRASPS_PER_DISC * n`` grasps, its
    partial run is dropped, the stuck configuration is spread by one straight,
    collision-free scaling about the goals' centroid (:func:`expand_cluster`), and the
    place rule runs from there (its own budget of 20 n grasps); the stages record both
    attempts.
    """
    from cellplan.assembly.sequential import sequential_assembly

    def place(start: Array, budget: int | None) -> SequentialResult:
        return sequential_assembly(
            problem.with_start(start),
            k,
            "place",
            epsilon=epsilon,
            tol=max(tol, 1e-12),
            settings=settings,
            max_switches=budget,
        )

    run = place(stuck.end, PLACE_GRASPS_PER_DISC * problem.n)
    stages.append(Stage(k, run.status, _place_reason(run, PLACE_STAGE), run.switches))
    head, evals = stuck.path, stuck.evaluations + run.evaluations
    if run.status is not Status.SOLVED:
        # drop the place rule's partial run; spread the cluster (all discs together,
        # straight), then place from there
        spread = expand_cluster(stuck.end, problem)
        head = np.concatenate([stuck.path, spread[None]])
        run = place(spread, None)  # the place rule's own budget (20 n grasps)
        evals += run.evaluations
        stages.append(Stage(k, run.status, _place_reason(run, PLACE_SPREAD), run.switches))
    gaps, bgap = clearances(head[-1], problem.radii, problem.workspace)
    clear = min(stuck.min_clearance, float(np.min(gaps)), float(np.min(bgap)))
    return FlowResult(
        run.status,
        np.concatenate([head, run.path[1:]]),
        stuck.steps,
        evals,
        min(clear, run.min_clearance),
        stuck.log_time,
        stages[-1].reason,
        stuck.log_w,
        stages,
        problem,
        run,
        stuck.end.copy(),
    )


#: Largest factor by which :func:`expand_cluster` scales the configuration.
SPREAD_FACTOR = 2.5


def expand_cluster(b: Array, problem: DiscProblem) -> Array:
    """The configuration scaled by a factor ``f > 1`` about the goals' centroid.

    Along the straight motion ``b -> c + f (b - c)`` every pairwise centre distance grows
    in proportion (``(1 + t (f - 1)) ||b_i - b_j||``), so no gap shrinks, and each disc's
    legal centres form a convex set (the workspace shrunk by its radius), so a move
    whose end points are legal stays legal. ``f`` is the largest of ``SPREAD_FACTOR``,
    then smaller factors down to 1.1, whose end point lies inside the workspace; with
    ``f = 2.5`` neighbours of a packed cluster get gaps of at least 3 radii, room for the
    place rule's routes. Returns ``b`` itself when no factor fits.
    """
    centre = problem.goal.mean(axis=0)
    for f in np.linspace(SPREAD_FACTOR, 1.1, 15):
        target = centre + f * (b - centre)
        if not legality_problems(target, problem.radii, problem.workspace):
            return target
    return b.copy()


def _place_reason(run: SequentialResult, name: str) -> str:
    return name if run.status is Status.SOLVED else f"{name}: {run.reason or run.status.value}"


def _gradient_stage(
    problem: DiscProblem,
    b0: Array,
    k: float,
    epsilon: float,
    tol: float,
    settings: FlowSettings,
    direction: Callable[[Array], Array] | None,
) -> FlowResult:
    """The flow (9) at one k from ``b0`` (see :func:`gradient_flow`)."""
    goal = problem.goal

    def stop(b: Array, ev: NavEval) -> Status | None:
        err = float(np.sqrt(np.sum((b - goal) ** 2)))
        if err < tol:
            return Status.SOLVED
        if float(np.sqrt(np.sum(ev.v * ev.v))) < settings.stall_ratio * err:
            return Status.STUCK
        return None

    return integrate(problem, b0, k, epsilon, stop=stop, settings=settings, direction=direction)


# --- the default step length of the implicit flow (docs/assembly.md "The step length") ------


def step_max_rule(n: int) -> float:
    """The planner's default largest implicit step: ``max(0.05, c sqrt(n))``.

    The arc length is measured in R^2n; a step of length ``h`` moves each of ``m``
    equally moving discs by ``h / sqrt(m)``, so a fixed ``h`` makes the steps per disc
    shorter, and the runs longer, as n grows (3,600-4,600 steps of 0.05 for 50 discs).
    ``c = options.STEP_MAX_PER_SQRT_DISC`` (0.02, fitted on the fitting grid:
    ``benchmarks/fit_assembly_step.py``); ``options.STEP_MAX_FLOOR`` (0.05, the default
    of ``FlowSettings.step_max``, whose accuracy was measured for 7 discs) is the floor.
    """
    return max(STEP_MAX_FLOOR, STEP_MAX_PER_SQRT_DISC * math.sqrt(n))


# --- the automatic integrator choice (docs/assembly.md "The integrator") ---------------------

#: Goal pairs closer than this many disc radii (gap) count as tight ...
TIGHT_GOAL_GAP = 1.0
#: ... and RK4 is chosen when there are at most this many tight goal pairs per disc.
RK4_MAX_TIGHT_PER_DISC = 0.5


def choose_method(problem: DiscProblem) -> Literal["implicit", "rk4"]:
    """The integrator of ``integrator="auto"``: RK4 unless the goal pattern is packed.

    The implicit step costs an eigen-decomposition of the ``2n x 2n`` Hessian per step
    (``O(n^3)``); RK4 four field evaluations (``O(n^2)``), but its step is bounded by the
    repulsion stiffness, so it creeps wherever many discs are close to contact for long.
    Near the goal every pair of neighbouring goals is at its goal gap: a packed pattern
    (a hexagonal cluster has about 2.2 n pairs within one radius) makes RK4 creep there
    (on the fitting grid it ran out of 10,000 steps on every hexagonal problem of 20 and
    30 discs), while on loose goals (random goals: 0-6 such pairs) it was 1.5-9x faster
    than the implicit step at every n from 5 to 30 (``benchmarks/fit_assembly_integrator.py``,
    docs/assembly.md "The integrator").
    """
    gaps, _ = clearances(problem.goal, problem.radii, problem.workspace)
    scale = float(np.min(problem.radii))
    tight = int(np.count_nonzero(gaps < TIGHT_GOAL_GAP * scale)) // 2  # (i, j) and (j, i)
    return "rk4" if tight <= RK4_MAX_TIGHT_PER_DISC * problem.n else "implicit"

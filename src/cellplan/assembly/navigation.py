"""The navigation function of Whitcomb & Koditschek (1991), Section 3, in log space.

For n discs with centres ``b`` (shape ``(n, 2)``; spheres: ``(n, 3)``, the same formulas
hold in any dimension, R^{3n} for spheres), radii ``rho`` and goals ``d``:

* ``gamma = sum_i 1/2 ||b_i - d_i||^2``                         (equation (3))
* ``beta  = prod_{i<j} beta_ij * prod_i beta_0i``                (equations (4), (5))
  with ``beta_ij = 1/2 (||b_i - b_j||^2 - (rho_i + rho_j)^2)`` and a boundary term
  ``beta_0i`` (our addition, see below) that vanishes when disc i touches the boundary;
* ``phi = gamma / (gamma^k + beta)^(1/k)`` = ``sigma(alpha)``, ``alpha = gamma^k / beta``
  (equations (2), (6), (7));
* ``grad phi = (1/k) (beta + gamma^k)^(-(1+k)/k) [k beta Dgamma - gamma Dbeta]``  (eq. (8))
  ``= exp(s) * v`` with ``v = (b - d) - (gamma / k) grad(log beta)`` and
  ``s = log beta - ((1+k)/k) log(beta + gamma^k)``.

``beta`` itself reaches 1e-44 in the paper's Fig. 5 and overflows or underflows for a
few dozen discs, and ``gamma^k`` overflows at large k; here only ``log beta`` (a sum of
logs), ``log gamma`` and the direction ``v`` (free of both) are formed, and the scalar
factor ``exp(s)`` stays a logarithm. Everything is O(n^2) numpy per evaluation.

Boundary term. The paper leaves the workspace boundary out of ``beta``. We add one
factor per disc, so that ``beta`` vanishes when a disc touches the boundary:
``beta_0i = 1/2 ((R - rho_i)^2 - ||b_i - c||^2)`` for a circular workspace (the
Koditschek-Rimon obstacle-0 term) and the product of the four wall distances
``(x_i - xmin - rho_i)(xmax - rho_i - x_i)(y_i - ymin - rho_i)(ymax - rho_i - y_i)`` for
the workcell rectangle. Reports quote the paper's pairwise ``beta(d)`` separately.

The plain linear-space evaluation of the same formulas (:func:`phi_linear`,
:func:`grad_linear`) is kept as the baseline for tests and benchmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.layout import (
    BoxWorkspace,
    CircleWorkspace,
    Workspace,
    boundary_terms,
    clearances,
    log_beta_parts,
    min_clearance,
    pair_terms,
)
from cellplan.assembly.problems import DiscProblem

__all__ = [
    "BoxWorkspace",
    "CircleWorkspace",
    "NavEval",
    "Workspace",
    "boundary_terms",
    "clearances",
    "direction",
    "evaluate",
    "evaluate_numpy",
    "grad_linear",
    "grad_log_phi",
    "hessian_log_w",
    "hessian_log_w_numpy",
    "log_beta_parts",
    "log_w",
    "min_clearance",
    "pair_terms",
    "path_min_clearance",
    "phi_linear",
    "workspace_args",
]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class NavEval:
    """One evaluation of the navigation function at a configuration.

    Attributes
    ----------
    log_gamma, log_beta
        ``log gamma`` (``-inf`` at the goal) and ``log beta`` (``-inf`` in contact).
    v
        ``(n, 2)``: ``grad phi = exp(log_scale) * v`` (equation (8) factored).
    log_scale
        ``s = log beta - ((1+k)/k) log(beta + gamma^k)``.
    log_phi
        ``log phi`` (equation (6)).
    rep, rep_bnd
        ``(n, n)``: ``(gamma/k) ||b_i - b_j|| / beta_ij``, the magnitude of the repulsion
        of pair ij within ``v``, and ``(n,)`` the same for the boundary term. Near a
        contact the repulsion nearly cancels the attraction while both are large, so
        the net speed says nothing about the stiffness; step sizes use these.
    gaps, bgap
        The clearances of :func:`clearances` at ``b``.
    """

    log_gamma: float
    log_beta: float
    v: Array
    log_scale: float
    log_phi: float
    rep: Array
    rep_bnd: Array
    gaps: Array
    bgap: Array

    @property
    def log_grad_norm(self) -> float:
        """``log ||grad phi||`` in R^2n."""
        norm = float(np.sqrt(np.sum(self.v * self.v)))
        return self.log_scale + np.log(norm) if norm > 0 else -np.inf

    def log_block_norms(self) -> Array:
        """``log ||f_i||`` for the low-level flows f_i = S_i grad phi (equation (11))."""
        with np.errstate(divide="ignore"):
            return self.log_scale + np.log(np.sqrt(np.sum(self.v * self.v, axis=1)))


def workspace_args(ws: Workspace) -> tuple[bool, Array, Array]:
    """The workspace as the kernels take it: ``(circle, w0, w1)``, see ``nav_kernel``."""
    if isinstance(ws, CircleWorkspace):
        return True, ws.center, np.array([ws.radius, 0.0])
    return False, ws.lo, ws.hi


def evaluate(b: Array, problem: DiscProblem, k: float) -> NavEval:
    """Evaluate ``phi`` and its gradient (equations (2)-(8)) in log space (numba kernel).

    Same result as :func:`evaluate_numpy`; see :mod:`cellplan.assembly.kernels`.
    """
    from cellplan.assembly.kernels import nav_kernel

    circle, w0, w1 = workspace_args(problem.workspace)
    log_gamma, log_beta, v, rep, rep_bnd, gaps, bgap = nav_kernel(
        np.ascontiguousarray(b, dtype=np.float64),
        problem.goal,
        problem.radii,
        circle,
        w0,
        w1,
        float(k),
    )
    with np.errstate(invalid="ignore"):
        log_sum = float(np.logaddexp(k * log_gamma, log_beta))
    return NavEval(
        log_gamma,
        log_beta,
        v,
        log_beta - (1.0 + k) / k * log_sum,
        log_gamma - log_sum / k,
        rep,
        rep_bnd,
        gaps,
        bgap,
    )


def evaluate_numpy(b: Array, problem: DiscProblem, k: float) -> NavEval:
    """Evaluate ``phi`` and its gradient (equations (2)-(8)) in log space (numpy reference).

    Parameters
    ----------
    b
        ``(n, 2)`` disc centres; must be a legal configuration (otherwise ``log_beta``
        is ``-inf`` or ``nan`` and ``v`` is meaningless).
    problem
        Radii, goals and workspace.
    k
        The exponent of equations (2) and (6), ``k > 0``.
    """
    d = problem.goal
    diff, B, dist = pair_terms(b, problem.radii)
    e = b - d
    gamma = 0.5 * float(np.sum(e * e))
    with np.errstate(divide="ignore", invalid="ignore"):
        log_pairs = 0.5 * float(np.sum(np.log(B)))
        # grad_{b_i} log beta = sum_j (b_i - b_j) / beta_ij (+ the boundary term)
        inv_b = 1.0 / B
        np.fill_diagonal(inv_b, 0.0)
        g = np.einsum("ijk,ij->ik", diff, inv_b)
        log_bnd, g_bnd = boundary_terms(b, problem.radii, problem.workspace)
        log_beta = log_pairs + float(np.sum(log_bnd))
        g = g + g_bnd
        log_gamma = float(np.log(gamma)) if gamma > 0 else -np.inf
        v = e - (gamma / k) * g
        log_sum = float(np.logaddexp(k * log_gamma, log_beta))
        log_scale = log_beta - (1.0 + k) / k * log_sum
        log_phi = log_gamma - log_sum / k
        rep = (gamma / k) * dist * np.abs(inv_b)
        rep_bnd = (gamma / k) * np.sqrt(np.sum(g_bnd * g_bnd, axis=1))
    gaps, bgap = clearances(b, problem.radii, problem.workspace)
    return NavEval(log_gamma, log_beta, v, log_scale, log_phi, rep, rep_bnd, gaps, bgap)


def direction(b: Array, problem: DiscProblem, k: float) -> Array:
    """``v`` of :class:`NavEval` only: a positive multiple of ``grad phi`` (n, 2)."""
    return evaluate(b, problem, k).v


def grad_log_phi(b: Array, problem: DiscProblem, k: float) -> Array:
    """``grad log phi = exp(s - log phi) v`` (n, 2); finite wherever ``b`` is legal."""
    ev = evaluate(b, problem, k)
    return np.exp(ev.log_scale - ev.log_phi) * ev.v


def path_min_clearance(path: Array, radii: Array, ws: Workspace) -> float:
    """Smallest gap along a path ``(m, n, d)`` taken straight between its rows, exactly.

    Issue 35: a clearance taken at the rows only overstates the minimum (by up to 10.6%
    on a 20-disc ring). Between two rows every centre moves linearly, so per pair the
    centre distance is smallest where the relative motion passes closest to the origin
    (:func:`kernels.path_pair_gap_kernel`, exact); the distance of a centre to the
    boundary of a convex workspace is concave along a segment, so the rows bound the
    boundary gaps.
    """
    from cellplan.assembly.kernels import path_pair_gap_kernel

    rows = np.ascontiguousarray(path, dtype=np.float64)
    pair = float(path_pair_gap_kernel(rows, radii)) if rows.shape[1] > 1 else np.inf
    if isinstance(ws, CircleWorkspace):
        bnd = float(np.min(ws.radius - radii - np.linalg.norm(rows - ws.center, axis=2)))
    else:
        bnd = float(
            min(np.min(rows - ws.lo - radii[:, None]), np.min(ws.hi - rows - radii[:, None]))
        )
    return min(pair, bnd)


# --- the plain linear-space baseline ---------------------------------------------------------


def phi_linear(b: Array, problem: DiscProblem, k: float) -> float:
    """``phi`` by equations (2)-(6) in plain floating point (baseline; under/overflows)."""
    _, B, _ = pair_terms(b, problem.radii)
    iu = np.triu_indices(problem.n, 1)
    with np.errstate(all="ignore"):
        beta = np.prod(B[iu]) * np.prod(
            np.exp(boundary_terms(b, problem.radii, problem.workspace)[0])
        )
        # numpy scalars, so that overflow gives inf as it would in C, not an exception
        gamma = np.float64(0.5 * np.sum((b - problem.goal) ** 2))
        alpha = gamma**k / beta if beta != 0 else np.inf
        return float((alpha / (1.0 + alpha)) ** (1.0 / k)) if np.isfinite(alpha) else 1.0


def grad_linear(b: Array, problem: DiscProblem, k: float) -> Array:
    """``grad phi`` by equation (8) in plain floating point (baseline; under/overflows).

    ``Dbeta`` is formed by the product rule, ``beta * sum_ij grad beta_ij / beta_ij``,
    in linear space; when ``beta`` underflows to 0 the gradient is exactly 0 and when
    it (or ``gamma^k``) overflows the result is ``nan``.
    """
    diff, B, _ = pair_terms(b, problem.radii)
    iu = np.triu_indices(problem.n, 1)
    with np.errstate(all="ignore"):
        log_bnd, g_bnd = boundary_terms(b, problem.radii, problem.workspace)
        beta = np.prod(B[iu]) * np.prod(np.exp(log_bnd))
        inv_b = 1.0 / B
        np.fill_diagonal(inv_b, 0.0)
        dbeta = beta * (np.einsum("ijk,ij->ik", diff, inv_b) + g_bnd)
        e = b - problem.goal
        gamma = np.float64(0.5 * np.sum(e * e))
        pre = (1.0 / k) * (beta + gamma**k) ** (-(1.0 + k) / k)
        return pre * (k * beta * e - gamma * dbeta)


def log_w(ev: NavEval, k: float) -> float:
    """``L = log alpha^(1/k) = log gamma - log(beta) / k``: a monotone function of ``phi``.

    ``grad L = v / gamma``, so the gradient flow of ``L`` has the trajectories of the
    flow of ``phi`` (equations (6), (9)); unlike ``log phi`` (about 0 far from the goal at
    large k) it is well scaled everywhere.
    """
    return ev.log_gamma - ev.log_beta / k


def hessian_log_w(b: Array, problem: DiscProblem, k: float) -> Array:
    """Hessian ``(2n, 2n)`` of ``L = log gamma - log(beta) / k`` (numba kernel).

    Same result as :func:`hessian_log_w_numpy` (the reference it is tested against), in
    one pass over the pairs (:func:`kernels.hessian_kernel`); what the flows call.
    """
    from cellplan.assembly.kernels import hessian_kernel

    circle, w0, w1 = workspace_args(problem.workspace)
    hess: Array = hessian_kernel(
        np.ascontiguousarray(b, dtype=np.float64),
        problem.goal,
        problem.radii,
        circle,
        w0,
        w1,
        float(k),
    )
    return hess


def hessian_log_w_numpy(b: Array, problem: DiscProblem, k: float) -> Array:
    """Hessian ``(dn, dn)`` of ``L = log gamma - log(beta) / k`` (numpy reference; d = 2, 3).

    Differentiates equations (3)-(5) (and the boundary term) twice, in log form:
    ``D^2 log gamma = I / gamma - e e^T / gamma^2``; per pair, with ``x = b_i - b_j``,
    ``D_x^2 log beta_ij = I / beta_ij - x x^T / beta_ij^2`` entered with signs ``+`` on
    the ``ii``, ``jj`` and ``-`` on the ``ij``, ``ji`` blocks; for the circular boundary,
    ``y = b_i - c``, ``D^2 log beta_0i = -I / w - y y^T / w^2``; for the box
    ``-1 / t^2`` per wall on the diagonal. Vectorised, O(n^2). The linearly implicit
    step of :mod:`cellplan.assembly.flows`, where it resolves the stiff repulsion near
    contacts, uses the same formulas through :func:`hessian_log_w`.
    """
    n = problem.n
    dim = b.shape[1]
    diff, B, _ = pair_terms(b, problem.radii)
    e = (b - problem.goal).reshape(-1)
    gamma = 0.5 * float(e @ e)
    eye2 = np.eye(dim)
    inv_b = 1.0 / B
    np.fill_diagonal(inv_b, 0.0)
    # M[i, j] = D_x^2 log beta_ij, (n, n, dim, dim), zero on the diagonal
    M = (
        inv_b[:, :, None, None] * eye2
        - (inv_b * inv_b)[:, :, None, None] * diff[:, :, :, None] * diff[:, :, None, :]
    )
    blocks = -M
    idx = np.arange(n)
    blocks[idx, idx] = np.sum(M, axis=1)
    ws = problem.workspace
    if isinstance(ws, CircleWorkspace):
        rel = b - ws.center
        w = 0.5 * ((ws.radius - problem.radii) ** 2 - np.sum(rel * rel, axis=1))
        blocks[idx, idx] += (
            -(1.0 / w)[:, None, None] * eye2
            - (1.0 / w**2)[:, None, None] * rel[:, :, None] * rel[:, None, :]
        )
    else:
        lo, hi, r = ws.lo, ws.hi, problem.radii
        for axis in range(dim):
            t_lo = b[:, axis] - lo[axis] - r
            t_hi = hi[axis] - r - b[:, axis]
            blocks[idx, idx, axis, axis] -= 1.0 / t_lo**2 + 1.0 / t_hi**2
    hess_log_beta = blocks.transpose(0, 2, 1, 3).reshape(dim * n, dim * n)
    hess_gamma = np.eye(dim * n) / gamma - np.outer(e, e) / gamma**2
    return hess_gamma - hess_log_beta / k

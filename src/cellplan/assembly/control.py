"""Assembly control (Section 3.4): discs as double integrators driven by the navigation function.

The paper "lifts" the gradient system to a feedback law for mechanical systems
(its reference [4]). For discs with dynamics ``b'' = u`` we use gradient plus damping,

    ``u = -K_p grad W(b) - K_d b'``,   ``W = gamma (beta(d) / beta)^(1/k)``,

where ``W = (alpha / alpha-scale)^(1/k)`` is the navigation function before squashing
(``phi = sigma(alpha)`` with ``sigma`` increasing, so ``W`` has exactly the critical points
of ``phi``); it equals ``gamma`` to first order at the goal (unit stiffness) and grows
without bound at every contact. Its gradient is ``(beta(d)/beta)^(1/k) v`` with ``v`` of
:func:`navigation.evaluate`, formed in log space. The energy ``E = |b'|^2 / 2 + K_p W``
never increases (``E' = -K_d |b'|^2``), so ``W`` stays below ``E(0) / K_p`` and no contact
can occur: the controller is collision-free by construction.

The simulation is velocity Verlet with a step bounded by the clearance (as in
:mod:`flows`) and rejected whenever the discrete energy grows, so the simulated run
keeps the continuous guarantee.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.flows import step_is_safe
from cellplan.assembly.navigation import clearances, evaluate, log_beta_parts
from cellplan.assembly.problems import DiscProblem
from cellplan.core import Status

Array = NDArray[np.float64]


@dataclass
class ControlResult:
    """A simulated controlled assembly."""

    status: Status
    times: Array  # (m,)
    path: Array  # (m, n, 2)
    energy: Array  # (m,)
    min_clearance: float
    steps: int
    problem: DiscProblem | None = None  # the problem simulated

    def length(self) -> float:
        seg = np.diff(self.path, axis=0).reshape(len(self.path) - 1, -1)
        return float(np.sum(np.linalg.norm(seg, axis=1)))


def simulate_control(
    problem: DiscProblem,
    k: float,
    kp: float = 1.0,
    kd: float | None = None,
    *,
    dt_max: float = 0.05,
    t_max: float = 400.0,
    tol: float = 1e-3,
    max_steps: int = 200000,
) -> ControlResult:
    """Simulate ``b'' = -K_p grad W - K_d b'`` from rest at the start until at rest at the goal.

    Parameters
    ----------
    kp, kd
        Gains; ``kd`` defaults to ``2 sqrt(kp)`` (critical damping at the goal).
    tol
        Success when ``||b - d|| < tol`` and ``||b'|| < tol``.
    """
    kd = 2.0 * math.sqrt(kp) if kd is None else kd
    ws = problem.workspace
    pairs_d, bnd_d = log_beta_parts(problem.goal, problem.radii, ws)
    log_beta_d = pairs_d + bnd_d

    def potential_and_grad(b: Array) -> tuple[float, Array]:
        ev = evaluate(b, problem, k)
        log_ratio = (log_beta_d - ev.log_beta) / k
        gamma = math.exp(ev.log_gamma) if np.isfinite(ev.log_gamma) else 0.0
        return gamma * math.exp(log_ratio), math.exp(log_ratio) * ev.v

    b = np.array(problem.start, dtype=float)
    p = np.zeros_like(b)
    w, grad = potential_and_grad(b)
    energy = kp * w
    times, path, energies = [0.0], [b.copy()], [energy]
    gaps, bgap = clearances(b, problem.radii, ws)
    min_clear = float(min(np.min(gaps), np.min(bgap)))
    t, steps, dt = 0.0, 0, dt_max
    status = Status.BUDGET_EXHAUSTED
    while steps < max_steps and t < t_max:
        if np.linalg.norm(b - problem.goal) < tol and np.linalg.norm(p) < tol:
            status = Status.SOLVED
            break
        acc = -kp * grad - kd * p
        dt = min(dt_max, 2.0 * dt)
        for _ in range(60):
            p_half = p + 0.5 * dt * acc
            delta = dt * p_half
            if step_is_safe(delta, gaps, bgap, 0.5):
                b_new = b + delta
                w_new, grad_new = potential_and_grad(b_new)
                p_new = p_half + 0.5 * dt * (-kp * grad_new - kd * p_half)
                e_new = 0.5 * float(np.sum(p_new * p_new)) + kp * w_new
                if np.isfinite(e_new) and e_new <= energy * (1 + 1e-9) + 1e-15:
                    break
            dt *= 0.5
        else:
            status = Status.STUCK
            break
        b, p, grad, energy = b_new, p_new, grad_new, e_new
        t += dt
        steps += 1
        gaps, bgap = clearances(b, problem.radii, ws)
        min_clear = min(min_clear, float(min(np.min(gaps), np.min(bgap))))
        times.append(t)
        path.append(b.copy())
        energies.append(energy)
    return ControlResult(
        status, np.array(times), np.array(path), np.array(energies), min_clear, steps, problem
    )

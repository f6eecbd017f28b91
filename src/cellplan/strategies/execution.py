"""Executing a strategy at real-valued states with guaranteed progress (Section IV-B).

The paper executes the strategy by evaluating the right-hand side of equation (9) at the
robot's actual configuration, the cost-to-go of each successor interpolated between grid
cells. At a cell centre that is exactly the solved MDP. Between centres it is not: the
MDP's transition from a centre spreads the landing point over the *live* corners of its
stencil (the weights renormalised over them), which beside a narrow passage is a
sideways snap into a corridor one cell wide. A robot that moves only along its axis
(problem 3) cannot snap; at real states beside such corridors the interpolated values
are *inconsistent* (no action delivers the decrease that (9) promises) and the plain rule
cycles between two actions for ever (docs/strategies.md, "Executing P3 off the grid").

:class:`Executor` keeps (9) as the scoring rule and adds three things in the layers that
have a request to finish (W and C):

* a lookahead (:func:`lookahead`): every motion sequence of up to ``D`` stages that stays
  in the strategy's domain (each motion passes the swept check and ends in a live cell),
  scored in the average-cost form of (9): stage losses less the gain ``g`` per stage,
  plus the interpolated cost-to-go where it ends (or FMP there);
* commitment: the best sequence is carried out to its end unless the mode changes or a
  planned FMP is refused (in the deterministic W/C layers its outcome is as predicted);
* the learning step of real-time dynamic programming (Korf's LRTA*, 1990; Barto, Bradtke
  and Singh, 1995) on a private copy of the cost-to-go: when a plan starting at ``q`` is
  worth more than the interpolated ``H(q)`` by over half a stage's progress
  (``(l - g) / 2``), the live corners of ``q``'s stencil are raised by the difference.

A plan's value is its ``D`` stages of progress plus ``H`` at the next plan's start, so
once no correction fires, ``H(s_i) >= (D - 1/2) (l - g) + H(s_{i+1})`` for consecutive
plan starts. Round a cycle of plan starts that would make ``H`` fall and come back to
itself, which is impossible; so every pass round a cycle raises some value, until
leaving it is the better plan, and no request can be held for ever. (This is the LRTA*
argument; with interpolation a raise also lifts neighbouring states that share corners,
so it is a sketch, which the tests and measurements confirm, not a proof.) Where the
values are consistent (cell centres, open space) nothing is raised and, with ``D = 1``
at a cell centre, the action is the paper's.

The corrections belong to one execution (one simulated run); the strategy's values are
never modified.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit

from cellplan.strategies import kernels, stencils
from cellplan.strategies.model import LayeredMDP
from cellplan.strategies.strategy import FMP, Strategy, best_action

# Fraction of one stage's progress (l - g) below which an inconsistency is left alone.
RAISE_FRACTION = 0.5
# Motion sequences examined per stage by the lookahead, and its deepest horizon.
LEAF_BUDGET = 400
MAX_DEPTH = 6


@njit(cache=True)
def _leaf(
    q,
    m,
    h,
    live,
    branch_ptr,
    branch_layer,
    branch_prob,
    shape,
    lower,
    spacing,
    periodic,
    idx,
    w,
    ibuf,
    frac,
):  # pragma: no cover - numba
    """Expected interpolated cost-to-go after a motion in layer ``m`` (NaN: unsupported)."""
    n = stencils.stencil(q, shape, lower, spacing, periodic, idx, w, ibuf, frac)
    val = 0.0
    for b in range(branch_ptr[m], branch_ptr[m + 1]):
        L = branch_layer[b]
        v = kernels.interp(h[L], live[L], idx, w, n)
        if np.isnan(v):
            return np.nan
        val += branch_prob[b] * v
    return val


@njit(cache=True)
def lookahead(
    q,
    m,
    depth,
    h,
    live,
    free,
    disp,
    nact,
    heading_axis,
    vcls,
    cost,
    fmp_next,
    tf,
    fmp_root,
    offset,
    branch_ptr,
    branch_layer,
    branch_prob,
    shape,
    lower,
    upper,
    spacing,
    periodic,
    collect,
    nodes,
    fmp_ok,
    seq,
):  # pragma: no cover - numba
    """The best motion sequence of up to ``depth`` stages from ``q`` (a lookahead on (9)).

    The value of a sequence is its stage losses less ``offset`` per stage (the gain, as in
    the average-cost form of (9)) plus the interpolated cost-to-go where it ends: after
    ``depth`` motions, or by FMP at a configuration whose cell allows it (at ``q`` itself
    only if ``fmp_root``). Every motion must pass the swept check and end in a cell that is
    a live state of layer ``m`` (inside the strategy's domain). A motion followed by its
    inverse is skipped (it returns to the same configuration). Returns
    ``(value, length, count)``: the best sequence is ``seq[:length]`` (move indices, -2
    for FMP, which ends it; length 0 when no sequence qualifies) and ``count`` the
    configurations after the root whose cell allows FMP.

    The exact region test is not available in compiled code, so FMP away from the root
    takes two calls: with ``collect`` the count configurations are written to ``nodes``
    (and FMP is not offered there); without it ``fmp_ok[i]`` says whether FMP is possible
    at the i-th of them, in the same order.
    """
    d = shape.shape[0]
    k = vcls[m]
    na = nact[k]
    nxt = fmp_next[m]
    step = cost[m] - offset
    qd = np.empty((depth + 1, d))
    dq = np.empty(d)
    acc = np.zeros(depth + 1)
    choice = np.full(depth + 1, -1, np.int64)
    idx = np.empty(1 << d, np.int64)
    w = np.empty(1 << d)
    ibuf = np.empty(2 * stencils.MAX_DIM, np.int64)
    frac = np.empty(stencils.MAX_DIM)
    mbuf = np.empty(3 * stencils.MAX_DIM, np.int64)
    best = np.inf
    count = 0
    length = 0
    for j in range(d):
        qd[0, j] = q[j]
    if nxt >= 0 and fmp_root:
        c = stencils.cell_containing(q, shape, lower, spacing, periodic)
        if tf[m, c] < np.inf:
            n = stencils.stencil(q, shape, lower, spacing, periodic, idx, w, ibuf, frac)
            v = kernels.interp(h[nxt], live[nxt], idx, w, n)
            if not np.isnan(v):
                best = tf[m, c] - offset + v
                seq[0] = -2
                length = 1
    level = 0
    while level >= 0:
        choice[level] += 1
        a = choice[level]
        if a >= na:
            choice[level] = -1
            level -= 1
            continue
        if level > 0:
            inverse = True
            prev = choice[level - 1]
            for j in range(d):
                if abs(disp[k, a, j] + disp[k, prev, j]) > 1e-12:
                    inverse = False
                    break
            if inverse:
                continue
        stencils.displacement(qd[level], disp[k, a], heading_axis, dq)
        if not kernels.motion_ok(
            qd[level], dq, free[k], shape, lower, upper, spacing, periodic, mbuf
        ):
            continue
        for j in range(d):
            qd[level + 1, j] = qd[level, j] + dq[j]
        stencils.wrap(qd[level + 1], lower, upper, periodic)
        c = stencils.cell_containing(qd[level + 1], shape, lower, spacing, periodic)
        if not live[m, c]:
            continue
        acc[level + 1] = acc[level] + step
        fmp_here = False
        if nxt >= 0 and tf[m, c] < np.inf:
            if collect:
                if count < nodes.shape[0]:
                    for j in range(d):
                        nodes[count, j] = qd[level + 1, j]
            else:
                fmp_here = count < fmp_ok.shape[0] and fmp_ok[count]
            count += 1
        if fmp_here:
            n = stencils.stencil(qd[level + 1], shape, lower, spacing, periodic, idx, w, ibuf, frac)
            v = kernels.interp(h[nxt], live[nxt], idx, w, n)
            if not np.isnan(v) and acc[level + 1] + tf[m, c] - offset + v < best:
                best = acc[level + 1] + tf[m, c] - offset + v
                for i in range(level + 1):
                    seq[i] = choice[i]
                seq[level + 1] = -2
                length = level + 2
        if level + 1 == depth:
            v = _leaf(
                qd[level + 1],
                m,
                h,
                live,
                branch_ptr,
                branch_layer,
                branch_prob,
                shape,
                lower,
                spacing,
                periodic,
                idx,
                w,
                ibuf,
                frac,
            )
            if not np.isnan(v) and acc[level + 1] + v < best:
                best = acc[level + 1] + v
                for i in range(level + 1):
                    seq[i] = choice[i]
                length = level + 1
        else:
            level += 1
    return best, length, count


def default_depth(mdp: LayeredMDP, budget: int = LEAF_BUDGET) -> int:
    """The deepest lookahead whose motion sequences number at most ``budget``.

    With ``A`` motions per stage (a motion is never followed by its inverse) there are
    ``A (A - 1)^(D - 1)`` sequences of ``D`` stages: 5 stages for the rotating robot's 4
    motions, 2 for 16 headings, 3 for an arm's 6 joint steps.
    """
    na = int(mdp.nact.max())
    depth = 1
    while na * max(na - 1, 1) ** depth <= budget and depth < MAX_DEPTH:
        depth += 1
    return depth


class Executor:
    """Equation (9) at real states, with the LRTA* correction of inconsistent values.

    Parameters
    ----------
    strategy
        The solved strategy (its model supplies actions, collisions and transitions).
    values
        ``(M, N)`` cost-to-go to execute (NaN outside the live states); default the
        strategy's own. The baselines pass their per-request values.
    offset
        The constant subtracted in the Bellman equation of the W and C layers: the gain
        ``g`` for the optimal strategy's relative values, 0 for time-to-finish values.
    learn
        Whether to correct inconsistent values.
    depth
        Stages of lookahead in the W and C layers (1: the paper's rule (9) alone; default
        :func:`default_depth`).
    fmp_test
        The exact region test ``(configurations (n, dim), mode) -> (n,) bool`` that the
        lookahead applies where a configuration's cell allows FMP (default: the cell's
        word, which near a region's border can promise an FMP that is then refused).
    """

    def __init__(
        self,
        strategy: Strategy,
        values: np.ndarray | None = None,
        offset: float | None = None,
        learn: bool = True,
        depth: int | None = None,
        fmp_test: Callable[[np.ndarray, int], np.ndarray] | None = None,
    ) -> None:
        mdp = strategy.mdp
        raw = strategy.values if values is None else values
        self.strategy = strategy
        self.live = np.isfinite(raw) & mdp.live
        self.h = np.where(self.live, np.nan_to_num(raw, nan=0.0), 0.0)
        if offset is None:
            offset = strategy.gain if values is None else 0.0
        self.offset = float(offset)
        self.learn = learn
        self.depth = default_depth(mdp) if depth is None else int(depth)
        self.fmp_test = fmp_test
        na = int(mdp.nact.max())
        nodes = sum(na * max(na - 1, 1) ** i for i in range(self.depth))
        self._nodes = np.empty((nodes, len(mdp.shape)))
        self._all = np.ones(nodes, np.bool_)
        self._seq = np.empty(self.depth + 1, np.int64)
        self._plan: list[int] = []
        self._plan_mode = -1
        self.corrections = 0
        self.raised = 0.0
        d = len(mdp.shape)
        self._out = np.empty(2 + mdp.disp.shape[1])
        self._idx = np.empty(1 << d, np.int64)
        self._w = np.empty(1 << d)
        self._ibuf = np.empty(2 * stencils.MAX_DIM, np.int64)
        self._frac = np.empty(stencils.MAX_DIM)

    def action_values(
        self, q: np.ndarray, mode: int, fmp_allowed: bool | None = None
    ) -> np.ndarray:
        """Right-hand side of (9) per action, ``[FMP, stay, move 0, ...]`` (NaN: unavailable).

        As :meth:`Strategy.action_values`, on this execution's (corrected) values; the
        returned array is reused by the next call.
        """
        mdp = self.strategy.mdp
        q = np.ascontiguousarray(q, dtype=float)
        tf_here = float(mdp.tf[mode, self.strategy.cell_of(q)])
        if fmp_allowed is None:
            fmp_allowed = bool(np.isfinite(tf_here))
        actions, grid = mdp.point_args()
        kernels.action_values_at(q, mode, self.h, self.live, *actions,
                                 tf_here if np.isfinite(tf_here) else 0.0, fmp_allowed, *grid,
                                 self._out)
        return self._out

    def value(self, q: np.ndarray, mode: int) -> float:
        """The interpolated cost-to-go ``H(q)`` of a layer (NaN outside its live states)."""
        mdp = self.strategy.mdp
        n = stencils.stencil(
            np.ascontiguousarray(q, dtype=float),
            mdp.shape,
            mdp.lower,
            mdp.spacing,
            mdp.periodic,
            self._idx,
            self._w,
            self._ibuf,
            self._frac,
        )
        return float(kernels.interp(self.h[mode], self.live[mode], self._idx, self._w, n))

    def correct(self, q: np.ndarray, mode: int, target: float) -> float:
        """The LRTA* step: raise ``H(q)`` to ``target`` if it is lower by more than half a
        stage's progress; returns the raise (0 if none).

        ``target`` is the best backed-up value at ``q`` (the minimum of (9) less the
        offset, or the lookahead's best). Only layers with a request to finish are
        corrected (NR has no progress to make).
        """
        mdp = self.strategy.mdp
        if not self.learn or mdp.fmp_next[mode] < 0 or not np.isfinite(target):
            return 0.0
        here = self.value(q, mode)  # also leaves q's stencil in _idx, _w
        if np.isnan(here):
            return 0.0
        progress = float(mdp.cost[mode]) - self.offset
        residual = target - here
        if residual <= RAISE_FRACTION * progress:
            return 0.0
        corners = self._idx[(self._w > 1e-12) & self.live[mode, self._idx]]
        # Raising every live corner equally raises the interpolated H(q) by exactly the
        # residual (the weights are renormalised over the live corners).
        self.h[mode, corners] += residual
        self.corrections += 1
        self.raised += residual
        return residual

    def action(self, q: np.ndarray, mode: int, fmp_allowed: bool | None = None) -> int:
        """The action at ``(q, mode)``: FMP (-2), stay (-1) or a move index.

        In NR, or with ``depth`` 1, the minimiser of (9) followed by the correction step.
        In a layer with a request to finish the executor plans: the best motion sequence
        of :func:`lookahead` (falling back to (9) where no sequence stays in the domain),
        with the correction step at its start, is carried out to its end unless the mode
        changes or a planned FMP is refused. Raises ``ValueError`` where no action is
        available.
        """
        mdp = self.strategy.mdp
        q = np.ascontiguousarray(q, dtype=float)
        if self._plan and self._plan_mode == mode:
            u = self._plan.pop(0)
            if not (u == FMP and fmp_allowed is False):
                return u
        self._plan = []
        self._plan_mode = mode
        if mdp.fmp_next[mode] >= 0 and self.depth > 1:
            best, plan = self._lookahead(q, mode, fmp_allowed is not False)
            if plan:
                self.correct(q, mode, best)
                self._plan = plan[1:]
                return plan[0]
        vals = self.action_values(q, mode, fmp_allowed)
        u = best_action(vals)
        self.correct(q, mode, float(np.nanmin(vals)) - self.offset)
        return u

    def _lookahead(self, q: np.ndarray, mode: int, fmp_root: bool) -> tuple[float, list[int]]:
        """:func:`lookahead` with FMP confirmed by ``fmp_test`` where one is given."""
        flags = self._all
        if self.fmp_test is not None:
            _, _, count = self._call(q, mode, fmp_root, True, flags)
            flags = np.zeros(len(self._all), np.bool_)
            if count:
                flags[:count] = self.fmp_test(self._nodes[:count], mode)
        best, length, _ = self._call(q, mode, fmp_root, False, flags)
        return float(best), [int(a) for a in self._seq[:length]]

    def _call(
        self, q: np.ndarray, mode: int, fmp_root: bool, collect: bool, flags: np.ndarray
    ) -> tuple[float, int, int]:
        mdp = self.strategy.mdp
        return lookahead(
            q,
            mode,
            self.depth,
            self.h,
            self.live,
            mdp.free,
            mdp.disp,
            mdp.nact,
            mdp.heading_axis,
            mdp.vcls,
            mdp.cost,
            mdp.fmp_next,
            mdp.tf,
            fmp_root,
            self.offset,
            mdp.branch_ptr,
            mdp.branch_layer,
            mdp.branch_prob,
            mdp.shape,
            mdp.lower,
            mdp.upper,
            mdp.spacing,
            mdp.periodic,
            collect,
            self._nodes,
            flags,
            self._seq,
        )

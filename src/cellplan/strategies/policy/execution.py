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

* a lookahead (:func:`cellplan.strategies.model.points.lookahead`): every motion sequence of
  up to ``D`` stages that stays in the strategy's domain (each motion passes the swept
  check and ends in a live cell),
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

With FMP options (simultaneous requests) the lookahead is off (depth 1) and the
correction runs only where the robot meets a cell again since its mode last changed
(:meth:`Executor._revisit`): a held request is a cycle, whose cells are met again, while
raising at every state drifted the values away from the solved ones (issue 35).

The corrections belong to one execution (one simulated run); the strategy's values are
never modified.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellplan.strategies.model import stencils
from cellplan.strategies.model.bundles import Probe, Search
from cellplan.strategies.model.interpolation import interp
from cellplan.strategies.model.mdp import LayeredMDP
from cellplan.strategies.model.points import action_values_at, after_motion, lookahead
from cellplan.strategies.policy.baselines import motions_leave_layers
from cellplan.strategies.policy.decisions import FMP, best_action, option_or_motion
from cellplan.strategies.policy.strategy import Strategy, checked_state
from cellplan.strategies.variants.registry import model_variants

# Fraction of one stage's progress (:meth:`Executor._progress`, ``l - g`` in Section V's
# W and C layers) below which an inconsistency is left alone.
RAISE_FRACTION = 0.5
# Motion sequences examined per stage by the lookahead, and its deepest horizon.
LEAF_BUDGET = 400
MAX_DEPTH = 6


def default_depth(mdp: LayeredMDP, budget: int = LEAF_BUDGET) -> int:
    """The deepest lookahead whose motion sequences number at most ``budget``.

    With ``A`` motions per stage (a motion is never followed by its inverse) there are
    ``A (A - 1)^(D - 1)`` sequences of ``D`` stages: 5 stages for the rotating robot's 4
    motions, 2 for 16 headings, 3 for an arm's 6 joint steps. With noisy motion (Section
    VI-4) it is 1: rule (9) with the expectation over the landings; so it is in a
    time-varying model (Section VI-1), whose every motion leads to the next phase's layer,
    and with FMP options (Section VI-2). A variant sets its limit
    (:meth:`~cellplan.strategies.variants.base.Variant.lookahead`).
    """
    limits = [d for v in model_variants(mdp) if (d := v.lookahead(mdp)) is not None]
    if limits:
        return min(limits)  # a variant's own (noisy motion, FMP options: 1)
    if motions_leave_layers(mdp):
        return 1  # the lookahead stays in one layer; a time-varying model's next is the next phase
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
    option_test
        In a model with FMP options (simultaneous requests, Section VI-2), the exact test
        of option ``j``: ``(configurations, mode, j) -> bool``
        (:meth:`~cellplan.strategies.policy.regions.RegionTest.option`). Such a model is
        executed with rule (9) over the motions and the options the test confirms, and
        the correction step (depth 1: the lookahead follows one FMP per mode).
    """

    def __init__(
        self,
        strategy: Strategy,
        values: np.ndarray | None = None,
        offset: float | None = None,
        learn: bool = True,
        depth: int | None = None,
        fmp_test: Callable[[np.ndarray, int], np.ndarray] | None = None,
        option_test: Callable[[np.ndarray, int, int], np.ndarray] | None = None,
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
        self.option_test = option_test
        self.options = any(v.fmp_options() for v in model_variants(mdp))
        if self.options:
            self.depth = 1  # the lookahead follows one FMP per mode, not a choice of them
        na = int(mdp.nact.max())
        nodes = sum(na * max(na - 1, 1) ** i for i in range(self.depth))
        self._nodes = np.empty((nodes, len(mdp.shape)))
        self._all = np.ones(nodes, np.bool_)
        self._seq = np.empty(self.depth + 1, np.int64)
        self._plan: list[int] = []
        self._plan_mode = -1
        self._visited: set[int] = set()  # cells met since the mode last changed (options)
        self._visited_mode = -1
        self.corrections = 0
        self.raised = 0.0
        d = len(mdp.shape)
        self._out = np.empty(2 + mdp.disp.shape[1])
        self._idx = np.empty(1 << d, np.int64)
        self._w = np.empty(1 << d)
        self._ibuf = np.empty(2 * stencils.MAX_DIM, np.int64)
        self._frac = np.empty(stencils.MAX_DIM)
        self._model = mdp.kernel_args()
        # The point queries' scratch: the stencil of the last query stays in _idx, _w.
        mbuf = np.empty(3 * stencils.MAX_DIM, np.int64)
        self._probe = Probe(self._idx, self._w, self._ibuf, self._frac, mbuf)
        self._here = float("nan")  # H(q) of the last _progress call

    def action_values(
        self, q: np.ndarray, mode: int, fmp_allowed: bool | None = None
    ) -> np.ndarray:
        """Right-hand side of (9) per action, ``[FMP, stay, move 0, ...]`` (NaN: unavailable).

        As :meth:`Strategy.action_values`, on this execution's (corrected) values; the
        returned array is reused by the next call.
        """
        q, mode = checked_state(self.strategy.mdp, q, mode)
        return self._action_values(q, mode, fmp_allowed)

    def _action_values(self, q: np.ndarray, mode: int, fmp_allowed: bool | None) -> np.ndarray:
        mdp = self.strategy.mdp
        tf_here = float(mdp.tf[mode, self.strategy._cell_of(q)])
        if fmp_allowed is None:
            fmp_allowed = bool(np.isfinite(tf_here))
        action_values_at(
            q,
            mode,
            self.h,
            self.live,
            tf_here if np.isfinite(tf_here) else 0.0,
            fmp_allowed,
            self._model,
            self._out,
        )
        return self._out

    def value(self, q: np.ndarray, mode: int) -> float:
        """The interpolated cost-to-go ``H(q)`` of a layer (NaN outside its live states)."""
        q, mode = checked_state(self.strategy.mdp, q, mode)
        return self._value(q, mode)

    def _value(self, q: np.ndarray, mode: int) -> float:
        n = stencils.stencil(q, self._model.grid, self._idx, self._w, self._ibuf, self._frac)
        return float(interp(self.h[mode], self.live[mode], self._idx, self._w, n))

    def correct(self, q: np.ndarray, mode: int, target: float) -> float:
        """The LRTA* step: raise ``H(q)`` to ``target`` if it is lower by more than half a
        stage's progress; returns the raise (0 if none).

        ``target`` is the best backed-up value at ``q`` (the minimum of (9) less the
        offset, or the lookahead's best). Only layers with a request to finish are
        corrected (NR has no progress to make).
        """
        q, mode = checked_state(self.strategy.mdp, q, mode)
        return self._correct(q, mode, target)

    def _correct(self, q: np.ndarray, mode: int, target: float) -> float:
        mdp = self.strategy.mdp
        if not self.learn or mdp.fmp_next[mode] < 0 or not np.isfinite(target):
            return 0.0
        progress = self._progress(q, mode)  # also leaves q's stencil in _idx, _w
        here = self._here
        if np.isnan(here) or not progress > 0.0:
            return 0.0
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

    def _progress(self, q: np.ndarray, mode: int) -> float:
        """One stage's progress at ``(q, mode)``, the scale of the correction's threshold:
        the smaller positive one of ``l(m) - offset`` and the cost of one stage of delay in
        the values' terms, ``l(m) - offset + sum_b P_b H_{L_b}(q) - H_m(q)`` (the
        right-hand side of (9) for staying less ``H(q)``); NaN where neither is positive.

        Round a cycle of real states the residuals of the correction step sum to the sum
        of the delay costs over the cycle (the ``H`` terms cancel), so a threshold below a
        fraction of it keeps the LRTA* argument; the smaller of the two only corrects
        sooner. In a W or C layer of Section V (its only branch is itself) both are
        ``l - g``. In a mode whose loss is below the gain (one request open among
        simultaneous requests, Section VI-2) ``l - g`` is negative, but delay is still
        costly where the grid's optimal action is an FMP, through the arrivals that lead
        to costlier modes (``P_b (H_{L_b} - H_m) > 0``): with ``l - g`` alone a cycle there
        was never corrected (issue 35: a delivery refused at the edge of D2 held the
        robot until the next arrival). Sets ``self._here`` to ``H_m(q)`` and leaves
        ``q``'s stencil in ``_idx``, ``_w``.
        """
        mdp = self.strategy.mdp
        self._here = self._value(q, mode)
        after = after_motion(q, mode, self.h, self.live, self._model, self._probe)
        stage = float(mdp.cost[mode]) - self.offset
        delay = stage + float(after) - self._here
        positive = [v for v in (stage, delay) if v > 0.0]
        return min(positive) if positive else float("nan")

    def action(self, q: np.ndarray, mode: int, fmp_allowed: bool | None = None) -> int:
        """The action at ``(q, mode)``: FMP (-2), stay (-1) or a move index.

        In NR, or with ``depth`` 1, the minimiser of (9) followed by the correction step.
        In a layer with a request to finish the executor plans: the best motion sequence
        of :func:`lookahead` (falling back to (9) where no sequence stays in the domain),
        with the correction step at its start, is carried out to its end unless the mode
        changes or a planned FMP is refused. In a model with FMP options (simultaneous
        requests) it is (9) over the motions and the options ``option_test`` confirms
        (:func:`~.strategy.option_or_motion`), then the correction step where the robot
        meets a cell again in the same mode (:meth:`_revisit`); an option ``j`` is
        returned as ``fmp_code(j)``. Raises ``ValueError`` where no action is
        available.
        """
        mdp = self.strategy.mdp
        q, mode = checked_state(mdp, q, mode)
        if self.options:
            u, best = option_or_motion(
                q,
                mode,
                self.h,
                self.live,
                self._model,
                self._out,
                fmp_allowed is False,
                self.option_test,
            )
            if self._revisit(q, mode):
                self._correct(q, mode, best - self.offset)
            return u
        if self._plan and self._plan_mode == mode:
            u = self._plan.pop(0)
            if not (u == FMP and fmp_allowed is False):
                return u
        self._plan = []
        self._plan_mode = mode
        if mdp.fmp_next[mode] >= 0 and self.depth > 1:
            best, plan = self._lookahead(q, mode, fmp_allowed is not False)
            if plan:
                self._correct(q, mode, best)
                self._plan = plan[1:]
                return plan[0]
        vals = self._action_values(q, mode, fmp_allowed)
        u = best_action(vals)
        self._correct(q, mode, float(np.nanmin(vals)) - self.offset)
        return u

    def _revisit(self, q: np.ndarray, mode: int) -> bool:
        """Whether ``q``'s cell was met before since the mode last changed (and note it).

        With FMP options the correction step runs only on such a revisit: a request held
        for ever in one mode is a cycle, whose cells are all met again, so the LRTA*
        argument holds on them; elsewhere the robot is making its way and rule (9) acts
        alone. Correcting at every state instead raised the values at about one stage in
        ten in ``strategies_pending`` (the interpolation residuals of its many modes
        exceed half the small delay cost of a cheap mode) and the raises, kept for the
        run, cost about 7% more loss than rule (9) (issue 35; docs/strategies.md).
        """
        if mode != self._visited_mode:
            self._visited_mode, self._visited = mode, set()
        cell = int(self.strategy._cell_of(q))
        if cell in self._visited:
            return True
        self._visited.add(cell)
        return False

    def _lookahead(self, q: np.ndarray, mode: int, fmp_root: bool) -> tuple[float, list[int]]:
        """The lookahead (:func:`.points.lookahead`), FMP confirmed by ``fmp_test`` if given."""
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
        search = Search(self.depth, self.offset, fmp_root, collect, self._nodes, flags, self._seq)
        return lookahead(q, mode, self.h, self.live, self._model, search)

"""Simulating simultaneous requests (Section VI-2): the optimal strategy and its baselines.

One run draws, per stage, whether a request arrives and of which type from a stream
seeded by ``seed`` alone, so every policy of one seed meets the same requests at the same
stages (common random numbers: the paired differences between policies have far less
noise than the policies' own figures). The process is that of
:mod:`cellplan.strategies.variants.pending`: a request arriving while ``max_pending`` are open is
turned away (counted); none arrives during an FMP.

Policies (:data:`PENDING_POLICIES`):

* ``optimal``: the solved strategy, one step of equation (9) at the real configuration
  (every move, stay, and every FMP option the robot's grid cell allows, the best taken;
  with a workcell an FMP option must also pass the exact region test of the request it
  serves); the pick decides which open request is served. It runs through the Section V
  :class:`~cellplan.strategies.policy.execution.Executor` (its LRTA* correction, one per run), so
  a configuration whose grid cell promises an FMP that the exact test refuses cannot hold
  the robot in a cycle: each pass raises the promised value until leaving is better
  (issue 35: a delivery 0.018 short of D2's edge held a run for 147,000 stages).
* ``fcfs``: first come, first served. The robot serves the oldest waiting request with
  the Section V strategy of that request alone (the W and C layers of the same model
  with one request open, :func:`single_request_model`), and while nothing is open it
  waits where the Section V strategy waits (it anticipates as well as Section V allows).
* ``nearest``: as ``fcfs``, but it serves the waiting request that the Section V
  strategy would finish soonest from where the robot is (its W value there): shortest
  time to serve first. The choice is made when the robot sets off and kept until the pick.
* ``reactive``: ``fcfs`` that stays where it is while nothing is open (the reactive
  robot of Section V-C).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from cellplan.core import Progress
from cellplan.strategies.model.mdp import NR, LayeredMDP, Mode, compute_live
from cellplan.strategies.model.stencils import fmp_code
from cellplan.strategies.policy.decisions import FMP, STAY, best_action
from cellplan.strategies.policy.execution import Executor
from cellplan.strategies.policy.regions import region_test
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.section import SolverSpec
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.sim.records import (
    Request,
    Simulation,
    default_start,
    open_requests,
)
from cellplan.strategies.solve.solver import solve
from cellplan.strategies.variants.pending import mode_keys
from cellplan.strategies.variants.request_sets import PENDING_POLICIES

__all__ = [
    "PENDING_POLICIES",
    "PendingSimulation",
    "Rules",
    "simulate_pending",
    "single_request_model",
    "single_request_strategy",
]


@dataclass
class PendingSimulation(Simulation):
    """A run with simultaneous requests: :class:`Simulation` plus the queue's figures."""

    open_counts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    durations: np.ndarray = field(default_factory=lambda: np.zeros(0))  # time of each stage
    turned_away: int = 0
    arrivals: int = 0

    def metrics(self) -> dict[str, float]:
        """:meth:`Simulation.metrics` plus ``mean_open`` (the time average of the number
        of open requests, waiting or carried), ``turned_away`` and ``arrivals`` (requests
        drawn, turned away or not)."""
        out = super().metrics()
        total = float(self.durations.sum())
        out["mean_open"] = (
            float((self.open_counts * self.durations).sum() / total) if total else float("nan")
        )
        out["turned_away"] = float(self.turned_away)
        out["arrivals"] = float(self.arrivals)
        return out


def single_request_model(mdp: LayeredMDP) -> LayeredMDP:
    """The Section V model inside a simultaneous-requests model: NR, and for each request
    type ``r`` the modes ``({r}, none)`` (W) and ``(empty, r)`` (C), requests arriving in NR
    only, unweighted loss. Same grid, move classes and fine motions; live states anew.
    """
    R = len(mdp.request_prob)
    # pending_modes puts the modes ({r}, none) right after NR, in request order.
    names = [mdp.modes[1 + r].waiting[0] for r in range(R)]
    triples = [_triple(name) for name in names]
    by_key = mode_keys(mdp)
    w_layers = [by_key[((name,), "", "", "")] for name in names]
    c_layers = [by_key[((), p, s, d)] for p, s, d in triples]
    keep = [0, *w_layers, *c_layers]
    opt = mdp.options
    tf = np.full((len(keep), mdp.n_cells), np.inf)
    fmp_next = np.full(len(keep), -1, np.int64)
    for i, m in enumerate(keep[1:], start=1):
        # The W layer's single option is the pick; the C layer's the delivery (unweighted).
        tf[i] = mdp.tf[opt[m]] * mdp.stage_time / mdp.cost[m]
        fmp_next[i] = 1 + R + (i - 1) if i <= R else 0
    ptr = [0]
    layers = [0, *range(1, 1 + R)]
    probs = [1.0 - mdp.arrival, *(mdp.arrival * mdp.request_prob)]
    ptr.append(len(layers))
    for i in range(1, 1 + 2 * R):
        layers.append(i)
        probs.append(1.0)
        ptr.append(len(layers))
    cost = np.full(len(keep), mdp.stage_time)
    cost[0] = 0.0
    used, vcls = np.unique(mdp.vcls[keep], return_inverse=True)
    sub = replace(
        mdp,
        modes=[Mode(NR)]
        + [Mode("W", p, s, d) for p, s, d in triples]
        + [Mode("C", p, s, d) for p, s, d in triples],
        cost=cost,
        vcls=vcls.astype(np.int64),
        free=mdp.free[used],
        disp=mdp.disp[used],
        nact=mdp.nact[used],
        valid=mdp.valid[used],
        offs=mdp.offs[used],
        fr=mdp.fr[used],
        coff=mdp.coff[used],
        cw=mdp.cw[used],
        interior=mdp.interior[used],
        labels=[mdp.labels[k] for k in used],
        fmp_next=fmp_next,
        tf=tf,
        branch_ptr=np.asarray(ptr, np.int64),
        branch_layer=np.asarray(layers, np.int64),
        branch_prob=np.asarray(probs, float),
        live=np.stack([mdp.free[mdp.vcls[m]] for m in keep]),
        outcomes=None,
        opt_ptr=None,
    )
    compute_live(sub)
    return sub


def single_request_strategy(strategy: Strategy, tolerance: float | None = None) -> Strategy:
    """The solved Section V strategy of :func:`single_request_model`: the baselines'
    navigation (``fcfs``, ``nearest``, ``reactive``).

    It is solved to ``tolerance``, by default the tolerance the strategy itself was solved
    to (its ``tolerance`` metadata, the planner's option or the scenario's
    ``strategy.solver.tolerance``; a file written before it was recorded: the
    scenario schema's default). The optimal policy never needs it.
    """
    if tolerance is None:
        recorded = strategy.meta.get("tolerance")
        tolerance = float(recorded) if recorded is not None else DEFAULT_TOLERANCE
    sub = single_request_model(strategy.mdp)
    return Strategy.from_solution(sub, solve(sub, "auto", tolerance))


#: The solver's tolerance for a strategy file that does not record its own (the
#: scenario schema's default, :class:`~cellplan.strategies.section.SolverSpec`).
DEFAULT_TOLERANCE = float(SolverSpec.model_fields["tolerance"].default)


class Rules:
    """The action rules of :data:`PENDING_POLICIES` on one solved strategy.

    ``single`` is the solved Section V strategy of :func:`single_request_model`
    (:func:`single_request_strategy`), the baselines' navigation; the optimal policy runs
    without it (None), and a baseline asked for without it raises ``ValueError``. Build
    once per strategy and reuse it across runs (the experiment runs many seeds).
    """

    def __init__(self, strategy: Strategy, single: Strategy | None = None) -> None:
        self.strategy = strategy
        mdp = strategy.mdp
        self._single = single
        self.R = len(mdp.request_prob)
        # pending_modes puts the modes ({r}, none) right after NR, in request order.
        self.names = [mdp.modes[1 + r].waiting[0] for r in range(self.R)]
        self.index = mode_keys(mdp)

    @property
    def single(self) -> Strategy:
        """The Section V strategy of the baselines (``ValueError`` where none was given)."""
        if self._single is None:
            raise ValueError(
                "the baseline policies need the Section V strategy inside the model: "
                "Rules(strategy, single_request_strategy(strategy))"
            )
        return self._single

    def mode_of(self, waiting: list[int], carried: int) -> int:
        """The model's mode of these waiting request types and the carried one (-1)."""
        names = tuple(self.names[r] for r in sorted(waiting))
        if carried < 0:
            return self.index[(names, "", "", "")]
        p, s, d = _triple(self.names[carried])
        return self.index[(names, p, s, d)]

    def optimal(self, executor: Executor, q: np.ndarray, m: int) -> int:
        """The best action of (9) at ``q`` in mode ``m`` by the run's ``executor`` (a move,
        stay or an FMP code, the options confirmed by its exact test, with its
        correction step); stay where none is available."""
        try:
            return executor.action(q, m)
        except ValueError:
            return STAY

    def serve(self, q: np.ndarray, target: int, carrying: bool, forbid_fmp: bool = False) -> int:
        """The Section V strategy's action for request ``target`` alone (FMP, stay, move);
        stay where none is available (the run's verdict then names the request waiting)."""
        layer = 1 + target + (self.R if carrying else 0)
        allowed = False if forbid_fmp else None  # None: where the grid cell allows it
        return _or_stay(self.single.action_values(q, layer, fmp_allowed=allowed))

    def idle(self, q: np.ndarray) -> int:
        """Where the Section V strategy goes while no request is open."""
        return _or_stay(self.single.action_values(q, 0))

    def finish_time(self, q: np.ndarray, r: int) -> float:
        """The Section V value of request ``r`` waiting, at ``q`` (time to serve it alone)."""
        vals = self.single.action_values(q, 1 + r)
        return float(np.nanmin(vals)) if not np.all(np.isnan(vals)) else np.inf


def simulate_pending(
    strategy: Strategy,
    stages: int,
    seed: int,
    options: SimulationOptions | None = None,
    *,
    rules: Rules | None = None,
    cell: Any = None,
    progress: Progress | None = None,
) -> PendingSimulation:
    """Run ``options.policy`` for ``stages`` stages from NR at ``options.start`` (module
    docstring; ``start`` None: the strategy's recorded start where it is live in NR, else
    :func:`~cellplan.strategies.sim.records.default_start`).

    With a workcell (``cell``), every FMP is confirmed by its exact region test
    (:meth:`~cellplan.workcell.Workcell.in_region`, ``options.regions``, by default the
    strategy's): the source of the request a pick serves, the destination of the carried
    one; a refused FMP falls back to the best motion (an ``fmp_refused`` event). Without
    one, FMP follows the grid cell. ``rules``: the policies' rules built once for many
    runs (:class:`Rules`); ``start_mode``, ``home`` and ``learn`` do not apply here (a run
    starts in NR; the optimal policy always corrects).

    Every request's waiting time counts each stage (and each FMP's fine-motion time) from
    its arrival until its delivery; the loss of a stage is that of the model (the weighted
    number of open requests times the stage's time).
    """
    opts = options if options is not None else SimulationOptions(policy="optimal")
    if opts.policy not in PENDING_POLICIES:
        raise ValueError(f"policy must be one of {PENDING_POLICIES}, not {opts.policy!r}")
    if rules is None:
        # The baselines' navigation is solved here, visibly, to the strategy's own
        # tolerance; the optimal policy needs none.
        single = single_request_strategy(strategy) if opts.policy != "optimal" else None
        rules = Rules(strategy, single)
    run = _PendingRun(strategy, stages, seed, opts, (rules, cell))
    every = max(1, stages // 200)
    for k in range(stages):
        if progress is not None and k % every == 0:
            progress(float(k), float(stages), f"stage {k:,} of {stages:,}")
        run.stage(k)
    return run.simulation()


class _PendingRun:
    """The state of one run of :func:`simulate_pending`, advanced a stage at a time:
    the open requests (``waiting`` in order of arrival, ``carried``), the robot's ``q``
    and mode ``m``, and the samples. ``with_`` is the policies' rules and the workcell."""

    def __init__(
        self,
        strategy: Strategy,
        stages: int,
        seed: int,
        opts: SimulationOptions,
        with_: tuple[Rules, Any],
    ) -> None:
        mdp = strategy.mdp
        self.s, self.mdp, self.policy = strategy, mdp, opts.policy
        self.rules, self.cell = with_
        self.regions = opts.region_test(strategy)
        self.k_max = max(open_requests(m) for m in mdp.modes)
        stream = np.random.default_rng(seed)
        self.arrive = stream.random(stages) < mdp.arrival
        p = mdp.request_prob / mdp.request_prob.sum()
        self.kinds = stream.choice(self.rules.R, size=stages, p=p)
        start = opts.start if opts.start is not None else _start(strategy)
        self.q = np.asarray(start, float).copy()
        self.qs = np.empty((stages + 1, len(self.q)))
        self.ms = np.empty(stages + 1, np.int64)
        self.acts = np.empty(stages, np.int64)
        self.losses = np.empty(stages)
        self.counts = np.empty(stages, np.int64)
        self.durations = np.empty(stages)
        self.waiting: list[Request] = []  # in order of arrival
        self.waiting_type: list[int] = []
        self.carried: Request | None = None
        self.carried_type = -1
        self.target = -1  # the baselines' committed request type
        self.requests: list[Request] = []
        self.events: list[tuple[int, str, str]] = []
        self.turned = 0
        self.refused = 0
        self.m = 0
        self.qs[0], self.ms[0] = self.q, self.m
        test = self.cell is not None
        self.test = _CountingTest(region_test(strategy, self.cell, self.regions)) if test else None
        self.executor = Executor(strategy, option_test=self.test)

    def stage(self, k: int) -> None:
        """One stage: the policy's action (a move, stay, or FMP option ``j``), its loss and
        duration, the pick or delivery, or the move and an arrival."""
        mdp, m = self.mdp, self.m
        c = self.s.cell_of(self.q)
        u, j = self._action(k)
        opt = mdp.options
        if j >= 0 and not np.isfinite(mdp.tf[opt[m] + j, c]):
            j, u = -1, STAY  # a baseline's FMP the grid cell does not allow
        open_now = len(self.waiting) + (self.carried is not None)
        self.counts[k] = open_now
        if j >= 0:
            loss = float(mdp.tf[opt[m] + j, c])
            duration = loss * mdp.stage_time / mdp.cost[m]
        else:
            loss = float(mdp.cost[m])
            duration = mdp.stage_time
        self.durations[k] = duration
        for r in self.waiting:
            r.waiting += duration
        if self.carried is not None:
            self.carried.waiting += duration
        if j >= 0:
            self._fmp(k, j)
        else:
            if u != STAY:
                self.q = self.s.next_configuration(self.q, m, u)
            if self.arrive[k]:
                self._arrival(k, open_now)
        self.losses[k] = loss
        self.acts[k] = u
        self.m = self.rules.mode_of(self.waiting_type, self.carried_type)
        self.qs[k + 1], self.ms[k + 1] = self.q, self.m

    def _action(self, k: int) -> tuple[int, int]:
        """The policy's action ``u`` and its FMP option ``j`` (-1: a move or stay); an FMP
        the exact region test refuses is replaced by the best motion."""
        rules, q, m = self.rules, self.q, self.m
        if self.policy == "optimal":
            before = self.test.refused if self.test is not None else 0
            u = rules.optimal(self.executor, q, m)
            if self.test is not None and self.test.refused > before:
                self.refused += self.test.refused - before
                self.events.append((k, "fmp_refused", self.mdp.modes[m].label))
            # The executor confirmed its FMP options by the exact test.
            return u, -1 if u >= STAY else (0 if u == FMP else -3 - u)
        forbid = False
        while True:
            u = self._baseline(q, forbid)
            j = -1 if u >= STAY else (0 if u == FMP else -3 - u)
            if j < 0 or self.cell is None or forbid:
                return u, j
            if self.carried is not None:
                where, part = self.carried.destination, self.carried.part
            else:
                name = rules.names[sorted(set(self.waiting_type))[j]]
                where, part = _triple(name)[1], None
            if self.cell.in_region(q[None, :], where, self.regions, None, part)[0]:
                return u, j
            forbid = True  # the grid cell allows it, the exact test does not
            self.refused += 1
            self.events.append((k, "fmp_refused", self.mdp.modes[m].label))

    def _baseline(self, q: np.ndarray, forbid: bool) -> int:
        """A baseline's action: serve the carried request, else the committed waiting one
        (chosen anew when it is no longer waiting), else idle."""
        rules = self.rules
        if self.carried is not None:
            u = rules.serve(q, self.carried_type, True, forbid)
            return fmp_code(0) if u == FMP else u
        if self.waiting:
            if self.target not in self.waiting_type:
                self.target = _choose(self.policy, q, self.waiting_type, rules)
            u = rules.serve(q, self.target, False, forbid)
            if u == FMP:
                u = fmp_code(sorted(set(self.waiting_type)).index(self.target))
            return u
        return STAY if self.policy == "reactive" else rules.idle(q)

    def _fmp(self, k: int, j: int) -> None:
        """Deliver the carried request, or pick the oldest waiting one of option ``j``."""
        if self.carried is not None:
            carried = self.carried
            carried.delivery = k + 1
            self.events.append((k + 1, "place", f"{carried.part} at {carried.destination}"))
            self.carried, self.carried_type = None, -1
            return
        r_type = sorted(set(self.waiting_type))[j]
        i = self.waiting_type.index(r_type)  # the oldest request of that type
        self.carried, self.carried_type = self.waiting.pop(i), self.waiting_type.pop(i)
        self.carried.pickup = k + 1
        self.events.append((k + 1, "pick", f"{self.carried.part} at {self.carried.source}"))
        self.target = -1

    def _arrival(self, k: int, open_now: int) -> None:
        """This stage's drawn request arrives, or is turned away when ``k_max`` are open."""
        r_type = int(self.kinds[k])
        p, s, d = _triple(self.rules.names[r_type])
        if open_now >= self.k_max:
            self.turned += 1
            self.events.append((k + 1, "turned_away", f"<{p},{s},{d}>"))
            return
        req = Request(p, s, d, k + 1)
        self.requests.append(req)
        self.waiting.append(req)
        self.waiting_type.append(r_type)
        self.events.append((k + 1, "request", f"<{p},{s},{d}>"))

    def simulation(self) -> PendingSimulation:
        return PendingSimulation(
            q=self.qs,
            modes=self.ms,
            actions=self.acts,
            losses=self.losses,
            requests=self.requests,
            policy=self.policy,
            events=self.events,
            open_counts=self.counts,
            durations=self.durations,
            turned_away=self.turned,
            fmp_refused=self.refused,
            corrections=self.executor.corrections,
            raised=self.executor.raised,
            arrivals=int(self.arrive.sum()),
        )


class _CountingTest:
    """An option's exact region test
    (:meth:`~cellplan.strategies.policy.regions.RegionTest.option`) that counts its
    refusals, for the run's ``fmp_refused``."""

    def __init__(self, test: Any) -> None:
        self.test = test
        self.refused = 0

    def __call__(self, points: np.ndarray, m: int, j: int) -> np.ndarray:
        ok = np.asarray(self.test.option(points, m, j), dtype=bool)
        self.refused += int((~ok).sum())
        return ok


def _choose(policy: str, q: np.ndarray, waiting_type: list[int], rules: Rules) -> int:
    """The baselines' next request: the oldest, or the soonest finished (``nearest``)."""
    if policy == "nearest":
        times = [rules.finish_time(q, r) for r in waiting_type]
        return waiting_type[int(np.argmin(times))]
    return waiting_type[0]


def _or_stay(values: np.ndarray) -> int:
    """:func:`~cellplan.strategies.policy.strategy.best_action`,
    or stay where every action is NaN."""
    return STAY if np.all(np.isnan(values)) else best_action(values)


def _triple(name: str) -> tuple[str, str, str]:
    """``(part, source, destination)`` of a request's name ``"part,source,destination"``."""
    p, s, d = name.split(",")
    return p, s, d


def _start(strategy: Strategy) -> np.ndarray:
    """The start the strategy records (the robot's), if live in NR; else the default."""
    recorded = strategy.meta.get("start")
    if recorded is not None:
        q = np.asarray(recorded, float)
        if strategy.mdp.live[0, strategy.cell_of(q)]:
            return q
    return default_start(strategy)

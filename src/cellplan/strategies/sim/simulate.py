"""Execute a strategy in the stochastic assembly process (Sections III-B and V).

Each stage the policy picks an action at the robot's real-valued configuration (not the
grid), the configuration moves by equation (5) (or its variant), and the next mode is
drawn from ``P(m_{k+1} | x_k, u_k)``: request arrivals in NR (type 1), destination changes
while carrying (type 2), source changes while waiting (type 3); FMP switches W -> C and
C -> NR with probability one. The loss of each stage is equation (7), so a request's
waiting time is the loss summed from its arrival to its delivery.

Three policies run in the same simulator: ``optimal`` (the strategy), ``reactive`` and
``home`` (see :mod:`cellplan.strategies.policy.baselines`). While a request waits, each picks
its action through an :class:`~cellplan.strategies.policy.execution.Executor` (equation (9)
with a lookahead and the LRTA* correction, so that no request waits for ever); every
stage is one of the robot's own motions, a stay, or FMP.

:func:`simulate` returns the raw :class:`Simulation`; :func:`simulate_result` (the
library's ``cellplan.simulate``) wraps it in the common :class:`~cellplan.core.Result`,
with the run as a :class:`~cellplan.trajectory.Trajectory` (stage, configuration, mode,
request / pick / place events) and a status that says whether every request was served
within a bound (:func:`wait_bound`; docs/strategies.md, "Simulation status").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from cellplan.core import Progress, Result, Status
from cellplan.errors import ArgumentError, Problem
from cellplan.strategies.model.mdp import NR
from cellplan.strategies.policy.baselines import home_values, per_request_values
from cellplan.strategies.policy.decisions import FMP, STAY, best_action
from cellplan.strategies.policy.execution import Executor
from cellplan.strategies.policy.regions import region_test
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.sim.options import POLICIES, SimulationOptions, run_problems
from cellplan.strategies.sim.records import (
    COUNT_METRICS,
    Request,
    Simulation,
    default_start,
)
from cellplan.strategies.sim.report import (
    _configuration,
    _verdict,
    axis_names,
    first_collision,
    to_trajectory,
    wait_bound,
)
from cellplan.strategies.variants.registry import model_variants
from cellplan.strategies.variants.simulators import simulator_of


class _Policies:
    """The action rules of the three policies on one strategy, for one run.

    Every rule that finishes a request executes (9) through an
    :class:`~cellplan.strategies.policy.execution.Executor` (its corrections last for the run).
    """

    def __init__(
        self,
        strategy: Strategy,
        home: np.ndarray | None,
        learn: bool = True,
        fmp_test: Callable[[np.ndarray, int], np.ndarray] | None = None,
    ) -> None:
        self.s = strategy
        self.learn = learn
        self.fmp_test = fmp_test
        self.optimal = Executor(strategy, learn=learn, fmp_test=fmp_test)
        self._req: Executor | None = None
        self._home: np.ndarray | None = None
        self.home_q = home

    @property
    def request(self) -> Executor:
        """Executor of the per-request values (the baselines while a request waits)."""
        if self._req is None:
            self._req = Executor(
                self.s,
                per_request_values(self.s.mdp),
                offset=0.0,
                learn=self.learn,
                fmp_test=self.fmp_test,
            )
        return self._req

    @property
    def home_layers(self) -> np.ndarray:
        if self._home is None:
            mdp = self.s.mdp
            q = (
                self.home_q
                if self.home_q is not None
                else np.array(self.s.meta.get("home", default_start(self.s)))
            )
            # The home cell: the live NR cell whose centre is nearest to the home configuration.
            live = np.flatnonzero(mdp.live[0])
            centres = (
                mdp.lower
                + (np.array(np.unravel_index(live, tuple(mdp.shape))).T + 0.5) * mdp.spacing
            )
            home_cell = int(live[np.argmin(np.linalg.norm(centres - q, axis=1))])
            hv = home_values(mdp, home_cell)
            # NR's successors are NR and the W layers; giving them all the home values makes
            # (9) pick the move that gets closest to home.
            layers = np.tile(hv, (self.s.mdp.n_modes, 1))
            self._home = layers
        return self._home

    def executor(self, policy: str, mode: int) -> Executor | None:
        """The executor behind a policy in a mode (None: the baselines' idle rules)."""
        if policy == "optimal":
            return self.optimal
        return None if self.s.mdp.modes[mode].kind == NR else self.request

    def values(self, policy: str, q: np.ndarray, mode: int, fmp_allowed: bool | None) -> np.ndarray:
        ex = self.executor(policy, mode)
        if ex is not None:
            return ex.action_values(q, mode, fmp_allowed)
        if policy == "reactive":
            out = np.full(2 + self.s.mdp.disp.shape[1], np.nan)
            out[1] = 0.0
            return out
        return self.s.action_values(q, 0, values=self.home_layers, fmp_allowed=False)

    def action(self, policy: str, q: np.ndarray, mode: int, fmp_allowed: bool | None) -> int:
        """The policy's action at ``(q, mode)``, with the executor's correction step."""
        ex = self.executor(policy, mode)
        if ex is not None:
            return ex.action(q, mode, fmp_allowed)
        return best_action(self.values(policy, q, mode, fmp_allowed))

    @property
    def corrections(self) -> tuple[int, float]:
        """Number and total size of the value corrections made so far."""
        exs = [self.optimal] + ([self._req] if self._req is not None else [])
        return sum(e.corrections for e in exs), sum(e.raised for e in exs)


def simulate(
    strategy: Strategy,
    stages: int,
    seed: int,
    options: SimulationOptions | None = None,
    *,
    cell: Any = None,
    progress: Progress | None = None,
) -> Simulation:
    """Run the assembly process for ``stages`` stages from ``(options.start, options.start_mode)``.

    Parameters
    ----------
    strategy
        The solved strategy (its model supplies the transition probabilities).
    stages, seed
        Length of the run and the seed of its random generator.
    options
        The policy, start, region test, home and learning of the run
        (:class:`~cellplan.strategies.sim.options.SimulationOptions`; ``start`` None is
        :func:`~cellplan.strategies.sim.records.default_start` here). ``max_wait`` is
        :func:`simulate_result`'s.
    cell
        With a workcell, every FMP is confirmed by the exact region test
        (:meth:`~cellplan.workcell.Workcell.in_region`, ``options.regions``); a refused
        FMP falls back to the best motion.
    progress
        Called as ``progress(done, stages, text)`` about 200 times in the run (the CLI
        draws a bar with it).

    A variant whose process this simulator does not run names a simulator of its own
    (:data:`cellplan.strategies.variants.simulators.SIMULATORS`: simultaneous requests,
    Section VI-2, run in :func:`~cellplan.strategies.variants.pending_sim.simulate_pending`,
    whose policies are ``optimal``, ``fcfs``, ``nearest`` and ``reactive``); the others
    change this one through their simulation hooks (:class:`~.base.Variant`).
    """
    opts = options if options is not None else SimulationOptions()
    own = simulator_of(strategy.mdp)
    if own is not None:
        return own(strategy, stages, seed, opts, cell=cell, progress=progress)
    if opts.policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, not {opts.policy!r}")
    run = _Run(strategy, stages, seed, opts, cell)
    every = max(1, stages // 200)
    for k in range(stages):
        if progress is not None and k % every == 0:
            progress(
                float(k), float(stages), f"stage {k:,} of {stages:,}, {len(run.requests)} requests"
            )
        run.stage(k)
    return run.simulation()


class _Run:
    """The state of one run of the Section V simulator, advanced a stage at a time.

    The variants the model carries (:func:`~cellplan.strategies.variants.registry.model_variants`)
    change it through their hooks: where a move lands (Section VI-4) and the events of an
    FMP's outcome (Section VI-3).
    """

    def __init__(
        self, strategy: Strategy, stages: int, seed: int, opts: SimulationOptions, cell: Any
    ) -> None:
        mdp = strategy.mdp
        self.s, self.mdp, self.cell, self.policy = strategy, mdp, cell, opts.policy
        self.variants = model_variants(mdp)
        self.rng = np.random.default_rng(seed)
        self.idle = [mode.kind == NR for mode in mdp.modes]
        self.out = mdp.fmp_outcomes()
        self.test = (
            region_test(strategy, cell, opts.region_test(strategy)) if cell is not None else None
        )
        home = None if opts.home is None else np.asarray(opts.home, float)
        self.rules = _Policies(strategy, home, opts.learn, self.test)
        start = opts.start if opts.start is not None else default_start(strategy)
        self.q = np.asarray(start, float).copy()
        self.m = int(opts.start_mode)
        self.qs = np.empty((stages + 1, len(self.q)))
        self.ms = np.empty(stages + 1, np.int64)
        self.acts = np.empty(stages, np.int64)
        self.losses = np.empty(stages)
        self.qs[0], self.ms[0] = self.q, self.m
        self.requests: list[Request] = []
        self.events: list[tuple[int, str, str]] = []
        self.current: Request | None = None
        self.refused = 0
        if not self.idle[self.m]:
            self._arrive(0, mdp.modes[self.m])

    def stage(self, k: int) -> None:
        """One stage: the policy's action, its loss (7) and the transition."""
        mdp, q, m = self.mdp, self.q, self.m
        u = self.rules.action(self.policy, q, m, self._fmp_allowed(k))
        # Loss (7).
        if self.idle[m]:
            loss = 0.0
        elif u == FMP:
            loss = float(mdp.tf[m, self.s.cell_of(q)])
        else:
            loss = mdp.stage_time
        if self.current is not None:
            self.current.waiting += loss
        if u == FMP:
            m_next, rework = self._fmp(k)
            # A rework time (retry in place, Section VI-3) is a loss of the stage.
            loss += rework
        else:
            m_next = self._motion(k, u)
        self.m = m_next
        self.acts[k], self.losses[k] = u, loss
        self.qs[k + 1], self.ms[k + 1] = self.q, m_next

    def _fmp_allowed(self, k: int) -> bool | None:
        """False where the grid cell allows FMP but the exact region test at ``q`` does
        not (then (9) is evaluated without FMP; stay is not offered while a motion is
        possible, so the robot does not wait beside the region for ever); else None."""
        q, m = self.q, self.m
        if (
            self.test is None
            or self.idle[m]
            or not np.isfinite(self.mdp.tf[m, self.s.cell_of(q)])
            or self.test(q[None, :], m)[0]
        ):
            return None
        self.refused += 1
        self.events.append((k, "fmp_refused", self.mdp.modes[m].label))
        return False

    def _fmp(self, k: int) -> tuple[int, float]:
        """Draw the FMP's outcome; returns the next layer and the outcome's rework time."""
        mdp, out, m, current = self.mdp, self.out, self.m, self.current
        o0, o1 = out.ptr[m], out.ptr[m + 1]
        oprob = out.prob[o0:o1]
        pick = np.searchsorted(np.cumsum(oprob), self.rng.random() * oprob.sum(), side="right")
        o = o0 + min(int(pick), o1 - o0 - 1)
        m_next = int(out.layer[o])
        assert current is not None
        event = next((e for v in self.variants if (e := v.fmp_event(mdp, m, o)) is not None), None)
        kind = mdp.modes[m].kind
        if event is not None:  # a variant's outcome (Section VI-3: a failure, a dropped part)
            self.events.append((k + 1, event.kind, event.detail))
            if event.kind == "fmp_failed":
                current.failures += 1
            nxt = mdp.modes[m_next]
            if nxt.kind == "W" and kind != "W":  # the part waits at a source again
                if nxt.source != current.source:
                    self.events.append(
                        (k + 1, "source_change", f"{current.source} to {nxt.source}")
                    )
                    current.source = nxt.source
                current.pickup = -1
        elif kind == "W":
            current.pickup = k + 1
            self.events.append((k + 1, "pick", f"{current.part} at {current.source}"))
        else:
            current.delivery = k + 1
            self.events.append((k + 1, "place", f"{current.part} at {current.destination}"))
            self.current = None
        return m_next, float(out.cost[o])

    def _motion(self, k: int, u: int) -> int:
        """Move (or stay), then draw the next mode from the branches of ``m``."""
        mdp, m = self.mdp, self.m
        if u != STAY:
            # Where the move lands: a variant's draw (noisy motion, Section VI-4) or as commanded.
            landing = next(
                (j for v in self.variants if (j := v.landing(mdp, self.rng)) is not None), None
            )
            self.q = self.s.next_configuration(self.q, m, u, landing)
        b0, b1 = mdp.branch_ptr[m], mdp.branch_ptr[m + 1]
        probs = mdp.branch_prob[b0:b1]
        pick = int(np.searchsorted(np.cumsum(probs), self.rng.random() * probs.sum(), side="right"))
        m_next = int(mdp.branch_layer[b0 + min(pick, b1 - b0 - 1)])
        M = mdp.modes_per_phase
        if m_next % M != m % M:  # the phase of a time-varying model aside
            mode = mdp.modes[m_next]
            if self.idle[m]:
                self._arrive(k + 1, mode)
            elif self.current is not None:
                self._change(k + 1, mode)
        return m_next

    def _arrive(self, k: int, mode: Any) -> None:
        self.current = Request(mode.part, mode.source, mode.destination, k)
        self.requests.append(self.current)
        self.events.append((k, "request", _request_detail(self.current)))

    def _change(self, k: int, mode: Any) -> None:
        """A request's destination (type 2) or source (type 3) changes to ``mode``'s."""
        current = self.current
        assert current is not None
        if mode.destination != current.destination:
            self.events.append(
                (k, "destination_change", f"{current.destination} to {mode.destination}")
            )
        if mode.source != current.source:
            self.events.append((k, "source_change", f"{current.source} to {mode.source}"))
        current.source, current.destination = mode.source, mode.destination
        current.changes += 1

    def simulation(self) -> Simulation:
        fixes, raised = self.rules.corrections
        return Simulation(
            self.qs,
            self.ms,
            self.acts,
            self.losses,
            self.requests,
            self.policy,
            self.refused,
            fixes,
            raised,
            self.events,
            modes_per_phase=self.mdp.modes_per_phase,  # all layers in a stationary model
        )


def _request_detail(r: Request) -> str:
    return f"{r.part} from {r.source} to {r.destination}"


def compare_policies(
    strategy: Strategy,
    stages: int,
    seeds: list[int],
    options: SimulationOptions | None = None,
    *,
    cell: Any = None,
) -> dict[str, list[dict[str, float]]]:
    """Metrics of the three policies over the same seeds (paired comparison); ``options``
    (its ``policy`` aside) as in :func:`simulate`."""
    opts = options if options is not None else SimulationOptions()
    return {
        p: [
            simulate(strategy, stages, s, replace(opts, policy=p), cell=cell).metrics()
            for s in seeds
        ]
        for p in POLICIES
    }


# --- the simulation as a Result ---------------------------------------------------------------


def simulate_result(
    strategy: Strategy,
    stages: int,
    seed: int,
    options: SimulationOptions | None = None,
    *,
    cell: Any = None,
    progress: Progress | None = None,
    robot_spec: Any = None,
) -> Result:
    """Run a strategy in the stochastic assembly process and return the run as a Result.

    This is ``cellplan.simulate``: :func:`simulate` (Sections III-B and V) wrapped in the
    common :class:`~cellplan.core.Result`.

    Parameters
    ----------
    strategy
        A solved strategy (``cellplan.plan(setup, "strategies").solution`` or
        :meth:`Strategy.load <cellplan.strategies.policy.strategy.Strategy.load>`).
    stages, seed
        Length of the run (1 to :data:`MAX_STAGES`) and the seed of its random stream.
    options
        How the run is run (:class:`~cellplan.strategies.sim.options.SimulationOptions`,
        ``cellplan.SimulationOptions``): the policy (``optimal``, ``reactive`` or ``home``,
        the baselines of Section V-C; with simultaneous requests, Section VI-2,
        ``optimal``, ``fcfs``, ``nearest`` or ``reactive``), the start and start mode
        (default: the start recorded in the strategy, the robot's ``start``, in NR), the
        region test and home (default: the strategy's), the executor's correction and the
        bound ``max_wait`` on any request's waiting time (default :func:`wait_bound`).
    cell
        The :class:`~cellplan.workcell.Workcell`: with it every FMP is confirmed by the
        exact region test, and the trajectory's columns take the robot's axis names.
    progress
        ``progress(done, stages, text)`` during the run (see :func:`simulate`).
    robot_spec
        The scenario's robot section: its ``speed`` times the trajectory's seconds
        (default: the URDF's or the default speeds, :mod:`cellplan.timing`).

    Returns
    -------
    Result
        ``trajectory``: the run (see :func:`to_trajectory`); ``solution``: the
        :class:`Simulation`; ``stats``: the finite entries of
        :meth:`Simulation.metrics` plus ``wait_bound``. ``status`` is ``SOLVED`` unless a
        request (delivered or still open at the end) waited longer than ``max_wait``,
        which is ``FAILED`` (docs/strategies.md, "Simulation status"). A run in which no
        request arrives is solved: nothing was left waiting.

    Raises
    ------
    ArgumentError
        ``stages`` or ``seed`` out of range, an option that does not fit the strategy
        (:meth:`SimulationOptions.problems`), a start that is not a configuration of the
        strategy's C-space or lies outside its domain.
    """
    opts = options if options is not None else SimulationOptions()
    problems = run_problems(strategy, stages, seed, opts)
    if problems:
        raise ArgumentError(problems)
    resolved = _resolved(strategy, opts, cell)
    sim = simulate(strategy, int(stages), int(seed), resolved, cell=cell, progress=progress)
    collision = first_collision(strategy, sim, cell) if cell is not None else None
    if collision is not None and collision[0] > 0:
        # The same run (same seed, same draws) stopped at the sample that collides.
        sim = simulate(strategy, collision[0], int(seed), resolved, cell=cell)
    elif collision is not None:
        raise ArgumentError([Problem("start", f"collides with the workcell ({collision[1]})")])
    bound = float(opts.max_wait) if opts.max_wait is not None else wait_bound(strategy)
    status, message = _verdict(strategy, sim, sim.metrics(), bound)
    if collision is not None:
        status = Status.FAILED
        message = (
            f"stage {collision[0]}: {collision[1]}; the run stops there (the strategy does "
            "not match this workcell: solve the scenario again)"
        )
    meta: dict[str, str | int | float | bool] = {
        "scenario": str(strategy.meta.get("scenario_name", "")),
        "policy": opts.policy,
        "seed": int(seed),
        "stages": int(stages),
        "gain": strategy.gain,
    }
    return Result(
        status,
        message,
        planner="strategies.simulate",
        stats=_stats(sim, bound),
        solution=sim,
        trajectory=to_trajectory(strategy, sim, cell, meta, robot_spec),
        options={
            "stages": int(stages),
            "seed": int(seed),
            "policy": opts.policy,
            "max_wait": bound,
        },
    )


def _resolved(strategy: Strategy, opts: SimulationOptions, cell: Any) -> SimulationOptions:
    """``opts`` with the start, home and region test the run uses (the strategy's where
    not given); ``ArgumentError`` for a start that is no configuration of the strategy or
    lies outside its domain, or a home that is none."""
    names = axis_names(strategy, cell)
    q0 = _configuration(opts.start, strategy.meta.get("start"), names, "start")
    if q0 is None:
        q0 = default_start(strategy)
    if not strategy.in_domain(q0, opts.start_mode):
        raise ArgumentError(
            [Problem("start", "lies outside the strategy's domain (no live state there)")]
        )
    home = _configuration(opts.home, strategy.meta.get("home"), names, "home")
    return replace(opts, start=q0, home=home, regions=opts.region_test(strategy))


def _stats(sim: Simulation, bound: float) -> dict[str, int | float | bool]:
    """The finite metrics of a run plus its ``wait_bound``; counts are stored as ints
    (their JSON keeps them integers), measures as floats."""
    stats: dict[str, int | float | bool] = {
        k: int(v) if k in COUNT_METRICS else v for k, v in sim.metrics().items() if np.isfinite(v)
    }
    stats["wait_bound"] = bound
    return stats

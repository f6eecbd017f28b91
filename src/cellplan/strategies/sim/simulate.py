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

import functools
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from cellplan.core import Progress, Result, Status
from cellplan.errors import ArgumentError, Problem
from cellplan.strategies.model.mdp import NR
from cellplan.strategies.policy.baselines import home_values, per_request_values
from cellplan.strategies.policy.decisions import FMP, STAY, best_action
from cellplan.strategies.policy.execution import Executor
from cellplan.strategies.policy.regions import region_test
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.section import MAX_STAGES
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
from cellplan.strategies.variants.pending_sim import PENDING_POLICIES, simulate_pending

Policy = Literal["optimal", "reactive", "home"]
POLICIES: tuple[str, ...] = ("optimal", "reactive", "home")


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
    *,
    policy: str = "optimal",
    start: np.ndarray | None = None,
    start_mode: int = 0,
    cell: Any = None,
    regions: str = "contact",
    home: np.ndarray | None = None,
    learn: bool = True,
    progress: Progress | None = None,
) -> Simulation:
    """Run the assembly process for ``stages`` stages from ``(start, start_mode)``.

    Parameters
    ----------
    strategy
        The solved strategy (its model supplies the transition probabilities).
    stages, seed
        Length of the run and the seed of its random generator.
    policy
        ``optimal``, ``reactive`` or ``home``.
    start
        Start configuration (default: the grid centre of the first live NR cell nearest
        to the middle).
    cell, regions
        With a workcell, every FMP is confirmed by the exact region test
        (:meth:`~cellplan.workcell.Workcell.in_region`); a refused FMP falls back to the
        best motion.
    home
        Home configuration of the ``home`` policy.
    learn
        Correct inconsistent values while executing (the LRTA* step of
        :class:`~cellplan.strategies.policy.execution.Executor`); False keeps its lookahead but
        drops the correction, and with it the guarantee that no request waits for ever.
    progress
        Called as ``progress(done, stages, text)`` about 200 times in the run (the CLI
        draws a bar with it).

    A model of simultaneous requests (Section VI-2) runs in
    :func:`cellplan.strategies.variants.pending_sim.simulate_pending` instead (its policies are
    ``optimal``, ``fcfs``, ``nearest`` and ``reactive``).
    """
    if strategy.mdp.opt_ptr is not None:
        return simulate_pending(
            strategy,
            stages,
            seed,
            policy=policy,
            start=start,
            cell=cell,
            regions=regions,
            progress=progress,
        )
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, not {policy!r}")
    rng = np.random.default_rng(seed)
    mdp = strategy.mdp
    M = mdp.modes_per_phase
    idle = [mode.kind == NR for mode in mdp.modes]
    out = mdp.fmp_outcomes()
    test = region_test(strategy, cell, regions) if cell is not None else None
    rules = _Policies(strategy, home, learn, test)
    q = np.asarray(start if start is not None else default_start(strategy), float).copy()
    m = int(start_mode)
    dim = len(q)
    qs = np.empty((stages + 1, dim))
    ms = np.empty(stages + 1, np.int64)
    acts = np.empty(stages, np.int64)
    losses = np.empty(stages)
    qs[0], ms[0] = q, m
    requests: list[Request] = []
    events: list[tuple[int, str, str]] = []
    current: Request | None = None
    refused = 0
    if not idle[m]:
        mode = mdp.modes[m]
        current = Request(mode.part, mode.source, mode.destination, 0)
        requests.append(current)
        events.append((0, "request", _request_detail(current)))
    every = max(1, stages // 200)
    for k in range(stages):
        if progress is not None and k % every == 0:
            progress(
                float(k), float(stages), f"stage {k:,} of {stages:,}, {len(requests)} requests"
            )
        fmp_allowed = None
        if (
            cell is not None
            and not idle[m]
            and np.isfinite(mdp.tf[m, strategy.cell_of(q)])
            and test is not None
            and not test(q[None, :], m)[0]
        ):
            # The grid cell allows FMP but the exact region test at q does not: (9) is
            # evaluated without FMP (stay is not offered while a motion is possible, so the
            # robot does not wait beside the region for ever).
            fmp_allowed = False
            refused += 1
            events.append((k, "fmp_refused", mdp.modes[m].label))
        u = rules.action(policy, q, m, fmp_allowed)
        # Loss (7).
        if idle[m]:
            loss = 0.0
        elif u == FMP:
            loss = float(mdp.tf[m, strategy.cell_of(q)])
        else:
            loss = mdp.stage_time
        if current is not None:
            current.waiting += loss
        # Transition.
        if u == FMP:
            o0, o1 = out.ptr[m], out.ptr[m + 1]
            oprob = out.prob[o0:o1]
            o = o0 + min(
                int(np.searchsorted(np.cumsum(oprob), rng.random() * oprob.sum(), side="right")),
                o1 - o0 - 1,
            )
            m_next = int(out.layer[o])
            # A rework time (retry in place, Section VI-3) is lost while the request waits.
            loss += float(out.cost[o])
            assert current is not None
            kind = mdp.modes[m].kind
            where = current.source if kind == "W" else current.destination
            if o > o0 and kind in ("W", "C"):
                current.failures += 1
                then = "retry" if m_next == m else f"reject to {mdp.modes[m_next].reject}"
                events.append((k + 1, "fmp_failed", f"{current.part} at {where}, {then}"))
            elif kind == "W":
                current.pickup = k + 1
                events.append((k + 1, "pick", f"{current.part} at {current.source}"))
            elif kind == "X":
                events.append((k + 1, "reject", f"{current.part} at {mdp.modes[m].reject}"))
                mode = mdp.modes[m_next]
                if mode.source != current.source:
                    events.append((k + 1, "source_change", f"{current.source} to {mode.source}"))
                    current.source = mode.source
                current.pickup = -1
            else:
                current.delivery = k + 1
                events.append((k + 1, "place", f"{current.part} at {current.destination}"))
                current = None
        else:
            if u != STAY:
                landing = None
                if len(mdp.noise_prob) > 1:  # Section VI-4: draw where the move lands
                    cum = np.cumsum(mdp.noise_prob)
                    landing = min(
                        int(np.searchsorted(cum, rng.random() * cum[-1], "right")), len(cum) - 1
                    )
                q = strategy.next_configuration(q, m, u, landing)
            b0, b1 = mdp.branch_ptr[m], mdp.branch_ptr[m + 1]
            probs = mdp.branch_prob[b0:b1]
            pick = int(np.searchsorted(np.cumsum(probs), rng.random() * probs.sum(), side="right"))
            m_next = int(mdp.branch_layer[b0 + min(pick, b1 - b0 - 1)])
            if m_next % M != m % M:  # the phase of a time-varying model aside
                mode = mdp.modes[m_next]
                if idle[m]:
                    current = Request(mode.part, mode.source, mode.destination, k + 1)
                    requests.append(current)
                    events.append((k + 1, "request", _request_detail(current)))
                elif current is not None:
                    if mode.destination != current.destination:
                        events.append(
                            (
                                k + 1,
                                "destination_change",
                                f"{current.destination} to {mode.destination}",
                            )
                        )
                    if mode.source != current.source:
                        events.append(
                            (k + 1, "source_change", f"{current.source} to {mode.source}")
                        )
                    current.source, current.destination = mode.source, mode.destination
                    current.changes += 1
        m = m_next
        acts[k], losses[k] = u, loss
        qs[k + 1], ms[k + 1] = q, m
    fixes, raised = rules.corrections
    return Simulation(
        qs,
        ms,
        acts,
        losses,
        requests,
        policy,
        refused,
        fixes,
        raised,
        events,
        modes_per_phase=M,  # one phase of all layers in a stationary model
    )


def _request_detail(r: Request) -> str:
    return f"{r.part} from {r.source} to {r.destination}"


def compare_policies(
    strategy: Strategy, stages: int, seeds: list[int], **kw: Any
) -> dict[str, list[dict[str, float]]]:
    """Metrics of the three policies over the same seeds (paired comparison)."""
    return {
        p: [simulate(strategy, stages, s, policy=p, **kw).metrics() for s in seeds]
        for p in POLICIES
    }


# --- the simulation as a Result ---------------------------------------------------------------


def simulate_result(
    strategy: Strategy,
    stages: int,
    seed: int,
    *,
    policy: str = "optimal",
    cell: Any = None,
    start: ArrayLike | None = None,
    start_mode: int = 0,
    regions: str | None = None,
    home: ArrayLike | None = None,
    learn: bool = True,
    max_wait: float | None = None,
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
    policy
        ``optimal`` (the strategy), ``reactive`` or ``home`` (the baselines of Section V-C);
        with simultaneous requests (Section VI-2) ``optimal``, ``fcfs``, ``nearest`` or
        ``reactive`` (:mod:`cellplan.strategies.variants.pending_sim`).
    cell
        The :class:`~cellplan.workcell.Workcell`: with it every FMP is confirmed by the
        exact region test, and the trajectory's columns take the robot's axis names.
    start, start_mode
        Where the run starts (radians for angles); ``start`` defaults to the start
        configuration recorded in the strategy (the robot's ``start``), ``start_mode`` to NR.
    regions
        ``contact`` or ``enclosure`` for the exact region test (default: the strategy's).
    home
        Home configuration of the ``home`` policy (default: the strategy's).
    learn
        Keep the executor's LRTA* correction (see :func:`simulate`).
    max_wait
        Bound on any request's waiting time (time units); default :func:`wait_bound`.
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
        ``stages`` or ``seed`` out of range, an unknown ``policy``, a start that is not a
        configuration of the strategy's C-space or lies outside its domain.
    """
    problems = []
    if not isinstance(stages, int | np.integer) or not 1 <= int(stages) <= MAX_STAGES:
        problems.append(
            Problem("stages", f"must be an integer in [1, {MAX_STAGES}], got {stages!r}")
        )
    if not isinstance(seed, int | np.integer) or int(seed) < 0:
        problems.append(Problem("seed", f"must be a non-negative integer, got {seed!r}"))
    allowed = POLICIES
    if strategy.mdp.opt_ptr is not None:  # simultaneous requests (Section VI-2)
        allowed = PENDING_POLICIES
    if policy not in allowed:
        problems.append(Problem("policy", f"must be one of {', '.join(allowed)}, got {policy!r}"))
    if max_wait is not None and not (np.isfinite(max_wait) and max_wait > 0):
        problems.append(Problem("max_wait", f"must be a positive number, got {max_wait!r}"))
    mdp = strategy.mdp
    if not 0 <= start_mode < mdp.n_modes:
        problems.append(Problem("start_mode", f"must be in [0, {mdp.n_modes - 1}]"))
    if problems:
        raise ArgumentError(problems)
    names = axis_names(strategy, cell)
    q0 = _configuration(start, strategy.meta.get("start"), names, "start")
    if q0 is None:
        q0 = default_start(strategy)
    if not strategy.in_domain(q0, start_mode):
        raise ArgumentError(
            [Problem("start", "lies outside the strategy's domain (no live state there)")]
        )
    home_q = _configuration(home, strategy.meta.get("home"), names, "home")
    run = functools.partial(
        simulate,
        strategy,
        seed=int(seed),
        policy=policy,
        start=q0,
        start_mode=start_mode,
        cell=cell,
        regions=regions or str(strategy.meta.get("regions", "contact")),
        home=home_q,
        learn=learn,
    )
    sim = run(int(stages), progress=progress)
    collision = first_collision(strategy, sim, cell) if cell is not None else None
    if collision is not None and collision[0] > 0:
        # The same run (same seed, same draws) stopped at the sample that collides.
        sim = run(collision[0])
    elif collision is not None:
        raise ArgumentError([Problem("start", f"collides with the workcell ({collision[1]})")])
    bound = float(max_wait) if max_wait is not None else wait_bound(strategy)
    metrics = sim.metrics()
    # Counts are stored as ints (their JSON keeps them integers); measures as floats.
    stats: dict[str, int | float | bool] = {
        k: int(v) if k in COUNT_METRICS else v for k, v in metrics.items() if np.isfinite(v)
    }
    stats["wait_bound"] = bound
    status, message = _verdict(strategy, sim, metrics, bound)
    if collision is not None:
        status = Status.FAILED
        message = (
            f"stage {collision[0]}: {collision[1]}; the run stops there (the strategy does "
            "not match this workcell: solve the scenario again)"
        )
    meta: dict[str, str | int | float | bool] = {
        "scenario": str(strategy.meta.get("scenario_name", "")),
        "policy": policy,
        "seed": int(seed),
        "stages": int(stages),
        "gain": strategy.gain,
    }
    return Result(
        status,
        message,
        planner="strategies.simulate",
        stats=stats,
        solution=sim,
        trajectory=to_trajectory(strategy, sim, cell, meta, robot_spec),
        options={"stages": int(stages), "seed": int(seed), "policy": policy, "max_wait": bound},
    )

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
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from cellplan import timing, units
from cellplan.core import Progress, Result, Status
from cellplan.strategies.model.mdp import NR, LayeredMDP, Mode
from cellplan.strategies.planners import MAX_STAGES
from cellplan.strategies.policy.baselines import home_values, per_request_values
from cellplan.strategies.policy.execution import Executor
from cellplan.strategies.policy.strategy import FMP, STAY, Strategy, best_action
from cellplan.strategies.variants.periodic import region_offset
from cellplan.trajectory import Event, Trajectory

Policy = Literal["optimal", "reactive", "home"]
POLICIES: tuple[str, ...] = ("optimal", "reactive", "home")


@dataclass
class Request:
    """One request's life: arrival, pick-up and delivery stages, and its waiting time."""

    part: str
    source: str
    destination: str
    arrival: int
    pickup: int = -1
    delivery: int = -1
    waiting: float = 0.0
    changes: int = 0
    failures: int = 0  # failed FMPs (Section VI-3)


@dataclass
class Simulation:
    """A simulated run: the trajectory and the per-request statistics."""

    q: np.ndarray  # (K+1, dim)
    modes: np.ndarray  # (K+1,)
    actions: np.ndarray  # (K,)
    losses: np.ndarray  # (K,)
    requests: list[Request] = field(default_factory=list)
    policy: str = "optimal"
    fmp_refused: int = 0
    corrections: int = 0
    raised: float = 0.0
    events: list[tuple[int, str, str]] = field(default_factory=list)
    """``(sample, kind, detail)``: ``request`` (at the first W sample), ``pick`` (first C
    sample), ``place`` (first NR sample after delivery), ``fmp_refused`` (the stage whose
    FMP the exact region test refused), ``source_change`` / ``destination_change``, and with
    failure modes (Section VI-3) ``fmp_failed`` (a failed pick or delivery: retried, or the
    part rejected) and ``reject`` (the rejected part dropped in the reject region)."""
    # The modes of one phase of a time-varying model (Section VI-1), whose ``modes`` are
    # layers ``phase * modes_per_phase + mode``; 0: a stationary model.
    modes_per_phase: int = 0

    def metrics(self) -> dict[str, float]:
        """Loss per stage, waiting time per request (delivered only and all), counts.

        ``loss_per_stage`` is the paper's objective: the long-run expected waiting per
        stage, which the gain ``g`` predicts. ``mean_wait`` is the mean waiting time of the
        delivered requests only; ``mean_wait_all`` counts every request that arrived, those
        still open at the end at their age so far (their waiting up to the last stage), so
        it equals the total loss divided by the number of requests and cannot hide a
        request that is never served. ``open_requests`` is how many were still open (at
        most one: a request arrives only in NR) and ``open_wait`` their waiting so far.
        """
        done = [r.waiting for r in self.requests if r.delivery >= 0]
        waits = [r.waiting for r in self.requests]
        still = [r.waiting for r in self.requests if r.delivery < 0]
        stages = len(self.actions)
        nan = float("nan")
        return {
            "stages": float(stages),
            "requests": float(len(self.requests)),
            "served": float(len(done)),
            "mean_wait": float(np.mean(done)) if done else nan,
            "mean_wait_all": float(np.mean(waits)) if waits else nan,
            "open_requests": float(len(still)),
            "open_wait": float(np.sum(still)),
            "idle_fraction": float(np.mean(self.base_modes()[:-1] == 0)) if stages else nan,
            "loss_per_stage": float(self.losses.mean()) if stages else nan,
            "fmp_refused": float(self.fmp_refused),
            "corrections": float(self.corrections),
            "raised": float(self.raised),
            "fmp_failures": float(sum(r.failures for r in self.requests)),
        }

    def base_modes(self) -> np.ndarray:
        """The assembly mode of every sample, without the phase of a time-varying model."""
        return self.modes % self.modes_per_phase if self.modes_per_phase else self.modes

    def segments(self) -> list[tuple[int, int]]:
        """``(first, last)`` stage of every maximal run of one mode (one frame each, Fig. 9)."""
        out = []
        start = 0
        modes = self.base_modes()
        for k in range(1, len(modes)):
            if modes[k] != modes[k - 1]:
                out.append((start, k))
                start = k
        out.append((start, len(self.modes) - 1))
        return out


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
        from cellplan.strategies.variants.pending_sim import simulate_pending

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
        modes_per_phase=M if mdp.period > 1 else 0,
    )


def _request_detail(r: Request) -> str:
    return f"{r.part} from {r.source} to {r.destination}"


def default_start(strategy: Strategy) -> np.ndarray:
    """A live NR cell centre near the middle of the C-space box."""
    mdp = strategy.mdp
    live = np.flatnonzero(mdp.live[0])
    idx = np.array(np.unravel_index(live, tuple(mdp.shape))).T
    centres = mdp.lower + (idx + 0.5) * mdp.spacing
    mid = mdp.lower + 0.5 * (mdp.upper - mdp.lower)
    return np.asarray(centres[np.argmin(np.linalg.norm(centres - mid, axis=1))])


def region_test(strategy: Strategy, cell: Any, regions: str) -> RegionTest:
    """The exact FMP region test of a workcell: ``(configurations, mode) -> bool array``.

    W modes test the source (empty robot), C modes the destination with the carried part,
    X modes (a rejected part, Section VI-3) the reject region with the part
    (:meth:`~cellplan.workcell.Workcell.in_region`). In a time-varying model (Section VI-1)
    a region on a belt is tested where it is at the layer's phase.
    """
    return RegionTest(strategy.mdp, cell, regions)


@dataclass(frozen=True, eq=False)
class RegionTest:
    """:func:`region_test`'s callable; a module-level class, not a closure, so that a
    strategy holding it (and the planner's :class:`~cellplan.core.Result`) pickles."""

    mdp: LayeredMDP
    cell: Any
    regions: str

    def __call__(self, points: np.ndarray, m: int) -> np.ndarray:
        return self.option(points, m, 0)

    def option(self, points: np.ndarray, m: int, j: int) -> np.ndarray:
        """The test of FMP option ``j`` of mode ``m``: the only option of a W, C or X mode;
        with simultaneous requests (Section VI-2, a Q mode) the delivery of the carried
        request (its destination, with its part), or while empty the pick of the ``j``-th
        waiting request type in the order of the model's options (its source)."""
        mode = self.mdp.modes[m]
        if mode.kind == "W":
            region, part = mode.source, None
        elif mode.kind == "X":
            region, part = mode.reject, mode.part
        elif mode.kind == "Q" and not mode.part:
            # The options of an empty Q mode are its distinct waiting request types, in
            # the order of mode.waiting (pending.assemble_pending).
            waiting = list(dict.fromkeys(mode.waiting))
            region, part = waiting[j].split(",")[1], None
        else:
            region, part = mode.destination, mode.part
        offset = region_offset(self.mdp, region, m)
        return np.asarray(
            self.cell.in_region(points, region, self.regions, None, part, offset), dtype=bool
        )


def compare_policies(
    strategy: Strategy, stages: int, seeds: list[int], **kw: Any
) -> dict[str, list[dict[str, float]]]:
    """Metrics of the three policies over the same seeds (paired comparison)."""
    return {
        p: [simulate(strategy, stages, s, policy=p, **kw).metrics() for s in seeds]
        for p in POLICIES
    }


# --- the simulation as a Result ---------------------------------------------------------------

#: A request that waits longer than this many crossings of the C-space box (at the slowest
#: speed, plus a pick and a place) counts as starved; see :func:`wait_bound`.
WAIT_CROSSINGS = 10.0


def wait_bound(strategy: Strategy) -> float:
    """The default bound on a request's waiting time (time units) in :func:`simulate_result`.

    ``WAIT_CROSSINGS`` times the time the robot needs to cross the C-space box once along
    every axis at its slowest speed (its step per stage in each mode's action set), plus
    the largest fine-motion time twice (a pick and a place). A served request under the
    optimal strategy waits for a path between two regions and two FMPs (Section III-C), so
    a wait beyond this bound means that the strategy (or its execution) is not serving it.
    """
    mdp = strategy.mdp
    dim = len(mdp.shape)
    step = np.abs(np.asarray(mdp.disp, float))  # (classes, actions, dim)
    if mdp.heading_axis >= 0:
        # Robot-frame translation: a step along the heading moves either workcell axis.
        planar = np.linalg.norm(step[:, :, :2], axis=2)
        step[:, :, 0] = planar
        step[:, :, 1] = planar
    per_axis = step.max(axis=1).min(axis=0)  # the slowest class's largest step per axis
    extent = np.asarray(mdp.upper, float) - np.asarray(mdp.lower, float)
    stages = float(sum(extent[j] / per_axis[j] for j in range(dim) if per_axis[j] > 0))
    tf = np.asarray(mdp.tf, float)
    finite = tf[np.isfinite(tf)]
    tf_max = float(finite.max()) if finite.size else 0.0
    return WAIT_CROSSINGS * stages * float(mdp.stage_time) + 2.0 * tf_max


def axis_names(strategy: Strategy, cell: Any = None) -> tuple[str, ...]:
    """Names of the configuration axes: the workcell's, else those the strategy records.

    A strategy file written before the planner recorded them falls back on the layout of
    its grid: ``x, y, theta`` for a robot-frame action set, else ``x, y`` for a 2-D box
    beyond two full turns, else ``q1 ... qn``.
    """
    if cell is not None:
        return tuple(cell.robot.axis_names)
    axes = strategy.meta.get("axes")
    dim = len(strategy.mdp.shape)
    if isinstance(axes, list) and len(axes) == dim:
        return tuple(str(a) for a in axes)
    mdp = strategy.mdp
    if mdp.heading_axis >= 0 and dim == 3:
        return ("x", "y", "theta")
    extent = np.asarray(mdp.upper, float) - np.asarray(mdp.lower, float)
    if dim == 2 and np.any(extent > 2.0 * units.ANGLE_LIMIT):
        return ("x", "y")
    return tuple(f"q{j + 1}" for j in range(dim))


def to_trajectory(
    strategy: Strategy,
    sim: Simulation,
    cell: Any = None,
    meta: Mapping[str, str | int | float | bool] | None = None,
    robot_spec: Any = None,
) -> Trajectory:
    """A simulated run as a :class:`~cellplan.trajectory.Trajectory`.

    ``t`` is the stage, ``q`` the configuration (radians for angles; periodic axes
    unwrapped), ``mode`` the assembly mode of each stage (``NR``, ``<P1,S1,D1,W>`` ...),
    and the events are the simulation's (:attr:`Simulation.events`), typed. ``seconds``
    is ``stage x stage_duration``: the time of the longest step of any action at the
    robot's speeds (``robot_spec``: the scenario's robot section; else the URDF's or the
    default speeds), :func:`cellplan.timing.stage_duration`.
    """
    names = axis_names(strategy, cell)
    axis_units = units.axis_units(names)
    robot = cell.robot if cell is not None else None
    _, vlim, alim = timing.robot_motion(robot_spec, robot, names, axis_units)
    mdp = strategy.mdp
    dim = len(mdp.shape)
    step = np.abs(np.asarray(mdp.disp, float)).reshape(-1, dim)
    if mdp.heading_axis >= 0:
        # Robot-frame translation: a step along the heading may move either workcell axis.
        planar = np.linalg.norm(step[:, :2], axis=1)
        step[:, 0] = planar
        step[:, 1] = planar
    return Trajectory(
        t=np.arange(len(sim.modes), dtype=float),
        q=sim.q,
        mode=sim.modes,
        modes=tuple(m.label for m in mdp.modes),
        columns=names,
        units=axis_units,
        time_unit="stage",
        events=tuple(Event.from_text(k, kind, detail) for k, kind, detail in sim.events),
        meta=dict(meta or {}),
        periodic=tuple(bool(p) for p in np.asarray(mdp.periodic).reshape(-1)),
        stage_duration=timing.stage_duration(step, vlim),
        velocity_limits=vlim,
        acceleration_limits=alim,
    )


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
    from cellplan.errors import ArgumentError, Problem

    problems = []
    if not isinstance(stages, int | np.integer) or not 1 <= int(stages) <= MAX_STAGES:
        problems.append(
            Problem("stages", f"must be an integer in [1, {MAX_STAGES}], got {stages!r}")
        )
    if not isinstance(seed, int | np.integer) or int(seed) < 0:
        problems.append(Problem("seed", f"must be a non-negative integer, got {seed!r}"))
    allowed = POLICIES
    if strategy.mdp.opt_ptr is not None:  # simultaneous requests (Section VI-2)
        from cellplan.strategies.variants.pending_sim import PENDING_POLICIES as allowed
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
    if not mdp.live[start_mode, strategy.cell_of(q0)]:
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


#: The metrics of a run that are counts (:meth:`Simulation.metrics` gives floats, for
#: averaging over seeds; a result's ``stats`` keeps these as ints).
COUNT_METRICS = frozenset(
    (
        "stages",
        "requests",
        "served",
        "open_requests",
        "fmp_refused",
        "corrections",
        "fmp_failures",
        "turned_away",
        "arrivals",
    )
)
#: Samples of a checked motion per grid cell it crosses (:func:`first_collision`).
SAMPLES_PER_CELL = 4
#: Segments checked in one batch (bounds the samples held at once).
COLLISION_BATCH = 4096


def carried_part(mode: Mode) -> str | None:
    """The part the robot holds in ``mode``: C and X modes (Section VI-3) and a Q mode
    that carries a request (Section VI-2) hold one."""
    if mode.kind in ("C", "X") or (mode.kind == "Q" and mode.part):
        return mode.part
    return None


def first_collision(strategy: Strategy, sim: Simulation, cell: Any) -> tuple[int, str] | None:
    """The first sample of a run whose motion there collides with the workcell, exactly.

    The check the grid cannot give for a strategy it did not build: each stage's straight
    motion ``q[k] -> q[k + 1]`` (and the start) is tested against the workcell's
    obstacles and bounds (the sources are not obstacles here: the robot picks inside
    them) with the part of the stage's mode, sampled :data:`SAMPLES_PER_CELL` times per
    grid cell of workspace travel (:meth:`~cellplan.workcell.Workcell.motion_collides`).
    A strategy solved for this workcell never collides (its free cells are collision-free
    in their whole box, cspace.py); one that does was solved for another.

    Returns ``(k, description)`` for the first colliding sample ``k`` (0: the start), or
    None.
    """
    mdp = strategy.mdp
    modes = mdp.modes
    names = tuple(cell.robot.axis_names)
    cell_travel = cell.robot.workspace_step(np.diag(np.asarray(mdp.spacing, float)))
    step = float(cell_travel[cell_travel > 0].min()) / SAMPLES_PER_CELL
    q, ms = sim.q, sim.modes

    def describe(k: int, m: int) -> str:
        part = carried_part(modes[m])
        holding = f" carrying {part}" if part else ""
        shown = ", ".join(f"{n} {v:.4g}" for n, v in zip(names, q[k], strict=True))
        return f"the robot{holding} collides with the workcell at {shown} in mode {modes[m].label}"

    m0 = int(ms[0])
    if cell.collides(q[:1], carried_part(modes[m0]), "none")[0]:
        return 0, describe(0, m0)
    moved = np.flatnonzero(np.any(q[1:] != q[:-1], axis=1))
    parts = np.array([carried_part(modes[int(m)]) or "" for m in ms[:-1]], dtype=object)
    first: int | None = None
    for part in sorted(set(parts[moved].tolist())):
        ks = moved[parts[moved] == part]
        for lo in range(0, len(ks), COLLISION_BATCH):
            batch = ks[lo : lo + COLLISION_BATCH]
            if first is not None and batch[0] >= first:
                break
            hit = cell.motion_collides(
                q[batch], q[batch + 1], step, part or None, "none", certified=False
            )
            if hit.any():
                k = int(batch[np.argmax(hit)])
                first = k if first is None else min(first, k)
                break
    if first is None:
        return None
    return first + 1, describe(first + 1, int(ms[first]))


def _configuration(
    given: ArrayLike | None, recorded: Any, names: tuple[str, ...], field: str
) -> np.ndarray | None:
    if given is not None:
        return units.check_configurations(given, names, field)[0]
    if recorded is not None:
        return np.asarray(recorded, dtype=float)
    return None


def _verdict(
    strategy: Strategy, sim: Simulation, metrics: Mapping[str, float], bound: float
) -> tuple[Status, str]:
    stages = len(sim.actions)
    if not sim.requests:
        return Status.SOLVED, f"no request arrived in {stages} stages"
    late = [(i, r) for i, r in enumerate(sim.requests) if r.waiting > bound]
    if late:
        i, r = late[0]
        state = "still open" if r.delivery < 0 else f"delivered at stage {r.delivery}"
        return (
            Status.FAILED,
            f"request {i + 1} (<{r.part},{r.source},{r.destination}>, arrived at stage "
            f"{r.arrival}) waited {r.waiting:g} > {bound:g} ({state}); "
            f"{len(late)} request(s) over the bound",
        )
    served = int(metrics["served"])
    open_part = (
        f" ({int(metrics['open_requests'])} open after {metrics['open_wait']:g})"
        if metrics["open_requests"]
        else ""
    )
    wait = f"mean wait {metrics['mean_wait']:.2f}, " if served else ""
    return (
        Status.SOLVED,
        f"served {served} of {len(sim.requests)} requests{open_part}, {wait}"
        f"loss {metrics['loss_per_stage']:.3f} per stage (gain {strategy.gain:.3f})",
    )

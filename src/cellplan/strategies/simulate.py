"""Execute a strategy in the stochastic assembly process (Sections III-B and V).

Each stage the policy picks an action at the robot's real-valued configuration (not the
grid), the configuration moves by equation (5) (or its variant), and the next mode is
drawn from ``P(m_{k+1} | x_k, u_k)``: request arrivals in NR (type 1), destination changes
while carrying (type 2), source changes while waiting (type 3); FMP switches W -> C and
C -> NR with probability one. The loss of each stage is equation (7), so a request's
waiting time is the loss summed from its arrival to its delivery.

Three policies run in the same simulator: ``optimal`` (the strategy), ``reactive`` and
``home`` (see :mod:`cellplan.strategies.baselines`). While a request waits, each picks
its action through an :class:`~cellplan.strategies.execution.Executor` (equation (9)
with a lookahead and the LRTA* correction, so that no request waits for ever); every
stage is one of the robot's own motions, a stay, or FMP.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from cellplan.strategies.baselines import home_values, per_request_values
from cellplan.strategies.execution import Executor
from cellplan.strategies.strategy import FMP, STAY, Strategy, best_action

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
            "idle_fraction": float(np.mean(self.modes[:-1] == 0)) if stages else nan,
            "loss_per_stage": float(self.losses.mean()) if stages else nan,
            "fmp_refused": float(self.fmp_refused),
            "corrections": float(self.corrections),
            "raised": float(self.raised),
        }

    def segments(self) -> list[tuple[int, int]]:
        """``(first, last)`` stage of every maximal run of one mode (one frame each, Fig. 9)."""
        out = []
        start = 0
        for k in range(1, len(self.modes)):
            if self.modes[k] != self.modes[k - 1]:
                out.append((start, k))
                start = k
        out.append((start, len(self.modes) - 1))
        return out


class _Policies:
    """The action rules of the three policies on one strategy, for one run.

    Every rule that finishes a request executes (9) through an
    :class:`~cellplan.strategies.execution.Executor` (its corrections last for the run).
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
        return None if mode == 0 else self.request

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
        :class:`~cellplan.strategies.execution.Executor`); False keeps its lookahead but
        drops the correction, and with it the guarantee that no request waits for ever.
    """
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, not {policy!r}")
    rng = np.random.default_rng(seed)
    mdp = strategy.mdp
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
    current: Request | None = None
    refused = 0
    if m != 0:
        mode = mdp.modes[m]
        current = Request(mode.part, mode.source, mode.destination, 0)
        requests.append(current)
    for k in range(stages):
        fmp_allowed = None
        if (
            cell is not None
            and m != 0
            and np.isfinite(mdp.tf[m, strategy.cell_of(q)])
            and test is not None
            and not test(q[None, :], m)[0]
        ):
            # The grid cell allows FMP but the exact region test at q does not: (9) is
            # evaluated without FMP (stay is not offered while a motion is possible, so the
            # robot does not wait beside the region for ever).
            fmp_allowed = False
            refused += 1
        u = rules.action(policy, q, m, fmp_allowed)
        # Loss (7).
        if m == 0:
            loss = 0.0
        elif u == FMP:
            loss = float(mdp.tf[m, strategy.cell_of(q)])
        else:
            loss = mdp.stage_time
        if current is not None:
            current.waiting += loss
        # Transition.
        if u == FMP:
            m_next = int(mdp.fmp_next[m])
            if mdp.modes[m].kind == "W":
                assert current is not None
                current.pickup = k + 1
            else:
                assert current is not None
                current.delivery = k + 1
                current = None
        else:
            if u != STAY:
                q = strategy.next_configuration(q, m, u)
            b0, b1 = mdp.branch_ptr[m], mdp.branch_ptr[m + 1]
            probs = mdp.branch_prob[b0:b1]
            pick = int(np.searchsorted(np.cumsum(probs), rng.random() * probs.sum(), side="right"))
            m_next = int(mdp.branch_layer[b0 + min(pick, b1 - b0 - 1)])
            if m_next != m:
                mode = mdp.modes[m_next]
                if m == 0:
                    current = Request(mode.part, mode.source, mode.destination, k + 1)
                    requests.append(current)
                elif current is not None:
                    current.source, current.destination = mode.source, mode.destination
                    current.changes += 1
        m = m_next
        acts[k], losses[k] = u, loss
        qs[k + 1], ms[k + 1] = q, m
    fixes, raised = rules.corrections
    return Simulation(qs, ms, acts, losses, requests, policy, refused, fixes, raised)


def default_start(strategy: Strategy) -> np.ndarray:
    """A live NR cell centre near the middle of the C-space box."""
    mdp = strategy.mdp
    live = np.flatnonzero(mdp.live[0])
    idx = np.array(np.unravel_index(live, tuple(mdp.shape))).T
    centres = mdp.lower + (idx + 0.5) * mdp.spacing
    mid = mdp.lower + 0.5 * (mdp.upper - mdp.lower)
    return np.asarray(centres[np.argmin(np.linalg.norm(centres - mid, axis=1))])


def region_test(
    strategy: Strategy, cell: Any, regions: str
) -> Callable[[np.ndarray, int], np.ndarray]:
    """The exact FMP region test of a workcell: ``(configurations, mode) -> bool array``.

    W modes test the source (empty robot), C modes the destination with the carried part
    (:meth:`~cellplan.workcell.Workcell.in_region`).
    """
    modes = strategy.mdp.modes

    def test(points: np.ndarray, m: int) -> np.ndarray:
        mode = modes[m]
        if mode.kind == "W":
            hit = cell.in_region(points, mode.source, regions, None, None)
        else:
            hit = cell.in_region(points, mode.destination, regions, None, mode.part)
        return np.asarray(hit, dtype=bool)

    return test


def compare_policies(
    strategy: Strategy, stages: int, seeds: list[int], **kw: Any
) -> dict[str, list[dict[str, float]]]:
    """Metrics of the three policies over the same seeds (paired comparison)."""
    return {
        p: [simulate(strategy, stages, s, policy=p, **kw).metrics() for s in seeds]
        for p in POLICIES
    }

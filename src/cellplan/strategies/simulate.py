"""Execute a strategy in the stochastic assembly process (Sections III-B and V).

Each stage the policy picks an action at the robot's real-valued configuration (not the
grid), the configuration moves by equation (5) (or its variant), and the next mode is
drawn from ``P(m_{k+1} | x_k, u_k)``: request arrivals in NR (type 1), destination changes
while carrying (type 2), source changes while waiting (type 3); FMP switches W -> C and
C -> NR with probability one. The loss of each stage is equation (7), so a request's
waiting time is the loss summed from its arrival to its delivery.

Three policies run in the same simulator: ``optimal`` (the strategy), ``reactive`` and
``home`` (see :mod:`cellplan.strategies.baselines`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from cellplan.strategies.baselines import home_values, per_request_values
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
    cycles_broken: int = 0

    def metrics(self) -> dict[str, float]:
        """Waiting time per delivered request, requests served, idle fraction, loss per stage."""
        done = [r.waiting for r in self.requests if r.delivery >= 0]
        stages = len(self.actions)
        return {
            "stages": float(stages),
            "requests": float(len(self.requests)),
            "served": float(len(done)),
            "mean_wait": float(np.mean(done)) if done else float("nan"),
            "idle_fraction": float(np.mean(self.modes[:-1] == 0)) if stages else float("nan"),
            "loss_per_stage": float(self.losses.mean()) if stages else float("nan"),
            "fmp_refused": float(self.fmp_refused),
            "cycles_broken": float(self.cycles_broken),
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
    """The action rules of the three policies on one strategy."""

    def __init__(self, strategy: Strategy, home: np.ndarray | None) -> None:
        self.s = strategy
        self._req: np.ndarray | None = None
        self._home: np.ndarray | None = None
        self.home_q = home

    @property
    def request_values(self) -> np.ndarray:
        if self._req is None:
            self._req = per_request_values(self.s.mdp)
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

    def values(self, policy: str, q: np.ndarray, mode: int, fmp_allowed: bool | None) -> np.ndarray:
        if policy == "optimal":
            return self.s.action_values(q, mode, fmp_allowed=fmp_allowed)
        if mode == 0:
            if policy == "reactive":
                out = np.full(2 + self.s.mdp.disp.shape[1], np.nan)
                out[1] = 0.0
                return out
            return self.s.action_values(q, 0, values=self.home_layers, fmp_allowed=False)
        return self.s.action_values(q, mode, values=self.request_values, fmp_allowed=fmp_allowed)


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
    """
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, not {policy!r}")
    rng = np.random.default_rng(seed)
    mdp = strategy.mdp
    rules = _Policies(strategy, home)
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
    cycles = 0
    if m != 0:
        mode = mdp.modes[m]
        current = Request(mode.part, mode.source, mode.destination, 0)
        requests.append(current)
    for k in range(stages):
        u = (
            strategy.action(q, m)
            if policy == "optimal"
            else best_action(rules.values(policy, q, m, None))
        )
        if u == FMP and cell is not None and not _fmp_confirmed(strategy, cell, regions, q, m):
            # The grid cell allows FMP but the exact region test at q does not: take the
            # best motion instead (not stay, which would wait beside the region for ever).
            vals = rules.values(policy, q, m, False)
            vals[1] = np.nan
            u = best_action(vals)
            refused += 1
        if u >= 0 and m != 0 and _revisits(strategy.next_configuration(q, m, u), qs, ms, k, m):
            # Interpolated values at off-grid states can make a few states each prefer the
            # next one round a loop. Break the loop on the grid: step to the centre of the
            # current cell (collision-free: a free cell is free throughout its box, which is
            # convex) and take the solver's action there.
            centre = strategy.cell_centre(q)
            u_grid = strategy.grid_action(q, m)
            if u_grid is not None and u_grid != STAY:
                q = centre
                u = u_grid
                cycles += 1
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
    return Simulation(qs, ms, acts, losses, requests, policy, refused, cycles)


def _revisits(q_next: np.ndarray, qs: np.ndarray, ms: np.ndarray, k: int, m: int) -> bool:
    """Whether ``q_next`` repeats one of the last eight states of the same mode."""
    j0 = max(0, k - 7)
    same = np.all(np.abs(qs[j0 : k + 1] - q_next) < 1e-9, axis=1) & (ms[j0 : k + 1] == m)
    return bool(same.any())


def default_start(strategy: Strategy) -> np.ndarray:
    """A live NR cell centre near the middle of the C-space box."""
    mdp = strategy.mdp
    live = np.flatnonzero(mdp.live[0])
    idx = np.array(np.unravel_index(live, tuple(mdp.shape))).T
    centres = mdp.lower + (idx + 0.5) * mdp.spacing
    mid = mdp.lower + 0.5 * (mdp.upper - mdp.lower)
    return np.asarray(centres[np.argmin(np.linalg.norm(centres - mid, axis=1))])


def _fmp_confirmed(strategy: Strategy, cell: Any, regions: str, q: np.ndarray, m: int) -> bool:
    mode = strategy.mdp.modes[m]
    if mode.kind == "W":
        return bool(cell.in_region(q[None, :], mode.source, regions, None, None)[0])
    return bool(cell.in_region(q[None, :], mode.destination, regions, None, mode.part)[0])


def compare_policies(
    strategy: Strategy, stages: int, seeds: list[int], **kw: Any
) -> dict[str, list[dict[str, float]]]:
    """Metrics of the three policies over the same seeds (paired comparison)."""
    return {
        p: [simulate(strategy, stages, s, policy=p, **kw).metrics() for s in seeds]
        for p in POLICIES
    }

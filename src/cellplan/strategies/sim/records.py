"""The record of a simulated run: its requests, its samples, and their statistics.

Shared by the Section V simulator (:mod:`cellplan.strategies.sim.simulate`) and that of
simultaneous requests (:mod:`cellplan.strategies.variants.pending_sim`), which import it
and not each other's modules.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellplan.strategies.model.mdp import Mode
from cellplan.strategies.policy.strategy import Strategy


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
    # layers ``phase * modes_per_phase + mode`` (all layers in a stationary model); 0: the
    # run's modes are its samples' modes.
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


def default_start(strategy: Strategy) -> np.ndarray:
    """A live NR cell centre near the middle of the C-space box."""
    mdp = strategy.mdp
    live = np.flatnonzero(mdp.live[0])
    idx = np.array(np.unravel_index(live, tuple(mdp.shape))).T
    centres = mdp.lower + (idx + 0.5) * mdp.spacing
    mid = mdp.lower + 0.5 * (mdp.upper - mdp.lower)
    return np.asarray(centres[np.argmin(np.linalg.norm(centres - mid, axis=1))])


def open_requests(mode: Mode) -> int:
    """Requests open in ``mode``: those waiting (Section VI-2, ``waiting``) and the one it
    serves (a mode names the part of the request it serves: W waits for its pick, C and X
    carry; NR and a mode of waiting requests alone serve none)."""
    return len(mode.waiting) + bool(mode.part)


def carried_part(mode: Mode) -> str | None:
    """The part the robot holds in ``mode``: C and X modes (Section VI-3) and a Q mode
    that carries a request (Section VI-2) hold one."""
    if mode.kind in ("C", "X") or (mode.kind == "Q" and mode.part):
        return mode.part
    return None


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

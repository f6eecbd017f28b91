"""The options of a simulated run, in one frozen bundle: :class:`SimulationOptions`.

``cellplan.simulate(strategy, stages, seed, options)`` takes them as scipy's
``minimize(..., options=)`` does: the run's identity (strategy, length, seed) stays in the
call, how it is run travels in one typed object, written and checked in one place
(:meth:`SimulationOptions.problems`). Both simulators (:mod:`cellplan.strategies.sim.simulate`
and, for simultaneous requests, :mod:`cellplan.strategies.variants.pending_sim`) read it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cellplan.errors import Problem
from cellplan.strategies.section import MAX_STAGES
from cellplan.strategies.variants.registry import model_variants

#: The policies of the Section V simulator (Section V-C: the strategy and two baselines);
#: a variant with a simulator of its own names its own (``Variant.policies``).
POLICIES: tuple[str, ...] = ("optimal", "reactive", "home")

#: The exact region tests of the workcell (:meth:`~cellplan.workcell.Workcell.in_region`).
REGION_TESTS: tuple[str, ...] = ("contact", "enclosure")


@dataclass(frozen=True, eq=False)
class SimulationOptions:
    """How a simulated run is run; every field has its default here and nowhere else.

    ``eq=False``: ``start`` and ``home`` are kept as given (array-like), so two bundles
    compare by identity.

    Parameters
    ----------
    policy
        ``optimal`` (the strategy), ``reactive`` or ``home`` (the baselines of Section
        V-C); a variant with a simulator of its own names its policies
        (:meth:`~cellplan.strategies.variants.base.Variant.policies`: with simultaneous
        requests, Section VI-2, ``optimal``, ``fcfs``, ``nearest`` or ``reactive``).
    start
        Start configuration (radians for angles). None: in ``cellplan.simulate`` the
        start the strategy records (the robot's ``start``), else a live NR cell centre
        near the middle of the C-space box (:func:`~.records.default_start`); the raw
        :func:`~.simulate.simulate` takes the latter (the simulator of simultaneous
        requests the recorded start where it is live in NR).
    start_mode
        The mode (layer) the run starts in; 0 is NR.
    regions
        ``contact`` or ``enclosure``: the exact region test that confirms every FMP when a
        workcell is given. None: the strategy's (its ``regions`` metadata), else
        ``contact``.
    home
        Home configuration of the ``home`` policy. None: the strategy's ``home`` metadata,
        else the default start.
    learn
        Keep the executor's LRTA* correction
        (:class:`~cellplan.strategies.policy.execution.Executor`); False keeps its
        lookahead but drops the correction, and with it the guarantee that no request
        waits for ever.
    max_wait
        Bound on any request's waiting time (time units) of ``cellplan.simulate``'s
        status. None: :func:`~.report.wait_bound`.
    """

    policy: str = "optimal"
    start: ArrayLike | None = None
    start_mode: int = 0
    regions: str | None = None
    home: ArrayLike | None = None
    learn: bool = True
    max_wait: float | None = None

    def policies(self, strategy: Any) -> tuple[str, ...]:
        """The policies a strategy's model is simulated with: those of the first variant
        it carries that names its own, else :data:`POLICIES`."""
        for variant in model_variants(strategy.mdp):
            own = variant.policies()
            if own is not None:
                return own
        return POLICIES

    def region_test(self, strategy: Any) -> str:
        """The exact region test of the run: ``regions``, else the strategy's."""
        return self.regions or str(strategy.meta.get("regions", "contact"))

    def problems(self, strategy: Any) -> list[Problem]:
        """One :class:`~cellplan.errors.Problem` per field that does not fit ``strategy``
        (``start`` is checked against the strategy's axes and domain where it is read,
        :func:`~.simulate.simulate_result`)."""
        out = []
        allowed = self.policies(strategy)
        if self.policy not in allowed:
            out.append(
                Problem("policy", f"must be one of {', '.join(allowed)}, got {self.policy!r}")
            )
        n_modes = strategy.mdp.n_modes
        if not 0 <= self.start_mode < n_modes:
            out.append(Problem("start_mode", f"must be in [0, {n_modes - 1}]"))
        if self.regions is not None and self.regions not in REGION_TESTS:
            out.append(
                Problem(
                    "regions", f"must be one of {', '.join(REGION_TESTS)}, got {self.regions!r}"
                )
            )
        if not isinstance(self.learn, bool | np.bool_):
            out.append(Problem("learn", f"must be True or False, got {self.learn!r}"))
        if self.max_wait is not None and not (
            isinstance(self.max_wait, int | float | np.integer | np.floating)
            and math.isfinite(self.max_wait)
            and self.max_wait > 0
        ):
            out.append(Problem("max_wait", f"must be a positive number, got {self.max_wait!r}"))
        return out


def run_problems(
    strategy: Any, stages: Any, seed: Any, options: SimulationOptions
) -> list[Problem]:
    """Every mistake in a run's arguments: ``stages``, ``seed`` and :attr:`options`."""
    out = []
    if not _is_int(stages) or not 1 <= int(stages) <= MAX_STAGES:
        out.append(Problem("stages", f"must be an integer in [1, {MAX_STAGES}], got {stages!r}"))
    if not _is_int(seed) or int(seed) < 0:
        out.append(Problem("seed", f"must be a non-negative integer, got {seed!r}"))
    if not isinstance(options, SimulationOptions):
        out.append(Problem("options", f"must be SimulationOptions, got {type(options).__name__}"))
        return out
    return out + options.problems(strategy)


def _is_int(value: Any) -> bool:
    return isinstance(value, int | np.integer)

"""The variants that run in a simulator of their own: variant name -> that simulator.

Most variants change the Section V simulator through the simulation hooks of
:class:`~.base.Variant` (where a move lands, the events of an FMP, where a region is).
A variant whose process the Section V simulator cannot run (simultaneous requests,
Section VI-2: several requests open, a choice of FMP) names its own simulator here, so
that :func:`cellplan.strategies.sim.simulate.simulate` hands such a model over without
testing which variant it has.

This table is apart from :data:`~.registry.VARIANTS` because a simulator imports the
strategy and the executor, which import the scenario schema, which imports the variants:
holding the simulator in the variant's own module would close that circle.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Protocol

from cellplan.core import Progress
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.sim.records import Simulation
from cellplan.strategies.variants.pending_sim import simulate_pending
from cellplan.strategies.variants.registry import model_variants
from cellplan.strategies.variants.simultaneous import SIMULTANEOUS


class Simulator(Protocol):
    """A variant's simulator: the call form of :func:`~.pending_sim.simulate_pending`."""

    def __call__(
        self,
        strategy: Any,
        stages: int,
        seed: int,
        options: SimulationOptions | None = None,
        *,
        cell: Any = None,
        progress: Progress | None = None,
    ) -> Simulation: ...


#: The variants with a simulator of their own (read-only).
SIMULATORS: Mapping[str, Simulator] = MappingProxyType({SIMULTANEOUS.name: simulate_pending})


def simulator_of(mdp: Any) -> Simulator | None:
    """The simulator of the first variant of ``mdp`` that has its own, or None (the
    Section V simulator, with the variants' hooks)."""
    for variant in model_variants(mdp):
        if variant.name in SIMULATORS:
            return SIMULATORS[variant.name]
    return None

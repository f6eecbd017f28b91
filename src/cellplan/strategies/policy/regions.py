"""The exact region test of a fine motion (FMP) at a real configuration.

The grid offers an FMP wherever a cell's centre lies in the region; at a real
configuration near the region's edge the workcell's exact test
(:meth:`~cellplan.workcell.Workcell.in_region`) may refuse it. The strategy
(:meth:`~cellplan.strategies.policy.strategy.Strategy.attach`), the executor and both
simulators confirm every FMP they take with this test.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cellplan.strategies.model.mdp import LayeredMDP
from cellplan.strategies.policy.decisions import fmp_target
from cellplan.strategies.variants.registry import model_variants


def region_test(strategy: Any, cell: Any, regions: str) -> RegionTest:
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
        """The test of FMP option ``j`` of mode ``m``, in the region
        :func:`~.decisions.fmp_target` names (with the part carried into it): the only
        option of a W, C or X mode; with simultaneous requests (Section VI-2) the delivery
        of the carried request, or while empty the pick of the ``j``-th waiting request
        type in the order of the model's options."""
        region, part = fmp_target(self.mdp.modes[m], j)
        offset = None  # where the scenario puts it, unless a variant moves it
        for variant in model_variants(self.mdp):
            moved = variant.region_offset(self.mdp, region, m)
            if moved != (0.0, 0.0):
                offset = moved
        return np.asarray(
            self.cell.in_region(points, region, self.regions, None, part, offset), dtype=bool
        )

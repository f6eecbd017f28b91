"""Every registered planner obeys the core contract (the Gymnasium-style conformance test).

For each planner: its smoke run returns a :class:`PlanResult` with a
:class:`Status`, plain finite numeric statistics, and is deterministic for a
seed (timing statistics aside).
"""

from __future__ import annotations

import gc

import pytest

from cellplan.core import PlanResult, Status, check_stats
from cellplan.registry import planners

PLANNERS = planners()
TIMING = ("time", "seconds", "wall")


def _deterministic_part(stats):
    return {k: v for k, v in stats.items() if not any(t in k for t in TIMING)}


def test_registry_names_are_qualified_by_paper():
    for name, entry in PLANNERS.items():
        assert name == entry.name
        assert entry.paper in ("strategies", "adaptive", "assembly")
        assert name.startswith(entry.paper + ".")
        assert entry.summary


@pytest.mark.parametrize("name", sorted(PLANNERS))
def test_planner_conformance(name):
    entry = PLANNERS[name]
    first = entry.smoke(0)
    second = entry.smoke(0)
    gc.collect()
    for result in (first, second):
        assert isinstance(result, PlanResult)
        assert isinstance(result.status, Status)
        assert check_stats(result.stats) == []
    assert first.status == second.status
    assert _deterministic_part(first.stats) == _deterministic_part(second.stats)

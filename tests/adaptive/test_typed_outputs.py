"""Counts are ints, measures floats, flags bools: the adaptive stats and validate facts
keep their types in every JSON output (issue 34)."""

from __future__ import annotations

import json
from collections.abc import Mapping

import pytest
from adaptive_scenarios import POINT_SCENARIO

import cellplan.api as api
from cellplan.adaptive import ExperiencePlanner
from cellplan.adaptive.plugin import describe
from cellplan.core import Fact

COUNTS = (
    "tasks",
    "solved",
    "paths_ok",
    "checks",
    "solve_calls",
    "vertices",
    "edges",
    "generation",
    "solve_only_checks",
    "s_fallbacks",
)


def _exact(stats: Mapping[str, object], counts: tuple[str, ...]) -> None:
    for key in counts:
        assert type(stats[key]) is int, (key, stats[key])
    for key, value in stats.items():
        if key not in counts:
            assert type(value) in (float, bool), (key, value)
    # and they survive JSON with their types
    assert json.loads(json.dumps(dict(stats))) == stats


def test_the_adaptive_planners_counts_are_ints() -> None:
    res = api.plan(api.loads(POINT_SCENARIO), "adaptive", tasks=5, seed=0)
    assert set(COUNTS) <= set(res.stats)
    _exact(res.stats, COUNTS)
    assert res.stats["solved"] == sum(int(r["success"]) for r in res.solution.tasks)


@pytest.mark.parametrize(
    ("peer", "key"), [("adaptive.rrtconnect", "checks"), ("adaptive.prm", "checks_time_dependent")]
)
def test_the_peers_counts_are_ints(peer: str, key: str) -> None:
    res = api.plan(api.loads(POINT_SCENARIO), peer, tasks=3, seed=0)
    _exact(res.stats, ("tasks", "solved", key))
    assert res.stats["tasks"] == 3


def test_a_querys_counts_are_ints_and_its_flag_a_bool() -> None:
    ep = ExperiencePlanner(api.loads(POINT_SCENARIO))
    res = ep.plan(None, "g1")
    checks = [k for k in res.stats if k.endswith("checks")]
    counts = (*checks, "solve_calls", "s_fallbacks", "vertices", "edges", "generation")
    _exact(res.stats, counts)
    assert res.stats["timed_out"] is False
    assert all(type(v) is int for v in ep.stats().values())


def test_describe_returns_typed_facts() -> None:
    facts = describe(api.loads(POINT_SCENARIO))
    assert all(isinstance(f, Fact) for f in facts)
    by_key = {f.key: f.value for f in facts}
    assert by_key["adaptive_goals"] == ["g1", "g2", "home"]
    assert by_key["adaptive_tasks"] == {"count": 7, "random": False, "seed": None}
    assert by_key["workcell_changes"] == 1 and type(by_key["workcell_changes"]) is int
    assert by_key["repair_solve_reach"] == {
        "repair": "A3",
        "solve": "rrtconnect",
        "reach": "straight",
    }
    text = {f.label: f.text for f in facts}
    assert text["adaptive tasks"] == "7 (listed)"

"""The strategy section: probabilities, Poisson rates (equation (4)), cross-references."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st
from strategies_helpers import TINY, tiny

from cellplan.errors import ScenarioError
from cellplan.scenario import loads_scenario
from cellplan.strategies.section import Rate


@given(st.floats(1e-4, 50.0), st.floats(1e-3, 10.0))
def test_poisson_rate_becomes_a_probability(rate, dt):
    p = Rate(rate=rate).per_stage(dt)
    assert p == pytest.approx(1.0 - math.exp(-rate * dt))
    assert 0.0 < p < 1.0 or p == pytest.approx(1.0)


def test_rate_needs_exactly_one_value():
    with pytest.raises(ValueError):
        Rate()
    with pytest.raises(ValueError):
        Rate(probability=0.1, rate=2.0)


def _text(strategy_lines: str) -> str:
    head = TINY.split("strategy:")[0].replace("CELLS", "16")
    return head + "strategy:\n" + strategy_lines


def _problems(text: str) -> list[str]:
    with pytest.raises(ScenarioError) as err:
        loads_scenario(text)
    return [str(p) for p in err.value.problems]


def test_each_mistake_is_one_problem():
    probs = _problems(
        _text(
            "  speed: 2.0\n"
            "  arrival: {probability: 0.1}\n"
            "  requests:\n"
            "    - {part: P9, source: S1, destination: D1, probability: 0.5}\n"
            "    - {part: P1, source: S7, destination: D1, probability: 0.3}\n"
            "  carry_speed_factor: {PX: 0.5}\n"
            "  fine_motion_regions: {D5: {time: 1}}\n"
        )
    )
    assert any("requests[0].part" in p and "P9" in p for p in probs)
    assert any("requests[1].source" in p and "S7" in p for p in probs)
    assert any("sum to 0.8" in p for p in probs)
    assert any("carry_speed_factor.PX" in p for p in probs)
    assert any("fine_motion_regions.D5" in p for p in probs)
    assert len(probs) == 5


def test_probability_outside_unit_interval_is_refused():
    probs = _problems(_text("  speed: 2.0\n  arrival: {probability: 1.5}\n"))
    assert any("strategy.arrival.probability" in p for p in probs)


def test_destination_change_needs_another_destination():
    probs = _problems(
        _text(
            "  speed: 2.0\n  arrival: {probability: 0.1}\n"
            "  destination_change: {probability: 0.02}\n"
        )
    )
    assert any("destination_change" in p and "no other destination" in p for p in probs)


def test_rotating_robot_needs_turn_speed():
    text = (
        _text("  speed: 2.0\n  arrival: {probability: 0.1}\n")
        .replace("type: translating", "type: rotating")
        .replace("start: [15, 8]", "start: [15, 8, 0]")
    )
    assert any("turn_speed" in p for p in _problems(text))


def test_uniform_requests_cover_every_combination():
    sc, _ = tiny()
    reqs = sc.strategy.request_list(sc)
    assert len(reqs) == 2  # 1 part x 2 sources x 1 destination
    assert sum(r[3] for r in reqs) == pytest.approx(1.0)


def test_unreachable_region_is_named_before_solving():
    from cellplan.strategies.model.mdp import build_model

    text = TINY.replace("CELLS", "16").replace(
        "D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}",
        "D1: {components: [{type: box, min: [13, 13.5], max: [17, 14.5]}]}",
    )
    sc = loads_scenario(text)
    from cellplan.workcell import Workcell

    with pytest.raises(ScenarioError) as err:
        build_model(sc, Workcell.from_scenario(sc))
    assert any("D1" in str(p) for p in err.value.problems)


# --- the compiled problem and the variant seam (issue 33) ----------------------------------


@pytest.mark.parametrize(
    ("name", "variants"),
    [
        ("strategies_tiny", ()),
        ("strategies_p4", ()),
        ("strategies_failures", ("failures",)),
        ("strategies_noise", ("noise",)),
        ("strategies_pending", ("simultaneous",)),
        ("strategies_conveyor", ("time_varying",)),
    ],
)
def test_compile_reads_the_section_once_with_its_active_variants(name, variants):
    import dataclasses

    from cellplan.scenario import load_scenario
    from cellplan.strategies.model.spec import ProblemSpec

    sc = load_scenario(name)
    spec = sc.strategy.compile(sc)
    assert isinstance(spec, ProblemSpec) and spec.variant_names() == variants
    assert list(spec.requests) == sc.strategy.request_list(sc)
    assert spec.arrival == sc.strategy.arrival.per_stage(sc.strategy.stage_time)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.arrival = 0.5  # type: ignore[misc]


def test_every_variant_is_registered_with_its_hooks_documented():
    from cellplan.strategies.variants.base import Variant
    from cellplan.strategies.variants.registry import CHECK_ORDER, VARIANTS

    assert set(CHECK_ORDER) == set(VARIANTS)
    hooks = [n for n, f in vars(Variant).items() if callable(f) and not n.startswith("_")]
    assert len(hooks) >= 15
    for name in hooks:  # each hook says who calls it
        doc = getattr(Variant, name).__doc__ or ""
        assert "alled by" in doc or name == "describe", name
    for name, variant in VARIANTS.items():
        assert variant.name == name and variant.paper.startswith("Section VI-")
        assert name in variant.describe()


def test_the_model_never_imports_a_variant():
    import ast
    from pathlib import Path

    import cellplan.strategies.model as model

    for path in Path(model.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                assert not node.module.startswith("cellplan.strategies.variants"), path.name
                assert node.module != "cellplan.strategies.section", path.name


def test_a_loaded_model_names_the_variants_it_was_built_with(tmp_path):
    from strategies_helpers import tiny_failures

    from cellplan.strategies.policy.strategy import Strategy, solve_scenario
    from cellplan.strategies.variants.registry import model_variants

    for then, names in (("reject", ["failures"]), ("retry", ["failures"])):
        sc, cell = tiny_failures(0.3, then, cells=12)
        strategy, _ = solve_scenario(sc, cell)
        built = model_variants(strategy.mdp)
        assert [v.name for v in built] == names
        back = Strategy.load(strategy.save(tmp_path / f"{then}.npz"), sc)
        assert back.mdp.variants == () and model_variants(back.mdp) == built
    sc, cell = tiny(cells=12)
    assert model_variants(solve_scenario(sc, cell)[0].mdp) == ()

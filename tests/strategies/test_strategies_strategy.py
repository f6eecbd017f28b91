"""The Strategy object: online queries (equation (9)), persistence, collision-free actions."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from strategies_helpers import tiny

import cellplan
from cellplan.errors import ArgumentError, PersistenceError
from cellplan.strategies.model.points import query
from cellplan.strategies.policy.decisions import Action, Actions
from cellplan.strategies.policy.strategy import FMP, STAY, Strategy, solve_scenario
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.sim.simulate import simulate_result


@pytest.fixture(scope="module")
def solved():
    sc, cell = tiny(cells=16)
    strategy, result = solve_scenario(sc, cell)
    return sc, cell, strategy, result


def test_query_at_cell_centres_matches_solver_policy(solved):
    _, _, strategy, result = solved
    mdp = strategy.mdp
    rng = np.random.default_rng(0)
    live = np.argwhere(mdp.live)
    agree = 0
    picks = live[rng.choice(len(live), 200, replace=False)]
    for m, c in picks:
        q = mdp.lower + (np.array(np.unravel_index(c, tuple(mdp.shape))) + 0.5) * mdp.spacing
        vals = strategy.action_values(q, int(m))
        u = strategy.action_code(q, int(m))
        # The chosen action attains the minimum of (9); the solver's action does too.
        pol = int(result.policy[m, c])
        j = {FMP: 0, STAY: 1}.get(pol, pol + 2)
        assert np.nanmin(vals) == pytest.approx(vals[{FMP: 0, STAY: 1}.get(u, u + 2)])
        assert vals[j] == pytest.approx(np.nanmin(vals), abs=1e-9)
        agree += u == pol
    assert agree >= 190  # the rest are exact ties


def test_save_load_roundtrip(solved, tmp_path):
    sc, _, strategy, _ = solved
    path = strategy.save(tmp_path / "s.npz")
    back = Strategy.load(path, sc)
    assert back.gain == strategy.gain
    assert back.meta["scenario_digest"] == sc.digest()
    np.testing.assert_array_equal(back.values, strategy.values)
    q = np.array([15.0, 8.0])
    assert back.action(q, 0) == strategy.action(q, 0)
    assert [m.label for m in back.modes] == [m.label for m in strategy.modes]


def test_load_refuses_another_scenario(solved, tmp_path):
    _, _, strategy, _ = solved
    path = strategy.save(tmp_path / "s.npz")
    other, _ = tiny(cells=16, extra="")
    other = other.model_copy(update={"name": "changed"})
    with pytest.raises(PersistenceError, match="different scenario"):
        Strategy.load(path, other)


def test_load_rejects_garbage(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(PersistenceError, match="not a strategy file"):
        Strategy.load(bad)
    with pytest.raises(PersistenceError, match="no such"):
        Strategy.load(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(PersistenceError, match=r"meta: missing array .not a strategy file"):
        Strategy.load(tmp_path / "other.npz")


def test_mode_names(solved):
    _, _, strategy, _ = solved
    assert strategy.mode_index("NR") == 0
    m = strategy.mode_index("1,2,1,W")
    assert strategy.modes[m].label == "<P1,S2,D1,W>"
    assert strategy.mode_index("P1,S2,D1,C") == strategy.mdp.c_layer(1)
    with pytest.raises(PersistenceError):
        strategy.mode_index("1,9,1,W")


@settings(max_examples=80)
@given(x=st.floats(1.0, 29.0), y=st.floats(1.0, 29.0), mode=st.integers(0, 4))
def test_policy_never_commands_a_colliding_motion(solved, x, y, mode):
    _, cell, strategy, _ = solved
    q = np.array([x, y])
    c = strategy.cell_of(q)
    if not strategy.mdp.live[mode, c]:
        return
    try:
        u = strategy.action(q, mode)
    except ValueError:
        return
    if u.kind != "move":
        return
    m = strategy.modes[mode]
    carrying = m.part if m.kind == "C" else None
    avoid = "all" if m.kind == "NR" else cell.sources_except(m.source)
    q1 = strategy.next_configuration(q, mode, u)
    assert not cell.motion_collides(q[None], q1[None], 0.05, carrying, avoid)[0]


def test_queries_refuse_bad_arguments_with_one_line_each(solved):
    # The kernels index the model's arrays with q and the mode unchecked: a mode out of
    # range used to read past the end of them (a segmentation fault).
    _, _, strategy, _ = solved
    q = np.array([15.0, 8.0])
    n = strategy.mdp.n_modes
    cases = [
        (lambda: strategy.action(np.array([15.0, 8.0, 1.0]), 0), "q", "shape (2,), got (3,)"),
        (lambda: strategy.action(q[:1], 0), "q", "shape (2,), got (1,)"),
        (lambda: strategy.action(np.zeros((1, 3)), 0), "q", "got (1, 3)"),
        (lambda: strategy.action(["a", "b"], 0), "q", "array of numbers"),
        (lambda: strategy.action(np.array([np.nan, 8.0]), 0), "q", "NaN or infinite"),
        (lambda: strategy.action(np.array([15.0, -np.inf]), 0), "q", "NaN or infinite"),
        (lambda: strategy.action(q, n), "mode", f"[0, {n}), got {n}"),
        (lambda: strategy.action(q, -1), "mode", "got -1"),
        (lambda: strategy.action(q, 1.0), "mode", "got 1.0"),
        (lambda: strategy.action(q, True), "mode", "got True"),
        (lambda: strategy.action_values(q, n + 3), "mode", "layer index"),
        (lambda: strategy.action_values(np.array([np.nan, 1.0]), 0), "q", "NaN"),
        (lambda: strategy.action_values(q, 0, values=np.zeros((2, 2))), "values", "(2, 2)"),
        (lambda: strategy.cell_of(np.array([np.inf, 1.0])), "q", "NaN or infinite"),
        (lambda: strategy.next_configuration(q, 0, 10**6), "action", "got 1000000"),
        (lambda: strategy.next_configuration(q, 0, -3), "action", "got -3"),
        (lambda: strategy.next_configuration(q, n, 0), "mode", "layer index"),
    ]
    for call, field, text in cases:
        with pytest.raises(ArgumentError) as info:
            call()
        (problem,) = info.value.problems
        assert problem.field == field
        assert text in problem.message


@settings(max_examples=60)
@given(
    x=st.floats(-5.0, 35.0),
    y=st.floats(-5.0, 35.0),
    mode=st.integers(0, 4),
    forbid=st.booleans(),
)
def test_the_bound_query_kernel_is_the_dispatched_one(solved, x, y, mode, forbid):
    # Strategy.action calls the query's compiled code directly (points.compiled_for),
    # skipping numba's dispatcher: the same answer and action values as through it.
    _, _, strategy, _ = solved
    args = strategy._query_args()
    q = np.array([x, y])
    out = np.empty_like(args.out)
    expect = query(q, mode, args.h0, args.live, forbid, args.model, out)
    assert args.kernel(q, mode, args.h0, args.live, forbid, args.model, args.out) == expect
    np.testing.assert_array_equal(args.out, out)


def test_queries_follow_replaced_values(solved):
    _, _, strategy, _ = solved
    copy = Strategy(strategy.mdp, strategy.values.copy(), dict(strategy.meta))
    q = np.array([15.3, 8.2])
    copy.action(q, 0)
    before = copy._query_args()
    copy.values = -copy.values  # a strategy that heads for the worst states
    after = copy._query_args()
    assert after is not before and after.values is copy.values
    out = np.empty_like(after.out)
    expect = query(
        q, 0, np.nan_to_num(copy.values, nan=0.0), copy.mdp.live, False, after.model, out
    )
    assert copy.action_code(q, 0) == expect


def test_strategy_pickles_after_queries_and_still_answers():
    """The compiled query kernel is left out of the pickle and rebuilt (issue 36)."""
    result = cellplan.plan(cellplan.load("strategies_tiny"), "strategies")
    strategy = result.solution
    q, mode = result.trajectory.q[0], int(result.trajectory.mode[0])
    action = strategy.action(q, mode)  # builds the query cache (a compiled kernel)
    copy = pickle.loads(pickle.dumps(strategy))
    assert copy.action(q, mode) == action
    assert np.array_equal(copy.values, strategy.values, equal_nan=True)


def test_a_mode_is_taken_by_name_wherever_an_index_is(solved):
    # Issue 34: strategy.action(q, "NR") works, as does any label mode_index reads.
    _, cell, strategy, _ = solved
    q = np.asarray(cell.robot.start, float)
    assert strategy.action(q, "NR") == strategy.action(q, 0)
    for m, mode in enumerate(strategy.modes):
        if not strategy.live[m, strategy.cell_of(q)]:
            continue
        assert strategy.action(q, mode.label) == strategy.action(q, m)
        np.testing.assert_array_equal(
            strategy.action_values(q, mode.label), strategy.action_values(q, m)
        )
    with pytest.raises(ArgumentError) as err:
        strategy.action(q, "<P9,S1,D1,W>")
    assert [p.field for p in err.value.problems] == ["mode"]


def test_the_repr_is_one_short_line(solved):
    _, _, strategy, _ = solved
    text = repr(strategy)
    assert "\n" not in text and len(text) < 160 and "array" not in text
    assert "16 x 16 cells" in text and f"{strategy.mdp.n_modes} modes" in text
    assert f"{strategy.gain:.6g}" in text


def test_an_action_says_what_to_do(solved):
    # Issue 33: a typed action, not a code to decode: the kind, the move and its step,
    # the region of a pick or a drop; the code underneath is action_code's.
    _, _, strategy, _ = solved
    mdp = strategy.mdp
    rng = np.random.default_rng(3)
    kinds = set()
    for m, c in np.argwhere(mdp.live)[rng.choice(int(mdp.live.sum()), 300, replace=False)]:
        idx = np.array(np.unravel_index(c, tuple(mdp.shape)))
        q = mdp.lower + (idx + rng.uniform(0.1, 0.9, len(idx))) * mdp.spacing
        a = strategy.action(q, int(m))
        assert isinstance(a, Action) and a.code == strategy.action_code(q, int(m))
        kinds.add(a.kind)
        mode = strategy.modes[int(m)]
        if a.kind == "move":
            assert a.move == a.code >= 0 and a.region == ""
            np.testing.assert_allclose(a.step, strategy.move_vector(q, int(m), a.code), atol=1e-9)
            np.testing.assert_allclose(
                strategy.next_configuration(q, int(m), a), q + a.step, atol=1e-9
            )
        elif a.kind == "stay":
            assert a.code == STAY and not any(a.step)
        else:
            assert a.code == FMP and a.option == 0 and a.is_fmp
            assert (a.kind, a.region) == (
                ("pick", mode.source) if mode.kind == "W" else ("drop", mode.destination)
            )
            np.testing.assert_array_equal(strategy.next_configuration(q, int(m), a), q)
    assert {"move", "pick", "drop"} <= kinds


def test_actions_are_batched_over_configurations(solved):
    # (n, dim) in, a bundle of n actions out, each what the single query answers.
    _, _, strategy, _ = solved
    mdp = strategy.mdp
    m = 1
    cells = np.flatnonzero(mdp.live[m])[::7][:40]
    qs = np.array(
        [
            mdp.lower + (np.array(np.unravel_index(c, tuple(mdp.shape))) + 0.3) * mdp.spacing
            for c in cells
        ]
    )
    batch = strategy.action(qs, m)
    assert isinstance(batch, Actions) and len(batch) == len(qs)
    assert batch.step.shape == qs.shape and batch.kind.shape == (len(qs),)
    for i, q in enumerate(qs):
        assert batch[i] == strategy.action(q, m)
    assert list(batch) == [batch[i] for i in range(len(qs))]
    assert strategy.action(qs, strategy.modes[m].label)[0] == batch[0]  # a mode by name
    with pytest.raises(ValueError, match="outside the strategy's domain"):
        strategy.action(np.vstack([qs[:2], _dead_point(strategy, m)]), m)


def _dead_point(strategy, m):
    mdp = strategy.mdp
    c = int(np.flatnonzero(~mdp.live[m])[0])
    return mdp.lower + (np.array(np.unravel_index(c, tuple(mdp.shape))) + 0.5) * mdp.spacing


def test_no_action_outside_the_domain_the_simulator_refuses(solved):
    # Issue 35 part 5: one rule (Strategy.in_domain) for the strategy and the simulator's
    # start: where simulate refuses a start, action has no action either, though live
    # corners nearby would give values.
    _, _, strategy, _ = solved
    mdp = strategy.mdp
    checked = 0
    for m in range(mdp.n_modes):
        dead = np.flatnonzero(~mdp.live[m] & np.roll(mdp.live[m], 1))[:5]
        for c in dead:
            q = mdp.lower + (np.array(np.unravel_index(c, tuple(mdp.shape))) + 0.5) * mdp.spacing
            assert not strategy.in_domain(q, m)
            with pytest.raises(ValueError, match="outside the strategy's domain"):
                strategy.action(q, m)
            if m == 0:
                with pytest.raises(cellplan.ArgumentError, match="outside the strategy's domain"):
                    simulate_result(strategy, 10, 0, SimulationOptions(start=q, start_mode=m))
            checked += 1
    assert checked > 0


def test_one_plan_compiles_the_strategy_section_once(monkeypatch):
    # Issue 33: the memory check and the model build read one compiled specification.
    from cellplan.strategies.section import StrategySection

    calls = []
    compile_section = StrategySection.compile

    def counting(self, scenario):
        calls.append(scenario)
        return compile_section(self, scenario)

    monkeypatch.setattr(StrategySection, "compile", counting)
    result = cellplan.plan(cellplan.load("strategies_tiny"), "strategies")
    assert result.success
    assert len(calls) == 1


def test_a_batch_is_the_single_queries_in_every_mode_with_the_exact_region_test():
    # The batch runs one compiled loop and confirms its FMPs in one region-test call: the
    # same actions, field by field and dtype by dtype, as the single queries.
    sc, cell = tiny(cells=16)
    strategy, _ = solve_scenario(sc, cell)
    strategy.attach(cell)
    mdp = strategy.mdp
    rng = np.random.default_rng(5)
    kinds = set()
    for m in range(mdp.n_modes):
        cells = np.flatnonzero(mdp.live[m])
        index = np.array(np.unravel_index(cells, tuple(mdp.shape))).T
        qs = mdp.lower + (index + rng.uniform(0.02, 0.98, index.shape)) * mdp.spacing
        qs = np.array([q for q in qs if strategy.in_domain(q, m)])
        batch = strategy.action(qs, m)
        one = Actions.of([strategy.action(q, m) for q in qs], len(mdp.shape))
        for field in ("kind", "code", "move", "step", "region", "option"):
            got, want = getattr(batch, field), getattr(one, field)
            assert got.dtype == want.dtype and np.array_equal(got, want), field
        kinds |= set(batch.kind.tolist())
        with pytest.raises(cellplan.ArgumentError, match="NaN or infinite"):
            strategy.action(np.vstack([qs[:2], [np.nan] * len(mdp.shape)]), m)
    assert {"move", "pick", "drop"} <= kinds

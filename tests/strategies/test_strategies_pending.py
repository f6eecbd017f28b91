"""Simultaneous requests (Section VI-2 of the strategies paper).

Modes are (open requests waiting, request carried); FMP in an empty mode has one option
per waiting request type (the robot chooses the order of service). Checked here: the mode
counts against the enumeration; one open request at a time is exactly the Section V model;
the gain equals a plain sparse value iteration over the options; the urgent part is
fetched first where the unweighted model would not; every policy of a seed meets the same
requests; the simulated loss follows the gain; one line per mistake in the keys.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from strategies_helpers import TINY, assert_validate_names, lu_entries, tiny
from test_strategies_solver import sparse_rvi

from cellplan.api import load
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.section import mode_counts
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.solve.solver import solve
from cellplan.strategies.variants.pending import pending_modes
from cellplan.strategies.variants.pending_sim import (
    PENDING_POLICIES,
    Rules,
    simulate_pending,
    single_request_model,
    single_request_strategy,
)


def pending(k: int, cells: int = 12, extra: str = "") -> tuple:
    """The tiny workcell (two request types) with up to ``k`` open requests."""
    return tiny(cells, f"  max_pending: {k}\n" + extra)


def solved(sc, cell) -> Strategy:
    mdp = build_model(sc, cell)
    strategy = Strategy.from_solution(mdp, solve(mdp, "auto", 1e-9), sc)
    strategy.meta["start"] = list(cell.robot.start)
    return strategy


@given(st.integers(1, 6), st.integers(1, 4))
def test_mode_counts_are_those_of_the_enumeration(R, k):
    keys = pending_modes(R, k)
    empty, carrying = mode_counts(R, k)
    assert len(keys) == len(set(keys)) == empty + carrying
    assert keys[0] == ((), -1)
    assert all(len(q) + (r >= 0) <= k for q, r in keys)
    assert sum(1 for _, r in keys if r < 0) == empty


def test_one_open_request_at_a_time_is_the_section_v_model():
    # max_pending 1 with an urgency of 1 goes through the simultaneous-requests builder:
    # the same layers in the same order (NR, W..., C...), the same gain and values.
    sc, cell = tiny(16)
    v = build_model(sc, cell)
    sc1, _ = tiny(16, "  urgency: {P1: 1.0}\n")
    q = build_model(sc1, cell)
    assert q.opt_ptr is not None and not q.is_simple()
    assert [m.label for m in q.modes[1:3]] == ["{P1,S1,D1}", "{P1,S2,D1}"]
    np.testing.assert_array_equal(q.live, v.live)
    np.testing.assert_array_equal(q.tf, v.tf[1:])  # NR has no option
    rv, rq = solve(v, "structured", 1e-10), solve(q, "policy", 1e-10)
    assert rq.gain == pytest.approx(rv.gain, abs=1e-8)
    hv, hq = rv.values - rv.values[0, 0], rq.values - rq.values[0, 0]
    np.testing.assert_allclose(hq[v.live], hv[v.live], atol=1e-6)


@pytest.mark.parametrize("k", [2, 3])
def test_the_gain_is_that_of_a_plain_sparse_value_iteration(k):
    sc, cell = pending(k, extra="  urgency: {P1: 2.0}\n")
    mdp = build_model(sc, cell)
    assert mdp.n_modes == sum(mode_counts(2, k))
    res = solve(mdp, "auto", 1e-10)
    assert res.method == "policy"
    gain, _ = sparse_rvi(mdp, tol=1e-10, damping=0.5)
    assert res.gain == pytest.approx(gain, abs=1e-7)
    assert res.gain_lower <= gain + 1e-9 and gain - 1e-9 <= res.gain_upper


def test_more_open_requests_allowed_cost_more_per_stage():
    # Allowing more requests to wait cannot lower the number of requests waiting.
    gains = [solve(build_model(*pending(k)), "auto", 1e-9).gain for k in (1, 2, 3)]
    assert gains[0] < gains[1] < gains[2]


def test_the_single_request_model_inside_is_the_section_v_model():
    sc, cell = pending(2, 16)
    sub = single_request_model(build_model(sc, cell))
    sc1, _ = tiny(16)
    v = build_model(sc1, cell)
    assert sub.is_simple() and [m.label for m in sub.modes] == [m.label for m in v.modes]
    np.testing.assert_array_equal(sub.live, v.live)
    assert solve(sub, "auto", 1e-10).gain == pytest.approx(solve(v, "auto", 1e-10).gain)


def _first_pick(strategy: Strategy, q: np.ndarray, waiting: list[int]) -> str:
    """Follow the optimal strategy with ``waiting`` open and no arrivals until it picks."""
    rules = Rules(strategy)
    m = rules.mode_of(waiting, -1)
    for _ in range(200):
        u = strategy.action_code(q, m)
        if u <= -2 and u != -3:
            j = 0 if u == -2 else -3 - u
            return rules.names[sorted(set(waiting))[j]]
        q = strategy.next_configuration(q, m, u)
    raise AssertionError("no pick in 200 stages")


def test_the_urgent_part_is_fetched_first_from_beside_the_other_source():
    # The bundled scenario's workcell: a P1 request (source S1) and a P2 request (S2)
    # wait, the robot stands beside S1. With equal weights it serves P1 first (the nearer
    # one); with P2 three times as urgent it walks past the P1 part to fetch P2 first.
    setup = load("strategies_pending")
    sc = setup.scenario
    urgent = solved(sc.model_copy(update={"strategy": _with(sc, cells=[50, 50])}), setup.workcell)
    equal = solved(
        sc.model_copy(update={"strategy": _with(sc, cells=[50, 50], urgency={})}),
        setup.workcell,
    )
    beside_s1 = np.array([16.0, 20.0])
    names = [f"{p},{s},{d}" for p, s, d, _ in sc.strategy.request_list(sc)]
    waiting = [names.index("P1,S1,D1"), names.index("P2,S2,D1")]
    assert _first_pick(equal, beside_s1.copy(), waiting) == "P1,S1,D1"
    assert _first_pick(urgent, beside_s1.copy(), waiting) == "P2,S2,D1"


def _with(sc, **update):
    return sc.strategy.model_copy(update={"max_pending": 2, **update})


def test_every_policy_of_a_seed_meets_the_same_requests():
    strategy = solved(*pending(2))
    rules = Rules(strategy, single_request_strategy(strategy))
    runs = {
        p: simulate_pending(strategy, 3000, 5, SimulationOptions(policy=p), rules=rules)
        for p in PENDING_POLICIES
    }
    drawn = {p: r.arrivals for p, r in runs.items()}
    assert len(set(drawn.values())) == 1 and drawn["optimal"] > 50
    for r in runs.values():
        assert len(r.requests) + r.turned_away <= r.arrivals  # none arrives during an FMP
        served = [q for q in r.requests if q.delivery >= 0]
        assert len(served) >= len(r.requests) - 2
        assert all(q.arrival <= q.pickup < q.delivery for q in served)
        m = r.metrics()
        assert 0 <= m["mean_open"] <= 2


# slow: 18 s; test_strategies_pending_lockup.py simulates the same model over many seeds against
# the gain
@pytest.mark.slow
def test_the_simulated_loss_follows_the_gain():
    strategy = solved(*pending(2, 16))
    rules = Rules(strategy)
    losses = [
        simulate_pending(strategy, 20000, seed, rules=rules).metrics()["loss_per_stage"]
        for seed in range(4)
    ]
    assert np.mean(losses) == pytest.approx(strategy.gain, rel=0.1)


MISTAKES = {
    "  max_pending: 0\n": "strategy.max_pending:",
    "  max_pending: 9\n": "strategy.max_pending:",
    "  urgency: {P9: 2.0}\n": "strategy.urgency.P9: unknown part",
    "  urgency: {P1: 0}\n": "strategy.urgency.P1:",
    "  max_pending: 2\n  destination_change: {probability: 0.1}\n": (
        "strategy.destination_change: cannot be combined with simultaneous requests"
    ),
    "  max_pending: 2\n  failures:\n"
    "    - {region: D1, probability: 0.2, then: retry, rework: 1}\n": (
        "strategy.failures: cannot be combined with simultaneous requests"
    ),
}


@pytest.mark.parametrize("text", list(MISTAKES))
def test_each_pending_mistake_is_one_line_naming_the_field(cellplan, tmp_path, text):
    assert_validate_names(cellplan, tmp_path, TINY.replace("CELLS", "12") + text, MISTAKES[text])


def test_too_many_modes_are_refused_before_building(cellplan, tmp_path):
    # 2 sources x 27 destinations = 54 request types; 8 open make ~1e9 modes.
    text = TINY.replace("CELLS", "12").replace(
        "destinations:\n",
        "destinations:\n"
        + "".join(
            f"  E{i}: {{components: [{{type: box, min: [{i}, 27], max: [{i + 0.5}, 28]}}]}}\n"
            for i in range(2, 28)
        ),
    )
    path = tmp_path / "many.yaml"
    path.write_text(text + "  max_pending: 8\n")
    r = cellplan("validate", str(path))
    assert r.returncode == 2
    assert "error: strategy.max_pending: 8 open requests of 54 types make" in r.stderr, r.stderr


# slow: 20 s, the bundled scenario solved at 50 x 50; test_strategies_experiments.py::
# test_pending_experiment_on_two_tiny_request_types runs the same run() and report() with
# the same checks on a tiny scenario.
@pytest.mark.slow
def test_quick_pending_experiment_reports_three_claims(tmp_path):
    from cellplan.strategies.experiments.pending_experiment import EXPERIMENT

    rows = [EXPERIMENT.run(s) for s in EXPERIMENT.make_runs(2, True)]
    for r in rows:
        assert r["optimal_arrivals"] == r["fcfs_arrivals"] == r["nearest_arrivals"]
        assert r["optimal_wait_P2"] < r["optimal_wait_P1"]  # the urgent part waits less
    piece = EXPERIMENT.report(rows, tmp_path)
    assert len(piece.claims) == 3 and all(p.exists() for p in piece.figures)
    assert all(c.n == 2 and c.reproduced is None for c in piece.claims)  # too few seeds


# slow: 28 s; test_strategies_cli.py runs the same commands, test_strategies_pending_files.py
# draws the pending frames and GIF
@pytest.mark.slow
def test_solve_simulate_and_gif_on_the_command_line(cellplan, tmp_path):
    import json

    path = tmp_path / "q.yaml"
    path.write_text(TINY.replace("CELLS", "12") + "  max_pending: 2\n  urgency: {P1: 2.0}\n")
    r = cellplan("solve", str(path), "-o", str(tmp_path / "q.npz"))
    assert r.returncode == 0, r.stderr
    # Every policy runs through the API in the tests above; here the option's path, and
    # the frames and GIF once (drawing them is most of the time).
    for policy in ("optimal", "fcfs"):
        out = tmp_path / policy
        args = ["--strategy", str(tmp_path / "q.npz"), "--stages", "80", "--policy", policy]
        gif = ["--gif-size", "240"] if policy == "optimal" else ["--no-gif"]
        r = cellplan("simulate", str(path), *args, "-o", str(out), *gif)
        assert r.returncode == 0, r.stderr
        metrics = json.loads((out / "metrics.json").read_text())["metrics"]
        assert metrics["policy"] == policy and "mean_open" in metrics and "turned_away" in metrics
        assert (out / "trajectory.csv").exists() and (out / "frames.png").exists()
    assert (tmp_path / "optimal" / "simulation.gif").stat().st_size > 0
    r = cellplan("simulate", str(path), "--strategy", str(tmp_path / "q.npz"), "--policy", "home")
    assert r.returncode == 2
    assert "policy: must be one of optimal, fcfs, nearest, reactive" in r.stderr


def test_with_the_workcell_every_fmp_passes_the_exact_region_test():
    # simulate() with the workcell confirms each pick at its request's source and each
    # delivery at the carried request's destination, as the Section V simulator does.
    from cellplan.strategies.sim.simulate import simulate

    sc, cell = pending(2, 16)
    strategy = solved(sc, cell)
    for policy in ("optimal", "fcfs"):
        sim = simulate(
            strategy,
            1500,
            3,
            SimulationOptions(policy=policy, regions="contact"),
            cell=cell,
        )
        fmp = np.flatnonzero((sim.actions <= -2) & (sim.actions != -3))
        assert len(fmp) > 20
        for k in fmp:
            mode = strategy.mdp.modes[int(sim.modes[k])]
            q = sim.q[k][None, :]
            if mode.part:
                assert cell.in_region(q, mode.destination, "contact", None, mode.part)[0]
            else:
                sources = {w.split(",")[1] for w in mode.waiting}
                assert any(cell.in_region(q, s, "contact", None, None)[0] for s in sources)


def test_the_memory_estimate_counts_the_modes_and_options_of_simultaneous_requests(monkeypatch):
    # The planner refuses a grid that cannot fit before allocating; for simultaneous
    # requests the estimate must count their modes and FMP options, and policy iteration.
    import gc
    import tracemalloc

    from cellplan.strategies.model.memory import estimate_memory
    from cellplan.strategies.policy.strategy import solve_scenario

    sc, cell = pending(3, 40)
    solve_scenario(sc, cell)  # compile first
    factors = lu_entries(monkeypatch)
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        strategy, _ = solve_scenario(sc, cell)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    est = estimate_memory(sc, cell)
    assert est.modes == strategy.mdp.n_modes == sum(mode_counts(2, 3))
    assert est.method == "policy"
    # tracemalloc sees the arrays, not SuperLU's factors: those are checked on their own.
    assert 0.4 <= peak / (est.total - est.terms["factors"]) <= 1.35, (peak, dict(est.terms))
    assert 12 * max(factors) <= est.terms["factors"] <= 12 * 4 * max(factors)
    assert peak + 12 * max(factors) <= est.total

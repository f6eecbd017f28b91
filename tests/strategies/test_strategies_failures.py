"""Failure modes (Section VI-3 of the strategies paper): keys, model, solver, simulator, files.

The model: an FMP that fails with probability ``f`` is retried in place after a rework
time, or the part is carried to a reject region (an X mode) and then fetched again from
its source, or re-requested. The checks here: one clear line per mistake in
``strategy.failures``; the modes and FMP outcomes the scenario gives; the solved gain
against the Section V model (``f = 0``), growing with ``f``, and matched by simulation;
the simulated failure frequency against ``f``; strategy files that keep the outcomes and
refuse tampered ones.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from strategies_helpers import TINY, assert_validate_names, tiny, tiny_failures
from test_strategies_fileformat import _write, assert_refused, check_load, craft, solved_file

from cellplan.errors import PersistenceError
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.policy.strategy import Strategy, solve_scenario
from cellplan.strategies.sim.simulate import simulate
from cellplan.strategies.solve.solver import solve

BIN = (
    "  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}\n"
    "  R1: {components: [{type: box, min: [2, 25], max: [6, 28]}]}"
)
BASE = TINY.replace("CELLS", "12").replace(
    "  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}", BIN
)

# Each mistake gives exactly this line (field, then message) from `cellplan validate`.
MISTAKES = {
    "{region: D1, probability: 1.0, then: retry}": "strategy.failures[0].probability: must be "
    "below 1 (an FMP that always fails never serves its request)",
    "{region: D1, probability: 1.5, then: retry}": "strategy.failures[0].probability:",
    "{region: D1, probability: -0.1, then: retry}": "strategy.failures[0].probability:",
    "{region: D9, probability: 0.2, then: retry}": "strategy.failures[0].region: unknown source "
    "or destination 'D9'",
    "{region: D1, part: P7, probability: 0.2, then: retry}": "strategy.failures[0].part: unknown "
    "part 'P7'",
    "{region: D1, probability: 0.2, then: reject}": "strategy.failures[0].reject_region: then: "
    "reject needs a reject region",
    "{region: D1, probability: 0.2, then: reject, reject_region: R9}": "strategy.failures[0]."
    "reject_region: unknown region 'R9' (declare it under destinations)",
    "{region: D1, probability: 0.2, then: reject, reject_region: D1}": "strategy.failures[0]."
    "reject_region: is the region whose FMP fails",
    "{region: D1, probability: 0.2, then: retry, reject_region: R1}": "strategy.failures[0]."
    "reject_region: only with then: reject",
    "{region: D1, probability: 0.2, then: reject, reject_region: R1, rework: 2}": "strategy."
    "failures[0].rework: only with then: retry",
    "{region: D1, probability: 0.2, then: explode}": "strategy.failures[0].then:",
    "{region: R1, probability: 0.2, then: reject, reject_region: R1}": "strategy.failures[0]."
    "region: no request picks or delivers at 'R1'",
}


@pytest.mark.parametrize("spec", list(MISTAKES))
def test_each_mistake_is_one_line_naming_the_field(cellplan, tmp_path, spec):
    assert_validate_names(cellplan, tmp_path, BASE + f"  failures:\n    - {spec}\n", MISTAKES[spec])


def test_overlapping_entries_and_a_request_list_left_empty_are_refused(cellplan, tmp_path):
    path = tmp_path / "s.yaml"
    two = (
        "  failures:\n    - {region: D1, probability: 0.2, then: retry}\n"
        "    - {region: D1, part: P1, probability: 0.3, then: retry}\n"
    )
    path.write_text(BASE + two)
    r = cellplan("validate", str(path))
    assert r.returncode == 2
    assert "error: strategy.failures[1]: overlaps strategy.failures[0]" in r.stderr
    # Every destination a reject region: 'requests: all' leaves nothing to request.
    path.write_text(
        BASE
        + "  failures:\n    - {region: S1, probability: 0.2, then: reject, reject_region: D1}\n"
        "    - {region: S2, probability: 0.2, then: reject, reject_region: R1}\n"
    )
    r = cellplan("validate", str(path))
    assert r.returncode == 2
    assert "error: strategy.requests: 'all' leaves no request" in r.stderr


def test_validate_counts_the_failure_modes(cellplan):
    r = cellplan("validate", "strategies_failures")
    assert r.returncode == 0, r.stderr
    assert (
        "assembly modes: 21: 17 of Section III-A (8 requests) + 4 carrying a rejected part "
        "(Section VI-3)" in r.stdout
    )
    assert "failure modes: 8 of the 20 fine motions can fail" in r.stdout


def test_reject_modes_and_outcomes_follow_the_scenario():
    sc, cell = tiny_failures(0.3, "reject")
    mdp = build_model(sc, cell)
    labels = [m.label for m in mdp.modes]
    # 'requests: all' leaves the reject bin out; one X mode per request delivering at D1.
    assert labels == [
        "NR",
        "<P1,S1,D1,W>",
        "<P1,S2,D1,W>",
        "<P1,S1,D1,C>",
        "<P1,S2,D1,C>",
        "<P1,S1,D1,X:R1>",
        "<P1,S2,D1,X:R1>",
    ]
    out = mdp.fmp_outcomes()
    assert not mdp.is_simple()

    def outcomes(m):
        sl = slice(out.ptr[m], out.ptr[m + 1])
        cols = (out.layer[sl].tolist(), out.prob[sl].tolist(), out.cost[sl].tolist())
        return list(zip(*cols, strict=True))

    assert outcomes(0) == []
    assert outcomes(1) == [(3, 1.0, 0.0)]  # picks never fail here
    assert outcomes(3) == [(0, 0.7, 0.0), (5, 0.3, 0.0)]  # delivered, or rejected
    assert outcomes(5) == [(1, 1.0, 0.0)]  # dropped in R1, then fetched again from S1
    # The X mode carries the part (its move class is the C mode's) and drops it in R1 only.
    assert mdp.vcls[5] == mdp.vcls[3]
    drops = np.isfinite(mdp.tf[5])
    assert drops.any() and not (drops & np.isfinite(mdp.tf[3])).any()
    # A re-request: the W modes of the requests for the same part and destination.
    sc, cell = tiny_failures(0.3, "request")
    out = build_model(sc, cell).fmp_outcomes()
    assert out.layer[out.ptr[5] : out.ptr[6]].tolist() == [1, 2]
    assert out.prob[out.ptr[5] : out.ptr[6]].tolist() == [0.5, 0.5]


def test_the_variant_names_the_events_the_simulator_records():
    # The simulation hook of the failures variant (variants/failures.py: fmp_event) gives
    # the events of sim/simulate.py: a failed delivery, a rejected part dropped.
    from cellplan.strategies.variants.failures import FAILURES

    sc, cell = tiny_failures(0.3, "reject")
    mdp = build_model(sc, cell)
    assert [v.name for v in mdp.variants] == ["failures"] and FAILURES.in_model(mdp)
    out = mdp.fmp_outcomes()
    assert FAILURES.fmp_event(mdp, 1, out.ptr[1]) is None  # a pick
    assert FAILURES.fmp_event(mdp, 3, out.ptr[3]) is None  # a delivery
    failed = FAILURES.fmp_event(mdp, 3, out.ptr[3] + 1)
    assert failed is not None and (failed.kind, failed.detail) == (
        "fmp_failed",
        "P1 at D1, reject to R1",
    )
    dropped = FAILURES.fmp_event(mdp, 5, out.ptr[5])
    assert dropped is not None and (dropped.kind, dropped.detail) == ("reject", "P1 at R1")
    sc, cell = tiny_failures(0.25, "retry")
    mdp = build_model(sc, cell)
    out = mdp.fmp_outcomes()
    c = [m.label for m in mdp.modes].index("<P1,S1,D1,C>")
    assert out.layer[out.ptr[c] + 1] == c  # the retry: the same mode again
    retry = FAILURES.fmp_event(mdp, c, out.ptr[c] + 1)
    assert retry is not None and (retry.kind, retry.detail) == ("fmp_failed", "P1 at D1, retry")


def test_retry_in_place_is_an_outcome_into_the_same_mode_at_the_rework_cost():
    sc, cell = tiny_failures(0.25, "retry")
    mdp = build_model(sc, cell)
    out = mdp.fmp_outcomes()
    c = next(i for i, m in enumerate(mdp.modes) if m.label == "<P1,S1,D1,C>")
    sl = slice(out.ptr[c], out.ptr[c + 1])
    assert out.layer[sl].tolist() == [0, c]
    assert out.prob[sl].tolist() == [0.75, 0.25]
    assert out.cost[sl].tolist() == [0.0, 2.0]
    assert all(m.kind != "X" for m in mdp.modes)


def _gain(then: str, f: float) -> float:
    sc, cell = tiny_failures(f, then)
    result = solve(build_model(sc, cell))
    assert result.converged
    return result.gain


@pytest.mark.parametrize("then", ["reject", "retry"])
def test_the_gain_grows_with_the_failure_rate_from_the_section_v_gain(then):
    sc, cell = tiny(cells=12)
    plain = solve(build_model(sc, cell)).gain
    gains = [_gain(then, f) for f in (0.0, 0.2, 0.4, 0.6)]
    if then == "reject":  # without failures the reject bin is no request: Section V's model
        assert gains[0] == pytest.approx(plain, abs=2e-6)
    assert np.all(np.diff(gains) > 1e-3), gains


def test_simulation_matches_the_gain_and_the_failure_rate():
    f = 0.4
    sc, cell = tiny_failures(f, "reject")
    strategy, result = solve_scenario(sc, cell)
    sim = simulate(strategy, 40000, 7, cell=cell)
    # Batch means over 20 batches of 2,000 stages: the gain lies within 4 standard errors.
    batches = sim.losses.reshape(20, -1).mean(axis=1)
    se = batches.std(ddof=1) / np.sqrt(len(batches))
    assert abs(batches.mean() - result.gain) < 4 * se, (batches.mean(), result.gain, se)
    # Failed deliveries at D1: binomial count within 4 standard deviations of n f.
    failed = sum(1 for _, kind, d in sim.events if kind == "fmp_failed" and "at D1" in d)
    placed = sum(1 for _, kind, _ in sim.events if kind == "place")
    rejected = sum(1 for _, kind, _ in sim.events if kind == "reject")
    n = failed + placed
    assert n > 300
    assert abs(failed - n * f) < 4 * np.sqrt(n * f * (1 - f)), (failed, n)
    # Every rejected part is dropped in R1 (at most one still on its way at the end).
    assert failed - 1 <= rejected <= failed
    assert sim.metrics()["fmp_failures"] == failed


def test_idle_robot_waits_where_it_waits_without_failures():
    # Where the idle robot waits (the cells where NR's relative value is within 1e-4 of its
    # minimum) does not move with delivery failures: after a failure the robot is at the
    # destination, not idle, so failures add to the cost of the requests delivering there
    # but not to how far the next source is (docs/strategies.md, "Failure modes").
    waits = []
    for f in (0.0, 0.6):
        sc, cell = tiny_failures(f, "reject", cells=16)
        h = solve(build_model(sc, cell)).values[0]
        waits.append(set(np.flatnonzero(h < np.nanmin(h) + 1e-4).tolist()))
    assert waits[0] == waits[1]
    assert len(waits[0]) == 2  # the two mirror cells of the symmetric workcell


def test_strategy_file_keeps_the_outcomes_and_loads_for_simulate(tmp_path):
    sc, cell = tiny_failures(0.3, "reject")
    strategy, _ = solve_scenario(sc, cell)
    path = strategy.save(tmp_path / "f.npz")
    back = Strategy.load(path, sc)
    a, b = strategy.mdp.fmp_outcomes(), back.mdp.fmp_outcomes()
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert [m.label for m in back.mdp.modes] == [m.label for m in strategy.mdp.modes]
    assert back.mode_index("<P1,S2,D1,X:R1>") == 6
    np.testing.assert_array_equal(back.values, strategy.values)


@pytest.fixture(scope="module")
def failure_base(tmp_path_factory):
    """A solved strategy file of the bundled arm scenario with failures."""
    return solved_file("strategies_failures_arm", tmp_path_factory.mktemp("fbase"))


@pytest.mark.parametrize(
    ("field", "index", "value", "words"),
    [
        ("out_prob", 2, 0.5, "out_prob: the FMP outcomes of a mode do not sum to 1"),
        ("out_layer", 0, 0, "out_layer: the first outcome"),
        ("out_layer", 4, 2, "out_layer: mode 3 has an FMP outcome"),
        ("out_ptr", 1, 1, "out_ptr: NR has no FMP"),
        ("out_cost", 3, np.inf, "out_cost"),
    ],
)
def test_tampered_outcomes_are_named(failure_base, tmp_path, field, index, value, words):
    change = lambda a: a[field].reshape(-1).__setitem__(index, value)  # noqa: E731
    assert_refused(failure_base, tmp_path, change, words)


@pytest.mark.parametrize("version", [1, 2, 3])
def test_an_older_version_is_refused_with_a_line_that_says_so(failure_base, tmp_path, version):
    setup, _, arrays, meta = failure_base
    meta = dict(meta, version=version)
    path = _write(tmp_path / "old.npz", arrays, meta, True)
    words = rf"version {version} \(an older cellplan\); solve the scenario again to write version 4"
    with pytest.raises(PersistenceError, match=words):
        Strategy.load(path, setup.scenario)


def test_the_untouched_failure_file_loads_and_simulates(failure_base):
    setup, path, _, _ = failure_base
    assert check_load(path, setup) == "accepted"


@settings(
    max_examples=25,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_crafted_failure_files_are_refused_cleanly_or_usable(data, failure_base, tmp_path):
    _, path = craft(data, failure_base, tmp_path)
    check_load(path, failure_base[0])


def test_quick_failure_experiment_reports_three_claims(tmp_path):
    from cellplan.strategies.experiments.failure_experiment import SCALES
    from cellplan.strategies.experiments.paper import EXPERIMENTS

    exp = next(e for e in EXPERIMENTS if e.name == "strategies.failures")
    specs = exp.make_runs(2, True)
    assert len(specs) == 2 * len(SCALES)
    for s in specs:  # shorter runs: this checks the plumbing, not the verdicts
        s.params["stages"] = 400
    rows = [exp.run(s) for s in specs]
    assert rows[0] == exp.run(specs[0])  # a pure function of its spec
    gains = sorted({(float(r["scale"]), float(r["gain"])) for r in rows})
    assert [s for s, _ in gains] == list(SCALES)
    assert np.all(np.diff([g for _, g in gains]) > 0)
    piece = exp.report(rows, tmp_path)
    assert piece.figures and all(p.exists() for p in piece.figures)
    assert [c.claim.split(": ", 1)[1] for c in piece.claims] == [
        "the simulated loss per stage agrees with the solved gain",
        "under failures the optimal strategy makes parts wait less than the reactive one",
        "the waiting per stage grows with the failure rate",
    ]
    # Two seeds are too few to decide the interval claims.
    assert piece.claims[0].reproduced is None and piece.claims[1].reproduced is None
    assert all(c.explanation.endswith("#failure-modes-section-vi-3") for c in piece.claims)

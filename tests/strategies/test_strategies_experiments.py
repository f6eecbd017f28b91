"""The anticipation experiment (quick version) runs, reports, and states its claim."""

from __future__ import annotations

from dataclasses import replace

from strategies_helpers import TINY

from cellplan.core import Claim, Experiment
from cellplan.strategies.experiments.paper import (
    BEHAVIOURS,
    EXPERIMENTS,
    PROBLEMS,
    QUICK_BEHAVIOURS,
    behaviour_claims,
)


def test_quick_anticipation_experiment(tmp_path):
    exp = EXPERIMENTS[0]
    assert isinstance(exp, Experiment) and exp.paper == "strategies"
    specs = exp.make_runs(2, True)
    assert [s.seed for s in specs] == [0, 1]
    rows = [exp.run(s) for s in specs]
    assert rows[0] == exp.run(specs[0])  # a pure function of its spec
    piece = exp.report(rows, tmp_path)
    assert piece.figures and all(p.exists() for p in piece.figures)
    assert len(piece.claims) == 1 and piece.tables[0][1][0]["runs"] == 2
    for policy in ("optimal", "reactive", "home"):
        assert rows[0][f"{policy}_served"] > 0


def test_full_runs_cover_every_solvable_bundled_problem():
    specs = EXPERIMENTS[0].make_runs(3, False)
    assert {s.params["problem"] for s in specs} == set(PROBLEMS)
    assert len(specs) == 3 * len(PROBLEMS)


def test_behaviour_runs_cover_every_listed_behaviour():
    exp = EXPERIMENTS[1]
    full = exp.make_runs(10, False)
    assert {s.params["problem"] for s in full} == {b.problem for b in BEHAVIOURS}
    quick = exp.make_runs(2, True)
    assert {s.params["problem"] for s in quick} == set(QUICK_BEHAVIOURS)
    assert all(s.params["cells"] == PROBLEMS[s.params["problem"]] for s in full)


def test_every_behaviour_of_the_summary_is_a_claim(tmp_path):
    # The paper's summary lists six behaviours; the report checks each one.
    rows = [
        {"problem": b.problem, "seed": 0, "cells": PROBLEMS[b.problem], "starts": 5, b.key: 0.9}
        for b in BEHAVIOURS
    ]
    claims = behaviour_claims(rows)
    assert len(claims) == len(BEHAVIOURS) == 6
    assert all(isinstance(c, Claim) and c.n == 1 and c.reproduced is None for c in claims)
    assert all("95% interval" in c.rule and c.explanation.startswith("docs/") for c in claims)


def _rows(values, key="p2_nearer", problem="strategies_p2"):
    return [
        {"problem": problem, "seed": s, "cells": "48,48", "starts": 40, key: v}
        for s, v in enumerate(values)
    ]


def test_behaviour_verdicts_follow_the_interval():
    by_key = {b.key: b for b in BEHAVIOURS}
    yes = behaviour_claims(_rows([0.8, 0.85, 0.9, 0.82, 0.88]))
    no = behaviour_claims(_rows([0.2, 0.25, 0.3, 0.22, 0.28]))
    few = behaviour_claims(_rows([0.8, 0.9]))
    i = list(by_key).index("p2_nearer")
    assert (yes[i].reproduced, no[i].reproduced, few[i].reproduced) == (True, False, None)
    assert yes[i].n == 5 and few[i].n == 2
    # Behaviours without rows are stated as not measured, never as reproduced.
    others = [c for j, c in enumerate(yes) if j != i]
    assert all(c.reproduced is None and c.n == 0 and "not measured" in c.ours for c in others)


def test_quick_behaviours_report(tmp_path):
    exp = EXPERIMENTS[1]
    specs = [s for s in exp.make_runs(1, True) if s.params["problem"] == "strategies_p2"]
    rows = [{**s.params, "seed": s.seed, **exp.run(s)} for s in specs]
    piece = exp.report(rows, tmp_path)
    assert len(piece.claims) == len(BEHAVIOURS)
    (figure,) = piece.figures
    assert figure.exists()
    caption = piece.captions[figure.name]
    assert "1 seed " in caption and "P2 48 x 48" in caption and "40 random starts" in caption


# --- fast twins of the Section VI experiments' quick tests -----------------------------------
# Each runs the experiment's own run() and report() on a tiny scenario in place of the
# bundled one (the module's PROBLEM), so the code is the same and the solve takes a second.

# The tiny workcell with S1 on a belt and requests in two phases of eight (Section VI-1).
TINY_BELT = """  period: 8
  arrival_profile: [3, 3, 0, 0, 0, 0, 0, 0]
  belts:
    S1: {velocity: [1.5, 0]}
"""

# The tiny workcell with a second part from S2, three times as urgent, and up to two open
# requests (Section VI-2); arrivals rare enough that the robot keeps up.
TINY_P1 = "  P1: {shape: {type: box, min: [-2, -0.5], max: [2, 0.5]}}\n"
TINY_PENDING = """  requests:
    - {part: P1, source: S1, destination: D1}
    - {part: P2, source: S2, destination: D1}
  max_pending: 2
  urgency: {P2: 3.0}
"""


def _tiny_runs(module, monkeypatch, path, text, stages):
    """The quick runs of ``module``'s experiment on the tiny scenario ``text``."""
    path.write_text(text)
    monkeypatch.setattr(module, "PROBLEM", str(path))
    quick = module.EXPERIMENT.make_runs(2, True)
    return [replace(s, params={**s.params, "cells": "12,12", "stages": stages}) for s in quick]


def test_conveyor_experiment_on_a_tiny_belt(tmp_path, monkeypatch):
    # Fast twin of test_strategies_periodic.py::test_quick_conveyor_experiment_reports_
    # three_claims (slow, the bundled conveyor at 40 x 40): the same checks.
    from cellplan.strategies.experiments import conveyor_experiment as module

    quick = module.EXPERIMENT.make_runs(2, True)
    assert [(s.seed, s.params["cells"], s.params["stages"]) for s in quick] == [
        (0, module.CELLS, 4000),
        (1, module.CELLS, 4000),
    ]
    text = TINY.replace("CELLS", "12") + TINY_BELT
    specs = _tiny_runs(module, monkeypatch, tmp_path / "belt.yaml", text, 1000)
    rows = [module.EXPERIMENT.run(s) for s in specs]
    for r in rows:
        assert r["optimal_distance"] < r["reactive_distance"]
        assert r["period"] == 8 and r["layers"] > 8
    piece = module.EXPERIMENT.report(rows, tmp_path)
    assert len(piece.claims) == 3 and all(p.exists() for p in piece.figures)
    assert all(c.n == 2 and c.reproduced is None for c in piece.claims)  # too few seeds


def test_pending_experiment_on_two_tiny_request_types(tmp_path, monkeypatch):
    # Fast twin of test_strategies_pending.py::test_quick_pending_experiment_reports_
    # three_claims (slow, the bundled scenario at 50 x 50): the same checks.
    from cellplan.strategies.experiments import pending_experiment as module

    quick = module.EXPERIMENT.make_runs(2, True)
    assert {s.params["cells"] for s in quick} == {module.QUICK_CELLS}
    text = TINY.replace("CELLS", "12").replace("probability: 0.1", "probability: 0.02")
    text = text.replace(TINY_P1, TINY_P1 + TINY_P1.replace("P1", "P2")) + TINY_PENDING
    specs = _tiny_runs(module, monkeypatch, tmp_path / "pending.yaml", text, 3000)
    rows = [module.EXPERIMENT.run(s) for s in specs]
    for r in rows:
        assert r["optimal_arrivals"] == r["fcfs_arrivals"] == r["nearest_arrivals"]
        assert r["optimal_wait_P2"] < r["optimal_wait_P1"]  # the urgent part waits less
    piece = module.EXPERIMENT.report(rows, tmp_path)
    assert len(piece.claims) == 3 and all(p.exists() for p in piece.figures)
    assert all(c.n == 2 and c.reproduced is None for c in piece.claims)  # too few seeds


def test_noise_report_decides_its_claims_on_made_up_rows(tmp_path):
    # The noise experiment's runs are slow (test_strategies_noise.py, marked slow); its
    # report is checked here on rows where each claim's answer is plain: noisy clearance
    # 0.5 larger on every seed, loss equal to the gain, optimal waiting 20% below reactive.
    from cellplan.strategies.experiments.noise_experiment import EXPERIMENT

    rows = [
        {
            "seed": s,
            "cells": "64,64",
            "stages": 1500,
            "noisy_gain": 0.6,
            "exact_gain": 0.5,
            "noisy_states": 100,
            "exact_states": 100,
            "noisy_passage_moves": 60,
            "exact_passage_moves": 70,
            "noisy_passage_clearance": 2.0 + 0.01 * s,
            "exact_passage_clearance": 1.5 + 0.02 * s,
            "noisy_near_misses": 0.01,
            "exact_near_misses": 0.05,
            "noisy_optimal_loss_per_stage": 0.6 + 0.001 * (s - 2),
            "noisy_optimal_mean_wait_all": 8.0 + 0.1 * s,
            "noisy_reactive_loss_per_stage": 0.8,
            "noisy_reactive_mean_wait_all": 10.0 + 0.1 * s,
            "exact_optimal_loss_per_stage": 0.5,
            "exact_optimal_mean_wait_all": 7.0,
        }
        for s in range(5)
    ]
    piece = EXPERIMENT.report(rows, tmp_path)
    assert [c.reproduced for c in piece.claims] == [True, True, True]
    assert all(c.n == 5 for c in piece.claims) and all(p.exists() for p in piece.figures)
    assert "over 5 seeds" in piece.captions[piece.figures[0].name]
    assert "Runs of 1500 stages on 64 x 64 grids" in piece.captions[piece.figures[0].name]
    few = EXPERIMENT.report(rows[:2], tmp_path)
    assert all(c.reproduced is None for c in few.claims)  # too few seeds

"""The anticipation experiment (quick version) runs, reports, and states its claim."""

from __future__ import annotations

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

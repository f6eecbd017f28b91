"""The anticipation experiment (quick version) runs, reports, and states its claim."""

from __future__ import annotations

from cellplan.core import Experiment
from cellplan.strategies.experiments import EXPERIMENTS, PROBLEMS


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

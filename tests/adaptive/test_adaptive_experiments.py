from __future__ import annotations

from pathlib import Path

from cellplan.adaptive.experiments import EXPERIMENTS, curves
from cellplan.core import RunSpec


def test_quick_fig5_runs_and_reports(tmp_path: Path) -> None:
    exp = EXPERIMENTS[0]
    specs = exp.make_runs(1, True)
    # the quick version (the demo's) leaves the PRM peer out; the full one runs it
    assert {s.params["planner"] for s in specs} == {"A0", "A1", "A2", "A3"}
    assert "prm" in {s.params["planner"] for s in exp.make_runs(1, False)}
    chosen = [s for s in specs if s.params["planner"] in ("A0", "A3")]
    rows = [exp.run(s) for s in chosen]
    assert all(r["paths_ok"] == r["solved"] == 16 for r in rows)
    ratio, tasks = curves(rows)
    assert tasks == 16 and set(ratio) == {"A0", "A3"}
    # identical before the change (same seed, same planner), A0 forgets after it
    assert ratio["A0"][7] == ratio["A3"][7]
    assert ratio["A0"][-1] >= ratio["A3"][-1]
    piece = exp.report(rows, tmp_path)
    assert piece.claims and Path(piece.figures[0]).stat().st_size > 0
    caption = piece.captions[Path(piece.figures[0]).name]
    assert "after each of 16 tasks" in caption and "A0 1, A3 1" in caption


def test_runs_are_pure_functions_of_the_spec() -> None:
    spec = RunSpec("adaptive.fig5", {"planner": "A3", "tasks": 6, "change_after": 3}, 4)
    assert EXPERIMENTS[0].run(spec) == EXPERIMENTS[0].run(spec)


def test_per_seed_ratios_and_their_interval():
    import numpy as np

    from cellplan.adaptive.experiments import _interval, seed_ratios

    rows = [
        {"planner": "A3", "seed": s, "a001": 10.0 + s, "a002": 12.0, "b001": 5.0, "b002": 24.0}
        for s in range(5)
    ] + [{"planner": "prm", "seed": 0, "a001": 1.0, "a002": 2.0}]
    ratios = seed_ratios(rows, "A3", 2)
    assert ratios.shape == (5, 2)
    assert np.allclose(ratios[:, 1], 0.5) and np.allclose(ratios[:, 0], (10 + np.arange(5)) / 5)
    lo, hi = _interval(ratios[:, 0])
    assert lo < ratios[:, 0].mean() < hi

from __future__ import annotations

from pathlib import Path

from cellplan.adaptive.experiments import EXPERIMENTS, curves
from cellplan.core import RunSpec


def test_quick_fig5_runs_and_reports(tmp_path: Path) -> None:
    exp = EXPERIMENTS[0]
    specs = exp.make_runs(1, True)
    assert {s.params["planner"] for s in specs} == {"A0", "A1", "A2", "A3", "prm"}
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


def test_runs_are_pure_functions_of_the_spec() -> None:
    spec = RunSpec("adaptive.fig5", {"planner": "A3", "tasks": 6, "change_after": 3}, 4)
    assert EXPERIMENTS[0].run(spec) == EXPERIMENTS[0].run(spec)

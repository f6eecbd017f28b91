"""The UR5 Figure 5 experiment's report: its claims decided on synthetic rows whose
answers are known (the planning itself is covered by tests/adaptive/test_arms.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellplan.adaptive.experiments3d import STRATEGIES, make_runs, report, summarise


def synthetic_rows(n: int, a3_post: float, others_post: float) -> list[dict]:
    """``n`` seeds of 8 tasks (change after 4): Solve alone costs 100 per task; every
    strategy 10 per task before the change, then A3 ``a3_post`` and the others
    ``others_post`` per 100, with a little seed-to-seed noise."""
    rng = np.random.default_rng(0)
    rows = []
    for seed in range(n):
        row: dict = {"seed": seed, "tasks": 8, "change_after": 4}
        for s in STRATEGIES:
            after = a3_post if s == "A3" else others_post
            for t in range(1, 9):
                row[f"{s}_{t:03d}"] = (10.0 if t <= 4 else after) + rng.uniform(0, 0.5)
            row[f"{s}_solved"] = row[f"{s}_executed"] = row[f"{s}_paths_ok"] = 8
            row[f"{s}_solve_calls"] = 1
        for t in range(1, 9):
            row[f"b_{t:03d}"] = 100.0
        rows.append(row)
    return rows


def verdicts(rows: list[dict], tmp_path: Path) -> list:
    return [c.reproduced for c in report(rows, tmp_path).claims]


def test_claims_are_reproduced_when_a3_is_lowest(tmp_path: Path) -> None:
    rows = synthetic_rows(6, a3_post=20.0, others_post=40.0)
    sm = summarise(rows)
    np.testing.assert_allclose(sm["curves"]["A3"][3], 0.1, atol=0.01)
    assert verdicts(rows, tmp_path) == [True, True, True]


def test_a3_clearly_worse_after_the_change_differs(tmp_path: Path) -> None:
    rows = synthetic_rows(6, a3_post=60.0, others_post=20.0)
    assert verdicts(rows, tmp_path)[1] is False


def test_too_few_seeds_leave_every_claim_undecided(tmp_path: Path) -> None:
    assert verdicts(synthetic_rows(3, 20.0, 40.0), tmp_path) == [None, None, None]


def test_a_path_failing_the_recheck_differs(tmp_path: Path) -> None:
    rows = synthetic_rows(6, 20.0, 40.0)
    rows[2]["A1_paths_ok"] = 7
    assert verdicts(rows, tmp_path)[2] is False


def test_one_run_per_seed() -> None:
    runs = make_runs(20, quick=False)
    assert [r.seed for r in runs] == list(range(20))
    assert runs[0].params == {"tasks": 80, "change_after": 40}

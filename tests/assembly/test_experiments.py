"""The assembly experiments in their quick form: parameters reach the runs, reports read them."""

from __future__ import annotations

from pathlib import Path

from cellplan.assembly import experiments as ex
from cellplan.core import RunSpec, Scalar


def _rows(specs: list[RunSpec]) -> list[dict[str, Scalar]]:
    # what the runner stores per run: the parameters, the seed, the run's own row
    return [
        {**spec.params, "seed": spec.seed, "run_status": "ok", **ex.run(spec)} for spec in specs
    ]


def test_sensitivity_spreads_the_starts_and_reports_per_fill(tmp_path: Path) -> None:
    specs = ex._runs_sensitivity(2, quick=True)
    cells = {(s.params["fill"], s.params["start_gap"]) for s in specs}
    assert cells == {(0.05, 0.05), (0.0125, 0.05), (0.05, 1.0)}
    rows = _rows(specs)
    assert all(r["solved"] for r in rows)

    def straight(fill: float, seed: int) -> float:
        (r,) = [
            r for r in rows if r["fill"] == fill and r["start_gap"] == 0.05 and r["seed"] == seed
        ]
        return float(r["length"]) / float(r["ratio"])

    # a quarter of the fill is a workspace twice as wide: the same seed starts about
    # twice as far out
    assert all(straight(0.0125, s) > 1.5 * straight(0.05, s) for s in (0, 1))
    piece = ex._report_sensitivity(rows, tmp_path)
    ((_, table),) = piece.tables
    assert len(table) == 3 and all("solved at k" in row for row in table)
    assert all(Path(f).is_file() for f in piece.figures)
    assert len(piece.claims) == 1
    _captions_from_the_runs(piece, rows)


def test_ratio_vs_k_reports_the_flow_at_k_beside_the_escape(tmp_path: Path) -> None:
    rows = _rows(ex._runs_ratio_vs_k(2, quick=True))
    assert all("solved_at_k" in r and "escapes" in r for r in rows)
    piece = ex._report_ratio_vs_k(rows, tmp_path)
    labels = [c.claim for c in piece.claims]
    assert any("the flow at k alone" in c for c in labels)
    assert any("k lowered when stuck" in c for c in labels)
    ((_, table),) = piece.tables
    assert {"solved", "solved at k", "mean (solved at k)"} <= set(table[0])
    _captions_from_the_runs(piece, rows)


def test_sequential_reports_escapes_and_both_switch_claims(tmp_path: Path) -> None:
    rows = _rows(ex._runs_sequential(2, quick=True))
    paper = [r for r in rows if r["rule"] == "paper"]
    assert paper and all({"solved_at_k", "escapes", "k_final"} <= set(r) for r in paper)
    # the place rule never lowers k
    assert all(r["escapes"] == 0.0 for r in rows if r["rule"] == "place")
    piece = ex._report_sequential(rows, tmp_path)
    claims = {c.claim: c for c in piece.claims}
    assert "paper rule: about three switches per disc on easy goals" in claims
    rising = claims["paper rule: harder goals need more switches"]
    assert "easy -> hard" in rising.ours
    assert all(Path(f).is_file() for f in piece.figures)
    _captions_from_the_runs(piece, rows)


def _captions_from_the_runs(piece, rows) -> None:
    """Every figure has a caption naming the disc count and the runs behind it, and no text
    speaks of a disc count that was not run (the quick runs use 3 or 5 discs)."""
    import re

    ns = {int(r["n"]) for r in rows}
    assert piece.figures and set(piece.captions) == {Path(f).name for f in piece.figures}
    for caption in piece.captions.values():
        assert any(f"{n} discs" in caption for n in ns)
        assert re.search(r"\d+ runs \(\d+ solved\) over \d+ seeds?", caption)
    said = {
        int(m)
        for text in (piece.text, *piece.captions.values())
        for m in re.findall(r"(\d+)(?: and \d+)? discs", text)
    }
    assert said <= ns


def test_claim_intervals_and_their_combination():
    import numpy as np
    from scipy.stats import t

    from cellplan.assembly.experiments import _all, _difference, _interval, _ratio_interval
    from cellplan.core import mean_interval

    vals = np.array([1.1, 1.2, 1.3, 1.2, 1.2])
    group = {
        "mean": vals.mean(),
        "std": vals.std(),
        "half": mean_interval(vals)[1],  # as _group keeps it
        "solved": 5.0,
        "runs": 5.0,
    }
    lo, hi, n = _interval(group)
    half = t.ppf(0.975, 4) * vals.std(ddof=1) / np.sqrt(5)
    assert n == 5 and np.isclose(lo, vals.mean() - half) and np.isclose(hi, vals.mean() + half)
    other = {**group, "mean": group["mean"] + 1.0}
    lo, hi, n = _difference(other, group)
    assert lo > 0.9 and hi < 1.1 and n == 5
    lo, hi, _ = _ratio_interval(other, group)
    assert lo < other["mean"] / group["mean"] < hi
    assert _all([True, True]) is True
    assert _all([True, None]) is None
    assert _all([None, False]) is False
    assert _all([]) is None

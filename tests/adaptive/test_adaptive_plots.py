"""The adaptive pictures a stranger can read (issue 34): costs on a linear axis with
Adapt and Solve alone side by side, shorthand spelt out, labels and legends everywhere."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cellplan.plots
from cellplan.adaptive import plots

KEYS = ("reach", "trace", "solve", "abstract", "cut", "repair")


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    kept: dict[str, Any] = {}
    save = cellplan.plots.save_figure

    def spy(fig: Any, path: Path, dpi: int = 110) -> Path:
        kept[Path(path).name] = fig
        return save(fig, path, dpi)

    monkeypatch.setattr(cellplan.plots, "save_figure", spy)
    return kept


def _legend_texts(fig: Any) -> list[str]:
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend()] + list(fig.legends)
    return [t.get_text() for leg in legends for t in leg.get_texts()]


def test_cost_split_is_linear_with_adapt_beside_solve_alone(
    figures: dict[str, Any], tmp_path: Path
) -> None:
    rows = [
        {"task": t, **{k: 10.0 * (i + 1) for i, k in enumerate(KEYS)}, "baseline": 500.0 + t}
        for t in range(1, 6)
    ]
    plots.save_cost_split(rows, tmp_path / "costs.png")
    ax = figures["costs.png"].axes[0]
    assert ax.get_yscale() == "linear"
    # each task: the stack of Adapt's parts left of the task, Solve alone right of it
    bars = [p for c in ax.containers for p in c.patches]
    solve_alone = [p for c in ax.containers if c.get_label() == "Solve only" for p in c.patches]
    assert len(solve_alone) == len(rows)
    for t, bar in enumerate(solve_alone, start=1):
        assert bar.get_x() >= t - 1e-9 and bar.get_height() == 500.0 + t
    adapt_tops: dict[int, float] = {}
    for p in bars:
        if p not in solve_alone:
            assert p.get_x() + p.get_width() <= round(p.get_x() + 0.5) + 1e-9  # left of the task
            key = round(p.get_x() + 0.5)
            adapt_tops[key] = max(adapt_tops.get(key, 0.0), p.get_y() + p.get_height())
    assert all(np.isclose(v, 210.0) for v in adapt_tops.values())  # 10+20+...+60, stacked
    assert ax.get_xlabel() and "collision checks" in ax.get_ylabel()
    title = ax.get_title()
    assert "Reach" in title and "corner cutting" in title and "Repair" in title


def test_ratio_curves_spell_out_the_strategies(figures: dict[str, Any], tmp_path: Path) -> None:
    curves = {s: np.linspace(2.0, 0.5, 10) for s in ("A0", "A3", "rrtconnect")}
    plots.save_ratio_curves(curves, tmp_path / "ratio.png", change_after=[4, 40])
    fig = figures["ratio.png"]
    texts = _legend_texts(fig)
    assert "A3: repair G on demand" in texts and "A0: forget G after a change" in texts
    assert "workcell change" in texts and "equal cost (ratio 1)" in texts
    ax = fig.axes[0]
    assert ax.get_xlabel() == "task number" and "no unit" in ax.get_ylabel()
    # the change after the last task is not drawn (it would stretch the axis)
    assert ax.get_xlim()[1] < 20

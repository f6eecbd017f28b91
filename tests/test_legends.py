"""Legends where colours or markers carry meaning (checked on the matplotlib objects)."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

import cellplan.plots


@pytest.fixture
def saved(monkeypatch):
    """Each figure ``save_figure`` writes, drawn and kept open, by file name."""
    figures = {}
    save = cellplan.plots.save_figure

    def spy(fig, path, dpi=110):
        fig.canvas.draw()
        figures[path.name] = (fig, fig.get_window_extent())
        figures[path.name + ":legends"] = [
            (leg, leg.get_window_extent()) for ax in fig.axes for leg in [ax.get_legend()] if leg
        ] + [(leg, leg.get_window_extent()) for leg in fig.legends]
        return save(fig, path, dpi)

    monkeypatch.setattr(cellplan.plots, "save_figure", spy)
    return figures


def _labels(saved, name):
    return [t.get_text() for leg, _ in saved[name + ":legends"] for t in leg.get_texts()]


def test_experience_graph_snapshots_explain_edges_and_vertices(saved, tmp_path):
    from cellplan.adaptive.graph import FREE, UNKNOWN, ExperienceGraph
    from cellplan.adaptive.plots import save_snapshots
    from cellplan.adaptive.runner import Snapshot
    from cellplan.api import load

    cell = load("adaptive_fig3").workcell
    g = ExperienceGraph()
    start = np.asarray(cell.robot.start, float)
    a, b = g.add_vertex(start), g.add_vertex(start + 0.2, obj=None)
    c = g.add_vertex(start - 0.2)
    g.set_edge(a, b, FREE, 0)
    g.set_edge(b, c, UNKNOWN, 0)
    snap = Snapshot(1, g, cell, start, {"g1": (10.0, 10.0)}, None)
    save_snapshots([snap, snap], tmp_path / "snapshots.png")
    labels = _labels(saved, "snapshots.png")
    for expected in (
        "edge of G, known free",
        "edge of G, not yet checked",
        "subgoal attached to an object",
        "subgoal fixed in the world",
        "goal (named)",
    ):
        assert expected in labels
    fig, _ = saved["snapshots.png"]
    ((_legend, box),) = saved["snapshots.png:legends"]
    # Below the panels, not over them.
    assert all(box.y1 <= ax.get_window_extent().y0 + 1 for ax in fig.axes if ax.axison)


def test_cost_split_legend_stays_outside_the_data(saved, tmp_path):
    from cellplan.adaptive.plots import save_cost_split

    keys = ("reach", "trace", "solve", "abstract", "cut", "repair")
    rows = [{"task": t, **{k: 50.0 + t for k in keys}, "baseline": 400.0} for t in range(1, 81)]
    save_cost_split(rows, tmp_path / "costs.png")
    assert set(_labels(saved, "costs.png")) == {*keys, "Solve only"}
    fig, _ = saved["costs.png"]
    ((_legend, box),) = saved["costs.png:legends"]
    assert box.x0 >= fig.axes[0].get_window_extent().x1  # right of the plotting area


def test_assembly_sequence_names_discs_goals_and_paths(saved, tmp_path):
    from cellplan import api
    from cellplan.assembly.plots import save_sequence

    result = api.plan(api.load("discs_swap"), "assembly.gradient")
    run = result.solution
    save_sequence(run.problem, run.path, tmp_path / "sequence.png", "gradient")
    labels = _labels(saved, "sequence.png")
    assert [f"disc {i + 1}" for i in range(run.problem.n)] == labels[: run.problem.n]
    assert any(label.startswith("goal") for label in labels) and "path so far" in labels
    fig, _ = saved["sequence.png"]
    assert fig.get_suptitle() == f"gradient, {run.problem.n} discs"
    titles = [ax.get_title() for ax in fig.axes]
    assert titles[0] == f"(i) step 0 of {len(run.path) - 1}"


def test_a_failed_save_still_closes_the_figure(tmp_path: pathlib.Path) -> None:
    # The hostile-paths fuzzer: `show` and `plot` to a path that is a folder left every
    # figure open in the process (matplotlib warned after 20).
    import matplotlib.pyplot as plt

    from cellplan.errors import ArgumentError
    from cellplan.plots import new_figure, save_figure

    (tmp_path / "out.png").mkdir()
    fig, _ = new_figure()
    with pytest.raises(ArgumentError):
        save_figure(fig, tmp_path / "out.png")
    assert fig.number not in plt.get_fignums()

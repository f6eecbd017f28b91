"""What a user sees of an assembly run (issue 34): pictures, disc numbers, typed outputs.

- pictures: axes in workcell units, numbered discs and goals in one colour each, distinct
  hues, the GIF's blitted frames equal to a frame drawn whole (an independent oracle),
  ``show`` with the convention of ``assemble`` and on the bundled sphere scenarios;
- one numbering: discs from 1 in messages, pictures, CSV columns, events and actions;
- typed stats (counts ints, flags bools), ``describe`` facts, the ``finish`` event.
"""

from __future__ import annotations

import colorsys
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

import cellplan
from cellplan.assembly import plots
from cellplan.assembly.palette import disc_colors
from cellplan.cli import app
from cellplan.core import Fact
from cellplan.trajectory import EVENT_KINDS

from .assembly_scenarios import JAM

runner = CliRunner()

COUNTS = ("escapes", "placed", "steps", "evaluations", "switches")
FLAGS = ("rk4", "solved_at_k")
MEASURES = ("k", "k_final", "switches_per_disc", "ratio", "min_clearance")


# --- pictures --------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 60))
def test_disc_colours_are_distinct_hues_at_one_lightness(n: int) -> None:
    colors = disc_colors(n)
    assert len(colors) == n
    hsv = np.array([colorsys.rgb_to_hsv(*c[:3]) for c in colors])
    if n > 10:  # no light/dark pairs of one hue (tab20's problem): one value, one saturation
        np.testing.assert_allclose(hsv[:, 1:], hsv[:1, 1:].repeat(n, axis=0), atol=1e-9)
    # hues pairwise apart: at least the even spacing's half on the colour wheel for n > 10
    if n > 1:
        h = hsv[:, 0]
        d = np.abs(h[:, None] - h[None, :])
        d = np.minimum(d, 1.0 - d)[~np.eye(n, dtype=bool)]
        assert d.min() > (0.4 / n if n > 10 else 0.0)
    # neighbours by number get far-apart hues (the golden angle): never within 0.2 turn
    if n > 10:
        step = np.abs(np.diff(hsv[:, 0]))
        assert np.all(np.minimum(step, 1.0 - step) > 0.2)


def test_sequence_has_axes_in_units_and_numbered_discs_and_goals(
    tmp_path: Path, monkeypatch
) -> None:
    from matplotlib.patches import Circle, PathPatch

    import cellplan.plots

    figures = {}
    save = cellplan.plots.save_figure

    def spy(fig, path, dpi=110):
        figures[path.name] = fig
        fig.canvas.draw()
        return save(fig, path, dpi)

    monkeypatch.setattr(cellplan.plots, "save_figure", spy)
    result = cellplan.plan(cellplan.load("discs_swap"), "assembly.gradient")
    run = result.solution
    plots.save_sequence(run.problem, run.path, tmp_path / "s.png", "t")
    fig = figures["s.png"]
    n = run.problem.n
    for ax in fig.axes:
        assert ax.get_xlabel() == "x (workcell units)"
        assert ax.get_xticks().size > 0
        # each goal's number as text, each disc's as a glyph outline on the disc
        assert sorted(t.get_text() for t in ax.texts) == [str(i + 1) for i in range(n)]
        glyphs = [p for p in ax.patches if isinstance(p, PathPatch)]
        discs = [p for p in ax.patches if isinstance(p, Circle) and p.get_fill()]
        assert len(glyphs) == len(discs) == n
        on = ax.transData.inverted().transform(
            np.array([g.get_transform().transform((0.0, 0.0)) for g in glyphs])
        )
        np.testing.assert_allclose(on, [d.center for d in discs], atol=1e-9)
    assert fig.axes[0].get_ylabel() == "y (workcell units)"


def test_gif_frames_blitted_equal_a_frame_drawn_whole(tmp_path: Path, monkeypatch) -> None:
    """Oracle: the last GIF frame (one figure, moving artists blitted on a still
    background) against the same moment drawn on a fresh figure, before quantisation."""
    import matplotlib.pyplot as plt

    import cellplan.plots as core_plots

    frames: list[np.ndarray] = []
    texts: list[str] = []
    render = plots.frame_rgb

    def spy(fig):
        texts.extend(
            t.get_text() for ax in fig.axes for t in ax.texts if t.get_gid() == "frame-counter"
        )
        frames.append(render(fig))
        return frames[-1]

    monkeypatch.setattr(plots, "frame_rgb", spy)
    result = cellplan.plan(cellplan.load("discs_seven"), "assembly.gradient")
    run, traj = result.solution, result.trajectory
    plots.save_animation(run.problem, run.path, tmp_path / "a.gif", 5, "title", trajectory=traj)
    assert len(frames) == 5 and len(set(texts)) == 5
    fig, axes = core_plots.new_figure(size=4.8)
    plots.draw_configuration(axes[0][0], run.problem, run.path, len(run.path) - 1, "title")
    core_plots.frame_counter(axes[0][0], texts[-1])
    whole = core_plots.figure_to_rgb(fig, core_plots.GIF_SIZE)
    plt.close(fig)
    assert whole.shape == frames[-1].shape and whole.shape[1] == core_plots.GIF_SIZE >= 480
    differ = np.any(np.abs(whole.astype(int) - frames[-1].astype(int)) > 40, axis=2)
    # only antialiased edges may differ (goal outlines under discs are painted in
    # another order): under 1% of the pixels
    assert differ.mean() < 0.01
    # and the frames do move: the first differs from the last far more
    moved = np.any(np.abs(frames[0].astype(int) - frames[-1].astype(int)) > 40, axis=2)
    assert moved.mean() > 5 * differ.mean()


def test_run_titles_spell_out_the_algorithm() -> None:
    from cellplan.assembly.run import run_title

    setup = cellplan.load("discs_swap")
    gradient = run_title(cellplan.plan(setup, "assembly.gradient"))
    assert gradient.startswith("gradient flow (all discs at once), navigation exponent k = ")
    seq = run_title(cellplan.plan(setup, "assembly.sequential", rule="paper"))
    assert seq.startswith("sequential (one disc at a time), paper's rule T, navigation ")


def test_show_hook_draws_filled_starts_and_dashed_goals_numbered() -> None:
    """``show`` uses ``assemble``'s convention: filled where the disc is, a dashed outline
    of the same colour where it must go, both numbered from 1."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    from cellplan.assembly.drawing import draw_discs
    from cellplan.assembly.problems import problem_from_section

    setup = cellplan.load("discs_seven")
    problem = problem_from_section(setup.scenario.discs, setup.scenario)
    fig, ax = plt.subplots()
    draw_discs(setup, ax)
    # the discs' circles (the workspace boundary is a circle too, about the origin)
    circles = [
        p for p in ax.patches if isinstance(p, Circle) and np.isclose(p.radius, problem.radii[0])
    ]
    colors = disc_colors(problem.n)
    for i in range(problem.n):
        at_start = [c for c in circles if np.allclose(c.center, problem.start[i])]
        at_goal = [c for c in circles if np.allclose(c.center, problem.goal[i])]
        assert len(at_start) == 1 and at_start[0].get_fill()
        assert np.allclose(at_start[0].get_facecolor()[:3], colors[i][:3])
        assert len(at_goal) == 1 and not at_goal[0].get_fill()
        assert at_goal[0].get_linestyle() == "--"
        assert np.allclose(at_goal[0].get_edgecolor()[:3], colors[i][:3])
        labels = [t for t in ax.texts if t.get_text() == str(i + 1)]
        spots = sorted(tuple(np.round(t.xy, 6)) for t in labels)
        assert spots == sorted(tuple(np.round(p, 6)) for p in (problem.start[i], problem.goal[i]))
    plt.close(fig)


@pytest.mark.parametrize("name", ["spheres_cluster7", "spheres_stack13"])
def test_show_draws_the_bundled_sphere_scenarios(tmp_path: Path, name: str) -> None:
    from PIL import Image

    out = tmp_path / "cell.png"
    res = runner.invoke(app, ["show", name, "-o", str(out), "--view", "top"])
    assert res.exit_code == 0, res.output
    with Image.open(out) as image:
        assert image.size[0] >= 480
        pixels = np.asarray(image.convert("RGB"))
    assert (pixels != 255).any(axis=2).mean() > 0.02  # something drawn, not a blank page


def test_show_refuses_a_3d_cell_with_nothing_to_draw(tmp_path: Path, request) -> None:
    run_cli = request.getfixturevalue("cellplan")  # the console script, in process
    scenario = tmp_path / "empty.yaml"
    scenario.write_text(
        "cellplan: 2\nworkcell:\n  bounds: {xmin: 0, ymin: 0, zmin: 0, xmax: 1, ymax: 1, zmax: 1}\n"
    )
    res = run_cli("show", str(scenario), "-o", str(tmp_path / "c.png"))
    assert res.returncode == 2
    (line,) = res.stderr.strip().splitlines()
    assert "drawn with its robot or a section that draws in 3-D" in line


# --- one numbering: from 1 -------------------------------------------------------------------

OVERLAP = """cellplan: 1
workcell:
  bounds: {xmin: -10, ymin: -10, xmax: 10, ymax: 10}
discs:
  boundary: {type: disc, center: [0, 0], radius: 9}
  discs:
    - {radius: 1, start: [-5, 0], goal: [0, 0]}
    - {radius: 1, start: [5, 0], goal: [1.5, 0]}
"""


def test_messages_number_discs_from_1_and_name_the_file_entry(tmp_path: Path, request) -> None:
    run_cli = request.getfixturevalue("cellplan")
    scenario = tmp_path / "overlap.yaml"
    scenario.write_text(OVERLAP)
    res = run_cli("validate", str(scenario))
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        "error: discs.discs[1].goal: disc 2 touches or overlaps disc 1 (discs.discs[0], gap -0.5)"
    ]


def test_events_columns_and_actions_number_discs_from_1(tmp_path: Path) -> None:
    code = runner.invoke(
        app,
        [
            "assemble",
            "discs_swap",
            "--algorithm",
            "sequential",
            "--frames",
            "2",
            "-o",
            str(tmp_path),
        ],
    ).exit_code
    assert code == 0
    n = 3
    traj = cellplan.Trajectory.load(tmp_path / "trajectory.csv")
    assert traj.columns == tuple(f"disc{i}.{a}" for i in range(1, n + 1) for a in "xy")
    grasped = {int(e.detail.removeprefix("disc ")) for e in traj.events_of("grasp")}
    assert grasped and grasped <= set(range(1, n + 1))
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    picked = {a["disc"] for a in metrics["actions"] if a["action"] == "pick"}
    assert picked == grasped  # the same disc numbers as the events
    # the first pick starts at the start of the disc it names (number d: index d - 1)
    first = metrics["actions"][0]
    assert np.allclose(first["at"], metrics["start"][first["disc"] - 1])


# --- typed outputs ---------------------------------------------------------------------------


@pytest.mark.parametrize("algorithm", ["gradient", "sequential", "control"])
def test_stats_counts_are_ints_flags_bools_measures_floats(algorithm: str) -> None:
    result = cellplan.plan(cellplan.load("discs_swap"), f"assembly.{algorithm}")
    stats = result.stats
    assert set(stats) & set(COUNTS)
    for key, value in stats.items():
        if key in COUNTS:
            assert type(value) is int, key
        elif key in FLAGS:
            assert type(value) is bool, key
        else:
            assert type(value) is float, key  # measures (k, k_final, switches_per_disc...)
    assert {"rk4", "solved_at_k"} <= set(stats) if algorithm == "gradient" else True


def test_metrics_json_keeps_the_types(tmp_path: Path) -> None:
    res = runner.invoke(
        app, ["assemble", "discs_swap", "--frames", "2", "-o", str(tmp_path), "--json"]
    )
    assert res.exit_code == 0
    payload = json.loads(res.stdout)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    for stats in (payload["stats"], metrics):
        assert stats["rk4"] in (True, False) and type(stats["rk4"]) is bool
        assert type(stats["solved_at_k"]) is bool
        for key in ("escapes", "placed", "steps", "evaluations"):
            assert type(stats[key]) is int, key
        assert type(stats["k_final"]) is float


def test_describe_returns_typed_facts() -> None:
    from cellplan.assembly.plugin import describe

    (listed,) = describe(cellplan.load("spheres_cluster7"))
    assert isinstance(listed, Fact) and listed.key == "discs"
    assert listed.value == {
        "bodies": "spheres",
        "boundary": "ball",
        "k": 64.0,
        "count": 7,
        "source": "listed",
    }
    assert listed.text == "7 spheres listed, boundary ball, k = 64"
    (generated,) = describe(cellplan.load("discs_seven"))
    assert generated.value["count"] == 7 and type(generated.value["count"]) is int
    assert generated.value["seed"] == 1 and generated.value["source"] == "generated"
    assert generated.text.startswith("7 generated (seed 1, hex goals")


def test_finish_is_its_own_event_kind() -> None:
    """The sequential rule's place-rule finish is a ``finish`` event, not an ``escape``."""
    assert "finish" in EVENT_KINDS
    setup = cellplan.loads(JAM)
    result = cellplan.plan(setup, "assembly.sequential", escapes=0)
    assert result.success and result.stats["placed"] > 0 and result.stats["escapes"] == 0
    traj = result.trajectory
    assert not traj.events_of("escape")  # k was never lowered
    (finish,) = traj.events_of("finish")
    assert finish.detail == "place rule"
    run = result.solution
    paper = result.stats["switches"] - result.stats["placed"]  # the T map's own grasps
    assert finish.index == sum(len(g.path) - 1 for g in run.grasps[:paper])


def test_sphere_gif_frames_carry_the_counter(tmp_path: Path, frame_counters) -> None:
    """Spheres are drawn afresh per frame on 3-D axes; the counter is on those axes."""
    result = cellplan.plan(cellplan.load("spheres_cluster7"), "assembly.gradient")
    run = result.solution
    plots.save_animation(run.problem, run.path, tmp_path / "s.gif", 3, trajectory=result.trajectory)
    assert len(frame_counters) == 3
    assert all(c.startswith("stage 1 / ") and "path length" in c for c in frame_counters)


@pytest.mark.parametrize("dim", [2, 3])
def test_run_trajectory_is_one_builder_for_discs_and_spheres(dim: int) -> None:
    """Discs and spheres share one trajectory builder: a column per coordinate of each
    disc, events sorted by sample, and a controller's run (time unit s) keeps its own clock
    as seconds where a path-parametrised run is timed by the default speeds."""
    from cellplan import timing
    from cellplan.assembly.planners import _trajectory
    from cellplan.trajectory import Event

    rng = np.random.default_rng(dim)
    path = rng.normal(size=(5, 3, dim))
    t = np.array([0.5, 1.0, 1.5, 2.5, 4.0])
    mode = np.zeros(5, dtype=np.int64)
    events = (Event(3, "escape", "k=8"), Event(1, "escape", "k=16"))
    ran = _trajectory(path, t, "s", mode, ("all discs",), events, {})
    assert ran.columns == tuple(f"disc{i}.{a}" for i in range(1, 4) for a in "xyz"[:dim])
    assert np.array_equal(ran.q, path.reshape(5, 3 * dim))
    assert [e.index for e in ran.events] == [1, 3]
    assert np.allclose(ran.seconds, t - t[0])
    walked = _trajectory(path, t, "path", mode, ("all discs",), (), {})
    expected = timing.path_seconds(walked.q, np.asarray(walked.velocity_limits))
    assert np.allclose(walked.seconds, expected)

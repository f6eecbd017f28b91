"""Spheres in a 3-D workspace (issue 31): the navigation function in R^{3n}, its kernels,
the scenario format, the patterns, the planners and the exact clearance (issue 35)."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import cellplan
from cellplan.assembly.layout import (
    CircleWorkspace,
    clearances,
    close_packed_pattern,
    min_clearance,
    rule_k,
    stack_pattern,
)
from cellplan.assembly.navigation import (
    evaluate,
    evaluate_numpy,
    grad_linear,
    hessian_log_w,
    hessian_log_w_numpy,
    log_w,
    path_min_clearance,
    phi_linear,
)
from cellplan.assembly.problems import (
    BoxWorkspace,
    DiscProblem,
    default_workspace,
    generate_problem,
    generated_setup,
)
from cellplan.assembly.routes import segments_clearance, segments_clearance_numpy
from cellplan.assembly.section import GeneratorSpec
from cellplan.errors import ScenarioError
from cellplan.scenario import loads_scenario


def _problem(seed: int, n: int, box: bool) -> DiscProblem:
    if box:
        ws = BoxWorkspace(np.full(3, -6.0), np.full(3, 6.0))
        return generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.1), ws)
    return generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.05), default_workspace(n, dim=3))


# --- the kernels against their numpy references, in 3-D -------------------------------------


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 8), box=st.booleans())
def test_kernels_match_their_numpy_references_in_3d(seed, n, box):
    p = _problem(seed, n, box)
    k = 24.0
    a, b = evaluate(p.start, p, k), evaluate_numpy(p.start, p, k)
    assert a.v.shape == (n, 3)
    np.testing.assert_allclose(a.v, b.v, rtol=1e-10, atol=1e-12)
    assert a.log_beta == pytest.approx(b.log_beta, rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(a.gaps, b.gaps, rtol=1e-12)
    np.testing.assert_allclose(a.bgap, b.bgap, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(
        hessian_log_w(p.start, p, k), hessian_log_w_numpy(p.start, p, k), rtol=1e-9, atol=1e-12
    )
    rng = np.random.default_rng(seed)
    P = p.start[rng.integers(0, n, 16)] + rng.normal(0, 2, (16, 3))
    Q = P + rng.normal(0, 3, (16, 3))
    # route choices depend on these: bit for bit
    assert np.array_equal(
        segments_clearance(p, p.start, 0, P, Q), segments_clearance_numpy(p, p.start, 0, P, Q)
    )


def test_gradient_and_hessian_against_finite_differences_in_3d():
    """Independent oracle: central differences of the plain-float phi (equations (2)-(6))
    and of L = log gamma - log(beta) / k."""
    p = _problem(3, 4, box=False)
    k, h = 6.0, 1e-6
    b = p.start
    fd = np.zeros_like(b)
    for i in range(b.shape[0]):
        for a in range(3):
            e = np.zeros_like(b)
            e[i, a] = h
            fd[i, a] = (phi_linear(b + e, p, k) - phi_linear(b - e, p, k)) / (2 * h)
    g = grad_linear(b, p, k)
    np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-12)
    # v is a positive multiple of grad phi (equation (8) factored)
    v = evaluate(b, p, k).v
    cos = float(np.sum(v * g) / (np.linalg.norm(v) * np.linalg.norm(g)))
    assert cos == pytest.approx(1.0, abs=1e-8)
    hess = hessian_log_w(b, p, k)
    flat = b.reshape(-1)
    num = np.zeros_like(hess)
    for c in range(flat.size):
        e = np.zeros_like(flat)
        e[c] = 1e-5

        def grad_l(x):
            ev = evaluate(x.reshape(b.shape), p, k)
            return (ev.v / math.exp(ev.log_gamma)).reshape(-1)

        num[:, c] = (grad_l(flat + e) - grad_l(flat - e)) / 2e-5
    np.testing.assert_allclose(hess, num, rtol=1e-4, atol=1e-6)
    assert log_w(evaluate(b, p, k), k) == pytest.approx(
        math.log(0.5 * np.sum((b - p.goal) ** 2)) - evaluate_numpy(b, p, k).log_beta / k
    )


# --- the exact clearance over segments (issue 35 part 4) --------------------------------------


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), dim=st.sampled_from([2, 3]))
@example(seed=4588, dim=2)  # two centres pass through each other: a kink minimum
def test_path_clearance_is_the_exact_minimum_over_segments(seed, dim):
    rng = np.random.default_rng(seed)
    n = 4
    ws = CircleWorkspace(np.zeros(dim), 12.0)
    radii = rng.uniform(0.5, 1.0, n)
    path = rng.uniform(-5, 5, (3, n, dim))
    exact = path_min_clearance(path, radii, ws)
    # oracle: dense sampling of every segment never goes below it, and comes close to it.
    # Where two centres pass through each other the minimum is a kink, which a grid of
    # samples misses by up to half a step times the closing speed (seed 4588: 2.9e-4), so
    # the grid's best step is sampled again as finely.
    t = np.linspace(0.0, 1.0, 4001)
    coarse = [
        (min_clearance(a + ti * (b - a), radii, ws), k, i)
        for k, (a, b) in enumerate(itertools.pairwise(path))
        for i, ti in enumerate(t)
    ]
    _, k, i = min(coarse)
    a, b = path[k], path[k + 1]
    fine = np.linspace(t[max(i - 1, 0)], t[min(i + 1, len(t) - 1)], 4001)
    dense = min(
        min(c for c, _, _ in coarse), *(min_clearance(a + ti * (b - a), radii, ws) for ti in fine)
    )
    assert exact <= dense + 1e-12
    assert dense - exact < 1e-4
    # never above the rows' figure (up to rounding: the kernel and numpy sum differently)
    assert exact <= min(min_clearance(row, radii, ws) for row in path) + 1e-12


def test_reported_clearance_is_exact_and_can_be_below_the_rows():
    setup = cellplan.load("spheres_cluster7")
    res = cellplan.plan(setup, "assembly.gradient")
    assert res.status.ok
    assert 0.0 < res.stats["min_clearance"] <= res.stats["min_clearance_vertices"]
    problem = res.solution.problem
    assert res.stats["min_clearance"] == path_min_clearance(
        res.solution.path, problem.radii, problem.workspace
    )


# --- patterns ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [4, 6, 7, 13])
def test_close_packed_cluster_is_tight_and_centred(n):
    pts = close_packed_pattern(n, 1.0, 0.1, np.array([1.0, 2.0, 3.0]))
    gaps, _ = clearances(pts, np.ones(n), CircleWorkspace(np.zeros(3), 100.0))
    assert np.min(gaps) == pytest.approx(0.1)
    contacts = np.sum(np.abs(gaps - 0.1) < 1e-9, axis=1)
    assert np.all(contacts >= 3)
    np.testing.assert_allclose(pts.mean(axis=0), [1.0, 2.0, 3.0], atol=1e-12)


def test_stack_of_13_is_seven_below_six_above():
    pts = stack_pattern(13, 1.0, 0.1, np.zeros(3))
    z = np.round(pts[:, 2], 9)
    levels = sorted(set(z))
    assert len(levels) == 2
    assert [int(np.sum(z == v)) for v in levels] == [7, 6]
    assert levels[1] - levels[0] == pytest.approx(2.1 * math.sqrt(2.0 / 3.0))
    gaps, _ = clearances(pts, np.ones(13), CircleWorkspace(np.zeros(3), 100.0))
    assert np.min(gaps) == pytest.approx(0.1)


# --- the scenario format and its refusals -----------------------------------------------------

CELL3 = """
cellplan: 2
workcell:
  bounds: {xmin: -6, ymin: -6, zmin: -6, xmax: 6, ymax: 6, zmax: 6}
discs:
"""


def _lines(text: str) -> list[str]:
    with pytest.raises(ScenarioError) as err:
        loads_scenario(text)
    return str(err.value).splitlines()


def test_planar_discs_in_a_3d_cell_are_one_line():
    lines = _lines(
        CELL3
        + "  discs:\n"
        + "    - {radius: 1, start: [0, 0], goal: [3, 0]}\n"
        + "    - {radius: 1, start: [0, 3], goal: [-3, 0]}\n"
    )
    assert lines == [
        "discs: the points have 2 coordinates, for 2d workcells; this one is 3d (give 3: [x, y, z])"
    ]


def test_mixed_coordinates_are_one_line_per_point():
    lines = _lines(
        CELL3
        + "  discs:\n"
        + "    - {radius: 1, start: [0, 0, 0], goal: [3, 0]}\n"
        + "    - {radius: 1, start: [0, 3, 0], goal: [-3, 0, 0]}\n"
    )
    assert lines == ["discs.discs[0].goal: has 2 coordinates; this workcell is 3d (give 3)"]


def test_illegal_sphere_and_2d_stack_are_named():
    lines = _lines(
        CELL3
        + "  discs:\n"
        + "    - {radius: 1, start: [0, 0, 5.5], goal: [3, 0, 0]}\n"
        + "    - {radius: 1, start: [0, 3, 0], goal: [-3, 0, 0]}\n"
    )
    assert lines == [
        "discs.discs[0].start: disc 1 at (0, 0, 5.5) with radius 1 is not strictly inside "
        "the workspace boundary"
    ]
    planar = "cellplan: 1\nworkcell:\n  bounds: {xmin: -9, ymin: -9, xmax: 9, ymax: 9}\n"
    lines = _lines(planar + "discs:\n  generate: {n: 5, pattern: stack}\n")
    assert lines == ["discs.generate.pattern: stack is a 3-D pattern; this workcell is 2d"]


def test_ball_boundary_defaults_to_the_origin_in_3d():
    sc = loads_scenario(
        CELL3
        + "  boundary: {type: disc, radius: 5.5}\n"
        + "  discs:\n"
        + "    - {radius: 1, start: [0, 0, 2], goal: [0, 0, -2]}\n"
    )
    from cellplan.assembly.problems import problem_from_section

    p = problem_from_section(sc.discs, sc)
    assert p.dim == 3 and np.array_equal(p.workspace.center, np.zeros(3))


# --- the planners on the bundled and generated spheres ----------------------------------------


def test_bundled_cluster_every_planner():
    setup = cellplan.load("spheres_cluster7")
    for name, opts in (
        ("assembly.gradient", {}),
        ("assembly.sequential", {}),
        ("assembly.sequential", {"rule": "place"}),
        ("assembly.control", {}),
    ):
        res = cellplan.plan(setup, name, **opts)
        assert res.status.ok, (name, opts, res.message)
        assert res.stats["min_clearance"] > 0
        traj = res.trajectory
        assert traj.columns[:3] == ("disc1.x", "disc1.y", "disc1.z")
        assert traj.q.shape[1] == 21 and traj.meta["dim"] == 3
        np.testing.assert_allclose(traj.q[-1].reshape(7, 3), res.solution.problem.goal, atol=1e-2)


def test_bundled_stack_gradient_and_place_rule():
    setup = cellplan.load("spheres_stack13")
    for name, opts in (("assembly.gradient", {}), ("assembly.sequential", {"rule": "place"})):
        res = cellplan.plan(setup, name, **opts)
        assert res.status.ok, (name, res.message)
        assert res.stats["min_clearance"] > 0


def test_sphere_k_rule_grows_with_n():
    a = default_workspace(7, dim=3)
    b = default_workspace(20, dim=3)
    assert rule_k(np.ones(20), b) > rule_k(np.ones(7), a) >= 16.0
    assert a.radius == pytest.approx((7 / 0.05) ** (1 / 3))


def test_generated_sphere_setup_plans_like_a_file():
    setup = generated_setup({"n": 5, "seed": 2, "starts": "permutation"}, dim=3)
    res = cellplan.plan(setup, "assembly.gradient")
    assert res.status.ok and res.solution.problem.dim == 3


# --- the paper rule's finish (issue 35 part 2) ------------------------------------------------


def test_paper_rule_finish_solves_the_issue_case():
    """``assemble --random 15 --seed 4102 --algorithm sequential`` ended 47 from the goal."""
    from cellplan.assembly.problems import random_setup

    setup = random_setup(15, seed=4102)
    alone = cellplan.plan(setup, "assembly.sequential", finish="none")
    assert alone.status is cellplan.Status.BUDGET_EXHAUSTED
    assert alone.stats["placed"] == 0
    done = cellplan.plan(setup, "assembly.sequential")
    assert done.status.ok and done.stats["final_error"] == 0.0
    assert done.stats["placed"] > 0
    assert "the place rule finished" in done.message
    assert done.stats["switches"] == alone.stats["switches"] + done.stats["placed"]
    assert done.stats["escapes"] == alone.stats["escapes"]
    assert done.stats["min_clearance"] > 0


def test_cli_assembles_random_spheres(tmp_path, cellplan):
    from typer.testing import CliRunner

    from cellplan.cli import app

    out = tmp_path / "out"
    res = CliRunner().invoke(
        app, ["assemble", "--random", "4", "--dim", "3", "--frames", "2", "-o", str(out)]
    )
    assert res.exit_code == 0, res.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "solved" and len(metrics["goal"][0]) == 3
    header = (out / "trajectory.csv").read_text().splitlines()
    assert any("disc4.z" in line for line in header[:5])
    bad = cellplan("assemble", "--random", "4", "--dim", "4", "-o", str(tmp_path / "x"))
    assert bad.returncode == 2
    lines = bad.stderr.strip().splitlines()
    assert lines[0] == "error: --dim: must be 2 or 3, got 4" and len(lines) == 1


def test_sphere_and_finish_experiments_decide_their_claims(tmp_path):
    """The quick versions of ``assembly.spheres`` and ``assembly.finish``: every row comes
    from the run function, every claim states its sample size and rule."""
    from cellplan.assembly import experiments3d as ex3

    for make, report in (
        (ex3._runs_spheres, ex3._report_spheres),
        (ex3._runs_finish, ex3._report_finish),
    ):
        specs = make(5, True)
        assert {s.seed for s in specs} == set(range(5))
        rows = [{**s.params, "seed": s.seed, **ex3.run(s)} for s in specs]
        piece = report(rows, tmp_path)
        assert piece.claims and piece.tables
        for claim in piece.claims:
            assert claim.n >= 5 and claim.rule
    spheres = ex3._report_spheres(
        [{**s.params, "seed": s.seed, **ex3.run(s)} for s in ex3._runs_spheres(5, True)], tmp_path
    )
    assert any("falls as k grows" in c.claim for c in spheres.claims)
    assert any(str(f).endswith("assembly_spheres_ratio_vs_k.png") for f in spheres.figures)


def test_wilson_interval_against_known_values():
    from cellplan.assembly.experiments3d import wilson

    lo, hi = wilson(75, 75)
    assert lo == pytest.approx(0.9513, abs=1e-4) and hi == pytest.approx(1.0)
    lo, hi = wilson(5, 10)
    assert (lo, hi) == (pytest.approx(0.2366, abs=1e-4), pytest.approx(0.7634, abs=1e-4))

"""Issue 13: the default-k rule, the place-rule escape and the automatic integrator."""

from __future__ import annotations

import math

import numpy as np
import pytest

import cellplan
from cellplan.assembly.flows import choose_method, gradient_flow
from cellplan.assembly.layout import (
    K_RULE_C,
    K_RULE_MIN,
    BoxWorkspace,
    CircleWorkspace,
    clearances,
    rule_k,
)
from cellplan.assembly.problems import (
    DiscProblem,
    default_workspace,
    generate_problem,
    generated_setup,
)
from cellplan.assembly.section import DiscsSection, GeneratorSpec
from cellplan.core import Status

# --- the default k ---------------------------------------------------------------------------


def test_rule_k_is_c_n_squared_over_fill_and_scale_free() -> None:
    ws = default_workspace(12, 1.0, 0.05)
    radii = np.ones(12)
    assert rule_k(radii, ws) == pytest.approx(K_RULE_C * 144 / 0.05)
    # scaling every length leaves the fill, hence k, unchanged (the paths scale too)
    big = CircleWorkspace(ws.center * 3.0, ws.radius * 3.0)
    assert rule_k(3.0 * radii, big) == pytest.approx(rule_k(radii, ws))
    # a box of the same area gives the same k
    side = math.sqrt(math.pi) * ws.radius
    box = BoxWorkspace(np.zeros(2), np.array([side, side]))
    assert rule_k(radii, box) == pytest.approx(rule_k(radii, ws))
    # more discs or a denser workspace: larger k; never below the floor
    assert rule_k(np.ones(13), default_workspace(13)) > rule_k(radii, ws)
    assert rule_k(np.ones(2), CircleWorkspace(np.zeros(2), 2.0)) == K_RULE_MIN


def test_section_library_and_cli_share_the_rule() -> None:
    assert DiscsSection.model_fields["k"].default is None
    setup = generated_setup({"n": 6, "seed": 4})
    result = cellplan.plan(setup, "assembly.gradient")
    problem = result.solution.problem
    assert result.stats["k"] == rule_k(problem.radii, problem.workspace)
    assert result.trajectory.meta["k"] == result.stats["k"]
    # a k in the file, or passed, wins over the rule
    assert cellplan.plan(setup, "assembly.gradient", k=40.0).stats["k"] == 40.0
    assert cellplan.plan(cellplan.load("discs_seven"), "assembly.gradient").stats["k"] == 96.0


# --- escaping spurious minima ----------------------------------------------------------------


def _stuck_case() -> DiscProblem:
    """Eight discs onto a hexagonal cluster with gaps of 0.01 radius: at k=128 the flow
    ends in a spurious minimum, and halving k pushes the discs outward (issue 13)."""
    gen = GeneratorSpec(n=8, seed=27, gap=0.01)
    return generate_problem(gen, default_workspace(8))


def test_halving_k_spreads_this_stuck_case_but_the_place_rule_assembles_it() -> None:
    p = _stuck_case()
    halved = gradient_flow(p, 128.0, escapes=6, escape="halve-k")
    assert halved.status is Status.STUCK
    assert halved.stages[0].reason == "spurious minimum"
    assert float(np.linalg.norm(halved.end - p.goal)) > 20.0  # pushed outward

    placed = gradient_flow(p, 128.0, escapes=6, escape="place")
    assert placed.status is Status.SOLVED
    assert [s.status for s in placed.stages] == [Status.STUCK, Status.SOLVED]
    # the flow part is the same flow as before, up to the stuck point
    np.testing.assert_array_equal(placed.path[: placed.steps + 1], halved.path[: placed.steps + 1])
    np.testing.assert_allclose(placed.end, p.goal, atol=1e-9)
    assert placed.placement is not None and placed.placement.switches >= 1
    # every configuration of the whole path is legal (independent clearance oracle); the
    # reported minimum is over the segments between them (place routes), so not above
    worst = min(
        min(float(np.min(g)), float(np.min(b)))
        for g, b in (clearances(row, p.radii, p.workspace) for row in placed.path)
    )
    assert 0.0 < placed.min_clearance <= worst


def test_the_planner_says_why_it_escaped() -> None:
    setup = generated_setup({"n": 8, "seed": 27, "gap": 0.01})
    res = cellplan.plan(setup, "assembly.gradient", k=128.0)
    assert res.status is Status.SOLVED
    assert "the flow was stuck at a spurious minimum at k=128" in res.message
    assert "the place rule finished in" in res.message
    assert res.stats["escapes"] == 1.0 and res.stats["placed"] >= 1.0
    assert res.stats["stuck_error"] > 0.01 and res.stats["final_error"] < 1e-9
    traj = res.trajectory
    kinds = [e.kind for e in traj.events]
    assert kinds[0] == "escape" and "grasp" in kinds
    assert traj.modes[0] == "all discs" and set(traj.mode[: int(res.stats["steps"]) + 1]) == {0}
    # after the escape one disc moves per row, the one its mode names
    q = traj.q.reshape(len(traj.q), -1, 2)
    for i in range(int(res.stats["steps"]) + 1, len(q)):
        moved = np.flatnonzero(np.any(q[i] != q[i - 1], axis=1))
        assert set(moved) <= {int(traj.mode[i]) - 1}
    # the old escape is still there, and escapes=0 is the flow alone
    halved = cellplan.plan(setup, "assembly.gradient", k=128.0, escape="halve-k")
    assert halved.status is Status.STUCK and "lowered k 6 times" in halved.message
    alone = cellplan.plan(setup, "assembly.gradient", k=128.0, escapes=0)
    assert alone.status is Status.STUCK and alone.stats["escapes"] == 0.0


# --- the integrator --------------------------------------------------------------------------


@pytest.mark.parametrize("n", [7, 25])
def test_auto_integrator_picks_rk4_for_loose_goals_only(n: int) -> None:
    loose = generate_problem(
        GeneratorSpec(n=n, seed=0, pattern="random", min_start_gap=1.0), default_workspace(n)
    )
    packed = generate_problem(GeneratorSpec(n=n, seed=0, gap=0.1), default_workspace(n))
    assert choose_method(loose) == "rk4"
    assert choose_method(packed) == "implicit"
    # the threshold: at most n/2 goal pairs within one radius
    row = loose.goal.copy()
    row[:, 0] = np.arange(n) * 2.5  # a row of goals 0.5 radius apart: n - 1 tight pairs
    row[:, 1] = 0.0
    assert choose_method(
        DiscProblem(loose.radii, loose.start, row - row.mean(0), loose.workspace)
    ) == ("implicit")


def test_the_planner_reports_the_integrator_it_ran() -> None:
    packed = generated_setup({"n": 7, "seed": 1})
    assert cellplan.plan(packed, "assembly.gradient").stats["rk4"] == 0.0
    loose = generated_setup({"n": 7, "seed": 1, "pattern": "random", "min_start_gap": 1.0})
    auto = cellplan.plan(loose, "assembly.gradient")
    assert auto.stats["rk4"] == 1.0 and auto.status is Status.SOLVED
    implicit = cellplan.plan(loose, "assembly.gradient", integrator="implicit")
    assert implicit.stats["rk4"] == 0.0 and implicit.status is Status.SOLVED
    # the same paths up to the integrators' accuracy
    assert auto.stats["ratio"] == pytest.approx(implicit.stats["ratio"], rel=0.01)


def test_when_the_place_rule_cannot_unpack_the_cluster_it_spreads_it_first(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A zero grasp budget from the stuck point stands in for a walled-in cluster (a
    50-disc one cycles for 1,000 grasps); the discs are then spread by one straight
    scaling move and placed from there."""
    from cellplan.assembly import flows

    monkeypatch.setattr(flows, "PLACE_GRASPS_PER_DISC", 0)
    setup = generated_setup({"n": 8, "seed": 27, "gap": 0.01})
    res = cellplan.plan(setup, "assembly.gradient", k=128.0)
    problem = res.solution.problem
    run = res.solution
    assert res.status is Status.SOLVED
    assert run.stages[0].reason == "spurious minimum"
    assert run.stages[1].reason.startswith("place rule: ")
    assert run.stages[2].reason == "place rule after spreading the cluster"
    assert "after the cluster was spread the place rule finished in" in res.message
    assert "the flow was stuck at a spurious minimum at k=128" in res.message
    # the path: the flow to the stuck point, one spreading move, the place rule
    steps = int(res.stats["steps"])
    stuck, spread = run.path[steps], run.path[steps + 1]
    np.testing.assert_array_equal(stuck, run.stuck_at)
    centre = problem.goal.mean(axis=0)
    f = np.linalg.norm(spread - centre, axis=1) / np.linalg.norm(stuck - centre, axis=1)
    np.testing.assert_allclose(f, f[0])
    assert f[0] > 1.0
    # along the move every gap grows (checked at intermediate points) and stays legal
    for t in np.linspace(0.0, 1.0, 11):
        gaps, bgap = clearances(stuck + t * (spread - stuck), problem.radii, problem.workspace)
        assert np.all(bgap > 0)
        assert np.all(gaps >= clearances(stuck, problem.radii, problem.workspace)[0] - 1e-12)
    np.testing.assert_allclose(run.end, problem.goal, atol=1e-9)
    assert [e.kind for e in res.trajectory.events[:2]] == ["escape", "spread"]

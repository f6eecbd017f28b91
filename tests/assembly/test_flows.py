"""Gradient flow, sequential assembly and control: collision-free, executable, paper behaviour."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan.assembly.control import simulate_control
from cellplan.assembly.flows import FlowSettings, gradient_flow
from cellplan.assembly.navigation import clearances, min_clearance
from cellplan.assembly.problems import CircleWorkspace, DiscProblem, generate_problem
from cellplan.assembly.routes import segment_clearance
from cellplan.assembly.section import GeneratorSpec
from cellplan.assembly.sequential import sequential_assembly
from cellplan.core import Status


def _problem(seed: int, n: int = 5, starts: str = "random") -> DiscProblem:
    return generate_problem(
        GeneratorSpec(n=n, seed=seed, gap=0.1, starts=starts),  # type: ignore[arg-type]
        CircleWorkspace(np.zeros(2), 8.0),
    )


def _swept_ok(path: np.ndarray, p: DiscProblem, samples: int = 17) -> bool:
    """Every straight step between consecutive rows is collision-free (sampled densely)."""
    t = np.linspace(0.0, 1.0, samples)[:, None, None]
    for a, b in itertools.pairwise(path):
        # a step is a small fraction of a radius: 17 samples resolve any crossing
        if min(min_clearance(c, p.radii, p.workspace) for c in a + t * (b - a)) <= 0:
            return False
    return True


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gradient_flow_reaches_goal_without_collision(seed: int) -> None:
    p = _problem(seed)
    res = gradient_flow(p, 32.0)
    assert res.status is Status.SOLVED
    assert np.linalg.norm(res.end - p.goal) < 1e-3
    assert res.min_clearance > 0
    assert min(min_clearance(b, p.radii, p.workspace) for b in res.path) > 0
    assert _swept_ok(res.path, p)
    assert res.length() >= np.linalg.norm(p.start - p.goal) * (1 - 1e-9)


def test_small_k_gets_stuck_large_k_does_not() -> None:
    # Section 5.2.1: below a threshold k the flow stops at a spurious critical point
    outcomes = {k: [gradient_flow(_problem(s, 7), k).status for s in range(2)] for k in (2.0, 64.0)}
    assert all(s is not Status.SOLVED for s in outcomes[2.0])
    assert all(s is Status.SOLVED for s in outcomes[64.0])


def test_larger_k_gives_shorter_paths() -> None:
    # Figs. 3-4: the mean path-length ratio falls as k grows
    def mean_ratio(k: float) -> float:
        out = []
        for s in range(4):
            p = _problem(s, 7)
            out.append(gradient_flow(p, k).length() / np.linalg.norm(p.start - p.goal))
        return float(np.mean(out))

    assert mean_ratio(64.0) < mean_ratio(24.0)


def test_budget_exhausted_is_reported() -> None:

    res = gradient_flow(_problem(0), 32.0, settings=FlowSettings(max_steps=5))
    assert res.status is Status.BUDGET_EXHAUSTED and res.steps == 5


@pytest.mark.parametrize("rule", ["paper", "place"])
@pytest.mark.parametrize("starts", ["random", "permutation"])
def test_sequential_output_is_executable(rule: str, starts: str) -> None:
    _replay_sequential(_problem(4, 5, starts), rule)


@pytest.mark.parametrize("seed", [0, 1])
def test_place_rule_is_collision_free_on_tight_permuted_goals(seed: int) -> None:
    # seven discs, goal pattern with beta(d) = 1e-28 (gaps ~1e-4), starts permute the goals
    from cellplan.assembly.problems import default_workspace

    p = generate_problem(
        GeneratorSpec(n=7, seed=seed, starts="permutation", log10_beta_goal=-28.0),
        default_workspace(7),
    )
    _replay_sequential(p, "place")  # (the grasp count can exceed 2 n here: fallbacks)


def _replay_sequential(p: DiscProblem, rule: str) -> None:
    res = sequential_assembly(p, 32.0, rule)  # type: ignore[arg-type]
    assert res.status is Status.SOLVED
    # replay the pick / move / release actions: one disc at a time, never touching
    x = p.start.copy()
    actions = res.actions()
    assert len(actions) == 3 * res.switches
    for pick, move, release in zip(actions[::3], actions[1::3], actions[2::3], strict=True):
        assert 1 <= pick["disc"] <= p.n  # numbered from 1, as people count
        i = pick["disc"] - 1
        assert move["disc"] == i + 1 == release["disc"]
        path = np.array(move["path"])
        assert np.allclose(path[0], x[i])
        for b in path[1:]:
            assert segment_clearance(p, x, i, b) > 0
            x[i] = b
        assert np.allclose(release["at"], x[i])
    tol = 1e-2 if rule == "paper" else 1e-12
    assert np.linalg.norm(x - p.goal) < tol
    assert res.min_clearance > 0


def test_place_rule_needs_fewer_switches_than_the_paper() -> None:
    counts = {
        rule: [
            sequential_assembly(_problem(s, 6), 32.0, rule).switches  # type: ignore[arg-type]
            for s in range(3)
        ]
        for rule in ("paper", "place")
    }
    assert np.mean(counts["place"]) <= 2 * 6  # at most two grasps per disc
    assert np.mean(counts["place"]) < np.mean(counts["paper"])


def test_controller_reaches_goal_without_collision_and_loses_energy() -> None:
    p = _problem(1, 4)
    res = simulate_control(p, 32.0)
    assert res.status is Status.SOLVED
    assert res.min_clearance > 0
    assert np.all(np.diff(res.energy) <= 1e-9 * res.energy[0])


def test_segment_check_is_exact_not_only_at_the_ends() -> None:
    from cellplan.assembly.flows import segment_is_safe

    radii, ws = np.ones(2), CircleWorkspace(np.zeros(2), 20.0)
    b = np.array([[-3.0, 0.0], [0.0, 0.0]])
    gaps, bgap = clearances(b, radii, ws)

    def safe(delta: np.ndarray) -> bool:
        return segment_is_safe(
            b, delta, radii, gaps, bgap, clearances(b + delta, radii, ws)[1], 0.5
        )

    jump = np.array([[6.0, 0.0], [0.0, 0.0]])  # disc 0 jumps over disc 1; both ends legal
    assert min_clearance(b + jump, radii, ws) > 0 and not safe(jump)
    assert safe(0.05 * jump) and not safe(0.3 * jump)  # gap 1 -> 0.7 ok, -> 0.2 not
    # a slide past disc 1 that no triangle bound (sum of moves <= gap) would allow
    slide = np.array([[0.0, 3.0], [0.0, 0.0]])
    assert safe(slide) and np.linalg.norm(slide[0]) > gaps[0, 1]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.floats(0.01, 3.0))
def test_safe_segments_keep_half_of_every_gap(seed: int, scale: float) -> None:
    from cellplan.assembly.flows import segment_is_safe

    p = _problem(seed, 4)
    rng = np.random.default_rng(seed)
    b = p.start
    delta = scale * rng.normal(size=b.shape)
    gaps, bgap = clearances(b, p.radii, p.workspace)
    new_bgap = clearances(b + delta, p.radii, p.workspace)[1]
    if not segment_is_safe(b, delta, p.radii, gaps, bgap, new_bgap, 0.5):
        return
    for t in np.linspace(0.0, 1.0, 101):
        g, bg = clearances(b + t * delta, p.radii, p.workspace)
        assert np.all(g >= 0.5 * gaps - 1e-12) and np.all(bg >= 0.5 * bgap - 1e-12)


def test_implicit_step_follows_the_rk4_path_in_fewer_steps() -> None:

    for s in range(3):
        p = _problem(s, 7)
        imp = gradient_flow(p, 64.0)
        rk4 = gradient_flow(p, 64.0, settings=FlowSettings(method="rk4"))
        assert imp.status is Status.SOLVED and rk4.status is Status.SOLVED
        assert abs(imp.length() / rk4.length() - 1.0) < 0.01
        assert imp.steps < rk4.steps
    with pytest.raises(ValueError, match="rk4"):
        gradient_flow(p, 64.0, direction=lambda b: b)


def test_spurious_minimum_is_reported_as_stuck_not_solved() -> None:
    # ten packed discs, k = 256: two discs end swapped (each ~one goal spacing off)
    from cellplan.assembly.navigation import evaluate, hessian_log_w
    from cellplan.assembly.problems import default_workspace

    p = generate_problem(GeneratorSpec(n=10, seed=25, gap=0.1), default_workspace(10))
    res = gradient_flow(p, 256.0)
    assert res.status is Status.STUCK and res.reason == "spurious minimum"
    assert np.linalg.norm(res.end - p.goal) > 1.0 and res.steps < 2000
    ev = evaluate(res.end, p, 256.0)
    assert np.linalg.norm(ev.v) < 1e-4 * np.linalg.norm(res.end - p.goal)
    assert np.linalg.eigvalsh(hessian_log_w(res.end, p, 256.0))[0] > 0


def test_lowering_k_leaves_a_spurious_minimum_and_says_so() -> None:
    # Section 3.2: k is adjusted to eliminate local minima. The same seed as above ends
    # in a spurious minimum at k = 256; continued at k/2, k/4 it reaches the goal.
    import cellplan
    from cellplan.assembly.problems import default_workspace, generated_setup

    p = generate_problem(GeneratorSpec(n=10, seed=25, gap=0.1), default_workspace(10))
    plain = gradient_flow(p, 256.0)
    res = gradient_flow(p, 256.0, escapes=4)
    assert res.stages[0].status is Status.STUCK and res.stages[0].reason == "spurious minimum"
    assert res.stages[0].steps == plain.steps
    assert res.status is Status.SOLVED and res.escapes >= 1
    assert [s.k for s in res.stages] == [256.0 * 0.5**i for i in range(len(res.stages))]
    assert all(s.status is Status.STUCK for s in res.stages[:-1])
    # the first stage is the plain run; the path continues from its end point
    np.testing.assert_array_equal(res.path[: len(plain.path)], plain.path)
    assert np.linalg.norm(res.end - p.goal) < 1e-3
    assert res.min_clearance > 0 and _swept_ok(res.path, p, samples=5)
    assert res.steps == sum(s.steps for s in res.stages)
    # the planner with this escape (escapes=6 by default; its default escape is now the
    # place rule, issue 13) reports it, and its trajectory marks each escape; the step
    # length of gradient_flow's default settings (the planner's own grows with n)
    planned = cellplan.plan(
        generated_setup({"n": 10, "seed": 25, "gap": 0.1}),
        "assembly.gradient",
        k=256.0,
        escape="halve-k",
        step_max=FlowSettings.step_max,
    )
    stats = planned.stats
    assert stats["solved_at_k"] == 0.0 and stats["escapes"] == res.escapes
    assert stats["k_final"] == res.stages[-1].k
    assert planned.success and "lowered" in planned.message
    np.testing.assert_array_equal(planned.solution.path, res.path)
    escapes = planned.trajectory.events_of("escape")
    starts = np.cumsum([s.steps for s in res.stages])[:-1]
    assert [e.index for e in escapes] == starts.tolist()
    assert [e.detail for e in escapes] == [f"k={s.k:g}" for s in res.stages[1:]]
    with pytest.raises(ValueError, match="escape_factor"):
        gradient_flow(p, 256.0, escape_factor=1.0)


def test_no_escape_when_the_flow_at_k_solves() -> None:
    p = _problem(0)
    res = gradient_flow(p, 32.0, escapes=4)
    assert res.status is Status.SOLVED and res.escapes == 0
    assert len(res.stages) == 1 and res.stages[0].k == 32.0


def test_switches_within_counts_grasps_until_the_goal_is_near() -> None:
    p = _problem(1, 5)
    res = sequential_assembly(p, 32.0, "paper", tol=1e-2)
    assert res.status is Status.SOLVED
    # the paper rule stops as soon as ||x - d|| < tol: no earlier grasp got that close
    assert res.switches_within(p.goal, 1e-2) == res.switches
    assert res.switches_within(p.goal, 1e9) == 1
    counts = [res.switches_within(p.goal, t) for t in (1e-2, 1e-1, 1.0, 3.0)]
    assert counts == sorted(counts, reverse=True) and counts[1] < counts[0]


def test_place_route_goes_round_a_blocking_disc_almost_as_short_as_possible() -> None:
    from cellplan.assembly.routes import placement_route

    # disc 0 from (-5, 0) to (5, 0), disc 1 standing at the origin: the shortest path
    # of the centre keeps distance 2 from the origin, tangent - arc - tangent
    p = DiscProblem(
        np.ones(2),
        np.array([[-5.0, 0.0], [0.0, 0.0]]),
        np.array([[5.0, 0.0], [0.0, 10.0]]),
        CircleWorkspace(np.zeros(2), 20.0),
    )
    route = placement_route(p, p.start, 0)
    assert route is not None and np.array_equal(route[-1], p.goal[0])
    pts = np.array([p.start[0], *route])
    x = p.start.copy()
    for b in pts[1:]:
        assert segment_clearance(p, x, 0, b) > 0
        x[0] = b
    length = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    theta = np.arccos(2.0 / 5.0)
    shortest = 2.0 * np.sqrt(25.0 - 4.0) + 2.0 * (np.pi - 2.0 * theta)
    assert shortest - 1e-9 < length < 1.01 * shortest


def test_planner_step_length_grows_with_n_and_can_be_given() -> None:
    import cellplan
    from cellplan.assembly.flows import step_max_rule
    from cellplan.assembly.options import STEP_MAX_PER_SQRT_DISC
    from cellplan.assembly.problems import generated_setup
    from cellplan.errors import CellplanError

    assert step_max_rule(3) == FlowSettings.step_max  # the floor
    assert step_max_rule(50) == pytest.approx(STEP_MAX_PER_SQRT_DISC * 50**0.5)
    assert step_max_rule(50) > step_max_rule(20) > FlowSettings.step_max
    setup = generated_setup({"n": 10, "seed": 3, "gap": 0.1})
    rule = cellplan.plan(setup, "assembly.gradient", integrator="implicit", escapes=0)
    given = cellplan.plan(
        setup, "assembly.gradient", integrator="implicit", escapes=0, step_max=0.05
    )
    assert rule.stats["step_max"] == step_max_rule(10) and given.stats["step_max"] == 0.05
    assert rule.success and given.success
    # a longer step: fewer steps on the same path (ratios within 1%, the fitted tolerance)
    assert rule.stats["steps"] < given.stats["steps"]
    assert rule.stats["ratio"] == pytest.approx(given.stats["ratio"], rel=0.01)
    with pytest.raises(CellplanError, match="step_max"):
        cellplan.plan(setup, "assembly.gradient", step_max=0.0)

"""Gradient flow, sequential assembly and control: collision-free, executable, paper behaviour."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from cellplan.assembly.control import simulate_control
from cellplan.assembly.flows import gradient_flow
from cellplan.assembly.navigation import clearances, min_clearance
from cellplan.assembly.problems import CircleWorkspace, DiscProblem, generate_problem
from cellplan.assembly.section import GeneratorSpec
from cellplan.assembly.sequential import segment_clearance, sequential_assembly
from cellplan.core import Status


def _problem(seed: int, n: int = 5, starts: str = "random") -> DiscProblem:
    return generate_problem(GeneratorSpec(n=n, seed=seed, gap=0.1, starts=starts),  # type: ignore[arg-type]
                            CircleWorkspace(np.zeros(2), 8.0))


def _swept_ok(path: np.ndarray, p: DiscProblem) -> bool:
    """Every straight step between consecutive rows is collision-free (triangle bound)."""
    for a, b in itertools.pairwise(path):
        gaps, bgap = clearances(a, p.radii, p.workspace)
        m = np.linalg.norm(b - a, axis=1)
        if not (np.all(m[:, None] + m[None, :] < gaps) and np.all(m < bgap)):
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
    from cellplan.assembly.flows import FlowSettings

    res = gradient_flow(_problem(0), 32.0, settings=FlowSettings(max_steps=5))
    assert res.status is Status.BUDGET_EXHAUSTED and res.steps == 5


@pytest.mark.parametrize("rule", ["paper", "place"])
@pytest.mark.parametrize("starts", ["random", "permutation"])
def test_sequential_output_is_executable(rule: str, starts: str) -> None:
    p = _problem(4, 5, starts)
    res = sequential_assembly(p, 32.0, rule)  # type: ignore[arg-type]
    assert res.status is Status.SOLVED
    # replay the pick / move / release actions: one disc at a time, never touching
    x = p.start.copy()
    actions = res.actions()
    assert len(actions) == 3 * res.switches
    for pick, move, release in zip(actions[::3], actions[1::3], actions[2::3], strict=True):
        i = pick["disc"]
        assert move["disc"] == i == release["disc"]
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
    counts = {rule: [sequential_assembly(_problem(s, 6), 32.0, rule).switches  # type: ignore[arg-type]
                     for s in range(3)] for rule in ("paper", "place")}
    assert np.mean(counts["place"]) <= 2 * 6  # at most two grasps per disc
    assert np.mean(counts["place"]) < np.mean(counts["paper"])


def test_controller_reaches_goal_without_collision_and_loses_energy() -> None:
    p = _problem(1, 4)
    res = simulate_control(p, 32.0)
    assert res.status is Status.SOLVED
    assert res.min_clearance > 0
    assert np.all(np.diff(res.energy) <= 1e-9 * res.energy[0])

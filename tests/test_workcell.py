"""The workcell model: batched queries against shapely, modes, regions, swept motions."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import given
from hypothesis import strategies as st

from cellplan.errors import ArgumentError, ScenarioError
from cellplan.registry import scenario_path
from cellplan.scenario import load_scenario
from cellplan.workcell import Workcell, load_workcell
from workcells import rotating_cell

P1 = load_workcell("strategies_p1")[1]
P6 = load_workcell("strategies_p6")[1]
ROT = rotating_cell()


def _reference_geometry(cell: Workcell, q: np.ndarray, carrying: str | None):
    bodies, part = cell.robot_shapes(q, carrying)
    return shapely.union_all(bodies + ([part] if part is not None else []))


def _reference_obstacles(cell: Workcell, avoid: list[str]):
    # Discs are compared exactly below, so only polygons go through shapely here.
    geoms = list(cell.obstacle_geometries.values())
    geoms += [g for s in avoid for g in cell.sources[s].geometries]
    return geoms


def _reference_collides(
    cell: Workcell, q: np.ndarray, carrying: str | None, avoid: list[str]
) -> tuple[bool, float]:
    robot = _reference_geometry(cell, q, carrying)
    inside = shapely.box(*cell.bounds)
    out_of_bounds = not inside.contains_properly(robot)
    dmin = np.inf
    hit = out_of_bounds
    for g, spec in zip(_reference_obstacles(cell, avoid), _specs(cell, avoid), strict=True):
        if spec is not None:  # exact disc
            d = robot.distance(shapely.Point(spec[0])) - spec[1]
        else:
            d = robot.distance(g)
        dmin = min(dmin, d)
        hit |= d <= 0
    boundary_gap = inside.exterior.distance(robot) if not out_of_bounds else 0.0
    return hit, min(dmin, boundary_gap)


def _specs(cell: Workcell, avoid: list[str]):
    out = []
    for name in cell.obstacle_geometries:
        s = cell.obstacles[name]
        out.append((s.centres[0], s.radii[0]) if s.n_discs == 1 and s.n_polygons == 0 else None)
    for src in avoid:
        for comp in cell.sources[src].components:
            out.append(
                (comp.centres[0], comp.radii[0])
                if comp.n_discs == 1 and comp.n_polygons == 0
                else None
            )
    return out


def _random_configs(cell: Workcell, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(cell.robot.lower, cell.robot.upper, (n, cell.robot.dim))


@pytest.mark.parametrize("cell", [P1, P6, ROT], ids=["translating", "arm", "rotating"])
@given(
    seed=st.integers(0, 2**32 - 1), carrying=st.booleans(), avoid=st.sampled_from(["all", "none"])
)
def test_batched_collision_agrees_with_shapely(cell, seed, carrying, avoid):
    part = next(iter(cell.parts)) if carrying else None
    qs = _random_configs(cell, 25, seed)
    got = cell.collides(qs, part, avoid)
    gaps = cell.clearance(qs, part, avoid)
    names = list(cell.sources) if avoid == "all" else []
    for q, g, gap in zip(qs, got, gaps, strict=True):
        ref, dist = _reference_collides(cell, q, part, names)
        if abs(dist) > 1e-7:
            assert g == ref
            if not ref:
                assert gap == pytest.approx(dist, abs=1e-7)


def test_mode_obstacles_follow_equations_1_to_3():
    # A configuration touching source S1 only.
    q = np.array([[16.0, 14.0]])
    assert P1.collides(q, avoid_sources="all")[0]  # NR: every source is an obstacle (3)
    assert not P1.collides(q, avoid_sources=P1.sources_except("S1"))[0]  # serving S1 (1)
    assert P1.collides(q, avoid_sources=P1.sources_except("S2"))[0]  # serving S2: S1 is an obstacle
    assert P1.in_region(q, "S1", "contact")[0]
    assert not P1.in_region(q, "S1", "enclosure")[0]


def test_narrow_opening_is_passable_only_when_empty():
    q = np.array([[40.5, 51.0]])
    assert P1.free(q, avoid_sources="none")[0]
    for part in P1.parts:
        assert P1.collides(q, carrying=part, avoid_sources="none")[0]


def test_region_tests_against_shapely():
    rng = np.random.default_rng(3)
    qs = np.c_[rng.uniform(0, 40, 400), rng.uniform(0, 30, 400), rng.uniform(-np.pi, np.pi, 400)]
    for kind in ("contact", "enclosure"):
        for comp in (0, 1):
            got = ROT.in_region(qs, "D1", kind, component=comp)
            region = ROT.destinations["D1"].geometries[comp]
            for q, g in zip(qs, got, strict=True):
                robot = _reference_geometry(ROT, q, None)
                if comp == 1:  # exact disc
                    c, r = ROT.destinations["D1"].components[1].centres[0], 3.0
                    far = np.max(np.hypot(*(np.asarray(robot.exterior.coords) - c).T))
                    ref = robot.distance(shapely.Point(c)) <= r if kind == "contact" else far < r
                    margin = (
                        abs(robot.distance(shapely.Point(c)) - r)
                        if kind == "contact"
                        else abs(far - r)
                    )
                    if margin < 0.2:  # inscribed-polygon approximation of disc enclosure
                        continue
                else:
                    ref = (
                        robot.intersects(region)
                        if kind == "contact"
                        else region.contains_properly(robot)
                    )
                assert g == ref
    assert ROT.in_region(np.array([[34.0, 6.0, np.pi / 4]]), "D1", "enclosure")[0]
    assert not ROT.in_region(np.array([[34.0, 6.0, 0.0]]), "D1", "enclosure")[
        0
    ]  # touches the boundary


def test_arm_regions_use_the_end_effector():
    a = P6.robot
    sols, valid = a.ik(np.array([16.0]), np.array([34.0]), np.array([np.pi]))
    q = sols[0, int(np.argmax(valid[0]))]
    assert P6.in_region(q, "S1", "contact", component=1)[0]
    assert not P6.in_region(q, "S1", "contact", component=0)[0]


def test_certified_motion_check_never_misses_a_collision():
    rng = np.random.default_rng(7)
    q0 = rng.uniform(ROT.robot.lower, ROT.robot.upper, (300, 3))
    q1 = q0 + rng.normal(0, [3, 3, 0.5], (300, 3))
    hit = ROT.motion_collides(q0, q1, step=0.5, avoid_sources="none")
    # dense reference sampling of each segment
    t = np.linspace(0, 1, 400)
    d = ROT.robot.difference(q0, q1)
    for i in np.flatnonzero(~hit):
        samples = ROT.robot.wrap(q0[i] + t[:, None] * d[i])
        assert not ROT.collides(samples, avoid_sources="none").any()
    assert hit.any() and (~hit).any()


def test_start_in_collision_is_reported_with_the_obstacle_name():
    sc = load_scenario("strategies_p1")
    robot = sc.robot.model_copy(update={"start": (20.0, 51.0)})
    with pytest.raises(ScenarioError) as err:
        Workcell.from_scenario(sc.model_copy(update={"robot": robot}))
    assert (
        str(err.value) == "robot.start: configuration (20, 51) collides with obstacle 'wall_left'"
    )
    robot = sc.robot.model_copy(update={"start": (1.0, 50.0)})
    with pytest.raises(ScenarioError, match="leaves the workcell bounds"):
        Workcell.from_scenario(sc.model_copy(update={"robot": robot}))


def test_with_obstacles_changes_the_environment_only():
    from cellplan.geometry import ShapeSet

    q = np.array([[40.5, 51.0]])
    assert P1.free(q, avoid_sources="none")[0]
    plug = ShapeSet.from_polygons([np.array([[35, 48], [46, 48], [46, 54], [35, 54]], float)])
    closed = P1.with_obstacles({**P1.obstacles, "plug": plug})
    assert closed.collides(q, avoid_sources="none")[0]
    assert P1.free(q, avoid_sources="none")[0]  # the original is unchanged
    assert "plug" in closed.obstacle_geometries and "plug" not in P1.obstacles


def test_unknown_names_in_queries_are_one_line_naming_the_argument():
    """A name the workcell does not have is the caller's mistake, reported as such."""
    cell = Workcell.from_scenario(load_scenario(scenario_path("strategies_tiny")))
    q = np.array([[1.0, 1.0]])
    cases = [
        (lambda: cell.collides(q, "P9"), "carrying", "unknown part 'P9'"),
        (lambda: cell.collides(q, None, ["S9"]), "avoid_sources", "unknown sources ['S9']"),
        (lambda: cell.in_region(q, "R9"), "name", "unknown region 'R9'"),
        (lambda: cell.in_region(q, "S1", kind="touching"), "kind", "must be 'contact' or"),
    ]
    for call, field, message in cases:
        with pytest.raises(ArgumentError) as exc:
            call()
        (problem,) = exc.value.problems
        assert problem.field == field and problem.message.startswith(message), problem

"""The 3-D workcell behind the validity interface: conformance, conservatism against the
URDF's own meshes, certified motions with near misses, bitmaps, regions, bundled cells."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from cellplan import arm as arms
from cellplan.api import load, loads
from cellplan.cspace import Grid, free_bitmap
from cellplan.registry import scenario_names, scenario_path
from cellplan.validity import ValiditySpace, check_space
from cellplan.workcell import Workcell
from cellplan.workcell3d import Workcell3D

# Six- and seven-joint arms, and a UR5 with its wrist locked (three joints: the tool
# point is reached, not an orientation).
CELLS_3D = ("ur5_cell", "panda_shelf", "strategies_ur5")


@functools.cache
def cell(name: str) -> Workcell3D:
    built = load(name).workcell
    assert isinstance(built, Workcell3D)
    return built


def _mesh_obstacles(c: Workcell3D, avoid: list[str]) -> list[tuple[object, np.ndarray]]:
    solids = list(c.obstacles.values())
    for s in avoid:
        solids += list(c.sources[s].components)
    return [(s.to_coal(), s.pose) for s in solids]


def _outside_bounds(c: Workcell3D, q: np.ndarray) -> np.ndarray:
    """Whether any collision-mesh vertex of the arm leaves the bounds' box."""
    poses = arms.forward(c.robot.arm, q)
    out = np.zeros(len(q), bool)
    for mesh in arms.link_meshes(c.robot.arm):
        if mesh.frame < 0:
            continue
        m = poses[:, mesh.frame] @ mesh.placement
        pts = np.einsum("nij,vj->nvi", m[:, :3, :3], mesh.vertices) + m[:, None, :3, 3]
        out |= ((pts < c.lo) | (pts > c.hi)).any(axis=(1, 2))
    return out


@pytest.mark.parametrize("name", CELLS_3D)
def test_3d_cells_pass_the_conformance_check(name):
    space = cell(name)
    assert isinstance(space, ValiditySpace)
    assert space.dimension == 3 and space.geometry == "spheres"
    check_space(space, np.random.default_rng(3), n=128)


@pytest.mark.parametrize(
    "name", ["strategies_p1", "strategies_p6", "rotating_bar", "adaptive_fig4"]
)
def test_2d_cells_pass_the_same_conformance_check(name):
    space = load(name).workcell
    assert isinstance(space, Workcell) and isinstance(space, ValiditySpace)
    assert space.dimension == 2 and space.geometry == "exact"
    check_space(space, np.random.default_rng(3), n=128)


@pytest.mark.parametrize("name", CELLS_3D)
def test_free_for_the_spheres_is_free_for_the_urdf_meshes(name):
    """The sphere cover is conservative: a configuration it calls free has no contact
    between the URDF's collision meshes and the obstacles, nor between links the SRDF
    lets collide, and stays within the bounds."""
    c = cell(name)
    q = c.sample(3000, np.random.default_rng(11))
    free = c.free(q)
    exact = arms.exact_collides(c.robot.arm, q[free], _mesh_obstacles(c, list(c.sources)))
    assert free.sum() > 100
    assert not exact.any()
    assert not _outside_bounds(c, q[free]).any()


def _near_misses(c: Workcell3D, rng: np.random.Generator, count: int) -> tuple:
    """Segments whose ends are free and which pass within millimetres of an obstacle:
    a free and a colliding configuration are bisected to the boundary, a point a few
    millimetres of clearance back is taken, and a short segment is laid across the
    approach direction through it."""
    q = c.sample(4000, rng)
    hit = c.collides(q, avoid_sources="none")
    free_q, hit_q = q[~hit], q[hit]
    starts, ends = [], []
    for k in range(count):
        a = free_q[k % len(free_q)]
        b = hit_q[k % len(hit_q)]
        lo, hi = 0.0, 1.0
        d = c.robot.difference(a, b)
        for _ in range(30):  # the boundary along a -> b, to about 1e-9 of the segment
            mid = (lo + hi) / 2
            if c.collides(c.robot.wrap(a + mid * d), avoid_sources="none")[0]:
                hi = mid
            else:
                lo = mid
        # Back from the boundary to a clearance of 1 to 20 mm, or less where the cell
        # allows no more (the UR5's shoulder cover keeps 5 mm from its table).
        back = c.robot.wrap(a + np.linspace(lo, 0.0, 400)[:, None] * d)
        gap = c.clearance(back, avoid_sources="none")
        target = min(rng.uniform(0.001, 0.02), rng.uniform(0.2, 0.9) * gap.max())
        point = back[int(np.argmax(gap >= target))]
        side = rng.normal(size=c.robot.dim)
        side -= side @ d / (d @ d) * d  # across the approach direction
        side *= rng.uniform(0.02, 0.2) / np.linalg.norm(side)
        lo_q, hi_q = c.robot.lower, c.robot.upper
        starts.append(np.clip(c.robot.wrap(point - side), lo_q, hi_q))
        ends.append(np.clip(c.robot.wrap(point + side), lo_q, hi_q))
    return np.array(starts), np.array(ends)


@pytest.mark.parametrize("name", CELLS_3D)
def test_certified_motions_have_no_collision_between_samples(name):
    """A motion reported free is free everywhere along it: checked by sampling each
    segment 100 times more densely than the certified check's step, with the sphere
    check and with the URDF meshes, on near misses built on purpose."""
    c = cell(name)
    rng = np.random.default_rng(5)
    q0, q1 = _near_misses(c, rng, 60)
    step = 0.02
    hit = c.motion_collides(q0, q1, step, avoid_sources="none")
    assert hit.any() and (~hit).any(), "the near misses should include both answers"
    t = np.linspace(0.0, 1.0, 2001)
    d = c.robot.difference(q0, q1)
    obstacles = _mesh_obstacles(c, [])
    for i in np.flatnonzero(~hit):
        samples = c.robot.wrap(q0[i] + t[:, None] * d[i])
        assert not c.collides(samples, avoid_sources="none").any()
        assert not arms.exact_collides(c.robot.arm, samples[::10], obstacles).any()
    # An uncertified check may call free what the certified one refuses, never the reverse.
    loose = c.motion_collides(q0, q1, step, avoid_sources="none", certified=False)
    assert not (loose & ~hit).any()


def test_2d_certified_motions_have_no_collision_between_samples():
    """The same guarantee on the planar arm of problem 6 (an exact 2-D workcell)."""
    c = load("strategies_p6").workcell
    rng = np.random.default_rng(9)
    q0 = c.sample(300, rng)
    q1 = c.robot.wrap(q0 + rng.normal(0, 0.3, q0.shape))
    hit = c.motion_collides(q0, q1, step=0.5, avoid_sources="none")
    t = np.linspace(0, 1, 600)
    d = c.robot.difference(q0, q1)
    for i in np.flatnonzero(~hit):
        assert not c.collides(c.robot.wrap(q0[i] + t[:, None] * d[i]), avoid_sources="none").any()
    assert hit.any() and (~hit).any()


THREE_JOINTS = """
robot:
  type: urdf
  urdf: ur5
  base: {xyz: [0.0, 0.0, 0.755]}
  joints: [shoulder_pan_joint, shoulder_lift_joint, elbow_joint]
  locked: {wrist_1_joint: -90, wrist_2_joint: -90, wrist_3_joint: 0}
  start: [0, -90, 90]
cspace: {cells: [32, 32, 32]}
"""


@functools.cache
def three_joint_cell() -> Workcell3D:
    text = scenario_path("ur5_cell").read_text()
    head = text.split("\nrobot:")[0]
    tail = "\nparts:" + text.split("\nparts:")[1]
    built = loads(head + THREE_JOINTS + tail).workcell
    assert isinstance(built, Workcell3D)
    return built


def test_three_joint_bitmap_is_conservative():
    """A cell marked free holds no colliding configuration anywhere in its box."""
    c = three_joint_cell()
    # The UR5's joints turn +-360 degrees: over that range 32 cells are 0.4 rad wide and
    # nothing is free for sure; this box of the joints around the work is what a
    # planner would grid.
    grid = Grid(
        np.array([-1.5, -2.6, -0.2]), np.array([1.5, -0.5, 2.6]), (32, 32, 32), (False,) * 3
    )
    free = free_bitmap(c, grid)
    assert 0.05 < free.mean() < 0.95
    rng = np.random.default_rng(2)
    cells = np.argwhere(free)
    picks = cells[rng.choice(len(cells), size=min(60, len(cells)), replace=False)]
    centres = grid.config_of(picks)
    offsets = rng.uniform(-0.5, 0.5, (40, 3)) * grid.spacing
    for q in centres:
        assert not c.collides(c.robot.wrap(q + offsets)).any()
    # And the bitmap is no blind refusal: most cells whose centre keeps a clearance of
    # twice the cell's motion bound are marked free.
    assert free.sum() > 0.3 * (~c.collides(grid.points())).sum()


def test_regions_contact_and_enclosure_follow_the_tool():
    c = cell("ur5_cell")
    (q,) = c.reach_region("fixture")
    assert q is not None
    q = q[None, :]
    assert c.in_region(q, "fixture", "contact")[0]
    assert not c.in_region(q, "bin_a", "contact")[0]
    # The tool point lies inside; with the part it is enclosed only if the cover fits.
    tool = c.tool_position(q)[0]
    assert np.all(np.abs(tool - c.destinations["fixture"].components[0].pose[:3, 3]) < 0.06)
    moved = c.in_region(q, "fixture", "contact", offset=(1.0, 0.0, 0.0))
    assert not moved[0]
    with pytest.raises(Exception, match="component"):
        c.in_region(q, "fixture", component=3)


@pytest.mark.parametrize("name", CELLS_3D)
def test_bundled_cells_have_every_region_reachable(name):
    c = cell(name)
    for region in [*c.sources, *c.destinations]:
        found = c.reach_region(region)
        assert found and all(q is not None for q in found), region
        for i, q in enumerate(found):
            assert c.in_region(q, region, component=i)[0]
            avoid = c.sources_except(region) if region in c.sources else "all"
            assert c.free(q, avoid_sources=avoid)[0]


def test_every_bundled_3d_scenario_is_listed():
    assert set(CELLS_3D) <= set(scenario_names())


def test_carrying_a_part_adds_its_cover():
    c = cell("ur5_cell")
    q = c.robot.start[None, :]
    empty = c.clearance(q)[0]
    held = c.clearance(q, carrying="P1")[0]
    assert held <= empty
    with pytest.raises(Exception, match="unknown part"):
        c.collides(q, carrying="P9")


def test_queries_refuse_degrees_and_bad_shapes():
    c = cell("ur5_cell")
    with pytest.raises(Exception, match="radians"):
        c.collides(np.full(6, 90.0))
    with pytest.raises(Exception, match="shape"):
        c.collides(np.zeros(5))
    with pytest.raises(Exception, match="step"):
        c.motion_collides(np.zeros(6), np.zeros(6), step=0.0)

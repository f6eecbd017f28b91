"""Kinematics: forward, inverse (both elbow branches), displacement bounds."""

from __future__ import annotations

import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from cellplan.geometry import ShapeSet, transform_points, wrap_angle
from cellplan.robots import planar_arm, rotating_robot, translating_robot

angles3 = arrays(float, 3, elements=st.floats(-3.1, 3.1))
angles2 = arrays(float, 2, elements=st.floats(-3.1, 3.1))


def arm(n: int, limits=None, tool=None):
    lengths = [20.0, 15.0, 10.0][:n]
    return planar_arm((5.0, -2.0), lengths, [3.0] * n, limits, [0.0] * n, tool)


def test_forward_kinematics_of_a_straight_arm():
    a = arm(3)
    pts = a.joint_positions(np.array([0.0, 0.0, 0.0]))[0]
    np.testing.assert_allclose(pts, [[5, -2], [25, -2], [40, -2], [50, -2]])
    pts = a.joint_positions(np.array([np.pi / 2, -np.pi / 2, 0.0]))[0]
    np.testing.assert_allclose(pts[-1], [5 + 25, -2 + 20], atol=1e-12)


@given(q=angles2.filter(lambda q: abs(np.sin(q[1])) > 1e-3))
def test_two_link_fk_then_ik_returns_the_configuration(q):
    a = arm(2)
    x, y, _ = a.tool_pose(q)[0]
    sols, valid = a.ik(x, y)
    branch = 0 if q[1] >= 0 else 1
    assert valid[0, branch]
    np.testing.assert_allclose(wrap_angle(sols[0, branch] - q), 0.0, atol=1e-7)


@given(q=angles3.filter(lambda q: abs(np.sin(q[1])) > 1e-3))
def test_three_link_fk_then_ik_with_orientation_returns_the_configuration(q):
    a = arm(3)
    x, y, phi = a.tool_pose(q)[0]
    sols, valid = a.ik(x, y, phi)
    branch = 0 if q[1] >= 0 else 1
    assert valid[0, branch]
    np.testing.assert_allclose(wrap_angle(sols[0, branch] - q), 0.0, atol=1e-7)
    # the other branch reaches the same tool pose too
    other = a.tool_pose(sols[0, 1 - branch])[0]
    np.testing.assert_allclose(other[:2], [x, y], atol=1e-7)


def test_ik_reports_unreachable_and_joint_limits():
    a = arm(2, limits=[(-np.pi / 2, np.pi / 2), (0.0, np.pi)])
    _, valid = a.ik(np.array([200.0]), np.array([0.0]))
    assert not valid.any()
    sols, valid = a.ik(np.array([5 + 20.0]), np.array([-2 + 15.0]))
    # elbow +1 within limits; the mirror branch needs q2 < 0, outside [0, pi]
    assert valid[0, 0] and not valid[0, 1]
    assert np.all(sols[0, 0, 1] >= 0)


def test_fixed_tool_orientation():
    a = arm(3, tool=0.3)
    poses = a.tool_pose(np.random.default_rng(0).uniform(-3, 3, (10, 3)))
    np.testing.assert_allclose(poses[:, 2], 0.3)


def _all_points(robot, q):
    poses = robot.body_poses(q)
    out = []
    for b, body in enumerate(robot.bodies.bodies):
        v = body.verts[0, : body.counts[0]]
        out.append(transform_points(v, poses[:, b]))
    return out


@given(q=angles3, step=arrays(float, 3, elements=st.floats(-0.2, 0.2)), t=st.floats(0, 1))
def test_arm_displacement_bound_holds(q, step, t):
    a = arm(3)
    bound = a.body_displacement_bounds(np.abs(step))
    before = _all_points(a, q[None])
    after = _all_points(a, (q + t * step)[None])
    for j, (p0, p1) in enumerate(zip(before, after, strict=True)):
        assert np.max(np.linalg.norm(p1 - p0, axis=-1)) <= bound[j] + 1e-9


@given(
    q=arrays(float, 3, elements=st.floats(-5, 5)),
    step=arrays(float, 3, elements=st.floats(-0.3, 0.3)),
)
def test_rigid_displacement_bound_holds(q, step):
    shape = ShapeSet.from_polygons([np.array([[-3, -1], [4, -1], [4, 2], [-3, 2]], float)])
    r = rotating_robot(shape, (0, 0, 0), (-10, -10, 10, 10))
    bound = r.body_displacement_bounds(np.abs(step))[0]
    v = shape.verts[0, :4]
    p0 = transform_points(v, r.body_poses(q)[:, 0])
    p1 = transform_points(v, r.body_poses(q + step)[:, 0])
    assert np.max(np.linalg.norm(p1 - p0, axis=-1)) <= bound + 1e-9


def test_limits_periodicity_and_wrap():
    a = arm(3, limits=[(-np.pi, np.pi), (-1.0, 1.0), (-2.0, 2.0)])
    assert a.periodic == (True, False, False)
    assert list(a.within_limits(np.array([[3.0, 0.5, 1.9], [0.0, 1.5, 0.0]]))) == [True, False]
    t = translating_robot(ShapeSet.point(), (1, 1), (0, 0, 10, 10))
    assert t.dim == 2 and t.periodic == (False, False)
    np.testing.assert_allclose(
        a.difference(np.array([3.0, 0, 0]), np.array([-3.0, 0, 0]))[0], 2 * np.pi - 6.0
    )


# --- capsule links and periodic joints (issue 13) --------------------------------------------


def capsule_arm():
    return planar_arm(
        (0.5, -0.25), [1.0, 0.75], [0.2, 0.1], None, [0.0, 0.0], shapes=["capsule", "capsule"]
    )


def _capsule_geometry(a, q):
    """Independent oracle: each link is the set of points within w/2 of its joint segment."""
    import shapely

    pts = a.joint_positions(np.asarray(q, float)[None])[0]
    return [
        shapely.LineString(pts[i : i + 2]).buffer(a.widths[i] / 2, quad_segs=64)
        for i in range(a.n_links)
    ]


def test_capsule_link_is_a_box_and_two_discs():
    a = capsule_arm()
    body = a.bodies.bodies[0]
    assert body.n_polygons == 1 and body.n_discs == 2
    np.testing.assert_allclose(body.centres, [[0.0, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(body.radii, [0.1, 0.1])
    assert body.reach() == 1.1
    rect = planar_arm((0, 0), [1.0], [0.2], None, [0.0])
    assert rect.bodies.bodies[0].n_discs == 0 and rect.capsules == ()


@given(
    q=angles2,
    centre=arrays(float, 2, elements=st.floats(-2.0, 3.0)),
    radius=st.floats(0.01, 0.3),
)
def test_capsule_arm_collides_exactly_like_buffered_segments(q, centre, radius):
    import shapely

    from cellplan.geometry import RigidBodies, bodies_collide

    a = capsule_arm()
    obstacle = ShapeSet.disc(centre, radius)
    gap = min(g.distance(shapely.Point(centre)) for g in _capsule_geometry(a, q)) - radius
    assume(abs(gap) >= 1e-3)  # the oracle's polygonised discs are within 1e-3 of round
    hit = bodies_collide(RigidBodies(a.bodies.bodies), a.body_poses(q), obstacle)[0]
    assert hit == (gap < 0)


@given(q=angles2, step=arrays(float, 2, elements=st.floats(-0.2, 0.2)), t=st.floats(0, 1))
def test_capsule_displacement_bound_holds(q, step, t):
    a = capsule_arm()
    bound = a.body_displacement_bounds(np.abs(step))
    for j in range(a.n_links):
        # the far cap's rim: the farthest points of a capsule from its joint
        ang = np.linspace(0, 2 * np.pi, 33)
        local = np.stack(
            [a.lengths[j] + a.widths[j] / 2 * np.cos(ang), a.widths[j] / 2 * np.sin(ang)], 1
        )
        p0 = transform_points(local, a.body_poses(q[None])[0, j])
        p1 = transform_points(local, a.body_poses((q + t * step)[None])[0, j])
        assert np.max(np.linalg.norm(p1 - p0, axis=-1)) <= bound[j] + 1e-9


def test_capsule_lever_is_longer_than_the_rectangle_lever():
    rect = planar_arm((0, 0), [1.0, 0.75], [0.2, 0.1], None, [0.0, 0.0])
    cap = capsule_arm()
    assert np.all(cap._link_levers() > rect._link_levers() - 1e-12)
    assert cap._link_levers()[0, 0] == 1.1


def test_unlimited_and_full_turn_joints_are_periodic():
    assert planar_arm((0, 0), [1.0, 1.0], [0.1, 0.1], None, [0, 0]).periodic == (True, True)
    full = planar_arm((0, 0), [1.0, 1.0], [0.1, 0.1], [(-4.0, 4.0), (-1.0, 1.0)], [0, 0])
    assert full.periodic == (True, False)


def test_ik_puts_a_limited_joint_into_its_limits_by_a_whole_turn():
    # joint 1 limited to [0, 350] degrees: a tip below the base needs q1 near 270 degrees,
    # which plain atan2 reports as -90 degrees (outside the limits)
    a = planar_arm((0, 0), [1.0, 1.0], [0.1, 0.1], [(0.0, 6.1), (-3.0, 3.0)], [1.0, 0.0])
    sols, valid = a.ik(np.array([0.0]), np.array([-1.5]))
    assert valid[0].all()
    assert np.all((sols[0, :, 0] >= 0.0) & (sols[0, :, 0] <= 6.1))
    tip = a.tool_pose(sols[0])[:, :2]
    np.testing.assert_allclose(tip, [[0.0, -1.5], [0.0, -1.5]], atol=1e-9)

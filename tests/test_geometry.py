"""Exact batched collision and distance kernels against shapely."""

from __future__ import annotations

import numpy as np
import shapely
import shapely.affinity
from hypothesis import given
from hypothesis import strategies as st

from cellplan.geometry import (
    RigidBodies,
    ShapeSet,
    bodies_collide,
    body_gaps,
    compose,
    convex_pieces,
    transform_points,
    wrap_angle,
)
from shapes import poses, star_polygon


def _posed_shapely(poly: np.ndarray, pose: tuple[float, float, float]) -> shapely.Polygon:
    g = shapely.affinity.rotate(shapely.Polygon(poly), pose[2], origin=(0, 0), use_radians=True)
    return shapely.affinity.translate(g, pose[0], pose[1])


@given(
    robot=star_polygon(),
    obstacle=star_polygon(rmax=6.0),
    pose_list=st.lists(poses, min_size=1, max_size=20),
)
def test_polygon_collision_matches_shapely(robot, obstacle, pose_list):
    bodies = RigidBodies((ShapeSet.from_geometry(shapely.Polygon(robot)),))
    obs = ShapeSet.from_geometry(shapely.Polygon(obstacle))
    P = np.array(pose_list)[:, None, :]
    got = bodies_collide(bodies, P, obs)
    ref = np.array(
        [_posed_shapely(robot, p).intersects(shapely.Polygon(obstacle)) for p in pose_list]
    )
    dist = np.array(
        [_posed_shapely(robot, p).distance(shapely.Polygon(obstacle)) for p in pose_list]
    )
    # Exact agreement except for floating-point ties at exact contact.
    decided = dist > 1e-9
    assert np.array_equal(got[decided], ref[decided])


@given(
    robot=star_polygon(),
    obstacle=star_polygon(rmax=6.0),
    pose_list=st.lists(poses, min_size=1, max_size=20),
)
def test_polygon_distance_matches_shapely(robot, obstacle, pose_list):
    bodies = RigidBodies((ShapeSet.from_geometry(shapely.Polygon(robot)),))
    obs = ShapeSet.from_geometry(shapely.Polygon(obstacle))
    got = body_gaps(bodies, np.array(pose_list)[:, None, :], obs)
    ref = np.array(
        [_posed_shapely(robot, p).distance(shapely.Polygon(obstacle)) for p in pose_list]
    )
    np.testing.assert_allclose(np.maximum(got, 0.0), ref, atol=1e-9)


@given(
    robot=star_polygon(),
    centre=st.tuples(st.floats(-12, 12), st.floats(-12, 12)),
    radius=st.floats(0.1, 4.0),
    pose=poses,
)
def test_disc_obstacle_distance_is_exact(robot, centre, radius, pose):
    bodies = RigidBodies((ShapeSet.from_geometry(shapely.Polygon(robot)),))
    got = body_gaps(bodies, np.array([[pose]]), ShapeSet.disc(centre, radius))[0]
    ref = _posed_shapely(robot, pose).distance(shapely.Point(centre)) - radius
    assert abs(max(got, 0.0) - max(ref, 0.0)) < 1e-9
    if abs(ref) > 1e-9:
        assert (got <= 0) == (ref <= 0)


@given(
    c1=st.tuples(st.floats(-5, 5), st.floats(-5, 5)),
    c2=st.tuples(st.floats(-5, 5), st.floats(-5, 5)),
    r1=st.floats(0.1, 3),
    r2=st.floats(0.1, 3),
)
def test_disc_disc(c1, c2, r1, r2):
    bodies = RigidBodies((ShapeSet.disc(c1, r1),))
    got = body_gaps(bodies, np.zeros((1, 1, 3)), ShapeSet.disc(c2, r2))[0]
    assert abs(got - (np.hypot(c1[0] - c2[0], c1[1] - c2[1]) - r1 - r2)) < 1e-12


def test_point_and_segment_robots():
    square = ShapeSet.from_polygons([np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)])
    point = RigidBodies((ShapeSet.point(),))
    P = np.array([[[0.5, 0.5, 0]], [[1.5, 0.5, 0]], [[1.0, 1.0, 0]]])
    assert list(bodies_collide(point, P, square)) == [True, False, True]
    seg = RigidBodies((ShapeSet.from_polygons([np.array([[-1.0, 0.0], [1.0, 0.0]])]),))
    # collinear with the square's bottom edge but beyond it: separated along the segment's direction
    P = np.array([[[3.5, 0.0, 0]], [[1.5, 0.0, 0]], [[0.5, 2.0, 0]]])
    assert list(bodies_collide(seg, P, square)) == [False, True, False]


def test_non_convex_polygon_is_split_into_convex_pieces():
    u_shape = shapely.Polygon([(0, 0), (6, 0), (6, 6), (4, 6), (4, 2), (2, 2), (2, 6), (0, 6)])
    pieces = convex_pieces(u_shape)
    assert len(pieces) > 1
    assert abs(sum(shapely.Polygon(p).area for p in pieces) - u_shape.area) < 1e-9
    obs = ShapeSet.from_geometry(u_shape)
    inside_notch = RigidBodies((ShapeSet.disc((0, 0), 0.5),))
    assert not bodies_collide(inside_notch, np.array([[[3.0, 4.0, 0.0]]]), obs)[0]


def test_multiple_bodies_and_margins():
    obs = ShapeSet.from_polygons([np.array([[10, -1], [11, -1], [11, 1], [10, 1]], float)])
    two = RigidBodies((ShapeSet.point(), ShapeSet.point()))
    P = np.array([[[0, 0, 0], [9, 0, 0]]], float)
    assert body_gaps(two, P, obs)[0] == 1.0
    assert not bodies_collide(two, P, obs, margins=np.array([0.0, 0.9]))[0]
    assert bodies_collide(two, P, obs, margins=np.array([0.0, 1.0]))[0]


@given(pose_a=poses, pose_b=poses)
def test_compose_matches_sequential_transform(pose_a, pose_b):
    pts = np.array([[1.0, 2.0], [-3.0, 0.5]])
    a, b = np.array(pose_a), np.array(pose_b)
    np.testing.assert_allclose(
        transform_points(pts, compose(a, b)),
        transform_points(transform_points(pts, b), a),
        atol=1e-9,
    )


def test_wrap_angle_range():
    x = np.linspace(-20, 20, 1001)
    w = wrap_angle(x)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(x), atol=1e-12)

"""3-D solids: exact distances against independent oracles (dense surface samples, points
placed at a known distance from a face, edge, vertex or rim, coal), mesh grids as lower
bounds, mesh loading and its one-line refusals, and coal's size conventions."""

from __future__ import annotations

import math
from pathlib import Path

import coal
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from cellplan import budget, solids
from cellplan.errors import ArgumentError, ScenarioError
from cellplan.solids import (
    Solid,
    SolidSet,
    bounds_gaps,
    box,
    capsule,
    cylinder,
    distances,
    inside_gaps,
    load_mesh,
    mesh,
    pose_matrix,
    sphere,
    sphere_gaps,
    sphere_gaps_each,
)

MESHES = Path(__file__).parent / "data" / "meshes"

# L-shaped prism of the fixtures: the union of these two boxes (volume 0.32).
L_BOXES = ((np.zeros(3), np.array([1.0, 0.4, 0.5])), (np.zeros(3), np.array([0.4, 1.0, 0.5])))


def random_pose(rng: np.random.Generator) -> np.ndarray:
    return pose_matrix(rng.uniform(-1, 1, 3), rng.uniform(-math.pi, math.pi, 3))


def primitives(rng: np.random.Generator) -> list[Solid]:
    return [
        box(rng.uniform(0.1, 0.8, 3), random_pose(rng)),
        cylinder(rng.uniform(0.05, 0.4), rng.uniform(0.1, 0.8), random_pose(rng)),
        sphere(rng.uniform(0.05, 0.4), random_pose(rng)),
        capsule(rng.uniform(0.05, 0.4), rng.uniform(0.1, 0.8), random_pose(rng)),
    ]


def local_extent(solid: Solid) -> np.ndarray:
    """Half extents of the solid's local bounding box."""
    if solid.kind == "box":
        return solid.size / 2
    radius = solid.size[0]
    if solid.kind == "sphere":
        return np.full(3, radius)
    half = solid.size[1] / 2 + (radius if solid.kind == "capsule" else 0.0)
    return np.array([radius, radius, half])


def to_local(solid: Solid, points: np.ndarray) -> np.ndarray:
    return (points - solid.translation) @ solid.rotation


def to_world(solid: Solid, local: np.ndarray) -> np.ndarray:
    return local @ solid.rotation.T + solid.translation


# --- independent oracles --------------------------------------------------------------------


def surface_samples(solid: Solid, step: float) -> np.ndarray:
    """Local points on the surface, none farther than about ``step`` from any surface point."""

    def grid(a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
        u = np.linspace(-a, a, max(2, int(2 * a / step) + 2))
        v = np.linspace(-b, b, max(2, int(2 * b / step) + 2))
        uu, vv = np.meshgrid(u, v)
        return uu.ravel(), vv.ravel()

    def disc(radius: float, z: float) -> np.ndarray:
        rings = [np.array([[0.0, 0.0, z]])]
        for r in np.linspace(0, radius, max(2, int(radius / step) + 2))[1:]:
            t = np.linspace(0, 2 * np.pi, max(8, int(2 * np.pi * r / step) + 2))
            rings.append(np.stack([r * np.cos(t), r * np.sin(t), np.full_like(t, z)], axis=1))
        return np.vstack(rings)

    def tube(radius: float, half: float) -> np.ndarray:
        count = max(8, int(2 * np.pi * radius / step) + 2)
        angles = np.linspace(-np.pi, np.pi, count)
        heights = np.linspace(-half, half, max(2, int(2 * half / step) + 2))
        aa, hh = np.meshgrid(angles, heights)
        return np.stack(
            [radius * np.cos(aa.ravel()), radius * np.sin(aa.ravel()), hh.ravel()], axis=1
        )

    def ball(radius: float, count: int) -> np.ndarray:
        i = np.arange(count) + 0.5
        polar = np.arccos(1 - 2 * i / count)
        azimuth = np.pi * (1 + 5**0.5) * i
        return radius * np.stack(
            [np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)],
            axis=1,
        )

    if solid.kind == "box":
        half = solid.size / 2
        faces = []
        for axis in range(3):
            other = [q for q in range(3) if q != axis]
            u, v = grid(half[other[0]], half[other[1]])
            for sign in (-1, 1):
                face = np.zeros((len(u), 3))
                face[:, axis] = sign * half[axis]
                face[:, other[0]], face[:, other[1]] = u, v
                faces.append(face)
        return np.vstack(faces)
    radius = float(solid.size[0])
    ball_count = int(4 * np.pi * radius**2 / step**2 * 2) + 50
    if solid.kind == "sphere":
        return ball(radius, ball_count)
    half = float(solid.size[1]) / 2
    if solid.kind == "cylinder":
        return np.vstack([tube(radius, half), disc(radius, -half), disc(radius, half)])
    caps = ball(radius, ball_count)
    return np.vstack(
        [
            tube(radius, half),
            caps[caps[:, 2] <= 0] - [0, 0, half],
            caps[caps[:, 2] >= 0] + [0, 0, half],
        ]
    )


def inside_rule(solid: Solid, local: np.ndarray) -> np.ndarray:
    """Membership by the definition of each shape (not by a distance)."""
    x, y, z = local.T
    if solid.kind == "box":
        return np.all(np.abs(local) <= solid.size / 2, axis=1)
    radius = solid.size[0]
    if solid.kind == "sphere":
        return x**2 + y**2 + z**2 <= radius**2
    half = solid.size[1] / 2
    in_tube = (x**2 + y**2 <= radius**2) & (np.abs(z) <= half)
    if solid.kind == "cylinder":
        return in_tube
    ends = (x**2 + y**2 + (np.abs(z) - half) ** 2) <= radius**2
    return in_tube | ends


def triangle_distances(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Brute-force unsigned distance to triangles: the plane's foot if it falls inside
    (barycentric test), else the nearest of the three edges."""
    best = np.full(len(points), np.inf)
    for a, b, c in tris:
        n = np.cross(b - a, c - a)
        n = n / np.linalg.norm(n)
        height = (points - a) @ n
        foot = points - np.outer(height, n)
        inside = np.ones(len(points), dtype=bool)
        for p, q in ((a, b), (b, c), (c, a)):
            inside &= np.cross(q - p, foot - p) @ n >= 0
        d = np.where(inside, np.abs(height), np.inf)
        for p, q in ((a, b), (b, c), (c, a)):
            t = np.clip((points - p) @ (q - p) / ((q - p) @ (q - p)), 0, 1)
            d = np.minimum(d, np.linalg.norm(points - p - np.outer(t, q - p), axis=1))
        best = np.minimum(best, d)
    return best


def in_l_shape(local: np.ndarray) -> np.ndarray:
    return np.logical_or.reduce(
        [np.all((local >= lo) & (local <= hi), axis=1) for lo, hi in L_BOXES]
    )


def l_mesh(pose: np.ndarray | None = None, name: str = "l_shape.obj") -> Solid:
    vertices, faces = load_mesh(MESHES / name, field="mesh")
    return mesh(vertices, faces, pose)


# --- primitives -----------------------------------------------------------------------------


def test_primitive_distances_match_dense_surface_samples_and_the_inside_rule():
    rng = np.random.default_rng(1)
    step = 0.004
    for solid in primitives(rng):
        local = rng.uniform(-1.5, 1.5, (400, 3)) * local_extent(solid)
        sd = distances(SolidSet.build([solid]), to_world(solid, local))[:, 0]
        nearest, _ = cKDTree(surface_samples(solid, step)).query(local)
        # The exact distance is at most that to any surface point, and the samples are
        # dense, so at most a sample spacing more.
        assert np.all(np.abs(sd) <= nearest + 1e-12), solid.kind
        assert np.all(nearest - np.abs(sd) <= 1.5 * step), solid.kind
        inside = inside_rule(solid, local)
        assert inside.any() and not inside.all(), solid.kind
        assert np.array_equal(sd < 0, inside), solid.kind


BOX_HALF = np.array([0.3, 0.2, 0.45])
RADIUS, HALF_LENGTH = 0.25, 0.35

FEATURES = {
    "box": ("face", "edge", "vertex"),
    "cylinder": ("side", "cap", "rim"),
    "sphere": ("surface",),
    "capsule": ("side", "end"),
}


def feature_point(kind: str, feature: str, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A surface point of the reference solid of ``kind`` on ``feature`` and a unit
    direction in that feature's normal cone (outward), from ``u`` in ``[0, 1]^3``."""
    angle = 2 * np.pi * u[0]
    if kind == "box":
        signs = np.where(u * 7 % 1 < 0.5, -1.0, 1.0)
        free = (2 * u - 1) * 0.999
        if feature == "face":
            point = np.array([signs[0], free[1], free[2]]) * BOX_HALF
            return point, np.array([signs[0], 0.0, 0.0])
        weights = 0.05 + u  # positive combination of the meeting faces' normals
        if feature == "edge":
            point = np.array([signs[0], signs[1], free[2]]) * BOX_HALF
            n = np.array([signs[0] * weights[0], signs[1] * weights[1], 0.0])
        else:
            point = signs * BOX_HALF
            n = signs * weights
        return point, n / np.linalg.norm(n)
    radial = np.array([np.cos(angle), np.sin(angle), 0.0])
    if kind == "sphere":
        polar = np.arccos(2 * u[1] - 1)
        n = np.array([np.sin(polar) * np.cos(angle), np.sin(polar) * np.sin(angle), np.cos(polar)])
        return RADIUS * n, n
    end = 1.0 if u[2] < 0.5 else -1.0
    if feature == "side":
        z = (2 * u[1] - 1) * HALF_LENGTH
        return RADIUS * radial + [0, 0, z], radial
    if kind == "cylinder":
        if feature == "cap":
            point = RADIUS * 0.999 * u[1] * radial + [0, 0, end * HALF_LENGTH]
            return point, np.array([0.0, 0.0, end])
        tilt = u[1] * np.pi / 2  # anywhere between the side's normal and the cap's
        n = np.cos(tilt) * radial + [0, 0, end * np.sin(tilt)]
        return RADIUS * radial + [0, 0, end * HALF_LENGTH], n
    polar = u[1] * np.pi / 2
    n = np.cos(polar) * radial + [0, 0, end * np.sin(polar)]
    return n * RADIUS + [0, 0, end * HALF_LENGTH], n


def reference_solid(kind: str, pose: np.ndarray) -> Solid:
    if kind == "box":
        return box(2 * BOX_HALF, pose)
    if kind == "sphere":
        return sphere(RADIUS, pose)
    if kind == "cylinder":
        return cylinder(RADIUS, 2 * HALF_LENGTH, pose)
    return capsule(RADIUS, 2 * HALF_LENGTH, pose)


@given(
    st.sampled_from([(k, f) for k, fs in FEATURES.items() for f in fs]),
    st.lists(st.floats(0, 1), min_size=3, max_size=3),
    st.lists(st.floats(-3, 3), min_size=6, max_size=6),
    st.sampled_from([1e-9, 1e-7, 1e-4, 0.01, 0.3, 2.0]),
)
def test_points_placed_at_a_known_distance_from_faces_edges_and_rims(feature, u, pose, gap):
    """Outside a convex solid, ``q + gap n`` with ``n`` in the normal cone at surface point
    ``q`` is exactly ``gap`` away, whatever ``gap`` is (near misses included)."""
    kind, name = feature
    solid = reference_solid(kind, pose_matrix(pose[:3], pose[3:]))
    q, n = feature_point(kind, name, np.array(u))
    world = to_world(solid, np.vstack([q + gap * n, q]))
    sd = distances(SolidSet.build([solid]), world)[:, 0]
    assert sd[0] == pytest.approx(gap, abs=2e-15 * (1 + 4 * np.abs(pose[:3]).max()))
    assert abs(sd[1]) < 1e-14


@given(
    st.sampled_from(["box", "cylinder", "sphere", "capsule"]),
    st.lists(st.floats(0.3, 0.7), min_size=3, max_size=3),
    st.lists(st.floats(-3, 3), min_size=6, max_size=6),
    st.sampled_from([1e-9, 1e-6, 1e-3, 0.02]),
)
def test_points_just_inside_a_face_are_as_deep_as_placed(kind, u, pose, depth):
    solid = reference_solid(kind, pose_matrix(pose[:3], pose[3:]))
    feature = {"box": "face", "cylinder": "cap", "sphere": "surface", "capsule": "side"}[kind]
    # u within [0.3, 0.7] keeps the point farther than the depth from other faces.
    q, n = feature_point(kind, feature, np.array(u))
    sd = distances(SolidSet.build([solid]), to_world(solid, (q - depth * n)[None]))[0, 0]
    assert sd == pytest.approx(-depth, abs=1e-14)


def test_coal_takes_full_lengths_and_agrees_with_the_distances():
    assert coal.Cylinder(0.1, 1.0).halfLength == pytest.approx(0.5)
    assert coal.Capsule(0.1, 1.0).halfLength == pytest.approx(0.5)
    assert np.allclose(coal.Box(1.0, 2.0, 3.0).halfSide, [0.5, 1.0, 1.5])
    rng = np.random.default_rng(2)
    point = coal.Sphere(1e-12)
    for solid in primitives(rng):
        geometry = solid.to_coal()
        placed = coal.Transform3s(solid.rotation, solid.translation)
        world = rng.uniform(-2, 2, (40, 3))
        sd = distances(SolidSet.build([solid]), world)[:, 0]
        for p, expected in zip(world[sd > 1e-3], sd[sd > 1e-3], strict=True):
            result = coal.DistanceResult()
            there = coal.Transform3s(np.eye(3), p)
            coal.distance(geometry, placed, point, there, coal.DistanceRequest(), result)
            assert result.min_distance == pytest.approx(expected, abs=1e-9)


def test_aabb_is_exact_for_primitives():
    rng = np.random.default_rng(3)
    for solid in primitives(rng):
        lo, hi = solid.aabb()
        world = to_world(solid, surface_samples(solid, 0.003))
        assert np.all(world >= lo - 1e-12) and np.all(world <= hi + 1e-12), solid.kind
        # Every side of the box touches the solid (to within the sample spacing).
        assert np.allclose(world.min(axis=0), lo, atol=2e-3), solid.kind
        assert np.allclose(world.max(axis=0), hi, atol=2e-3), solid.kind
    corners = box([0.2, 0.4, 0.6], random_pose(rng))
    vertices, _ = corners.triangles()
    lo, hi = corners.aabb()
    assert np.allclose(lo, vertices.min(axis=0), atol=1e-15)
    assert np.allclose(hi, vertices.max(axis=0), atol=1e-15)


def test_tessellations_are_closed_outward_and_on_the_surface():
    rng = np.random.default_rng(4)
    for solid in primitives(rng):
        vertices, faces = solid.triangles(64)
        on_surface = distances(SolidSet.build([solid]), vertices)[:, 0]
        assert np.abs(on_surface).max() < 1e-12, solid.kind
        closed = mesh(vertices, faces)
        assert solids._is_closed(closed.vertices, closed.faces), solid.kind
        assert np.array_equal(closed.faces, faces), solid.kind  # not reversed: outward
        assert closed.volume == pytest.approx(solid.volume, rel=0.02), solid.kind
    with pytest.raises(ArgumentError):
        sphere(1.0).triangles(2)


def test_volumes_and_sizes_follow_urdf():
    assert box([1, 2, 3]).volume == pytest.approx(6)
    assert cylinder(1, 2).volume == pytest.approx(2 * np.pi)
    assert sphere(1).volume == pytest.approx(4 / 3 * np.pi)
    assert capsule(1, 2).volume == pytest.approx(2 * np.pi + 4 / 3 * np.pi)
    assert capsule(0.5, 1.0).aabb()[1][2] == pytest.approx(1.0)  # length/2 + radius
    assert cylinder(0.5, 1.0).aabb()[1][2] == pytest.approx(0.5)


def test_pose_matrix_is_urdf_rpy():
    roll, pitch, yaw = 0.3, -0.7, 1.9

    c, s = math.cos(roll), math.sin(roll)
    rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    c, s = math.cos(pitch), math.sin(pitch)
    ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    c, s = math.cos(yaw), math.sin(yaw)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    pose = pose_matrix([1, 2, 3], [roll, pitch, yaw])
    assert np.allclose(pose[:3, :3], rz @ ry @ rx, atol=1e-15)
    assert np.allclose(pose[:3, 3], [1, 2, 3])
    assert np.allclose(pose_matrix([0, 0, 0], [math.pi / 2, 0, 0])[:3, :3] @ [0, 1, 0], [0, 0, 1])
    with pytest.raises(ArgumentError):
        pose_matrix([0, 0], [0, 0, 0])


def test_transformed_premultiplies_and_shares_mesh_arrays():
    rng = np.random.default_rng(5)
    a, b = random_pose(rng), random_pose(rng)
    moved = box([1, 1, 1], b).transformed(a)
    assert np.allclose(moved.pose, a @ b)
    part = l_mesh(b)
    placed = part.transformed(a)
    assert placed.vertices is part.vertices and placed.faces is part.faces
    assert np.allclose(placed.pose, a @ b)


def test_bad_solids_are_refused():
    with pytest.raises(ArgumentError, match="positive"):
        box([1, 0, 1])
    with pytest.raises(ArgumentError, match="rigid"):
        sphere(1.0, np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ArgumentError, match="kind"):
        Solid("cone", np.eye(4), np.ones(2))
    with pytest.raises(ArgumentError, match="indices"):
        mesh(np.zeros((3, 3)), [[0, 1, 3]])
    frozen = box([1, 1, 1])
    with pytest.raises(ValueError):
        frozen.pose[0, 0] = 2


# --- batched sphere queries -----------------------------------------------------------------


def test_sphere_gaps_are_the_exact_clearance_for_primitives():
    rng = np.random.default_rng(6)
    shapes = primitives(rng) + primitives(rng)
    prepared = SolidSet.build(shapes)
    centers = rng.uniform(-1.5, 1.5, (300, 7, 3))
    radii = rng.uniform(0, 0.2, 7)
    margin = rng.uniform(0, 0.05, 7)
    exact = distances(prepared, centers.reshape(-1, 3)).reshape(300, 7, len(shapes))
    expected_each = (exact - (radii + margin)[None, :, None]).min(axis=1)
    each = sphere_gaps_each(prepared, centers, radii, margin)
    assert np.array_equal(each, expected_each)
    assert np.array_equal(sphere_gaps(prepared, centers, radii, margin), expected_each.min(axis=1))
    assert np.allclose(
        sphere_gaps(prepared, centers, radii, 0.01),
        (exact - radii[None, :, None] - 0.01).min(axis=(1, 2)),
        rtol=0,
        atol=1e-15,
    )
    # Against coal's collision test, away from touching.
    gaps = sphere_gaps(prepared, centers, radii)
    for n in np.flatnonzero(np.abs(gaps) > 1e-6)[:40]:
        hit = False
        for solid in shapes:
            for c, r in zip(centers[n], radii, strict=True):
                result = coal.CollisionResult()
                coal.collide(
                    solid.to_coal(),
                    coal.Transform3s(solid.rotation, solid.translation),
                    coal.Sphere(float(r)),
                    coal.Transform3s(np.eye(3), c),
                    coal.CollisionRequest(),
                    result,
                )
                hit |= result.isCollision()
        assert hit == (gaps[n] < 0)


def test_sphere_gaps_refuse_bad_input_and_handle_no_solids():
    prepared = SolidSet.build([sphere(1.0)])
    centers = np.zeros((2, 1, 3))
    centers[1, 0, 0] = np.nan
    with pytest.raises(ArgumentError, match="finite"):
        sphere_gaps(prepared, centers, [0.1])
    with pytest.raises(ArgumentError, match="radii"):
        sphere_gaps(prepared, np.zeros((2, 3, 3)), [0.1])
    assert np.all(np.isinf(sphere_gaps(SolidSet.build([]), np.zeros((4, 2, 3)), [0.1, 0.2])))


def test_inside_gaps_of_primitive_containers():
    rng = np.random.default_rng(7)
    pose = random_pose(rng)
    container = box([1.0, 0.6, 0.4], pose)
    local = rng.uniform(-1, 1, (500, 3, 3)) * [0.55, 0.33, 0.22]
    radii = np.array([0.02, 0.05, 0.0])
    gaps = inside_gaps(container, to_world(container, local), radii)
    # A sphere lies inside a box when its centre is a radius inside every wall, and then
    # that is its depth.
    room = ((np.array([0.5, 0.3, 0.2]) - np.abs(local)).min(axis=2) - radii).min(axis=1)
    assert np.array_equal(gaps > 0, room > 0)
    assert np.allclose(gaps[room > 0], room[room > 0], rtol=0, atol=1e-14)
    assert np.all(gaps <= room + 1e-14)
    assert (gaps > 0).sum() > 10 and (gaps < 0).sum() > 10
    ball = sphere(0.5, pose)
    centers = to_world(ball, rng.uniform(-0.5, 0.5, (200, 1, 3)))
    depth = 0.5 - np.linalg.norm(to_local(ball, centers[:, 0]), axis=1) - 0.1
    assert np.allclose(inside_gaps(ball, centers, [0.1]), depth, atol=1e-14)


def test_bounds_gaps_measure_to_the_walls():
    centers = np.array([[[0.5, 0.5, 0.5], [0.2, 0.9, 0.5]], [[1.5, 0.5, 0.5], [0.5, 0.5, 0.5]]])
    gaps = bounds_gaps([0, 0, 0], [1, 1, 2], centers, [0.1, 0.05])
    assert np.allclose(gaps, [0.05, -0.6])
    with pytest.raises(ArgumentError):
        bounds_gaps([0, 0, 0], [1, -1, 1], centers, [0.1, 0.05])


# --- meshes ---------------------------------------------------------------------------------


def test_fixture_meshes_load_in_every_format():
    tetra = [load_mesh(MESHES / name, field="m") for name in ("tetra.obj", "tetra.dae")]
    for vertices, faces in tetra:
        assert faces.shape == (4, 3)
        assert mesh(vertices, faces).volume == pytest.approx(1 / 6)
    obj, stl = l_mesh(), l_mesh(name="l_shape.stl")
    for part in (obj, stl):
        assert part.volume == pytest.approx(0.32, rel=1e-6)
        lo, hi = part.aabb()
        assert np.allclose(lo, 0) and np.allclose(hi, [1, 1, 0.5])
    vertices, faces = load_mesh(MESHES / "l_shape.stl", (2.0, 1.0, -1.0), field="m")
    mirrored = mesh(vertices, faces)
    assert mirrored.volume == pytest.approx(0.64, rel=1e-6)
    assert solids._signed_volume(vertices, faces) > 0  # mirrored, still wound outwards


def test_mesh_distances_are_exact_with_the_winding_sign():
    rng = np.random.default_rng(8)
    part = l_mesh(random_pose(rng))
    local = rng.uniform(-0.3, 1.3, (600, 3))
    sd = distances(SolidSet.build([part], mesh_spacing=0.1), to_world(part, local))[:, 0]
    assert part.vertices is not None and part.faces is not None
    expected = triangle_distances(local, part.vertices[part.faces])
    assert np.allclose(np.abs(sd), expected, atol=1e-12)
    assert np.array_equal(sd < 0, in_l_shape(local))


def test_inward_wound_meshes_are_turned_outwards_and_keep_their_inside():
    vertices, faces = load_mesh(MESHES / "tetra.obj", field="m")
    turned = mesh(vertices, faces[:, ::-1])
    assert np.array_equal(turned.faces, faces)
    inward = Solid("mesh", np.eye(4), np.ones(3), vertices, faces[:, ::-1])
    sd = distances(SolidSet.build([inward], mesh_spacing=0.1), [[0.1, 0.1, 0.1], [1, 1, 1]])
    assert sd[0, 0] == pytest.approx(-0.1) and sd[1, 0] > 0


def test_a_mesh_with_a_hole_is_inside_by_its_winding_number():
    """A cube missing its top: the centre sees 5 of 6 faces (w = 5/6 > 1/2), so it is
    inside."""
    vertices, faces = box([1, 1, 1]).triangles()
    centroid_z = vertices[faces].mean(axis=1)[:, 2]
    open_box = mesh(vertices, faces[centroid_z < 0.49])
    prepared = SolidSet.build([open_box], mesh_spacing=0.1)
    assert not prepared.meshes[0].closed
    sd = distances(prepared, [[0, 0, 0], [0, 0, 0.3], [0, 0, 2.0], [2, 0, 0]])[:, 0]
    # Distances are to the triangles: the missing top is no surface.
    assert np.allclose(sd, [-0.5, -0.5, math.sqrt(0.5**2 + 1.5**2), 1.5])


def grid_nodes(prepared: SolidSet, g: int = 0) -> np.ndarray:
    shape = prepared.grid_shape[g]
    index = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1)
    return prepared.grid_origin[g] + prepared.grid_spacing[g] * index.reshape(-1, 3)


@pytest.mark.parametrize("name", ["l_shape.obj", "l_shape.stl", "open"])
def test_mesh_grids_hold_exact_signed_distances(name):
    rng = np.random.default_rng(9)
    if name == "open":
        vertices, faces = box([0.8, 0.6, 0.5]).triangles()
        part = mesh(vertices, faces[:-1], random_pose(rng))
    else:
        part = l_mesh(random_pose(rng), name)
    prepared = SolidSet.build([part], mesh_spacing=0.04)
    exact = distances(prepared, to_world(part, grid_nodes(prepared)))[:, 0]
    assert np.allclose(prepared.grid_values, exact, rtol=0, atol=1e-14)
    assert (exact < 0).sum() > 50


def test_grids_of_a_finely_tessellated_mesh_match_the_shape():
    """Hundreds of triangles meeting at shared edges and poles: the signs carried up the
    grid's columns agree with the per-node rule, and both with the capsule."""
    rng = np.random.default_rng(13)
    pose = random_pose(rng)
    exact_shape = capsule(0.2, 0.3, pose)
    vertices, faces = capsule(0.2, 0.3).triangles(24)
    part = mesh(vertices, faces, pose)
    prepared = SolidSet.build([part], mesh_spacing=0.03)
    assert prepared.meshes[0].closed
    world = to_world(part, grid_nodes(prepared))
    exact = distances(prepared, world)[:, 0]
    assert np.allclose(prepared.grid_values, exact, rtol=0, atol=1e-14)
    # The tessellation lies within its chord error (2 percent of the radius) of the capsule.
    assert np.allclose(exact, distances(SolidSet.build([exact_shape]), world)[:, 0], atol=0.005)


def test_column_crossings_count_faces_and_distrust_edges():
    vertices, faces = load_mesh(MESHES / "tetra.obj", field="m")
    index = solids._MeshIndex.build(vertices, faces)
    stack = np.empty(256, dtype=np.int64)

    def crossings(x: float, y: float, z0: float, z1: float) -> tuple[int, bool]:
        return solids._column_crossings(
            x, y, z0, z1, index.tris, index.lo, index.hi, index.left, index.right,
            index.start, index.count, stack,
        )  # fmt: skip

    # Up through the floor (normal down) into the solid, then out through the slope.
    assert crossings(0.2, 0.2, -1.0, 0.3) == (-1, True)
    assert crossings(0.2, 0.2, -1.0, 2.0) == (0, True)
    assert crossings(0.2, 0.2, 0.3, 2.0) == (1, True)
    assert crossings(2.0, 2.0, -1.0, 2.0) == (0, True)
    assert crossings(0.0, 0.0, -1.0, 2.0)[1] is False  # through a vertex
    assert crossings(0.5, 0.0, -1.0, 2.0)[1] is False  # along a face, through an edge
    assert crossings(0.2, 0.2, -1.0, 0.0)[1] is False  # ends on the floor


@pytest.mark.parametrize("name", ["l_shape.obj", "l_shape.stl", "tetra.obj"])
def test_mesh_grid_lookups_bound_the_exact_distance(name):
    rng = np.random.default_rng(10)
    part = l_mesh(random_pose(rng), name)
    prepared = SolidSet.build([part], mesh_spacing=0.05)
    h = prepared.grid_spacing[0]
    lo = prepared.grid_origin[0]
    hi = lo + h * (prepared.grid_shape[0] - 1)
    local = np.vstack([rng.uniform(lo, hi, (3000, 3)), rng.uniform(lo - 1, hi + 1, (1000, 3))])
    in_grid = np.all((local >= lo) & (local <= hi), axis=1)
    world = to_world(part, local)
    exact = distances(prepared, world)[:, 0]
    lower = sphere_gaps(prepared, world[:, None, :], [0.0])
    upper = -inside_gaps(prepared, world[:, None, :], [0.0])
    assert np.all(lower <= exact + 1e-12)
    assert np.all(upper >= exact - 1e-12)
    diagonal = h * math.sqrt(3)
    assert np.all(lower[in_grid] >= exact[in_grid] - diagonal)
    assert np.all(upper[in_grid] <= exact[in_grid] + diagonal)
    # With radii: the bound shifts by the radius, and the spheres deep inside count.
    radii = np.array([0.0, 0.03])
    pairs = world[:200].reshape(100, 2, 3)
    assert np.all(
        sphere_gaps(prepared, pairs, radii)
        <= (exact[:200].reshape(100, 2) - radii).min(axis=1) + 1e-12
    )


def test_placements_of_one_mesh_share_a_grid_and_primitives_mix_in():
    rng = np.random.default_rng(11)
    part = l_mesh()
    placed = [part.transformed(random_pose(rng)) for _ in range(3)]
    shapes = [*placed, *primitives(rng)]
    prepared = SolidSet.build(shapes, mesh_spacing=0.05)
    assert len(prepared.meshes) == 1 and list(prepared.grid_index[:3]) == [0, 0, 0]
    centers = rng.uniform(-1.5, 1.5, (200, 4, 3))
    radii = np.array([0.0, 0.01, 0.05, 0.1])
    each = sphere_gaps_each(prepared, centers, radii)
    exact = distances(prepared, centers.reshape(-1, 3)).reshape(200, 4, len(shapes))
    truth = (exact - radii[None, :, None]).min(axis=1)
    assert np.array_equal(each[:, 3:], truth[:, 3:])
    assert np.all(each[:, :3] <= truth[:, :3] + 1e-12)
    assert np.array_equal(sphere_gaps(prepared, centers, radii), each.min(axis=1))


def test_grids_are_coarsened_to_the_node_cap():
    prepared = SolidSet.build([l_mesh()], mesh_spacing=0.001, max_grid_nodes=5000)
    assert np.prod(prepared.grid_shape[0]) <= 5000
    assert prepared.grid_spacing[0] > 0.001


def test_a_grid_that_cannot_fit_is_refused_before_it_is_built(monkeypatch):
    monkeypatch.setenv(budget.LIMIT_VARIABLE, str(budget.resident_memory() + 10**6))
    with pytest.raises(ScenarioError) as err:
        SolidSet.build([l_mesh()], mesh_spacing=0.002, names=["obstacles.fixture"])
    (problem,) = err.value.problems
    assert problem.field == "obstacles.fixture"
    assert problem.message.startswith("needs about")


def test_coal_mesh_models_agree_with_the_distances():
    rng = np.random.default_rng(12)
    part = l_mesh(random_pose(rng))
    world = to_world(part, rng.uniform(-0.5, 1.5, (60, 3)))
    sd = distances(SolidSet.build([part], mesh_spacing=0.1), world)[:, 0]
    geometry = part.to_coal()
    placed = coal.Transform3s(part.rotation, part.translation)
    for p, expected in zip(world[sd > 1e-3], sd[sd > 1e-3], strict=True):
        result = coal.DistanceResult()
        there = coal.Transform3s(np.eye(3), p)
        coal.distance(geometry, placed, coal.Sphere(1e-12), there, coal.DistanceRequest(), result)
        assert result.min_distance == pytest.approx(expected, abs=1e-6)


def test_inside_gaps_of_a_mesh_container_are_a_lower_bound():
    part = l_mesh()
    prepared = SolidSet.build([part], mesh_spacing=0.02)
    centers = np.array([[[0.2, 0.2, 0.25]], [[0.7, 0.2, 0.25]], [[0.7, 0.7, 0.25]]])
    gaps = inside_gaps(prepared, centers, [0.1])
    assert 0 < gaps[0] <= 0.1 + 1e-12 and 0 < gaps[1] <= 0.1 + 1e-12
    assert gaps[2] < 0


# --- mesh files -----------------------------------------------------------------------------


def _refusal(path: Path, scale: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> str:
    with pytest.raises(ScenarioError) as err:
        load_mesh(path, scale, field="parts.bracket.mesh")
    (problem,) = err.value.problems
    assert problem.field == "parts.bracket.mesh"
    assert "\n" not in problem.message
    return problem.message


def test_mesh_files_that_cannot_be_used_are_refused_in_one_line(tmp_path):
    assert "no such mesh file" in _refusal(tmp_path / "missing.stl")
    (tmp_path / "folder.obj").mkdir()
    assert "not a regular file" in _refusal(tmp_path / "folder.obj")
    (tmp_path / "empty.stl").write_bytes(b"")
    assert "is empty" in _refusal(tmp_path / "empty.stl")
    (tmp_path / "part.ply").write_text("ply\n")
    assert "expected STL, OBJ or DAE" in _refusal(tmp_path / "part.ply")
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    assert "has no volume" in _refusal(tmp_path / "flat.obj")
    (tmp_path / "noise.stl").write_bytes(b"solid x\n this is not an STL file \x00\x01\x02" * 3)
    assert "mesh" in _refusal(tmp_path / "noise.stl")
    assert "scale" in _refusal(MESHES / "tetra.obj", scale=(1.0, 0.0, 1.0))


def test_big_mesh_files_are_refused_by_size_and_memory(monkeypatch):
    monkeypatch.setattr(solids, "MAX_MESH_BYTES", 100)
    assert "are refused" in _refusal(MESHES / "l_shape.obj")
    monkeypatch.setattr(solids, "MAX_MESH_BYTES", 200 * 10**6)
    monkeypatch.setattr(solids, "MESH_BYTES_PER_TRIANGLE", 10**12)
    assert _refusal(MESHES / "l_shape.stl").startswith("needs about")

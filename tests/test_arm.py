"""Tests of cellplan.arm: kinematics against Pinocchio, the sphere cover against the
meshes and the exact check, the lever-arm bound, IK and every user error."""

from __future__ import annotations

import math
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest

from cellplan import arm as A
from cellplan.errors import ArgumentError, ScenarioError

TOY = Path(__file__).parent / "data" / "urdf" / "toy_arm.urdf"
PANDA_ARM = [f"panda_joint{i}" for i in range(1, 8)]
UR5_TYPICAL = np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0])
PANDA_READY = np.radians([0.0, -45.0, 0.0, -135.0, 0.0, 90.0, 45.0])


def _random_pose(rng: np.random.Generator, translation: float = 0.5) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    pose = np.eye(4)
    pose[:3, :3] = q
    pose[:3, 3] = rng.uniform(-translation, translation, 3)
    return pose


@pytest.fixture(scope="module")
def ur5() -> A.Arm:
    return A.load_arm("ur5")


@pytest.fixture(scope="module")
def panda() -> A.Arm:
    return A.load_arm("panda", joints=PANDA_ARM, locked={"panda_finger_joint1": 0.02})


@pytest.fixture(scope="module")
def toy() -> A.Arm:
    return A.load_arm(TOY)


def _uniform(arm: A.Arm, n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(arm.lower, arm.upper, (n, arm.dim))


# --------------------------------------------------------------------------- loading


def test_bundled_paths_and_unknown_name() -> None:
    urdf, srdf, share = A.bundled("ur5")
    assert urdf.name == "ur5_robot.urdf" and urdf.is_file()
    assert srdf is not None and srdf.name == "ur5.srdf"
    assert (share / "example-robot-data" / "robots").is_dir()
    assert A.bundled("panda")[0].name == "panda.urdf"
    with pytest.raises(ArgumentError) as err:
        A.bundled("kuka")
    assert "panda, ur5" in str(err.value)


def test_loaded_fields(ur5: A.Arm, panda: A.Arm, toy: A.Arm) -> None:
    assert ur5.dim == 6 and ur5.tool_frame == "tool0"
    assert ur5.fixed_links == ("base_link",)
    assert not ur5.periodic.any()
    np.testing.assert_allclose(ur5.velocity_limit, [3.15, 3.15, 3.15, 3.2, 3.2, 3.2])
    assert panda.dim == 7 and panda.tool_frame == "panda_hand_tcp"
    assert panda.locked == {"panda_finger_joint1": 0.02, "panda_finger_joint2": 0.0}
    assert set(panda.spheres.link) >= {"panda_link1", "panda_hand", "panda_leftfinger"}
    assert panda.fixed_links == ("panda_link0",)
    # The toy's continuous joint is periodic with limits (-pi, pi]; the others are not.
    assert toy.joint_names == ("turn", "bend", "slide")
    np.testing.assert_array_equal(toy.periodic, [True, False, False])
    np.testing.assert_allclose(toy.lower, [-math.pi, -2.0, 0.0])
    np.testing.assert_allclose(toy.upper, [math.pi, 2.0, 0.1])
    assert toy.tool_frame == "tip"


def test_self_pairs_follow_adjacency_and_srdf(ur5: A.Arm, panda: A.Arm) -> None:
    for arm in (ur5, panda):
        links = arm.spheres.link
        pairs = {frozenset((links[i], links[j])) for i, j in arm.self_pairs}
        assert all(len(p) == 2 for p in pairs)
        assert not pairs & arm.disabled
    ur5_pairs = {frozenset((ur5.spheres.link[i], ur5.spheres.link[j])) for i, j in ur5.self_pairs}
    # upper arm / wrist 1 is neither adjacent nor disabled; wrist 3 / ee_link are one body.
    assert frozenset(("upper_arm_link", "wrist_1_link")) in ur5_pairs
    assert frozenset(("wrist_3_link", "ee_link")) not in ur5_pairs
    assert frozenset(("shoulder_link", "upper_arm_link")) not in ur5_pairs
    fixed = {ur5.spheres.link[i] for i, _ in ur5.fixed_pairs}
    assert "forearm_link" in fixed and "shoulder_link" not in fixed


# --------------------------------------------------------------------------- kinematics


@pytest.mark.parametrize("which", ["ur5", "panda", "toy"])
def test_forward_matches_pinocchio(which: str, request: pytest.FixtureRequest) -> None:
    rng = np.random.default_rng(3)
    base = _random_pose(rng)
    if which == "ur5":
        arm = A.load_arm("ur5", base=base)
    elif which == "panda":
        # Shuffled columns and a locked finger: the column mapping must follow names.
        joints = ["panda_joint3", "panda_joint1", "panda_joint2", "panda_finger_joint2"] + [
            f"panda_joint{i}" for i in (7, 6, 5, 4)
        ]
        arm = A.load_arm("panda", base=base, joints=joints, locked={"panda_finger_joint1": 0.03})
    else:
        arm = A.load_arm(TOY, base=base)
    qs = _uniform(arm, 40, 4)
    poses = A.forward(arm, qs)
    tools = A.tool_pose(arm, qs)
    centres = A.sphere_centers(arm, qs)
    data = arm.model.createData()
    fid = arm.model.getFrameId(arm.tool_frame)
    for k, q in enumerate(qs):
        pin.forwardKinematics(arm.model, data, A._pin_q(arm, q))
        pin.updateFramePlacements(arm.model, data)
        for f in range(poses.shape[1]):
            np.testing.assert_allclose(poses[k, f], base @ data.oMi[f + 1].homogeneous, atol=1e-9)
        np.testing.assert_allclose(tools[k], base @ data.oMf[fid].homogeneous, atol=1e-9)
    s = arm.spheres
    frames = poses[:, s.frame]
    expected = np.einsum("nsij,sj->nsi", frames[..., :3, :3], s.centers) + frames[..., :3, 3]
    np.testing.assert_allclose(centres, expected, atol=1e-12)


def test_continuous_joint_is_an_angle(toy: A.Arm) -> None:
    q = np.array([-2.5, 0.3, 0.05])
    turned = q + np.array([2.0 * math.pi, 0.0, 0.0])
    np.testing.assert_allclose(A.forward(toy, turned), A.forward(toy, q), atol=1e-12)
    assert A.forward(toy, q).shape == (1, 3, 4, 4)


def test_configuration_checks(ur5: A.Arm) -> None:
    with pytest.raises(ArgumentError) as err:
        A.forward(ur5, np.zeros((3, 5)))
    assert err.value.problems[0].field == "q"
    with pytest.raises(ArgumentError, match="radians"):
        A.sphere_centers(ur5, np.array([0.0, -90.0, 90.0, 0.0, 0.0, 0.0]))
    with pytest.raises(ArgumentError, match="NaN"):
        A.self_collides(ur5, np.full(6, np.nan))
    with pytest.raises(ArgumentError):
        A.tool_pose(ur5, [[True] * 6])


# --------------------------------------------------------------------------- cover


def _covered(points: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    gap = np.linalg.norm(points[:, None, :] - centres[None], axis=2) - radii[None]
    return gap.min(axis=1) <= 1e-12


@pytest.mark.parametrize("seed", range(6))
def test_cover_contains_the_convex_hull(seed: int) -> None:
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(seed)
    vertices = rng.normal(size=(40, 3)) * rng.uniform(0.01, 0.1, 3)
    if seed == 0:  # a thin plate-like box
        vertices = np.array(
            [[x, y, z] for x in (0, 0.4) for y in (0, 0.2) for z in (0, 0.01)], dtype=float
        )
    faces = ConvexHull(vertices).simplices
    max_radius = [0.02, 0.05, 0.1, 0.03, 0.2, 0.04][seed]
    centres, radii = A.cover_mesh(vertices, faces, max_radius, max_spheres=400)
    assert radii.max() <= max_radius + 1e-6 or len(radii) >= 399
    hull = vertices[np.unique(faces)]
    simplex = rng.integers(0, len(hull), (3000, 4))
    weights = rng.dirichlet(np.ones(4), 3000)
    inside = np.einsum("nk,nkj->nj", weights, hull[simplex])
    tri = faces[rng.integers(0, len(faces), 3000)]
    bary = rng.dirichlet(np.ones(3), 3000)
    on_faces = np.einsum("nk,nkj->nj", bary, vertices[tri])
    points = np.vstack([inside, on_faces, hull])
    assert _covered(points, centres, radii).all()


def test_cover_refuses_flat_and_bad_meshes() -> None:
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    with pytest.raises(ArgumentError, match="no volume"):
        A.cover_mesh(flat, [[0, 1, 2], [1, 2, 3]], 0.1)
    with pytest.raises(ArgumentError):
        A.cover_mesh(np.zeros((4, 2)), [], 0.1)
    with pytest.raises(ArgumentError):
        A.cover_mesh(np.eye(4, 3), [[0, 1, 9]], 0.1)
    with pytest.raises(ArgumentError):
        A.cover_mesh(np.eye(4, 3), [], 0.0)


def _geometry_points(obj: object) -> np.ndarray:
    """Vertices of a collision object (a mesh's, or a box's corners) in its joint frame."""
    geom = obj.geometry  # type: ignore[attr-defined]
    if isinstance(geom, coal.Box):
        h = np.asarray(geom.halfSide)
        pts = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * h
    else:
        pts = np.asarray(geom.vertices())
    m = obj.placement.homogeneous  # type: ignore[attr-defined]
    return pts @ m[:3, :3].T + m[:3, 3]


@pytest.mark.parametrize("which", ["ur5", "panda"])
def test_cover_contains_every_collision_mesh(which: str, request: pytest.FixtureRequest) -> None:
    arm = request.getfixturevalue(which)
    for obj in arm.geometry.geometryObjects:
        link = arm.model.frames[obj.parentFrame].name
        frame = obj.parentJoint - 1
        spheres = arm.spheres if frame >= 0 else arm.fixed_spheres
        mine = (np.array(spheres.link) == link) & (spheres.frame == frame)
        assert mine.any(), link
        points = _geometry_points(obj)
        covered = _covered(points, spheres.centers[mine], spheres.radii[mine])
        assert covered.all(), f"{link}: {np.count_nonzero(~covered)} vertices outside"


def test_cover_of_primitives(toy: A.Arm) -> None:
    rng = np.random.default_rng(5)
    s = toy.spheres
    # link1: box 0.5 x 0.06 x 0.06 centred at x = 0.25 of frame 0.
    box = rng.uniform([0, -0.03, -0.03], [0.5, 0.03, 0.03], (2000, 3))
    mine = s.frame == 0
    assert _covered(box, s.centers[mine], s.radii[mine]).all()
    # link2: cylinder r = 0.03 along x from 0 to 0.4 of frame 1 (rim points included).
    t = rng.uniform(0, 2 * np.pi, 2000)
    x = rng.uniform(0.0, 0.4, 2000)
    rho = 0.03 * np.sqrt(rng.uniform(0, 1, 2000))
    rho[:500] = 0.03
    cyl = np.column_stack([x, rho * np.cos(t), rho * np.sin(t)])
    mine = s.frame == 1
    assert _covered(cyl, s.centers[mine], s.radii[mine]).all()
    # slider: a sphere stays one exact sphere.
    mine = s.frame == 2
    np.testing.assert_allclose(s.radii[mine], [0.04], atol=1e-8)
    assert toy.spheres.radii.max() <= toy.max_radius + 1e-6


# --------------------------------------------------------------------------- collisions


def _spheres_hit_box(centres: np.ndarray, radii: np.ndarray, pose: np.ndarray, half: np.ndarray):
    local = (centres - pose[:3, 3]) @ pose[:3, :3]
    nearest = np.clip(local, -half, half)
    return (np.linalg.norm(local - nearest, axis=-1) <= radii).any(axis=-1)


def test_sphere_check_is_conservative_near_a_box(ur5: A.Arm) -> None:
    half = np.array([0.15, 0.1, 0.2])
    pose = np.eye(4)
    pose[:3, :3] = pin.rpy.rpyToMatrix(0.2, -0.1, 0.5)
    pose[:3, 3] = [0.35, 0.15, 0.3]
    qs = _uniform(ur5, 400, 11)
    exact = A.exact_collides(ur5, qs, [(coal.Box(*(2 * half)), pose)])
    centres = A.sphere_centers(ur5, qs)
    hit_box = _spheres_hit_box(centres, ur5.spheres.radii, pose, half)
    flagged = hit_box | A.self_collides(ur5, qs)
    assert 0.2 < exact.mean() < 0.9  # the box is near: both outcomes occur
    assert not (exact & ~flagged).any()
    # The exact distance agrees in sign with the exact check where there is no self-hit.
    dist = A.exact_min_distance(ur5, qs[:40], [(coal.Box(*(2 * half)), pose)])
    self_hit = A.exact_collides(ur5, qs[:40])
    agree = (dist <= 0) == exact[:40]
    assert agree[~self_hit].all()


@pytest.mark.parametrize("which", ["ur5", "panda"])
def test_self_check_is_conservative(which: str, request: pytest.FixtureRequest) -> None:
    arm = request.getfixturevalue(which)
    qs = _uniform(arm, 400, 12)
    exact = A.exact_collides(arm, qs)
    spheres = A.self_collides(arm, qs)
    assert exact.any()
    assert not (exact & ~spheres).any()


def test_usual_poses_are_free_and_folded_elbow_collides(ur5: A.Arm, panda: A.Arm) -> None:
    ur5_free = np.vstack([np.zeros(6), UR5_TYPICAL])
    assert not A.self_collides(ur5, ur5_free).any()
    assert not A.exact_collides(ur5, ur5_free).any()
    assert not A.self_collides(panda, PANDA_READY).any()
    assert not A.exact_collides(panda, PANDA_READY).any()
    folded = np.radians([0.0, -90.0, 175.0, 0.0, 0.0, 0.0])  # forearm back on the upper arm
    assert A.exact_collides(ur5, folded).all()
    assert A.self_collides(ur5, folded).all()


def test_extra_spheres_and_base_pose(ur5: A.Arm) -> None:
    # A ball held 5 cm beyond the flange clears the arm stretched out, and meets the
    # upper arm once the wrist folds back toward it.
    held = A.Spheres(
        frame=np.array([ur5.tool_joint]),
        centers=np.array([ur5.tool_placement[:3, :3] @ [0, 0, 0.05] + ur5.tool_placement[:3, 3]]),
        radii=np.array([0.04]),
        link=("part",),
    )
    assert not A.self_collides(ur5, np.zeros(6), extra=held).any()
    folded = np.radians([0.0, -90.0, 150.0, 0.0, 0.0, 0.0])
    with_part = A.self_collides(ur5, folded, extra=held)
    assert with_part.all()
    bad = A.Spheres(np.array([99]), np.zeros((1, 3)), np.ones(1), ("x",))
    with pytest.raises(ArgumentError):
        A.self_collides(ur5, np.zeros(6), extra=bad)
    # Moving the base moves every sphere rigidly and leaves self-collision alone.
    base = np.eye(4)
    base[:3, 3] = [1.0, 2.0, 0.5]
    moved = A.load_arm("ur5", base=base)
    qs = _uniform(ur5, 50, 13)
    np.testing.assert_allclose(
        A.sphere_centers(moved, qs), A.sphere_centers(ur5, qs) + base[:3, 3], atol=1e-12
    )
    np.testing.assert_array_equal(A.self_collides(moved, qs), A.self_collides(ur5, qs))


# --------------------------------------------------------------------------- lever arms


def _surface_points(arm: A.Arm, poses: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """World points on every sphere's surface, rigidly attached to its frame."""
    s = arm.spheres
    local = s.centers[:, None, :] + s.radii[:, None, None] * dirs[None]
    frames = poses[:, s.frame]
    return np.einsum("nsij,skj->nski", frames[..., :3, :3], local) + frames[:, :, None, :3, 3]


@pytest.mark.parametrize("which", ["ur5", "panda", "toy"])
def test_lever_arms_bound_every_point(which: str, request: pytest.FixtureRequest) -> None:
    arm = request.getfixturevalue(which)
    rng = np.random.default_rng(21)
    tool_points = rng.uniform(-0.1, 0.1, (5, 3)) + np.array([0.0, 0.0, 0.1])
    lever = A.lever_arms(arm, tool_points)
    assert lever.shape == (arm.dim,) and (lever > 0).all()
    assert (A.lever_arms(arm) <= lever + 1e-12).all()
    dirs = rng.normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    n = 300
    q = _uniform(arm, n, 22)
    step = rng.uniform(-1, 1, (n, arm.dim)) * rng.uniform(0.001, 0.3, (n, 1))
    step = np.clip(q + step, arm.lower, arm.upper) - q
    bound = np.abs(step) @ lever
    start_poses = A.forward(arm, q)
    start = _surface_points(arm, start_poses, dirs)
    start_tool = A.tool_pose(arm, q)
    start_pts = (
        np.einsum("nij,kj->nki", start_tool[:, :3, :3], tool_points) + start_tool[:, None, :3, 3]
    )
    worst = 0.0
    for t in (0.3, 0.7, 1.0):
        poses = A.forward(arm, q + t * step)
        moved = np.linalg.norm(_surface_points(arm, poses, dirs) - start, axis=-1)
        tool = A.tool_pose(arm, q + t * step)
        pts = np.einsum("nij,kj->nki", tool[:, :3, :3], tool_points) + tool[:, None, :3, 3]
        moved_tool = np.linalg.norm(pts - start_pts, axis=-1)
        most = np.maximum(moved.reshape(n, -1).max(axis=1), moved_tool.max(axis=1))
        assert (most <= t * bound + 1e-12).all()
        worst = max(worst, float((most / (t * bound)).max()))
    assert worst > 0.1  # the bound is not vacuous


# --------------------------------------------------------------------------- IK


@pytest.mark.parametrize("which", ["ur5", "panda"])
def test_ik_reaches_reachable_targets(which: str, request: pytest.FixtureRequest) -> None:
    arm = request.getfixturevalue(which)
    qs = _uniform(arm, 12, 31)
    targets = A.tool_pose(arm, qs)
    results = [A.ik(arm, target, seed=k) for k, target in enumerate(targets)]
    rate = np.mean([r.success for r in results])
    assert rate >= 11 / 12, f"{which} IK success rate {rate:.0%}"
    for r, target in zip(results, targets, strict=True):
        if not r.success:
            continue
        assert r.q is not None
        reached = A.tool_pose(arm, r.q)[0]
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) <= 1e-4 + 1e-12
        assert r.rotation_error <= 1e-3
        assert ((r.q >= arm.lower - 1e-12) & (r.q <= arm.upper + 1e-12)).all()


def test_ik_position_only_valid_and_unreachable(ur5: A.Arm, toy: A.Arm) -> None:
    target = A.tool_pose(ur5, UR5_TYPICAL)[0]
    target[:3, :3] = np.eye(3)
    r = A.ik(ur5, target, position_only=True, q0=UR5_TYPICAL)
    assert r.success and r.position_error <= 1e-4
    # A solution valid() refuses is not a success; the next attempts go on.
    refused = A.ik(ur5, target, position_only=True, restarts=1, max_iter=50, valid=lambda q: False)
    assert not refused.success and "refused by valid" in refused.message
    far = np.eye(4)
    far[:3, 3] = [3.0, 0.0, 0.5]
    miss = A.ik(ur5, far, restarts=2, max_iter=60)
    assert not miss.success and miss.q is not None
    assert miss.position_error > 1.5
    # A continuous joint comes back wrapped into (-pi, pi].
    goal = A.tool_pose(toy, [3.0, 0.5, 0.05])[0]
    hit = A.ik(toy, goal, q0=[-3.0, 0.0, 0.0])
    assert hit.success and hit.q is not None and -math.pi < hit.q[0] <= math.pi
    with pytest.raises(ArgumentError):
        A.ik(ur5, np.ones((4, 4)))


# --------------------------------------------------------------------------- errors


def _write(tmp_path: Path, text: str, name: str = "arm.urdf") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _problem(excinfo: pytest.ExceptionInfo[ScenarioError]) -> tuple[str, str]:
    problems = excinfo.value.problems
    assert len(problems) == 1, problems
    return problems[0].field, problems[0].message


def test_urdf_errors(tmp_path: Path) -> None:
    text = TOY.read_text()
    cases = {
        "bad xml": (text.replace("</robot>", ""), "cell.urdf", "not valid XML"),
        "missing mesh": (
            text.replace('<sphere radius="0.04"/>', '<mesh filename="nowhere.stl"/>'),
            "cell.urdf",
            "nowhere.stl",
        ),
        "floating": (
            text.replace('type="prismatic"', 'type="floating"'),
            "cell.urdf",
            "can be active",
        ),
    }
    for name, (content, field, words) in cases.items():
        with pytest.raises(ScenarioError) as err:
            A.load_arm(_write(tmp_path, content), field="cell")
        got_field, message = _problem(err)
        assert (got_field, words in message) == (field, True), name
    with pytest.raises(ScenarioError) as err:
        A.load_arm(tmp_path / "absent.urdf")
    assert _problem(err)[0] == "robot.urdf"
    # A floating joint may stay locked (at its neutral pose).
    floating = _write(tmp_path, text.replace('type="prismatic"', 'type="floating"'))
    assert A.load_arm(floating, joints=["turn", "bend"]).dim == 2


def test_flat_mesh_is_refused(tmp_path: Path) -> None:
    stl = tmp_path / "flat.stl"
    stl.write_text(
        "solid flat\n"
        + "".join(
            f"facet normal 0 0 1\nouter loop\n{a}\n{b}\n{c}\nendloop\nendfacet\n"
            for a, b, c in [
                ("vertex 0 0 0", "vertex 1 0 0", "vertex 0 1 0"),
                ("vertex 1 0 0", "vertex 1 1 0", "vertex 0 1 0"),
            ]
        )
        + "endsolid flat\n"
    )
    text = TOY.read_text().replace('<sphere radius="0.04"/>', f'<mesh filename="{stl}"/>')
    with pytest.raises(ScenarioError) as err:
        A.load_arm(_write(tmp_path, text))
    field, message = _problem(err)
    assert field == "robot.urdf" and "slider" in message and "no volume" in message


@pytest.mark.parametrize(
    ("kwargs", "field", "words"),
    [
        ({"joints": ["turn", "elbow"]}, "robot.joints[1]", "joints: turn, bend, slide"),
        ({"joints": ["turn", "turn"]}, "robot.joints[1]", "twice"),
        ({"joints": ["turn"], "locked": {"turn": 0.1}}, "robot.locked.turn", "both"),
        ({"joints": ["turn"], "locked": {"bend": 2.5}}, "robot.locked.bend", "outside"),
        ({"joints": ["turn"], "locked": {"wrist": 0.0}}, "robot.locked.wrist", "unknown"),
        ({"tool": "flange"}, "robot.tool", "unknown frame 'flange'"),
        ({"tool": "base"}, "robot.tool", "does not move"),
        ({"base": np.ones((4, 4))}, "robot.base", "rigid"),
        ({"srdf": "/nonexistent.srdf"}, "robot.srdf", "does not exist"),
    ],
)
def test_argument_errors_name_the_field(kwargs: dict, field: str, words: str) -> None:
    with pytest.raises(ScenarioError) as err:
        A.load_arm(TOY, **kwargs)
    got_field, message = _problem(err)
    assert got_field == field
    assert words in message


def test_locking_toy_joints(toy: A.Arm) -> None:
    arm = A.load_arm(TOY, joints=["bend"], locked={"turn": 0.5})
    assert arm.dim == 1 and arm.locked == {"turn": 0.5, "slide": 0.0}
    full = A.forward(toy, [0.5, 0.3, 0.0])[0, 1]
    np.testing.assert_allclose(A.forward(arm, [0.3])[0, 0], full, atol=1e-12)

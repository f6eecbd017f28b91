"""Robots: configuration spaces, rigid bodies and kinematics.

Every robot describes its configuration space (``dim``, ``lower``, ``upper``,
``periodic``), its rigid bodies in local frames, and two batched maps:

* ``body_poses(Q) -> (N, B, 3)``: where each body is, for ``N`` configurations;
* ``tool_pose(Q) -> (N, 3)``: the gripper frame, where a carried part attaches.

Kinds (strategies paper, Section V; adaptive paper, Section 4):

* :class:`PointRobot` and :class:`TranslatingRobot`: C = R^2, ``q = (x, y)``;
* :class:`RotatingRobot`: C = R^2 x S^1, ``q = (x, y, theta)``; its axis of
  orientation (problem 3: "translate along its axis") is the body's +x axis;
* :class:`PlanarArm`: n revolute joints, ``q = (q_1, ..., q_n)``, joint i
  measured from link i-1 (joint 1 from the world +x axis); joint limits make an
  axis non-periodic; an optional fixed end-effector orientation keeps the
  gripper frame at one world orientation (problem 5).

Arm links are rectangles ``[0, L] x [-w/2, w/2]`` in their joint frame, or capsules:
the same rectangle with round end caps, discs of radius ``w/2`` centred on the link's
two joints (every point within ``w/2`` of the segment from joint to joint; built
exactly, as one convex polygon and two discs). Links of the same arm are not checked
against each other: planar arms of this kind (SCARA-like) move their links in stacked
planes.

A revolute joint without limits, or with limits spanning the full turn, is periodic:
``periodic[i]`` is true and its angle lives on the circle (-pi, pi]. Inverse kinematics
returns such angles wrapped; an angle of a limited joint is returned as the turn
(``q + 2 pi k``) that lies within its limits, if one does.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from cellplan import units
from cellplan.errors import Problem, ScenarioError
from cellplan.geometry import BoolArray, FloatArray, RigidBodies, ShapeSet, wrap_angle
from cellplan.scenario import PointRobotSpec, RobotSpec, RotatingRobotSpec, TranslatingRobotSpec
from cellplan.scenario3d import UrdfRobotSpec


def as_batch(q: FloatArray, dim: int) -> FloatArray:
    """Configurations as a float ``(N, dim)`` array (a single one becomes ``(1, dim)``)."""
    arr = np.asarray(q, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"configurations must have shape (N, {dim}), got {np.shape(q)}")
    return arr


@dataclass(frozen=True)
class Robot(ABC):
    """Base of all robots; see the module docstring for the conventions."""

    kind: str
    lower: FloatArray
    upper: FloatArray
    periodic: tuple[bool, ...]
    start: FloatArray
    bodies: RigidBodies
    axis_names: tuple[str, ...]

    @property
    def dim(self) -> int:
        return len(self.periodic)

    @abstractmethod
    def body_poses(self, q: FloatArray) -> FloatArray:
        """``(N, B, 3)`` pose of every body."""

    @abstractmethod
    def tool_pose(self, q: FloatArray) -> FloatArray:
        """``(N, 3)`` pose of the gripper frame."""

    @property
    def angular(self) -> tuple[bool, ...]:
        """Which axes are angles (every axis but ``x`` and ``y``)."""
        return units.angular_axes(self.axis_names)

    def within_limits(self, q: FloatArray) -> BoolArray:
        """Boolean ``(N,)``: each non-periodic coordinate within ``[lower, upper]``."""
        q = as_batch(q, self.dim)
        ok = np.ones(len(q), bool)
        for i, per in enumerate(self.periodic):
            if not per:
                ok &= (q[:, i] >= self.lower[i]) & (q[:, i] <= self.upper[i])
        return ok

    def wrap(self, q: FloatArray) -> FloatArray:
        """Wrap periodic coordinates to (-pi, pi]."""
        q = np.array(q, dtype=float, copy=True)
        for i, per in enumerate(self.periodic):
            if per:
                q[..., i] = wrap_angle(q[..., i])
        return q

    def difference(self, q0: FloatArray, q1: FloatArray) -> FloatArray:
        """``q1 - q0`` with periodic axes taking the short way round."""
        d = np.asarray(q1, float) - np.asarray(q0, float)
        for i, per in enumerate(self.periodic):
            if per:
                d[..., i] = wrap_angle(d[..., i])
        return d

    @abstractmethod
    def body_displacement_bounds(self, delta: FloatArray) -> FloatArray:
        """``(..., B)`` bound on how far any point of each body moves when each coordinate
        changes by at most ``delta[..., i]`` (along any path inside that box)."""

    @abstractmethod
    def tool_displacement_bound(self, delta: FloatArray, reach: float) -> FloatArray:
        """``(...)`` bound on how far a point at distance ``reach`` from the tool frame moves."""

    def workspace_step(self, dq: FloatArray, tool_reach: float = 0.0) -> FloatArray:
        """``(N,)`` bound on the workspace motion of any robot point for C-space steps ``dq``."""
        dq = np.abs(np.atleast_2d(np.asarray(dq, float)))
        bodies = np.max(self.body_displacement_bounds(dq), axis=-1)
        return np.maximum(bodies, self.tool_displacement_bound(dq, tool_reach))


# --- rigid robots ----------------------------------------------------------------------------


@dataclass(frozen=True)
class RigidRobot(Robot):
    """A single rigid body; the tool frame is the body frame."""

    reach: float = 0.0

    def pose_of(self, q: FloatArray) -> FloatArray:
        q = as_batch(q, self.dim)
        theta = q[:, 2] if self.dim == 3 else np.zeros(len(q))
        return np.stack([q[:, 0], q[:, 1], theta], axis=1)

    def body_poses(self, q: FloatArray) -> FloatArray:
        return self.pose_of(q)[:, None, :]

    def tool_pose(self, q: FloatArray) -> FloatArray:
        return self.pose_of(q)

    def body_displacement_bounds(self, delta: FloatArray) -> FloatArray:
        return self.tool_displacement_bound(delta, self.reach)[..., None]

    def tool_displacement_bound(self, delta: FloatArray, reach: float) -> FloatArray:
        # translation moves every point alike; a turn by d_theta moves a point at
        # distance r from the frame origin along an arc of length r * d_theta
        d = np.abs(np.asarray(delta, float))
        rot = d[..., 2] * reach if self.dim == 3 else 0.0
        return np.asarray(np.hypot(d[..., 0], d[..., 1]) + rot)


def point_robot(
    start: tuple[float, float], bounds: tuple[float, float, float, float]
) -> RigidRobot:
    """A point robot moving in the workcell's bounds."""
    return RigidRobot(
        kind="point",
        lower=np.array(bounds[:2], float),
        upper=np.array(bounds[2:], float),
        periodic=(False, False),
        start=np.array(start, float),
        bodies=RigidBodies((ShapeSet.point(),)),
        axis_names=("x", "y"),
        reach=0.0,
    )


def translating_robot(
    shape: ShapeSet, start: tuple[float, float], bounds: tuple[float, float, float, float]
) -> RigidRobot:
    """A rigid body that only translates; C = R^2 within the workcell bounds."""
    return RigidRobot(
        kind="translating",
        lower=np.array(bounds[:2], float),
        upper=np.array(bounds[2:], float),
        periodic=(False, False),
        start=np.array(start, float),
        bodies=RigidBodies((shape,)),
        axis_names=("x", "y"),
        reach=shape.reach(),
    )


def rotating_robot(
    shape: ShapeSet, start: tuple[float, float, float], bounds: tuple[float, float, float, float]
) -> RigidRobot:
    """A rigid body in SE(2); ``start`` is ``(x, y, theta)`` with theta in radians."""
    return RigidRobot(
        kind="rotating",
        lower=np.array([bounds[0], bounds[1], -math.pi]),
        upper=np.array([bounds[2], bounds[3], math.pi]),
        periodic=(False, False, True),
        start=np.array([start[0], start[1], float(wrap_angle(start[2]))]),
        bodies=RigidBodies((shape,)),
        axis_names=("x", "y", "theta"),
        reach=shape.reach(),
    )


# --- planar arms -----------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanarArm(Robot):
    """A planar chain of revolute joints (see the module docstring for conventions)."""

    base: FloatArray = field(default_factory=lambda: np.zeros(2))
    lengths: FloatArray = field(default_factory=lambda: np.zeros(0))
    widths: FloatArray = field(default_factory=lambda: np.zeros(0))
    tool_orientation: float | None = None
    capsules: tuple[bool, ...] = ()
    """Which links are capsules (empty: all rectangles)."""

    @property
    def n_links(self) -> int:
        return len(self.lengths)

    def link_angles(self, q: FloatArray) -> FloatArray:
        """Absolute orientation of each link, ``(N, n)``."""
        return np.cumsum(as_batch(q, self.dim), axis=1)

    def joint_positions(self, q: FloatArray) -> FloatArray:
        """Positions of the base, every joint and the tip: ``(N, n + 1, 2)``."""
        a = self.link_angles(q)
        steps = np.stack([np.cos(a), np.sin(a)], axis=-1) * self.lengths[None, :, None]
        pts = np.concatenate([np.zeros((len(a), 1, 2)), np.cumsum(steps, axis=1)], axis=1)
        return pts + self.base

    def body_poses(self, q: FloatArray) -> FloatArray:
        a = self.link_angles(q)
        joints = self.joint_positions(q)[:, :-1, :]
        return np.concatenate([joints, a[..., None]], axis=-1)

    def tool_pose(self, q: FloatArray) -> FloatArray:
        """Gripper frame at the tip; oriented like the last link unless fixed."""
        tip = self.joint_positions(q)[:, -1, :]
        if self.tool_orientation is None:
            theta = wrap_angle(self.link_angles(q)[:, -1])
        else:
            theta = np.full(len(tip), self.tool_orientation)
        return np.concatenate([tip, np.asarray(theta)[:, None]], axis=1)

    def body_displacement_bounds(self, delta: FloatArray) -> FloatArray:
        return np.abs(np.asarray(delta, float)) @ self._link_levers().T

    def _link_levers(self) -> FloatArray:
        """``(n, n)``: entry ``(j, i)`` bounds the distance from joint i to any point of link j.

        A point p of link j moves by at most ``|p - joint_i| * delta_i`` when joint i
        turns, and ``|p - joint_i| <= L_i + ... + L_{j-1} + reach of link j``; joints
        beyond j do not move link j.
        """
        reach = np.hypot(self.lengths, self.widths / 2)
        if any(self.capsules):
            # a capsule's farthest point from its joint is the far cap's rim
            caps = np.array(self.capsules, dtype=bool)
            reach = np.where(caps, self.lengths + self.widths / 2, reach)
        along = np.cumsum(self.lengths) - self.lengths  # chain length from the base to joint i
        lever = along[:, None] - along[None, :] + reach[:, None]
        return np.where(np.tril(np.ones((self.n_links, self.n_links), bool)), lever, 0.0)

    def tool_displacement_bound(self, delta: FloatArray, reach: float) -> FloatArray:
        # the tip is L_i + ... + L_n from joint i; a tool frame that turns with the
        # last link adds its own reach to every lever
        lever = np.cumsum(self.lengths[::-1])[::-1]
        if self.tool_orientation is None:
            lever = lever + reach
        return np.asarray(np.abs(np.asarray(delta, float)) @ lever)

    def elbow_branch(self, q: FloatArray) -> FloatArray:
        """``+1`` where joint 2 bends counter-clockwise (q_2 >= 0), ``-1`` otherwise."""
        q = as_batch(q, self.dim)
        return np.where(q[:, 1] >= 0.0, 1, -1)

    def _into_limits(self, q: FloatArray) -> FloatArray:
        """Each limited joint's angle moved by a whole turn into its limits where one fits
        (a joint limited to [0, 350] degrees takes -90 degrees as 270)."""
        for i, per in enumerate(self.periodic):
            if per:
                continue
            lo, hi = self.lower[i], self.upper[i]
            turns = np.ceil((lo - q[..., i]) / (2 * math.pi))
            shifted = q[..., i] + turns * 2 * math.pi
            fits = (turns != 0) & (shifted <= hi) & ((q[..., i] < lo) | (q[..., i] > hi))
            q[..., i] = np.where(fits, shifted, q[..., i])
        return q

    def ik(
        self, x: FloatArray, y: FloatArray, phi: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Analytic inverse kinematics of the tip, both elbow branches.

        For a 2-link arm, ``phi`` must be None: the tip ``(x, y)`` fixes the arm up to
        the elbow branch. For a 3-link arm, ``phi`` is the orientation of the last
        link (the end-effector orientation); the wrist ``(x, y) - L_3 (cos phi, sin phi)``
        is solved as a 2-link problem and ``q_3 = phi - q_1 - q_2``.

        Returns
        -------
        q : ``(N, 2, n)`` solutions, branch index 0 is ``q_2 >= 0`` (elbow +1), 1 is ``q_2 <= 0``.
        valid : ``(N, 2)`` reachable and within joint limits.
        """
        x = np.atleast_1d(np.asarray(x, float))
        y = np.atleast_1d(np.asarray(y, float))
        n = self.n_links
        if n == 2 and phi is not None:
            raise ValueError("a 2-link arm's tip position fixes its configuration; pass phi=None")
        if n == 3 and phi is None:
            raise ValueError("a 3-link arm needs the end-effector orientation phi")
        if n not in (2, 3):
            raise ValueError(f"analytic IK is for 2- and 3-link arms, not {n} links")
        wx, wy = x - self.base[0], y - self.base[1]
        if n == 3:
            phi_arr = np.broadcast_to(np.asarray(phi, float), wx.shape)
            wx = wx - self.lengths[2] * np.cos(phi_arr)
            wy = wy - self.lengths[2] * np.sin(phi_arr)
        l1, l2 = self.lengths[0], self.lengths[1]
        c2 = (wx**2 + wy**2 - l1**2 - l2**2) / (2 * l1 * l2)
        reachable = np.abs(c2) <= 1.0 + 1e-12
        q2 = np.arccos(np.clip(c2, -1.0, 1.0))
        sols = np.empty((len(wx), 2, n))
        for b, sign in enumerate((1.0, -1.0)):
            s2 = sign * q2
            q1 = np.arctan2(wy, wx) - np.arctan2(l2 * np.sin(s2), l1 + l2 * np.cos(s2))
            sols[:, b, 0] = wrap_angle(q1)
            sols[:, b, 1] = s2
            if n == 3:
                sols[:, b, 2] = wrap_angle(phi_arr - q1 - s2)
        sols = self._into_limits(sols)
        valid = np.repeat(reachable[:, None], 2, axis=1)
        valid &= self.within_limits(sols.reshape(-1, n)).reshape(-1, 2)
        return sols, valid


def planar_arm(
    base: tuple[float, float],
    lengths: list[float],
    widths: list[float],
    joint_limits: list[tuple[float, float]] | None,
    start: list[float],
    tool_orientation: float | None = None,
    shapes: list[str] | None = None,
) -> PlanarArm:
    """Build a :class:`PlanarArm`; angles in radians, ``None`` limits meaning a full turn.

    ``shapes``: ``"rectangle"`` (the default) or ``"capsule"`` per link.
    """
    n = len(lengths)
    lower = np.full(n, -math.pi)
    upper = np.full(n, math.pi)
    periodic = [True] * n
    for i, lim in enumerate(joint_limits or []):
        lo, hi = lim
        if hi - lo < 2 * math.pi - 1e-9:
            lower[i], upper[i] = lo, hi
            periodic[i] = False
    kinds = list(shapes) if shapes is not None else ["rectangle"] * n
    if len(kinds) != n or any(k not in ("rectangle", "capsule") for k in kinds):
        raise ValueError(f"shapes must be 'rectangle' or 'capsule' per link, got {shapes!r}")
    bodies = tuple(
        link_shape(ln, w, kind) for ln, w, kind in zip(lengths, widths, kinds, strict=True)
    )
    return PlanarArm(
        kind="arm",
        lower=lower,
        upper=upper,
        periodic=tuple(periodic),
        start=np.array(start, float),
        bodies=RigidBodies(bodies),
        axis_names=tuple(f"q{i + 1}" for i in range(n)),
        base=np.array(base, float),
        lengths=np.array(lengths, float),
        widths=np.array(widths, float),
        tool_orientation=tool_orientation,
        capsules=tuple(k == "capsule" for k in kinds) if "capsule" in kinds else (),
    )


def link_shape(length: float, width: float, kind: str = "rectangle") -> ShapeSet:
    """A link in its joint frame: the rectangle ``[0, L] x [-w/2, w/2]``, plus, for a
    capsule, discs of radius ``w/2`` on both joints (its round end caps)."""
    box = ShapeSet.from_polygons(
        [np.array([[0, -width / 2], [length, -width / 2], [length, width / 2], [0, width / 2]])]
    )
    if kind == "rectangle":
        return box
    caps = ShapeSet(
        np.zeros((0, 3, 2)),
        np.zeros(0, np.int64),
        np.array([[0.0, 0.0], [length, 0.0]]),
        np.full(2, width / 2),
    )
    return ShapeSet.union([box, caps])


def robot_from_spec(spec: RobotSpec, bounds: tuple[float, float, float, float]) -> Robot:
    """Build a robot from a scenario's ``robot`` section (degrees become radians)."""
    if isinstance(spec, PointRobotSpec):
        return point_robot(spec.start, bounds)
    if isinstance(spec, TranslatingRobotSpec):
        return translating_robot(ShapeSet.from_spec(spec.shape), spec.start, bounds)
    if isinstance(spec, RotatingRobotSpec):
        x, y, th = spec.start
        return rotating_robot(ShapeSet.from_spec(spec.shape), (x, y, units.radians(th)), bounds)
    if isinstance(spec, UrdfRobotSpec):
        raise ScenarioError(
            [Problem("robot.type", "a URDF robot needs a 3-D workcell (cellplan.workcell3d)")]
        )
    eo = spec.end_effector_orientation
    limits = spec.joint_limits
    return planar_arm(
        base=spec.base,
        lengths=[link.length for link in spec.links],
        widths=[link.width for link in spec.links],
        joint_limits=None
        if limits is None
        else [(units.radians(a), units.radians(b)) for a, b in limits],
        start=[units.radians(v) for v in spec.start],
        tool_orientation=None if eo is None else units.radians(eo),
        shapes=[link.shape for link in spec.links],
    )

"""The changing 3-D workcell of a URDF arm: objects, named goals as tool poses, generations.

The 3-D counterpart of :class:`~.world.World`, with the same methods, so that
:class:`~.adapt.Adapter` and :class:`~.experience.ExperiencePlanner` run on either
without asking which one they have. Objects are the solids of the cell; they are
added, removed, translated and turned. An object's displacement from where the scenario
put it is a rigid motion ``D``: a rotation ``turn`` about the solid's scenario centre
``c``, then the offset ``pose = (x, y, z)`` in metres,
``D(x) = turn (x - c) + c + pose``.

Subgoals are attached to objects through the tool's full pose (Chen, Section 2.3): a tag
holds the tool position in the object's frame, ``rel = D^-1(p)``, and a named goal also
the tool's orientation relative to the object, ``turn^T R``. A vertex of G keeps its
orientation in its configuration: when its object is displaced from ``D_old`` to
``D_new``, the target tool pose is ``D_new D_old^-1`` applied to the vertex's old tool
pose, so a turn of the object turns the attached tool pose with it. Inverse kinematics
(:func:`cellplan.arm.ik`, damped least squares) seeded from the subgoal's old
configuration then brings the subgoal back onto the moved pose; the first attempt starts
there, so the solution stays on the same branch whenever one exists nearby.

Validity for Reach (:meth:`World3D.is_free`) is certified: a configuration passes only
when the whole joint-space ball of radius ``resolution / 2`` around it is free
(:meth:`cellplan.workcell3d.Workcell3D.collides_within`, each sphere of the arm's cover
checked with the clearance its lever bound allows). Reach samples a segment at most
``resolution`` apart, so every point of a segment lies within ``resolution / 2`` of a
sample: a segment that passes Reach is free everywhere along it.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cellplan import arm as arms
from cellplan import solids, units
from cellplan.adaptive.section import (
    AdaptiveSection,
    GoalSpec,
    MoveObject,
    RotateObject,
)
from cellplan.adaptive.space import FloatArray
from cellplan.adaptive.tags import Tag
from cellplan.adaptive.worldbase import (
    ChangingWorld,
    checked_pose,
    checked_turn,
    validated_spec,
)
from cellplan.errors import ArgumentError, Problem
from cellplan.scenario import Scenario
from cellplan.scenario3d import MeshSolid, Solid
from cellplan.workcell3d import UrdfRobot, Workcell3D, scenario_solid

Offset = tuple[float, float, float]

DOWN = (1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0)
"""The tool's z axis pointing down (a pick from above): the default goal orientation."""

IK_RESTARTS = 8
"""Random restarts of a goal's IK after the attempt from the seed configuration."""

IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
"""No turn (a row-major 3x3 rotation)."""


@dataclass
class Object3D:
    """A solid as the scenario placed it, its current offset (a translation) and its
    turn (a row-major 3x3 rotation about the solid's scenario centre)."""

    solid: solids.Solid
    pose: Offset = (0.0, 0.0, 0.0)
    turn: tuple[float, ...] = IDENTITY

    def frame(self) -> FloatArray:
        """``D`` (``(4, 4)``): the object's displacement from where the scenario put it,
        ``D(x) = turn (x - c) + c + pose`` with ``c`` the solid's scenario centre."""
        rotation = np.asarray(self.turn, float).reshape(3, 3)
        centre = self.solid.translation
        out = np.eye(4)
        out[:3, :3] = rotation
        # pose + (c - R c): exactly the offset when there is no turn (c - I c = 0)
        out[:3, 3] = np.asarray(self.pose, float) + (centre - rotation @ centre)
        return out

    def placed(self) -> solids.Solid:
        """The solid in the world now."""
        if self.pose == (0.0, 0.0, 0.0) and self.turn == IDENTITY:
            return self.solid
        return self.solid.transformed(self.frame())


def solid_from_spec(spec: Any, field: str) -> solids.Solid:
    """A primitive solid of a scenario (box, cylinder, sphere, capsule) in code units, as
    :func:`cellplan.workcell3d.scenario_solid` builds it; a mesh is refused (no folder to
    load it from)."""
    if isinstance(spec, MeshSolid):
        raise ArgumentError(f"a {spec.type} cannot be added to a changing cell here", field)
    return scenario_solid(spec, None, field)


def _rotation(rpy_degrees: Sequence[float] | None) -> tuple[float, ...]:
    if rpy_degrees is None:
        return DOWN
    _, rpy = units.pose_from_file((0.0, 0.0, 0.0), rpy_degrees)
    return tuple(float(v) for v in solids.pose_matrix(np.zeros(3), rpy)[:3, :3].ravel())


class World3D(ChangingWorld[Object3D, solids.Solid]):
    """Objects, goals and arm of one adaptive problem in a 3-D cell (see the module
    docstring); the same methods as :class:`~.world.World` (the bookkeeping shared in
    :class:`~.worldbase.ChangingWorld`)."""

    def __init__(
        self, scenario: Scenario, cell: Workcell3D, resolution: float | None = None
    ) -> None:
        self.scenario: Scenario | None = scenario
        self.section: AdaptiveSection | None = scenario.adaptive
        self.base_cell = cell.with_obstacles({})
        self.robot: UrdfRobot = cell.robot
        self.radius = 0.0 if resolution is None else resolution / 2.0
        levers = arms.sphere_levers(self.robot.arm)
        # The largest clearance any sphere is checked with (for messages).
        self.margin = float(np.linalg.norm(levers, axis=1).max()) * self.radius
        self.objects: dict[str, Object3D] = {n: Object3D(s) for n, s in cell.obstacles.items()}
        self.goals: dict[str, Tag] = {}
        self.attach_radius: float | None = None
        self.gen = 0
        self._cell: Workcell3D | None = None
        self._goal_cache: dict[tuple[str, int], FloatArray | None] = {}
        # Each object's frame before its latest displacement: the vertices attached to it
        # are followed (Adapter.follow_objects) right after each one, from this frame.
        self._moved_from: dict[str, FloatArray] = {}
        if self.section is not None:
            self.attach_radius = self.section.attach_radius
            for name, goal in self.section.goals.items():
                self.goals[name] = self._goal_tag(goal)

    # --- geometry -------------------------------------------------------------------------

    def workcell(self) -> Workcell3D:
        """The cell with the objects where they are now."""
        if self._cell is None:
            self._cell = self.base_cell.with_obstacles(
                {n: self.objects[n].placed() for n in sorted(self.objects)}
            )
        return self._cell

    def is_free(self, Q: FloatArray) -> np.ndarray:
        """Certified validity: the joint-space ball of radius ``resolution / 2`` is free,
        the held part (:meth:`~.worldbase.ChangingWorld.hold`) attached to the tool (its
        cover's spheres checked with their own lever bounds)."""
        return ~self.workcell().collides_within(Q, self.radius, self.carrying, avoid_sources="none")

    def alone(self, name: str) -> Workcell3D:
        """The cell with object ``name`` where it is now and no other object."""
        return self.base_cell.with_obstacles({name: self.objects[name].placed()})

    def check_free(self, q: FloatArray, name: str) -> None:
        """One line when ``q`` leaves the limits or the bounds, touches an object (named),
        collides with the arm itself, or lies closer to something than Reach certifies."""
        if self.is_free(q[None, :])[0]:
            return  # the common case, one check; the reasons below only when it fails
        shown = self.shown_within_limits(q, name)
        if self.base_cell.collides(q[None, :], self.carrying, avoid_sources="none")[0]:
            held = "" if self.carrying is None else f" (holding part {self.carrying!r})"
            raise ArgumentError(
                f"configuration {shown} leaves the workcell bounds or collides with the arm "
                f"itself{held}",
                name,
            )
        hits = self.hits(q)
        if hits:
            names = ", ".join(repr(h) for h in hits)
            raise ArgumentError(f"configuration {shown} collides with obstacle {names}", name)
        if not self.is_free(q[None, :])[0]:
            raise ArgumentError(
                f"configuration {shown} is closer to an obstacle or a wall than Reach's "
                f"certified clearance (up to {self.margin:.3g} m at the tool for resolution "
                f"{2 * self.radius:.3g} rad; a finer resolution shrinks it)",
                name,
            )

    # --- tags and inverse kinematics ------------------------------------------------------

    def tool(self, q: FloatArray) -> tuple[float, float, float]:
        """The tool position of one configuration (metres)."""
        p = self.robot.tool_pose(np.asarray(q, float)[None, :])[0, :3, 3]
        return (float(p[0]), float(p[1]), float(p[2]))

    def nearest_object(self, point: FloatArray) -> tuple[str | None, float]:
        """The object nearest to a workspace point and its (exact) distance."""
        if not self.objects:
            return None, math.inf
        names = sorted(self.objects)
        prepared = solids.SolidSet.build([self.objects[n].placed() for n in names])
        d = solids.distances(prepared, np.asarray(point, float)[None, :])[0]
        k = int(np.argmin(d))
        return names[k], float(d[k])

    def frame_of(self, name: str | None) -> FloatArray:
        """The displacement ``D`` (``(4, 4)``) of object ``name`` now (identity for the
        world, ``None``, or an object no longer there)."""
        if name is None or name not in self.objects:
            return np.eye(4)
        return self.objects[name].frame()

    def tag_of(self, q: FloatArray) -> Tag:
        """Attach a configuration to the nearest object (within ``attach_radius``), 2.3.

        ``rel`` is the tool position in the object's frame, ``D^-1(p)``; the orientation
        is the configuration's own (followed through ``D`` when the object is displaced,
        :meth:`config_of`)."""
        p = np.array(self.tool(q))
        obj, dist = self.nearest_object(p)
        radius = self.attach_radius
        if obj is None or (radius is not None and dist > radius):
            return Tag(None, (float(p[0]), float(p[1]), float(p[2])), None)
        frame = self.frame_of(obj)
        rel = frame[:3, :3].T @ (p - frame[:3, 3])
        return Tag(obj, (float(rel[0]), float(rel[1]), float(rel[2])), None)

    def tool_pose_of(self, tag: Tag) -> tuple[float, float, float]:
        """World tool position of a tag in the current environment, ``D(rel)``."""
        frame = self.frame_of(tag.obj)
        p = frame[:3, :3] @ np.asarray(tag.rel, float) + frame[:3, 3]
        return (float(p[0]), float(p[1]), float(p[2]))

    def tool_rotation_of(self, tag: Tag, seed: FloatArray) -> FloatArray:
        """World tool orientation of a tag now (``(3, 3)``): a named goal's relative
        orientation turned by its object, ``turn R_rel``; a vertex's (``rot`` None) is
        its old configuration ``seed``'s, turned by its object's latest displacement
        (``D_new D_old^-1``; none when the object has not been displaced)."""
        frame = self.frame_of(tag.obj)
        if tag.rot is not None:
            return np.asarray(frame[:3, :3] @ np.asarray(tag.rot, float).reshape(3, 3))
        rotation = self.robot.tool_pose(np.asarray(seed, float)[None, :])[0, :3, :3]
        before = self._moved_from.get(tag.obj) if tag.obj is not None else None
        if before is None:
            return np.asarray(rotation)
        return np.asarray(frame[:3, :3] @ before[:3, :3].T @ rotation)

    def config_of(self, tag: Tag, seed: FloatArray | None = None) -> FloatArray | None:
        """A configuration for a tag by IK from ``seed`` (the subgoal's old configuration);
        ``None`` if no free solution is found. The target is the tag's full tool pose now
        (:meth:`tool_pose_of`, :meth:`tool_rotation_of`)."""
        start = np.asarray(self.robot.start if seed is None else seed, float)
        target = np.eye(4)
        target[:3, :3] = self.tool_rotation_of(tag, start)
        target[:3, 3] = self.tool_pose_of(tag)

        def valid(q: FloatArray) -> bool:
            return bool(self.is_free(q[None, :])[0])

        result = arms.ik(
            self.robot.arm,
            target,
            q0=start,
            restarts=IK_RESTARTS if seed is None else 2,
            seed=0,
            valid=valid,
        )
        return np.asarray(result.q, float) if result.success else None

    def pose_goal(self, pose: FloatArray, seed: FloatArray) -> FloatArray:
        """The configuration of a tool-pose goal (``(4, 4)``, world frame): IK from ``seed``
        (where the robot stands), then with restarts; one line when none is free."""
        if not np.all(np.isfinite(pose)):
            raise ArgumentError("the tool pose must be finite", "goal")
        target = np.asarray(pose, float)
        x, y, z = target[:3, 3]
        inside = np.all(target[:3, 3] >= self.base_cell.lo) and np.all(
            target[:3, 3] <= self.base_cell.hi
        )
        if not inside:
            raise ArgumentError(
                f"the tool pose at ({x:.3g}, {y:.3g}, {z:.3g}) m lies outside the workcell bounds",
                "goal",
            )

        def valid(q: FloatArray) -> bool:
            return bool(self.is_free(q[None, :])[0])

        try:
            result = arms.ik(self.robot.arm, target, q0=seed, restarts=IK_RESTARTS, valid=valid)
        except ArgumentError as exc:
            raise ArgumentError(f"not a rigid tool pose: {exc}", "goal") from None
        if not result.success:
            raise ArgumentError(
                f"no collision-free inverse-kinematics solution reaches the tool pose at "
                f"({x:.3g}, {y:.3g}, {z:.3g}) m ({result.message})",
                "goal",
            )
        return np.asarray(result.q, float)

    def _goal_tag(self, goal: GoalSpec) -> Tag:
        """A named goal's tag: ``at`` and ``rpy`` (world, now) in its object's frame."""
        at = np.array([float(v) for v in goal.at])
        rot = np.asarray(_rotation(goal.rpy), float).reshape(3, 3)
        frame = self.frame_of(goal.object)
        rel = frame[:3, :3].T @ (at - frame[:3, 3])
        relative = frame[:3, :3].T @ rot
        return Tag(
            goal.object,
            (float(rel[0]), float(rel[1]), float(rel[2])),
            None,
            tuple(float(v) for v in relative.ravel()),
        )

    def goal_config(self, name: str) -> FloatArray | None:
        """A goal's configuration now (``None``: no free IK solution); cached per generation."""
        key = (name, self.gen)
        if key not in self._goal_cache:
            self._goal_cache[key] = self.config_of(self.goals[name])
        q = self._goal_cache[key]
        return None if q is None else q.copy()

    def goal_problems(
        self, where: str, when: str = "", skip: Collection[str] = ()
    ) -> list[Problem]:
        """Goals without a free IK solution now (fields ``where.<goal>``); goals named in
        ``skip`` are not solved."""
        problems = []
        for name in sorted(set(self.goals) - set(skip)):
            if self.goal_config(name) is None:
                x, y, z = self.tool_pose_of(self.goals[name])
                problems.append(
                    Problem(
                        f"{where}.{name}",
                        f"no collision-free inverse-kinematics solution reaches the tool pose "
                        f"at ({x:.3g}, {y:.3g}, {z:.3g}) m{when}",
                    )
                )
        return problems

    # --- changes --------------------------------------------------------------------------

    def shape_from_spec(self, spec: Any) -> solids.Solid:
        """The solid of an ``add_object`` change (a primitive; no mesh)."""
        return solid_from_spec(spec, "shape")

    def moved(self, change: MoveObject) -> Offset:
        """The offset a scheduled move shifts its object to."""
        p = self.objects[change.object].pose
        by = [float(v) for v in change.by]
        return (p[0] + by[0], p[1] + by[1], p[2] + by[2])

    def turn_angle(self, change: RotateObject) -> FloatArray:
        """A scheduled turn's ``rpy`` (degrees) as radians."""
        # the section gives a 3-D turn its rpy (adaptive.section._check_dimension)
        assert change.rpy is not None
        return np.asarray(units.radians(change.rpy), float)

    def turned(
        self, name: str, rpy: FloatArray, about: Any = None
    ) -> tuple[Offset, tuple[float, ...]]:
        """Offset and turn of object ``name`` after the rotation ``R_c`` of ``rpy``
        (radians, fixed world axes, ``R_c = Rz Ry Rx``) about ``about`` (metres; default:
        the object's centre now). ``D_new = T(a) R_c T(-a) D_old``, so
        ``turn_new = R_c turn_old`` and ``pose_new = R_c (c + pose_old - a) + a - c``."""
        obj = self.objects[name]
        spin = solids.pose_matrix(np.zeros(3), rpy)[:3, :3]
        centre = obj.solid.translation
        offset = np.asarray(obj.pose, float)
        at = centre + offset if about is None else np.asarray(about, float)
        new = spin @ (centre + offset - at) + at - centre
        turn = spin @ np.asarray(obj.turn, float).reshape(3, 3)
        return (
            (float(new[0]), float(new[1]), float(new[2])),
            tuple(float(v) for v in turn.ravel()),
        )

    def turn(self, name: str, angle: FloatArray, about: Any = None) -> set[str]:
        """Turn object ``name`` by ``angle = (roll, pitch, yaw)`` radians about ``about``
        (:meth:`turned`): its offset and turn are set, and its attached tags follow from
        the frame it had before (Chen, Section 2.3)."""
        offset, turn = self.turned(name, angle, about)
        self._moved_from[name] = self.objects[name].frame()
        obj = self.objects[name]
        obj.pose, obj.turn = offset, turn
        self._changed()
        return {name}

    def checked_turn(self, angle: Any, about: Any) -> tuple[FloatArray, Any]:
        """``ExperiencePlanner.turn``'s arguments: ``(roll, pitch, yaw)`` radians and an
        optional centre ``(x, y, z)`` metres."""
        return checked_turn(angle, about, "roll, pitch, yaw", "x, y, z")

    def set_pose(self, name: str, pose: Any) -> set[str]:
        """Place object ``name`` at offset ``pose`` (its turn kept); its attached tags
        follow from the frame it had before."""
        self._moved_from[name] = self.objects[name].frame()
        return super().set_pose(name, pose)

    def add_object(self, name: str, shape: solids.Solid, pose: Sequence[float] = (0, 0, 0)) -> None:
        """Add a solid, shifted by ``pose = (x, y, z)`` (its orientation is its solid's)."""
        self.objects[name] = Object3D(shape, _offset(pose))
        self._moved_from.pop(name, None)
        self._changed()

    def shape(self, shape: Any) -> solids.Solid:
        """A solid given to ``ExperiencePlanner.add``: a :class:`cellplan.solids.Solid`
        or a scenario solid (``{"type": "box", "size": [...], "pose": {...}}``)."""
        if isinstance(shape, solids.Solid):
            return shape
        return self.shape_from_spec(validated_spec(Solid, shape))

    def pose_of(self, pose: Sequence[float]) -> Offset:
        """A pose argument checked: three finite numbers (metres)."""
        return _offset(pose)

    # --- persistence ----------------------------------------------------------------------

    def objects_json(self) -> dict[str, Any]:
        """The objects as JSON values (solid kind, pose, size, offset)."""
        out: dict[str, Any] = {}
        for n, o in sorted(self.objects.items()):
            if o.solid.kind == "mesh":
                raise ArgumentError(f"object {n!r} is a mesh; it cannot be saved", "db")
            out[n] = {
                "solid": {
                    "kind": o.solid.kind,
                    "pose": o.solid.pose.tolist(),
                    "size": o.solid.size.tolist(),
                },
                "pose": list(o.pose),
                "turn": list(o.turn),
            }
        return out

    def goals_json(self) -> dict[str, Any]:
        """The goals' tags as JSON values."""
        return {
            n: [t.obj, list(t.rel), t.branch, None if t.rot is None else list(t.rot)]
            for n, t in sorted(self.goals.items())
        }

    def restore_json(self, objects: Mapping[str, Any], goals: Mapping[str, Any], gen: int) -> None:
        """Replace objects, goals and generation from :meth:`objects_json` / :meth:`goals_json`."""
        self.objects = {
            n: Object3D(
                solids.Solid(o["solid"]["kind"], np.array(o["solid"]["pose"]), o["solid"]["size"]),
                _offset(o["pose"]),
                tuple(float(v) for v in o.get("turn", IDENTITY)),
            )
            for n, o in objects.items()
        }
        self._moved_from = {}
        self.goals = {
            n: Tag(
                g[0],
                (float(g[1][0]), float(g[1][1]), float(g[1][2])),
                g[2],
                None if len(g) < 4 or g[3] is None else tuple(float(v) for v in g[3]),
            )
            for n, g in goals.items()
        }
        self.gen = gen
        self._cell = None
        self._goal_cache = {}

    def _forget(self) -> None:
        self._cell = None

    def _check_part(self, part: str) -> None:
        """An unknown part is refused in one line naming the known ones."""
        self.base_cell.part(part)


def _offset(pose: Sequence[float]) -> Offset:
    return checked_pose(pose, "x, y, z", " in metres (an offset; turns are rotate_object's)")

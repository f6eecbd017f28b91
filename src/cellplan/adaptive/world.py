"""The changing workcell: objects with poses, named goals, and the environment generation.

Objects keep their scenario shape and a pose ``(x, y, theta)`` that maps the
shape's original coordinates to the world; moving or rotating an object only
changes its pose. Goals and subgoals are object-attached tags (Section 2.3): a
tool-point pose relative to an object's frame (or the world) plus the IK branch;
:meth:`World.config_of` turns a tag back into a configuration by inverse
kinematics on the same branch. Every object change increments ``gen``, the
environment generation that edge verification is stamped with.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from cellplan import units
from cellplan.adaptive.section import (
    AdaptiveSection,
    GoalSpec,
    MoveObject,
    RotateObject,
    stage_words,
)
from cellplan.adaptive.space import FloatArray
from cellplan.adaptive.store import shape_from_json, shape_to_json
from cellplan.adaptive.tags import Tag
from cellplan.adaptive.world3d import World3D
from cellplan.adaptive.worldbase import (
    ChangingWorld,
    checked_pose,
    checked_turn,
    validated_spec,
)
from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.geometry import ShapeSet
from cellplan.robots import PlanarArm, Robot
from cellplan.scenario import Scenario
from cellplan.schema import Shape
from cellplan.setup import Setup, as_setup
from cellplan.workcell import Workcell
from cellplan.workcell3d import Workcell3D

Pose = tuple[float, float, float]


def compose(a: Pose, b: Pose) -> Pose:
    """Pose ``a`` applied after ``b`` (``a * b``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def inverse(a: Pose) -> Pose:
    """Inverse of a pose."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-(c * a[0] + s * a[1]), s * a[0] - c * a[1], -a[2])


@dataclass
class ObjectState:
    """An object's shape in its own coordinates and the pose that places it in the world."""

    shape: ShapeSet
    pose: Pose = (0.0, 0.0, 0.0)


def certified_margin(robot: Robot, resolution: float) -> float:
    """Clearance that makes Reach's sampled check certify the whole segment.

    Between two samples of a segment checked at ``resolution`` no joint is more
    than ``resolution / 2`` from the nearer sample, so no point of the robot is
    farther than this bound from where it was checked (the foundation's
    displacement bounds). Configurations are checked with this clearance, so a
    segment that passes Reach is free everywhere, not only at its samples.
    """
    delta = np.full(robot.dim, resolution / 2.0)
    return float(np.max(robot.body_displacement_bounds(delta)))


#: The most configurations Reach may check on one straight segment (a work limit: a finer
#: resolution gives no better plans, only runs that never end).
MAX_SEGMENT_STEPS = 1_000_000


def segment_memory(robot: Robot, steps: int) -> int:
    """Bytes Reach allocates to check one segment of ``steps`` steps.

    The configurations (float64 ``(n + 1, dim)`` and their wrapped copy), the bisection
    order (:func:`~cellplan.adaptive.reach.bisection_levels`: an int64 index per step plus
    a Python set entry, int and interval tuple, 160 bytes), and the collision check of the
    largest level (half the points: body poses float64 ``(n/2, B, 3)`` twice and gaps
    float64 ``(n/2, B)``).
    """
    bodies = len(robot.bodies.bodies) + 1  # a carried part is one more body
    return int((steps + 1) * (16 * robot.dim + 8 + 160 + (48 * bodies + 8 * bodies) // 2))


def check_resolution(robot: Robot, resolution: float, field: str = "adaptive.resolution") -> None:
    """Refuse a Reach resolution whose longest segment is pointless or cannot fit in memory.

    The longest segment crosses the configuration space's box (half a turn on a periodic
    coordinate); it is cut into ``ceil(length / resolution)`` steps.
    """
    from cellplan import budget

    span = np.where(
        np.asarray(robot.periodic, bool), math.pi, np.asarray(robot.upper) - robot.lower
    )
    # A float first: a resolution of 5e-324 makes the ratio infinite, which ceil refuses.
    ratio = float(np.linalg.norm(span)) / resolution
    shown = units.degrees(resolution) if isinstance(robot, PlanarArm) else resolution
    where = f"{field} {shown:g}"
    if not ratio <= MAX_SEGMENT_STEPS:
        raise ScenarioError(
            [
                Problem(
                    where,
                    f"a segment across the configuration space would take {ratio:.3g} "
                    f"collision checks (the limit is {MAX_SEGMENT_STEPS:,}); use a coarser "
                    "resolution",
                )
            ]
        )
    steps = math.ceil(ratio)
    budget.require(segment_memory(robot, steps), where, "per straight segment", ScenarioError)


class World(ChangingWorld[ObjectState, ShapeSet]):
    """Objects, goals and robot of one adaptive problem, changing over the tasks.

    With ``resolution`` (the Reach step, radians or units), configurations are
    tested with the :func:`certified_margin` clearance. A scenario without an
    ``adaptive:`` section (or a bare workcell, :meth:`from_workcell`) gives a world
    with no named goals whose subgoals attach to the nearest object. The bookkeeping
    of objects, goals and generations is :class:`~.worldbase.ChangingWorld`'s.
    """

    def __init__(self, scenario: Scenario, resolution: float | None = None) -> None:
        self.scenario: Scenario | None = scenario
        self.section: AdaptiveSection | None = scenario.adaptive
        cell = Workcell.from_scenario(scenario)
        objects = {n: ShapeSet.from_spec(s) for n, s in scenario.workcell.obstacles.items()}
        self._init(cell, objects, resolution)
        if self.section is not None:
            self.attach_radius = self.section.attach_radius
            for name, goal in self.section.goals.items():
                self.goals[name] = self._goal_tag(goal)

    @classmethod
    def from_workcell(
        cls, cell: Workcell, resolution: float | None = None, attach_radius: float | None = None
    ) -> World:
        """A world over a workcell model alone: its obstacles become the objects, no goals."""
        world = cls.__new__(cls)
        world.scenario = None
        world.section = None
        world._init(cell, dict(cell.obstacles), resolution)
        world.attach_radius = attach_radius
        return world

    def _init(self, cell: Workcell, objects: dict[str, ShapeSet], resolution: float | None) -> None:
        self.base_cell = cell
        self.robot: Robot = cell.robot
        if resolution is not None:
            check_resolution(self.robot, resolution)
        self.margin = 0.0 if resolution is None else certified_margin(self.robot, resolution)
        self.objects = {n: ObjectState(s) for n, s in objects.items()}
        self.goals: dict[str, Tag] = {}
        self.attach_radius = None
        self.gen = 0
        self._cell: Workcell | None = None
        self._geoms: dict[str, BaseGeometry] | None = None

    # --- geometry -------------------------------------------------------------------------

    def world_shape(self, name: str) -> ShapeSet:
        """An object's shape set in the world."""
        st = self.objects[name]
        return st.shape.transformed(st.pose)

    def geometries(self) -> dict[str, BaseGeometry]:
        """Shapely geometry of every object in the world (for distances and drawing)."""
        if self._geoms is None:
            self._geoms = {n: self.world_shape(n).to_shapely() for n in sorted(self.objects)}
        return self._geoms

    def workcell(self) -> Workcell:
        """The foundation's workcell model of the current environment."""
        if self._cell is None:
            obstacles = {n: self.world_shape(n) for n in sorted(self.objects)}
            self._cell = self.base_cell.with_obstacles(obstacles)
        return self._cell

    def is_free(self, Q: FloatArray) -> np.ndarray:
        """Validity of configurations in the current environment (with the clearance margin)."""
        return ~self.workcell().collides(Q, avoid_sources="none", margin=self.margin)

    def alone(self, name: str) -> Workcell:
        """The workcell with object ``name`` where it is now and no other object."""
        return self.base_cell.with_obstacles({name: self.world_shape(name)})

    # --- tags and inverse kinematics ------------------------------------------------------

    def tool(self, q: FloatArray) -> Pose:
        """Tool-point pose of one configuration."""
        x, y, phi = self.robot.tool_pose(np.asarray(q, float)[None, :])[0]
        return (float(x), float(y), float(phi))

    def branch(self, q: FloatArray) -> int | None:
        """Elbow branch of an arm configuration (sign of joint 2), ``None`` for a point robot."""
        if isinstance(self.robot, PlanarArm):
            return int(self.robot.elbow_branch(np.asarray(q, float)[None, :])[0])
        return None

    def nearest_object(self, x: float, y: float) -> tuple[str | None, float]:
        """The object nearest to a workspace point and its distance."""
        geoms = self.geometries()
        if not geoms:
            return None, math.inf
        pt = shapely.Point(x, y)
        names = list(geoms)
        d = [geoms[n].distance(pt) for n in names]
        k = int(np.argmin(d))
        return names[k], float(d[k])

    def tag_of(self, q: FloatArray) -> Tag:
        """Attach a configuration to the nearest object (within ``attach_radius``), Section 2.3."""
        pose = self.tool(q)
        obj, dist = self.nearest_object(pose[0], pose[1])
        radius = self.attach_radius
        if obj is None or (radius is not None and dist > radius):
            return Tag(None, pose, self.branch(q))
        return Tag(obj, compose(inverse(self.objects[obj].pose), pose), self.branch(q))

    def tool_pose_of(self, tag: Tag) -> Pose:
        """World tool pose of a tag in the current environment."""
        if tag.obj is None or tag.obj not in self.objects:
            return tag.rel
        return compose(self.objects[tag.obj].pose, tag.rel)

    def config_of(self, tag: Tag, seed: FloatArray | None = None) -> FloatArray | None:
        """Configuration for a tag by IK on the tag's branch (closed form: ``seed``, the
        subgoal's old configuration, is not needed); ``None`` if unreachable."""
        x, y, phi = self.tool_pose_of(tag)
        robot = self.robot
        if isinstance(robot, PlanarArm):
            sols, valid = robot.ik(
                np.array([x]), np.array([y]), np.array([phi]) if robot.n_links == 3 else None
            )
            k = 0 if (tag.branch or 1) > 0 else 1
            if not valid[0, k]:
                return None
            return np.asarray(sols[0, k], dtype=float)
        # A rigid robot's tool frame is its body frame: (x, y), or (x, y, theta) wrapped.
        q = np.array([x, y] if robot.dim == 2 else [x, y, phi], dtype=float)
        q = robot.wrap(q)
        return q if bool(robot.within_limits(q[None, :])[0]) else None

    def _goal_tag(self, goal: GoalSpec) -> Tag:
        phi = units.radians(goal.orientation) if goal.orientation is not None else 0.0
        pose: Pose = (float(goal.at[0]), float(goal.at[1]), phi)
        if goal.object is None:
            return Tag(None, pose, goal.elbow)
        return Tag(goal.object, compose(inverse(self.objects[goal.object].pose), pose), goal.elbow)

    def goal_config(self, name: str) -> FloatArray | None:
        """Configuration of a goal in the current environment (``None``: no IK solution)."""
        return self.config_of(self.goals[name])

    def goal_problems(
        self, where: str, when: str = "", skip: Collection[str] = ()
    ) -> list[Problem]:
        """Goals without IK solution or in collision now (fields ``where.<goal>``; ``when``
        ends each message, e.g. " after adaptive.changes[0]"); goals named in ``skip`` are
        not checked."""
        problems = []
        for name in sorted(set(self.goals) - set(skip)):
            q = self.goal_config(name)
            if q is None:
                problems.append(
                    Problem(
                        f"{where}.{name}",
                        f"no inverse-kinematics solution on its elbow branch{when}",
                    )
                )
            elif not (self.robot.within_limits(q[None, :])[0] and self.is_free(q[None, :])[0]):
                hits = self.hits(q, self.margin)
                what = (
                    f"collides with (or is within the clearance of) obstacle "
                    f"{', '.join(repr(h) for h in hits)}"
                    if hits
                    else "is outside the joint limits or the workcell bounds"
                )
                problems.append(Problem(f"{where}.{name}", f"the goal configuration {what}{when}"))
        return problems

    def check_free(self, q: FloatArray, name: str) -> None:
        """One clear line when ``q`` is outside the limits, the bounds, or in collision
        (naming the object), or within Reach's certified clearance of something."""
        shown = self.shown_within_limits(q, name)
        empty = self.base_cell.with_obstacles({})
        if empty.collides(q[None, :], avoid_sources="none")[0]:
            raise ArgumentError(f"configuration {shown} leaves the workcell bounds", name)
        for margin, how in ((0.0, "collides with"), (self.margin, "is within the clearance")):
            hits = self.hits(q, margin)
            if hits and margin == 0.0:
                names = ", ".join(repr(h) for h in hits)
                raise ArgumentError(f"configuration {shown} {how} obstacle {names}", name)
            if hits:
                raise ArgumentError(
                    f"configuration {shown} {how} margin {margin:.3g} of obstacle {hits[0]!r} "
                    "(Reach certifies its segments with this clearance; a finer resolution "
                    "shrinks it)",
                    name,
                )
        if not self.is_free(q[None, :])[0]:
            raise ArgumentError(
                f"configuration {shown} is within the clearance margin of the workcell bounds",
                name,
            )

    def pose_goal(self, pose: FloatArray, seed: FloatArray) -> FloatArray:
        """Tool-pose goals are for URDF arms; a planar robot's goal is a configuration."""
        raise ArgumentError(
            "a (4, 4) tool-pose goal needs a 3-D arm; give a configuration or a goal's name",
            "goal",
        )

    def shape(self, shape: Any) -> ShapeSet:
        """A shape given to ``ExperiencePlanner.add``: a :class:`ShapeSet` or a scenario
        shape (``{"type": "box", "min": ..., "max": ...}``, a polygon or a disc)."""
        if isinstance(shape, ShapeSet):
            return shape
        return self.shape_from_spec(validated_spec(Shape, shape))

    def pose_of(self, pose: Any) -> Pose:
        """A pose argument checked: three finite numbers ``(x, y, theta)``."""
        return checked_pose(pose, "x, y, theta")

    def objects_json(self) -> dict[str, Any]:
        """The objects as JSON values (shape and pose)."""
        return {
            n: {"shape": shape_to_json(st.shape), "pose": list(st.pose)}
            for n, st in sorted(self.objects.items())
        }

    def goals_json(self) -> dict[str, Any]:
        """The goals' tags as JSON values."""
        return {n: [t.obj, list(t.rel), t.branch] for n, t in sorted(self.goals.items())}

    def restore_json(self, objects: Mapping[str, Any], goals: Mapping[str, Any], gen: int) -> None:
        """Replace objects, goals and generation from :meth:`objects_json` / :meth:`goals_json`."""
        self.restore(
            {n: (shape_from_json(o["shape"]), self.pose_of(o["pose"])) for n, o in objects.items()},
            {
                n: Tag(obj, (float(r[0]), float(r[1]), float(r[2])), branch)
                for n, (obj, r, branch, *_) in goals.items()
            },
            gen,
        )

    # --- changes --------------------------------------------------------------------------

    def shape_from_spec(self, spec: Any) -> ShapeSet:
        """The shape of an ``add_object`` change (a polygon, box or disc)."""
        return ShapeSet.from_spec(spec)

    def moved(self, change: MoveObject) -> Pose:
        """The pose a scheduled move (a shift) puts its object at."""
        st = self.objects[change.object]
        return (st.pose[0] + change.by[0], st.pose[1] + change.by[1], st.pose[2])

    def turn_angle(self, change: RotateObject) -> FloatArray:
        """A scheduled turn's ``degrees`` as ``[theta]`` radians."""
        # the section gives a planar turn its degrees (adaptive.section._check_dimension)
        assert change.degrees is not None
        return np.array([units.radians(change.degrees)], float)

    def turn(self, name: str, angle: FloatArray, about: Any = None) -> set[str]:
        """Turn object ``name`` counter-clockwise by ``angle`` (``[theta]`` radians) about
        ``about = (x, y)`` (``None``: the object's centroid now): the pose becomes
        ``T(c) R(theta) T(-c) pose`` (Chen, Section 2.3: attached subgoals turn with it)."""
        st = self.objects[name]
        if about is None:
            c = self.geometries()[name].centroid
            cx, cy = float(c.x), float(c.y)
        else:
            cx, cy = float(about[0]), float(about[1])
        turn: Pose = (0.0, 0.0, float(np.asarray(angle, float).reshape(-1)[0]))
        pose = compose((cx, cy, 0.0), compose(turn, compose((-cx, -cy, 0.0), st.pose)))
        return self.set_pose(name, pose)

    def checked_turn(self, angle: Any, about: Any) -> tuple[FloatArray, Any]:
        """``ExperiencePlanner.turn``'s arguments: one angle ``theta`` (radians) and an
        optional centre ``(x, y)``."""
        return checked_turn(angle, about, "theta", "x, y")

    def add_object(self, name: str, shape: ShapeSet, pose: Pose = (0.0, 0.0, 0.0)) -> None:
        """Add an object: ``shape`` in its own coordinates, placed at ``pose``."""
        self.objects[name] = ObjectState(shape, pose)
        self._changed()

    def restore(
        self, objects: Mapping[str, tuple[ShapeSet, Pose]], goals: Mapping[str, Tag], gen: int
    ) -> None:
        """Replace the objects, goals and generation (a saved world being reopened)."""
        self.objects = {n: ObjectState(shape, pose) for n, (shape, pose) in objects.items()}
        self.goals = dict(goals)
        self.gen = gen
        self._forget()

    def _forget(self) -> None:
        self._cell = None
        self._geoms = None


AnyWorld = World | World3D


def make_world(scenario: Scenario | Setup, resolution: float | None = None) -> AnyWorld:
    """The changing workcell of a scenario: planar (:class:`World`) or 3-D
    (:class:`~.world3d.World3D`), as the scenario's workcell model is."""
    setup = as_setup(scenario)
    cell = setup.workcell
    if cell.dimension == 3:
        assert isinstance(cell, Workcell3D)
        return World3D(setup.scenario, cell, resolution)
    return World(setup.scenario, resolution)


def preflight(scenario: Scenario, resolution: float | None, seed: int) -> None:
    """Check every goal at every stage of the change schedule before any work is done.

    Also follows the task sequence (listed, or drawn with ``seed`` as the run draws it)
    assuming every task reaches its goal, and refuses a change that puts an obstacle on
    the robot where the previous task leaves it: the run would stop there.

    Raises
    ------
    ScenarioError
        One problem per goal that is unreachable or in collision at some stage, and one
        per change that lands on the parked robot.
    """
    from cellplan.adaptive.runner import choose_goal, task_count

    world = make_world(scenario, resolution)
    problems = world.goal_problems("adaptive.goals")
    failed = {p.field.rsplit(".", 1)[-1] for p in problems}
    sec = world.section
    assert sec is not None
    n_tasks = task_count(scenario, None)
    stages = sec.stages()
    q: FloatArray | None = np.asarray(world.robot.start, float)
    current: str | None = None
    # Only the stages count: the tasks, and the task numbers where changes land (a change
    # may name any task up to a million, so the loop must not walk every number up to it).
    for t in sorted(set(range(n_tasks)) | set(stages)):
        stage = stages.get(t, [])
        for _, change in stage:
            world.apply(change)
        if stage:
            # Once a stage, as the run checks (AdaptiveSection.stages): thousands of changes
            # at one task must not cost thousands of inverse-kinematics solves. A goal
            # already reported is not solved again: its first stage is enough.
            field, what = stage_words(stage)
            if t < n_tasks and q is not None and not world.is_free(q[None, :])[0]:
                where = "at its start" if current is None else f"at goal {current!r}"
                verb = "puts" if len(stage) == 1 else f"{what} put"
                words = f"{verb} an obstacle on the robot, parked {where} after task {t}"
                problems.append(Problem(field, words))
            for p in world.goal_problems(
                "adaptive.goals", f" after {what} (after task {t})", skip=failed
            ):
                failed.add(p.field.rsplit(".", 1)[-1])
                problems.append(p)
        if t < n_tasks:
            current = choose_goal(sec, list(world.goals), t, current, seed)
            q = world.goal_config(current) if current in world.goals else None
    if problems:
        raise ScenarioError(problems)

"""What the planar and the 3-D changing workcells share: the bookkeeping of a world.

:class:`~.world.World` (planar shapes with poses ``(x, y, theta)``) and
:class:`~.world3d.World3D` (solids translated by offsets ``(x, y, z)``) keep objects,
named goals and the environment generation the same way: every change goes through
:meth:`ChangingWorld.apply` and the primitives :meth:`~ChangingWorld.add_object`,
:meth:`~ChangingWorld.remove_object`, :meth:`~ChangingWorld.set_pose` and
:meth:`~ChangingWorld.turn` (a scheduled ``rotate_object`` and ``ExperiencePlanner.turn``
alike), and each starts a new generation (edge verification is stamped with it). What
differs (the shapes, how a pose composes, goals as tags, IK) is each subclass's.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Generic, Protocol, TypeVar

import numpy as np
from pydantic import TypeAdapter, ValidationError

from cellplan import units
from cellplan.adaptive.section import (
    AdaptiveSection,
    AddGoal,
    AddObject,
    Change,
    GoalSpec,
    MoveObject,
    RemoveGoal,
    RemoveObject,
    RotateObject,
)
from cellplan.adaptive.space import FloatArray
from cellplan.adaptive.tags import Tag
from cellplan.errors import ArgumentError, Problem
from cellplan.scenario import Scenario
from cellplan.schema import COORD_LIMIT
from cellplan.validity import RobotModel, ValiditySpace

Pose = tuple[float, float, float]
"""``(x, y, theta)`` of a planar object, ``(x, y, z)`` offset of a 3-D one."""


def validated_spec(model: Any, given: Any) -> Any:
    """``given`` (a shape handed to ``ExperiencePlanner.add``) validated as the scenario
    model ``model`` would read it; one line (field ``shape``) naming the first mistake."""
    try:
        return TypeAdapter(model).validate_python(given)
    except ValidationError as exc:
        first = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in first["loc"])
        message = f"{where}: {first['msg']}" if where else str(first["msg"])
        raise ArgumentError(message, "shape") from None


def checked_pose(pose: Any, axes: str, note: str = "") -> Pose:
    """``pose`` as three finite numbers, else one line (field ``pose``) that names the
    ``axes`` (``"x, y, theta"``) and adds ``note`` (units, what a pose may do)."""
    try:
        values = [float(v) for v in pose]
    except (TypeError, ValueError):
        raise ArgumentError(f"expected ({axes}) numbers{note}", "pose") from None
    if len(values) != 3 or not all(np.isfinite(values)):
        raise ArgumentError(f"expected three finite numbers ({axes}){note}, got {pose!r}", "pose")
    return (values[0], values[1], values[2])


def _finite_numbers(value: Any, count: int) -> list[float] | None:
    """``value`` as ``count`` finite real numbers (a bare number when ``count == 1``), else
    ``None``."""
    try:
        arr = units.real_array(value, "value")
    except ArgumentError:
        return None
    if arr.ndim > 1 or arr.size != count or not np.all(np.isfinite(arr)):
        return None
    return [float(v) for v in arr.reshape(-1)]


def checked_turn(
    angle: Any, about: Any, angles: str, point: str
) -> tuple[FloatArray, tuple[float, ...] | None]:
    """The arguments of ``ExperiencePlanner.turn`` checked before any work: ``angle`` as
    the numbers ``angles`` names (``"theta"``; ``"roll, pitch, yaw"``), radians within
    :data:`cellplan.units.ANGLE_LIMIT` (a value in degrees is the usual mistake), and
    ``about`` as ``None`` or the coordinates ``point`` names (``"x, y"``), within
    :data:`cellplan.schema.COORD_LIMIT`. One :class:`~cellplan.errors.Problem` per bad
    argument (fields ``angle`` and ``about``)."""
    problems = []
    n_angles, n_point = len(angles.split(", ")), len(point.split(", "))
    values = _finite_numbers(angle, n_angles)
    what = "one finite number" if n_angles == 1 else f"{n_angles} finite numbers"
    if values is None:
        problems.append(Problem("angle", f"expected {what} ({angles}) in radians, got {angle!r}"))
    elif max(abs(v) for v in values) > units.ANGLE_LIMIT:
        problems.append(
            Problem(
                "angle",
                f"({', '.join(f'{v:g}' for v in values)}) exceeds two turns; angles are "
                "radians here",
            )
        )
    centre = None
    if about is not None:
        pts = _finite_numbers(about, n_point)
        if pts is None or max(abs(v) for v in pts) > COORD_LIMIT:
            problems.append(
                Problem("about", f"expected {n_point} finite coordinates ({point}), got {about!r}")
            )
        else:
            centre = tuple(pts)
    if problems:
        raise ArgumentError(problems)
    assert values is not None
    return np.array(values, float), centre


class PlacedObject(Protocol):
    """An object's state: its pose (the shape is the subclass's own)."""

    pose: Pose


ObjectT = TypeVar("ObjectT", bound=PlacedObject)
ShapeT = TypeVar("ShapeT")


class ChangingWorld(ABC, Generic[ObjectT, ShapeT]):
    """Objects, goals and generation of one adaptive problem (see the module docstring).

    Subclasses set the attributes below and give the geometry: :meth:`workcell`,
    :meth:`alone`, :meth:`shape_from_spec`, :meth:`moved`, :meth:`add_object`,
    :meth:`pose_of`, :meth:`_goal_tag` and :meth:`_forget`.
    """

    scenario: Scenario | None
    section: AdaptiveSection | None
    robot: RobotModel
    objects: dict[str, ObjectT]
    goals: dict[str, Tag]
    attach_radius: float | None
    """Subgoals attach to the nearest object within this distance (``None``: always)."""
    gen: int
    """The environment generation: one more after every change."""
    carrying: str | None = None
    """The part the robot holds (a part of the workcell, attached to its tool): every
    validity test of the world is made with it (:meth:`hold`)."""

    # --- geometry (the subclass's) --------------------------------------------------------

    @abstractmethod
    def workcell(self) -> ValiditySpace:
        """The cell with the objects where they are now."""

    @abstractmethod
    def alone(self, name: str) -> ValiditySpace:
        """The cell with object ``name`` where it is now and no other object."""

    @abstractmethod
    def shape_from_spec(self, spec: Any) -> ShapeT:
        """The shape of a scenario's ``add_object`` change (a validated spec)."""

    @abstractmethod
    def moved(self, change: MoveObject) -> Pose:
        """The pose a scheduled move puts its object at."""

    @abstractmethod
    def turn_angle(self, change: RotateObject) -> FloatArray:
        """A scheduled turn's angle in radians, as :meth:`turn` takes it (the scenario
        writes degrees; :mod:`cellplan.units` converts)."""

    @abstractmethod
    def turn(self, name: str, angle: FloatArray, about: Any = None) -> set[str]:
        """Turn object ``name`` by ``angle`` (radians) about the point ``about`` (``None``:
        the subclass's default centre); returns ``{name}`` (its attached tags follow).
        The one law of a turn, for a scheduled ``rotate_object`` and
        ``ExperiencePlanner.turn`` alike; a new generation."""

    @abstractmethod
    def checked_turn(self, angle: Any, about: Any) -> tuple[FloatArray, Any]:
        """The arguments of ``ExperiencePlanner.turn`` checked (:func:`checked_turn`)."""

    @abstractmethod
    def add_object(self, name: str, shape: ShapeT, pose: Pose = (0.0, 0.0, 0.0)) -> None:
        """Add an object placed at ``pose`` (a new generation)."""

    @abstractmethod
    def pose_of(self, pose: Any) -> Pose:
        """A pose argument checked: three finite numbers."""

    @abstractmethod
    def _goal_tag(self, goal: GoalSpec) -> Tag:
        """The tag of a named goal (attached to its object, if it names one)."""

    @abstractmethod
    def _forget(self) -> None:
        """Drop what is cached of the objects' geometry (they changed)."""

    def _check_part(self, part: str) -> None:
        """Refuse (one line, field ``carrying``) a part this world cannot hold: by default
        every part (the planar world's certified clearance covers the bare robot only, so
        it has no carrying rule); a world that can hold parts overrides this."""
        raise ArgumentError(
            f"cannot hold part {part!r}: this workcell's experience planner checks the bare "
            "robot (carrying is for 3-D cells)",
            "carrying",
        )

    # --- shared ---------------------------------------------------------------------------

    def hold(self, part: str | None) -> None:
        """Let the robot hold ``part`` (``None``: nothing) from now on.

        A different part changes the robot's shape, so it is an environment change: a
        new generation, and G's edges and vertices are verified again (by the repair
        strategy, T) before they are used with it. The same part again changes nothing.
        """
        if part == self.carrying:
            return
        if part is not None:
            self._check_part(part)
        self.carrying = part
        self._changed()

    def is_free_exact(self, Q: FloatArray) -> np.ndarray:
        """No contact (re-checks of executed paths): validity without a clearance, the
        held part attached."""
        return ~self.workcell().collides(Q, self.carrying, avoid_sources="none")

    def hits(self, q: FloatArray, margin: float = 0.0) -> list[str]:
        """Names of the objects one configuration meets (within ``margin``, the held part
        attached), sorted."""
        q = np.asarray(q, float)[None, :]
        return [
            n
            for n in sorted(self.objects)
            if self.alone(n).collides(q, self.carrying, avoid_sources="none", margin=margin)[0]
        ]

    def shown_within_limits(self, q: FloatArray, name: str) -> str:
        """``q`` as messages show it, after refusing (one line, field ``name``) a
        configuration outside the joint limits, which it names."""
        robot = self.robot
        shown = "(" + ", ".join(f"{v:.4g}" for v in q) + ")"
        if not robot.within_limits(q[None, :])[0]:
            lim = ", ".join(
                f"{a} [{lo:.4g}, {hi:.4g}]"
                for a, lo, hi in zip(robot.axis_names, robot.lower, robot.upper, strict=True)
            )
            raise ArgumentError(f"configuration {shown} is outside the joint limits: {lim}", name)
        return shown

    def apply(self, change: Change) -> set[str]:
        """Apply one scheduled change; the names of objects whose pose changed (the tags
        attached to them move)."""
        if isinstance(change, AddObject):
            self.add_object(change.object, self.shape_from_spec(change.shape))
        elif isinstance(change, RemoveObject):
            self.remove_object(change.object)
        elif isinstance(change, RotateObject):
            return self.turn(change.object, self.turn_angle(change), change.about)
        elif isinstance(change, MoveObject):
            return self.set_pose(change.object, self.moved(change))
        elif isinstance(change, AddGoal):
            self.goals[change.goal] = self._goal_tag(change.spec())
        elif isinstance(change, RemoveGoal):
            del self.goals[change.goal]
        return set()

    # The primitives every environment change goes through (scheduled changes and
    # ExperiencePlanner.add / remove / move alike); each starts a new generation.

    def remove_object(self, name: str) -> None:
        """Remove an object (subgoals attached to it stay where they are)."""
        del self.objects[name]
        self._changed()

    def set_pose(self, name: str, pose: Any) -> set[str]:
        """Place an object at ``pose`` (checked by :meth:`pose_of`); returns ``{name}``
        (its attached tags move with it)."""
        self.objects[name].pose = self.pose_of(pose)
        self._changed()
        return {name}

    def _changed(self) -> None:
        self.gen += 1
        self._forget()

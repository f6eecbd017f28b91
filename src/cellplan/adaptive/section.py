"""The ``adaptive:`` scenario section: goals, tasks, environment changes, planner settings.

Goals are tool-point positions written in world coordinates of the initial
workcell, optionally attached to an object (then they move and turn with it,
Section 2.3). Tasks are an explicit list of goal names or a random sequence
from the goal set with a seed. Changes happen after a given task number and
add, remove, move or rotate an object, or add or remove a goal. Angles are in
degrees; ``resolution`` is in degrees for arm joints and in workcell units for
a point robot.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field

from cellplan.errors import Problem
from cellplan.scenario3d import Angle, AnyShape, Vec3
from cellplan.schema import Name, PositiveFloat, StrictModel, Vec2

if TYPE_CHECKING:
    from cellplan.scenario import Scenario

TaskIndex = Annotated[int, Field(ge=0, le=1_000_000)]
REPAIR_STRATEGIES = ("A0", "A1", "A2", "A3")
OmplPlanner = Annotated[str, Field(pattern=r"^ompl\.[A-Za-z][A-Za-z0-9]{0,63}$")]
"""``ompl.<Name>``: a planner class of ``ompl.geometric`` (checked before a run)."""


class GoalSpec(StrictModel):
    """A named goal: where the tool point must go."""

    at: Vec2 | Vec3 = Field(
        description="tool point in world coordinates of the initial workcell ((x, y) in a "
        "planar cell, (x, y, z) metres in a 3-D one)"
    )
    object: Name | None = Field(
        default=None, description="object the goal is attached to (moves with it)"
    )
    elbow: Literal[1, -1] = Field(default=1, description="arm IK branch: sign of joint 2")
    orientation: float | None = Field(
        default=None, description="tool orientation, degrees (3-link arms)"
    )
    rpy: tuple[float, float, float] | None = Field(
        default=None,
        description="3-D cells: the tool frame's roll, pitch, yaw in degrees (default: the "
        "tool's z axis pointing down)",
    )


class RandomTasks(StrictModel):
    """``count`` goals drawn uniformly from the goal set, never the robot's current goal."""

    count: Annotated[int, Field(ge=1, le=1_000_000)]
    """number of tasks"""
    seed: int = 0
    """seed of the draw"""


class _Change(StrictModel):
    after_task: TaskIndex = Field(description="applied after this many tasks (0: before the first)")


class AddObject(_Change):
    type: Literal["add_object"]
    """change kind"""
    object: Name
    """name of the new object"""
    shape: AnyShape
    """its shape (workcell units; a solid in a 3-D cell)"""


class RemoveObject(_Change):
    type: Literal["remove_object"]
    """change kind"""
    object: Name
    """name of the object removed"""


class MoveObject(_Change):
    type: Literal["move_object"]
    """change kind"""
    object: Name
    """name of the object moved"""
    by: Vec2 | Vec3
    """translation (workcell units; (x, y, z) metres in a 3-D cell)"""


class RotateObject(_Change):
    type: Literal["rotate_object"]
    """change kind"""
    object: Name
    """name of the object rotated"""
    degrees: float | None = None
    """planar cells: rotation, counter-clockwise, in degrees"""
    rpy: tuple[Angle, Angle, Angle] | None = None
    """3-D cells: the turn's roll, pitch, yaw about fixed world axes, degrees
    (R = Rz(yaw) Ry(pitch) Rx(roll)); attached subgoals turn with the object"""
    about: Vec2 | Vec3 | None = Field(
        default=None,
        description="centre of rotation (default: the object's centroid; (x, y, z) metres "
        "in a 3-D cell, where the default is the object's centre now)",
    )


class AddGoal(_Change):
    type: Literal["add_goal"]
    """change kind"""
    goal: Name
    """name of the new goal"""
    at: Vec2 | Vec3
    """tool point (workcell units; (x, y, z) metres in a 3-D cell)"""
    object: Name | None = None
    """object the goal is attached to (moves with it)"""
    elbow: Literal[1, -1] = 1
    """arm IK branch: sign of joint 2"""
    orientation: float | None = None
    """tool orientation, degrees (3-link arms)"""
    rpy: tuple[float, float, float] | None = None
    """3-D cells: tool roll, pitch, yaw, degrees (default: pointing down)"""

    def spec(self) -> GoalSpec:
        return GoalSpec(
            at=self.at,
            object=self.object,
            elbow=self.elbow,
            orientation=self.orientation,
            rpy=self.rpy,
        )


class RemoveGoal(_Change):
    type: Literal["remove_goal"]
    """change kind"""
    goal: Name
    """name of the goal removed"""


Change = Annotated[
    AddObject | RemoveObject | MoveObject | RotateObject | AddGoal | RemoveGoal,
    Field(discriminator="type"),
]


class AdaptiveSection(StrictModel):
    """Settings of the ``adaptive:`` section (Chen 1994)."""

    goals: dict[Name, GoalSpec] = Field(min_length=1)
    """named goals the tasks visit (tool points, degrees for orientations)"""
    tasks: list[Name] | RandomTasks = Field(description="explicit goal names, or random")
    changes: list[Change] = Field(default_factory=list)
    """workcell changes after given tasks: add, remove, move, rotate objects; add, remove goals"""
    repair: Literal["A0", "A1", "A2", "A3"] = "A3"
    """repair after a change: A0 forget, A1 verify all, A2 actively, A3 on demand (Sec. 2.5)"""
    solve: Literal["rrtconnect", "two_segment"] | OmplPlanner = "rrtconnect"
    """the global planner S: OMPL RRTConnect, any single-threaded OMPL geometric planner
    by name (``ompl.RRT``, ``ompl.KPIECE1``, ...), or the two-segment toy planner of Fig. 3"""
    reach: Literal["straight", "potential"] = "straight"
    """the local planner R: a straight line in C-space, or a potential-field descent"""
    resolution: PositiveFloat = Field(
        default=1.0, description="Reach step: degrees (arm) or units (point)"
    )
    attach_radius: PositiveFloat | None = Field(
        default=None,
        description="attach a subgoal to the nearest object within this distance (None: always)",
    )
    corner_cutting: bool = True
    """shorten executed paths by corner cutting (Sec. 2.6)"""
    max_chain: Annotated[int, Field(ge=1)] | None = None
    """longest subgoal chain T follows (None: no limit)"""
    max_solve_checks: Annotated[int, Field(ge=100)] = Field(
        default=200_000,
        description="Solve's budget in collision checks per S or T step (deterministic, "
        "load-independent; a 600 s wall-time guard only stops runaway calls)",
    )

    def ordered_changes(self) -> list[tuple[int, Change]]:
        """Changes with their index in the file, by task number (stable)."""
        return sorted(enumerate(self.changes), key=lambda ic: ic[1].after_task)

    def stages(self) -> dict[int, list[tuple[int, Change]]]:
        """The changes applied after each task number, with their index in the file.

        The robot sees the workcell only between tasks, so a stage's changes act together:
        its goals and the parked robot are checked after the last of them.
        """
        stages: dict[int, list[tuple[int, Change]]] = {}
        for i, change in self.ordered_changes():
            stages.setdefault(change.after_task, []).append((i, change))
        return stages

    def check(self, scenario: Scenario) -> list[Problem]:
        """Cross-references: objects and goals named by goals, tasks and changes exist then."""
        problems: list[Problem] = []
        robot = scenario.robot
        if robot is None:
            problems.append(Problem("robot", "the adaptive section needs a robot (point or arm)"))
        elif robot.type not in ("point", "arm", "urdf"):
            problems.append(
                Problem(
                    "robot.type", "the adaptive planner supports point robots, arms and URDF arms"
                )
            )
        elif robot.type == "arm" and len(robot.links) not in (2, 3):
            problems.append(Problem("robot.links", "object-attached IK needs a 2- or 3-link arm"))
        problems += self._check_dimension(scenario)
        objects = set(scenario.workcell.obstacles)
        for name, goal in self.goals.items():
            if goal.object is not None and goal.object not in objects:
                problems.append(
                    Problem(f"adaptive.goals.{name}.object", f"unknown object {goal.object!r}")
                )
        goals = set(self.goals)
        if isinstance(self.tasks, list):
            self._check_task_list(problems)
        for i, change in self.ordered_changes():
            where = f"adaptive.changes[{i}]"
            if isinstance(change, AddObject):
                if change.object in objects:
                    problems.append(
                        Problem(f"{where}.object", f"object {change.object!r} already exists")
                    )
                objects.add(change.object)
            elif isinstance(change, RemoveObject | MoveObject | RotateObject):
                if change.object not in objects:
                    problems.append(Problem(f"{where}.object", f"unknown object {change.object!r}"))
                elif isinstance(change, RemoveObject):
                    objects.discard(change.object)
                    for g in sorted(goals):
                        if self._goal_object(g) == change.object:
                            problems.append(
                                Problem(
                                    f"{where}.object",
                                    f"goal {g!r} is still attached to {change.object!r}",
                                )
                            )
            elif isinstance(change, AddGoal):
                if change.goal in goals:
                    problems.append(
                        Problem(f"{where}.goal", f"goal {change.goal!r} already exists")
                    )
                if change.object is not None and change.object not in objects:
                    problems.append(Problem(f"{where}.object", f"unknown object {change.object!r}"))
                goals.add(change.goal)
            elif isinstance(change, RemoveGoal):
                if change.goal not in goals:
                    problems.append(Problem(f"{where}.goal", f"unknown goal {change.goal!r}"))
                goals.discard(change.goal)
                if not goals:
                    problems.append(Problem(f"{where}.goal", "removes the last goal"))
        return problems

    def _check_dimension(self, scenario: Scenario) -> list[Problem]:
        """Points and translations have the workcell's dimension; a turn is ``degrees``
        in a planar cell and ``rpy`` in a 3-D one (Section 2.3: attached tags turn too)."""
        solid = scenario.robot is not None and scenario.robot.type == "urdf"
        want = 3 if solid else 2
        problems = []
        points = [(f"adaptive.goals.{n}.at", g.at) for n, g in self.goals.items()]
        for i, c in enumerate(self.changes):
            if isinstance(c, AddGoal):
                points.append((f"adaptive.changes[{i}].at", c.at))
            elif isinstance(c, MoveObject):
                points.append((f"adaptive.changes[{i}].by", c.by))
            elif isinstance(c, RotateObject):
                where = f"adaptive.changes[{i}]"
                if c.about is not None:
                    points.append((f"{where}.about", c.about))
                if solid and c.rpy is None:
                    problems.append(
                        Problem(
                            f"{where}.rpy",
                            "a 3-D cell turns an object by rpy: [roll, pitch, yaw] degrees",
                        )
                    )
                if solid and c.degrees is not None:
                    problems.append(
                        Problem(f"{where}.degrees", "is for planar cells; a 3-D turn is rpy")
                    )
                if not solid and c.degrees is None:
                    problems.append(
                        Problem(f"{where}.degrees", "a planar turn needs its angle in degrees")
                    )
                if not solid and c.rpy is not None:
                    problems.append(
                        Problem(f"{where}.rpy", "is for 3-D cells; a planar turn is degrees")
                    )
            elif isinstance(c, AddObject) and solid != hasattr(c.shape, "pose"):
                problems.append(
                    Problem(
                        f"adaptive.changes[{i}].shape",
                        "needs a solid in a 3-D cell" if solid else "needs a planar shape",
                    )
                )
        for where, value in points:
            if len(value) != want:
                problems.append(Problem(where, f"needs {want} coordinates in a {want}-D workcell"))
        return problems

    def _goal_object(self, goal: str) -> str | None:
        if goal in self.goals:
            return self.goals[goal].object
        for c in self.changes:
            if isinstance(c, AddGoal) and c.goal == goal:
                return c.object
        return None

    def _check_task_list(self, problems: list[Problem]) -> None:
        assert isinstance(self.tasks, list)
        if not self.tasks:
            problems.append(Problem("adaptive.tasks", "the task list is empty"))
        changes = self.ordered_changes()
        goals = set(self.goals)
        k = 0
        for t, name in enumerate(self.tasks):
            while k < len(changes) and changes[k][1].after_task <= t:
                c = changes[k][1]
                if isinstance(c, AddGoal):
                    goals.add(c.goal)
                elif isinstance(c, RemoveGoal):
                    goals.discard(c.goal)
                k += 1
            if name not in goals:
                problems.append(
                    Problem(f"adaptive.tasks[{t}]", f"goal {name!r} does not exist at task {t + 1}")
                )


def stage_words(stage: Sequence[tuple[int, Change]]) -> tuple[str, str]:
    """The field and the subject that name a stage's changes in a message.

    One change: ``("adaptive.changes[i]", "adaptive.changes[i]")``. Several: the first
    one's field, and ``"the N changes adaptive.changes[i, j, ...]"`` (at most four indices).
    """
    field = f"adaptive.changes[{stage[0][0]}]"
    if len(stage) == 1:
        return field, field
    shown = ", ".join(str(i) for i, _ in stage[:4]) + (", ..." if len(stage) > 4 else "")
    return field, f"the {len(stage)} changes adaptive.changes[{shown}]"

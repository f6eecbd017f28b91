"""The 3-D parts of the scenario format (format version 2): solids, poses, URDF robots.

A scenario is three-dimensional when its bounds name ``zmin`` and ``zmax``. Its obstacles,
parts, sources and destinations are then solids (box, cylinder, sphere, capsule or
triangle mesh), each with a pose: a position and roll-pitch-yaw angles in degrees, in
URDF's convention (``R = Rz(yaw) Ry(pitch) Rx(roll)``). Lengths are metres. A mesh path,
like a URDF or SRDF path, is relative to the scenario file.

The models here only describe files; :mod:`cellplan.workcell3d` builds the model.
Every 2-D file stays valid: a shape is read as a solid only when it says so (a solid
``type``, or a ``size`` or ``pose`` key), see :func:`shape_dimension`.
"""

from __future__ import annotations

import math
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, cast

from pydantic import (
    Discriminator,
    Field,
    SerializerFunctionWrapHandler,
    Tag,
    model_serializer,
    model_validator,
)

from cellplan.errors import Problem
from cellplan.fileio import kind_of
from cellplan.schema import Coord, Length, Name, Shape, StrictModel
from cellplan.timing import ACCELERATION_TIME, DEFAULT_ANGULAR_SPEED_DEG, DEFAULT_LINEAR_SPEED

if TYPE_CHECKING:
    from cellplan.scenario import Scenario, WorkcellSpec

__all__ = [
    "SOLID_MODELS",
    "SOLID_TYPES",
    "UNION_CHOOSERS",
    "UNION_TAGS",
    "AnyShape",
    "Bounds3",
    "CapsuleSolid",
    "CylinderSolid",
    "MeshSolid",
    "Pose",
    "RobotMotion",
    "Solid",
    "SolidBox",
    "SphereSolid",
    "UrdfRobotSpec",
    "Workcell3DSpec",
    "check_references_3d",
    "is_3d",
    "planar",
    "planar_workcell",
    "shape_dimension",
]

Vec3 = tuple[Coord, Coord, Coord]
Angle = Annotated[float, Field(ge=-360.0, le=360.0, allow_inf_nan=False)]
Scale = Annotated[float, Field(gt=0, le=1e3, allow_inf_nan=False)]
PathText = Annotated[str, Field(min_length=1, max_length=4096)]

UNION_TAGS = ("planar", "solid", "2d", "3d")
"""Tags of the 2-D/3-D unions, which pydantic puts in error locations (never keys)."""

SOLID_TYPES = ("box", "cylinder", "sphere", "capsule", "mesh")
"""Solid kinds; ``box`` is also a 2-D kind (with ``min`` and ``max``)."""


class Pose(StrictModel):
    """A rigid pose: position, then roll-pitch-yaw in degrees (URDF's ``origin``)."""

    xyz: Vec3 = Field(default=(0.0, 0.0, 0.0), description="position (metres)")
    rpy: tuple[Angle, Angle, Angle] = Field(
        default=(0.0, 0.0, 0.0),
        description="roll, pitch, yaw about x, y, z (degrees; R = Rz(yaw) Ry(pitch) Rx(roll))",
    )


class SolidBox(StrictModel):
    """A box centred at its pose (URDF's ``<box size>``)."""

    type: Literal["box"] = Field(description="shape kind")
    size: tuple[Length, Length, Length] = Field(
        description="full edge lengths along the local x, y, z (metres)", examples=[[0.3, 0.2, 0.1]]
    )
    pose: Pose = Field(default_factory=Pose, description="centre and orientation")


class CylinderSolid(StrictModel):
    """A cylinder along its local z axis, centred at its pose (URDF's ``<cylinder>``)."""

    type: Literal["cylinder"] = Field(description="shape kind")
    radius: Length = Field(description="radius (metres)")
    length: Length = Field(description="length along the local z axis (metres)")
    pose: Pose = Field(default_factory=Pose, description="centre and orientation")


class SphereSolid(StrictModel):
    """A ball centred at its pose's position."""

    type: Literal["sphere"] = Field(description="shape kind")
    radius: Length = Field(description="radius (metres)")
    pose: Pose = Field(default_factory=Pose, description="centre (orientation unused)")


class CapsuleSolid(StrictModel):
    """A capsule: the points within ``radius`` of a segment of ``length`` along local z."""

    type: Literal["capsule"] = Field(description="shape kind")
    radius: Length = Field(description="radius (metres)")
    length: Length = Field(description="length of the axis segment (metres), caps excluded")
    pose: Pose = Field(default_factory=Pose, description="centre and orientation")


class MeshSolid(StrictModel):
    """A closed triangle mesh (STL, OBJ or DAE), its path relative to the scenario file."""

    type: Literal["mesh"] = Field(description="shape kind")
    path: PathText = Field(description="mesh file, relative to the scenario file")
    scale: tuple[Scale, Scale, Scale] = Field(
        default=(1.0, 1.0, 1.0), description="scale along the mesh's x, y, z"
    )
    pose: Pose = Field(default_factory=Pose, description="pose of the mesh's frame")


Solid = Annotated[
    SolidBox | CylinderSolid | SphereSolid | CapsuleSolid | MeshSolid,
    Field(discriminator="type"),
]


def shape_dimension(value: Any) -> str:
    """``"solid"`` for a 3-D shape, ``"planar"`` for a 2-D one (the tag of :data:`AnyShape`).

    A mapping is a solid when its type exists only in 3-D or when it has a ``size`` or a
    ``pose`` (a 2-D box has ``min`` and ``max``), so every 2-D file reads as before.
    """
    if isinstance(value, dict):
        solid = value.get("type") in SOLID_TYPES[1:] or "size" in value or "pose" in value
        return "solid" if solid else "planar"
    return "solid" if hasattr(value, "pose") else "planar"


AnyShape = Annotated[
    Annotated[Shape, Tag("planar")] | Annotated[Solid, Tag("solid")],
    Discriminator(shape_dimension),
]
"""A 2-D shape or a solid; a 3-D scenario takes only solids (:func:`check_references_3d`)."""


class Bounds3(StrictModel):
    """The box ``[xmin, xmax] x [ymin, ymax] x [zmin, zmax]`` (metres)."""

    xmin: Coord = Field(description="lower x (metres)", examples=[-1.0])
    ymin: Coord = Field(description="lower y (metres)", examples=[-1.0])
    zmin: Coord = Field(description="lower z (metres)", examples=[0.0])
    xmax: Coord = Field(description="upper x (metres)", examples=[1.0])
    ymax: Coord = Field(description="upper y (metres)", examples=[1.0])
    zmax: Coord = Field(description="upper z (metres)", examples=[1.5])

    @model_validator(mode="after")
    def _ordered(self) -> Bounds3:
        if not (self.xmax > self.xmin and self.ymax > self.ymin and self.zmax > self.zmin):
            raise ValueError("bounds need xmax > xmin, ymax > ymin and zmax > zmin")
        return self

    @property
    def lo(self) -> tuple[float, float, float]:
        """The lower corner."""
        return (self.xmin, self.ymin, self.zmin)

    @property
    def hi(self) -> tuple[float, float, float]:
        """The upper corner."""
        return (self.xmax, self.ymax, self.zmax)


class Workcell3DSpec(StrictModel):
    """A 3-D cell: box bounds in metres and named solid obstacles."""

    units: Literal["m"] = Field(default="m", description="length unit of a 3-D cell")
    bounds: Bounds3 = Field(description="the box the robot stays in (metres)")
    obstacles: dict[Name, AnyShape] = Field(
        default_factory=dict,
        max_length=10_000,
        description="static obstacles by name: box, cylinder, sphere, capsule or mesh",
        examples=[{"table": {"type": "box", "size": [1.2, 0.8, 0.05]}}],
    )


def workcell_dimension(value: Any) -> str:
    """``"3d"`` when the bounds name ``zmin`` or ``zmax``, else ``"2d"``."""
    bounds = value.get("bounds") if isinstance(value, dict) else getattr(value, "bounds", None)
    if isinstance(bounds, dict):
        return "3d" if "zmin" in bounds or "zmax" in bounds else "2d"
    return "3d" if hasattr(bounds, "zmin") else "2d"


UNION_CHOOSERS = {
    frozenset(("planar", "solid")): shape_dimension,
    frozenset(("2d", "3d")): workcell_dimension,
}
"""How each 2-D/3-D union picks its member, by its set of tags (for error messages that
name what a mapping may hold)."""


#: Most axes a robot's ``speed`` or ``acceleration`` list may name.
MAX_AXES = 128
Rate = Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)]


class RobotMotion(StrictModel):
    """How fast a robot moves: the fields every robot kind shares (see cellplan.timing).

    Both are per axis, in the order of ``start``, in file units per second: workcell units
    (metres for URDF arms) for positions, degrees for angles. Absent (the default), a URDF
    arm uses its URDF's velocity limits, other robots
    ``cellplan.timing.DEFAULT_LINEAR_SPEED`` units/s and
    ``cellplan.timing.DEFAULT_ANGULAR_SPEED_DEG`` degrees/s; the acceleration reaches the
    speed in ``cellplan.timing.ACCELERATION_TIME`` seconds.
    """

    speed: list[Rate] | None = Field(
        default=None,
        max_length=MAX_AXES,
        description=(
            "top speed per axis: workcell units/s (metres/s for URDF arms), degrees/s for "
            f"angles (default: the URDF's velocity limits, else {DEFAULT_LINEAR_SPEED:g} "
            f"units/s and {DEFAULT_ANGULAR_SPEED_DEG:g} degrees/s)"
        ),
    )
    acceleration: list[Rate] | None = Field(
        default=None,
        max_length=MAX_AXES,
        description=(
            "top acceleration per axis: workcell units/s^2, degrees/s^2 for angles "
            f"(default: speed / {ACCELERATION_TIME:g} s)"
        ),
    )

    @model_validator(mode="after")
    def _one_per_axis(self) -> RobotMotion:
        dim = len(getattr(self, "start", ()))
        for name in ("speed", "acceleration"):
            value = getattr(self, name)
            if value is not None and len(value) != dim:
                raise ValueError(f"{name} needs one value per axis ({dim}), got {len(value)}")
        return self

    @model_serializer(mode="wrap")
    def _omit_absent_motion(self, handler: SerializerFunctionWrapHandler) -> Any:
        # A robot without speeds dumps as before these fields existed, so the digests of
        # existing scenarios (saved strategies, experience databases) do not change.
        data = handler(self)
        if isinstance(data, dict):
            for name in ("speed", "acceleration"):
                if data.get(name) is None:
                    data.pop(name, None)
        return data


class UrdfRobotSpec(RobotMotion):
    """An arm described by a URDF (kinematics by Pinocchio, collision geometry by coal).

    ``joints`` lists the active joints, in order; every other movable joint stays at
    its ``locked`` value (degrees for revolute joints, metres for prismatic ones; the
    default is 0, or the nearest limit when 0 is outside). Joint limits come from the
    URDF, and continuous joints are periodic. The bundled names ``ur5`` and ``panda`` load
    the robots of the ``example-robot-data`` package with their SRDFs.
    """

    type: Literal["urdf"]
    """robot kind"""
    urdf: PathText
    """a bundled name (ur5, panda) or a URDF file, relative to the scenario file"""
    srdf: PathText | None = None
    """an SRDF whose disabled collision pairs are not checked (bundled robots bring theirs)"""
    base: Pose = Field(default_factory=Pose)
    """the world pose of the URDF's root link"""
    tool: Name | None = None
    """the tool frame (default: tool0 for ur5, panda_hand for panda, else the last frame)"""
    joints: list[Name] | None = Field(default=None, min_length=1, max_length=32)
    """active joints in order (default: every movable joint)"""
    locked: dict[Name, float] = Field(default_factory=dict, max_length=64)
    """values of the joints that are not active (degrees, or metres for prismatic joints)"""
    limits: dict[Name, tuple[float, float]] = Field(default_factory=dict, max_length=32)
    """narrower limits of active joints, (lower, upper) in degrees (metres for prismatic
    joints), within the URDF's: the working range a planner and its bitmaps cover"""
    start: list[float] = Field(min_length=1, max_length=32)
    """start value of each active joint (degrees, or metres for prismatic joints)"""


def planar(shape: Any) -> Shape:
    """A shape of a 2-D scenario, typed as one (validation keeps solids out of 2-D
    workcells: :func:`cellplan.scenario.check_references`)."""
    if shape_dimension(shape) != "planar":
        raise TypeError("a solid where a 2-D shape was expected")
    return cast("Shape", shape)


def planar_workcell(sc: Scenario) -> WorkcellSpec:
    """The workcell section of a 2-D scenario, typed as one."""
    if isinstance(sc.workcell, Workcell3DSpec):
        raise TypeError("a 3-D workcell where a 2-D one was expected")
    return sc.workcell


def is_3d(sc: Scenario) -> bool:
    """Whether a scenario describes a 3-D cell."""
    return isinstance(sc.workcell, Workcell3DSpec)


SOLID_MODELS = (SolidBox, CylinderSolid, SphereSolid, CapsuleSolid, MeshSolid)
"""The models of :data:`Solid`."""


def _shape_fields(sc: Scenario) -> list[tuple[str, Any]]:
    """``(field, shape)`` of every part and region component."""
    out: list[tuple[str, Any]] = [
        (f"parts.{name}.shape", part.shape) for name, part in sc.parts.items()
    ]
    for section, regions in (("sources", sc.sources), ("destinations", sc.destinations)):
        for name, region in regions.items():
            out += [
                (f"{section}.{name}.components[{i}]", c) for i, c in enumerate(region.components)
            ]
    return out


def check_references_3d(sc: Scenario, folder: Path | None) -> list[Problem]:
    """Cross-field checks of a 3-D scenario (every problem found, one line each).

    Shapes must be solids; regions lie inside the bounds (their centres at least);
    obstacles are not placed far away from the box; the robot is a URDF arm; mesh files
    exist when the scenario was read from a file (``folder``). Collisions, joint names
    and limits are checked when the model is built
    (:meth:`cellplan.workcell3d.Workcell3D.from_scenario`), which needs the URDF.
    """
    problems: list[Problem] = []
    spec = sc.workcell
    if not isinstance(spec, Workcell3DSpec):
        raise TypeError("check_references_3d takes a 3-D scenario")
    if sc.cellplan < 2:
        problems.append(
            Problem("cellplan", "a 3-D workcell (bounds with zmin, zmax) needs 'cellplan: 2'")
        )
    solids: list[tuple[str, Any]] = []
    obstacles = [(f"workcell.obstacles.{n}", o) for n, o in spec.obstacles.items()]
    for field, shape in [*obstacles, *_shape_fields(sc)]:
        if isinstance(shape, SOLID_MODELS):
            solids.append((field, shape))
        else:
            problems.append(
                Problem(
                    field, "is a 2-D shape in a 3-D workcell; give a solid with a size and a pose"
                )
            )
    robot = sc.robot
    if robot is not None and robot.type != "urdf":
        problems.append(
            Problem(
                "robot.type", f"a 3-D workcell takes a URDF robot (type: urdf), not {robot.type!r}"
            )
        )
    if robot is None and (sc.parts or sc.sources or sc.destinations):
        problems.append(Problem("robot", "parts, sources and destinations need a robot"))
    if sc.cspace.cells is not None and len(sc.cspace.cells) > 3:
        problems.append(
            Problem(
                "cspace.cells",
                f"has {len(sc.cspace.cells)} entries; bitmaps of a 3-D arm take 1 to 3 joints",
            )
        )
    b = spec.bounds
    diagonal = math.dist(b.lo, b.hi)
    for field, shape in solids:
        if field.startswith("workcell.obstacles."):
            if _far_outside(shape.pose.xyz, b, diagonal):
                problems.append(Problem(field, "lies entirely outside the workcell bounds"))
        elif not field.startswith("parts.") and not _inside(shape.pose.xyz, b):
            problems.append(Problem(field, "lies outside the workcell bounds"))
    if folder is not None:
        for field, shape in solids:
            if isinstance(shape, MeshSolid):
                reason = _not_a_file(folder / shape.path)
                if reason:
                    problems.append(Problem(f"{field}.path", f"mesh file {shape.path!r} {reason}"))
    return problems


def _not_a_file(path: Path) -> str:
    """Why ``path`` is not a regular file one can read (empty when it is one)."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return f"not found (in {path.parent})"
    except OSError as exc:
        return f"cannot be read: {exc.strerror}"
    except ValueError:  # a NUL character: no file can have that name
        return "is not a file name (it holds a NUL character)"
    if not stat.S_ISREG(mode):
        return f"is {kind_of(mode)}, not a mesh file"
    return ""


def _inside(xyz: tuple[float, float, float], b: Bounds3) -> bool:
    return all(lo <= v <= hi for v, lo, hi in zip(xyz, b.lo, b.hi, strict=True))


def _far_outside(xyz: tuple[float, float, float], b: Bounds3, pad: float) -> bool:
    # Only a solid's pose is known here (a mesh's extent needs its file): one placed
    # beyond a diagonal of the box from it is a mistake whatever its size.
    return any(v < lo - pad or v > hi + pad for v, lo, hi in zip(xyz, b.lo, b.hi, strict=True))

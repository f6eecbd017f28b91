"""URDF arms in 3-D: batched kinematics, a conservative sphere cover, exact checks and IK.

An :class:`Arm` is built from a URDF (and optionally an SRDF) by :func:`load_arm`. Parsing,
the reduced model (locked joints folded into fixed placements) and the reference collision
check use Pinocchio; the hot paths (forward kinematics, sphere centres, self-collision over
many configurations) are numba kernels over a flat copy of the kinematic chain.

Conventions
-----------
Pinocchio keeps the *model* (constant: tree, placements, limits) apart from the *data*
(per-configuration work buffers) [1]_; an :class:`Arm` holds only models and constant
arrays, never a ``pin.Data``, so it can be shared between threads and each call creates
its own data. As in Pinocchio, joint ``i`` of the model has the pose
``oMi[i] = oMi[parent[i]] * jointPlacements[i] * M_joint(q_i)`` and a geometry object is
placed in its parent *joint* frame by ``GeometryObject.placement`` [2]_. Index 0 is the
universe; the arm's *moving frames* are joints ``1 .. njoints-1`` of the reduced model,
so moving frame ``f`` is Pinocchio joint ``f + 1``. Every world pose here is
``arm.base @ oMi``.

Configurations are in radians and metres, one column per entry of ``Arm.joint_names``
(the order the caller gave); a continuous joint (Pinocchio's ``RUBx``, stored as
``(cos q, sin q)``) is represented by its angle. Degrees never appear here: the caller
converts with :mod:`cellplan.units`.

References
----------
.. [1] J. Carpentier et al., "The Pinocchio C++ library: a fast and flexible
   implementation of rigid body dynamics algorithms and their analytical derivatives",
   IEEE/SICE SII 2019 (the Model/Data split).
.. [2] Pinocchio documentation, ``pinocchio::GeometryObject::placement``: "Position of
   geometry object in parent joint frame".
"""

from __future__ import annotations

import contextlib
import heapq
import importlib.metadata
import math
import os
import stat
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import coal
import numpy as np
import pinocchio as pin
from numba import njit
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.fileio import kind_of
from cellplan.schema import COORD_LIMIT
from cellplan.units import ANGLE_LIMIT, real_array

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

__all__ = [
    "BUNDLED",
    "Arm",
    "IkResult",
    "JointKind",
    "LinkMesh",
    "Spheres",
    "bundled",
    "cover_mesh",
    "exact_collides",
    "exact_min_distance",
    "fixed_collides",
    "forward",
    "ik",
    "joint_kinds",
    "lever_arms",
    "link_meshes",
    "load_arm",
    "self_collides",
    "sphere_centers",
    "sphere_levers",
    "tool_pose",
]

#: Joint kinds of the numba chain.
_REVOLUTE = 0
_PRISMATIC = 1

#: Pinocchio joint short names the chain supports: kind, fixed axis (None: read ``axis``),
#: continuous (``nq == 2``, cos/sin).
_JOINT_KINDS: Mapping[str, tuple[int, tuple[float, float, float] | None, bool]] = MappingProxyType(
    {
        "JointModelRX": (_REVOLUTE, (1.0, 0.0, 0.0), False),
        "JointModelRY": (_REVOLUTE, (0.0, 1.0, 0.0), False),
        "JointModelRZ": (_REVOLUTE, (0.0, 0.0, 1.0), False),
        "JointModelRevoluteUnaligned": (_REVOLUTE, None, False),
        "JointModelRUBX": (_REVOLUTE, (1.0, 0.0, 0.0), True),
        "JointModelRUBY": (_REVOLUTE, (0.0, 1.0, 0.0), True),
        "JointModelRUBZ": (_REVOLUTE, (0.0, 0.0, 1.0), True),
        "JointModelRevoluteUnboundedUnaligned": (_REVOLUTE, None, True),
        "JointModelPX": (_PRISMATIC, (1.0, 0.0, 0.0), False),
        "JointModelPY": (_PRISMATIC, (0.0, 1.0, 0.0), False),
        "JointModelPZ": (_PRISMATIC, (0.0, 0.0, 1.0), False),
        "JointModelPrismaticUnaligned": (_PRISMATIC, None, False),
    }
)

#: Bundled arms of example-robot-data: URDF, SRDF (relative to its ``robots`` folder) and
#: the default tool frame (the UR flange; the Panda's TCP between the fingertips).
_BUNDLED: Mapping[str, tuple[str, str, str]] = MappingProxyType(
    {
        "ur5": ("ur_description/urdf/ur5_robot.urdf", "ur_description/srdf/ur5.srdf", "tool0"),
        "panda": (
            "panda_description/urdf/panda.urdf",
            "panda_description/srdf/panda.srdf",
            "panda_hand_tcp",
        ),
    }
)

BUNDLED: tuple[str, ...] = tuple(_BUNDLED)
"""Names of the bundled arms (:func:`bundled`)."""

#: Default largest sphere radius of the cover (metres). Smaller radii add spheres faster
#: than they tighten the cover (flat link ends stick out of any sphere by about 0.4 times
#: their half-width); 7 cm gives the UR5 49 spheres and the Panda arm about 70.
DEFAULT_MAX_RADIUS = 0.07

#: Spheres per mesh at most: the cover stops splitting there even above ``max_radius``.
_MAX_SPHERES_PER_MESH = 64

#: Sides of the polygon circumscribing a cylinder's or cone's circle.
_CIRCLE_SIDES = 16


# --------------------------------------------------------------------------- data types


@dataclass(frozen=True, eq=False)
class Spheres:
    """Conservative sphere cover of collision geometry.

    Parameters
    ----------
    frame
        ``(S,)`` index into the arm's moving frames (see :func:`forward`) carrying each
        sphere; ``-1`` for geometry fixed to the URDF root.
    centers
        ``(S, 3)`` centre in that frame's local coordinates (metres); for frame ``-1``
        in the URDF root's coordinates (``Arm.base`` not applied).
    radii
        ``(S,)`` radii (metres).
    link
        ``(S,)`` URDF link name each sphere covers.
    """

    frame: IntArray
    centers: FloatArray
    radii: FloatArray
    link: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.radii)


@dataclass(frozen=True, eq=False)
class Arm:
    """A URDF arm reduced to its active joints, with its sphere cover.

    The public fields are described in :func:`load_arm`. The private-looking ones are
    for the kernels: the chain (``chain_*``, one row per moving frame), the Pinocchio
    models (``model``: the reduced ``pin.Model``; ``geometry``: its collision
    ``pin.GeometryModel``, meshes loaded) and the bookkeeping of the exact check.

    Attributes
    ----------
    fixed_spheres
        Cover of the links fixed to the URDF root (frame ``-1``, root coordinates).
    fixed_links
        Names of those links.
    fixed_pairs
        ``(P, 2)`` pairs (moving sphere, fixed sphere) tested for self-collision.
    frame_names
        ``(F,)`` Pinocchio joint name of each moving frame.
    geometry_pairs
        ``(G, 2)`` geometry-object index pairs of ``geometry`` tested by the exact
        self-collision check (the same link pairs as the spheres).
    moving_geometry
        Indices of the geometry objects carried by a moving frame.
    """

    name: str
    joint_names: tuple[str, ...]
    lower: FloatArray
    upper: FloatArray
    periodic: BoolArray
    velocity_limit: FloatArray
    base: FloatArray
    tool_frame: str
    locked: dict[str, float]
    spheres: Spheres
    self_pairs: IntArray
    fixed_spheres: Spheres
    fixed_links: tuple[str, ...]
    fixed_pairs: IntArray
    frame_names: tuple[str, ...]
    model: Any
    geometry: Any
    geometry_pairs: IntArray
    moving_geometry: IntArray
    disabled: frozenset[frozenset[str]]
    chain_parent: IntArray
    chain_placement: FloatArray
    chain_kind: IntArray
    chain_axis: FloatArray
    chain_column: IntArray
    pin_q_index: IntArray
    pin_v_index: IntArray
    tool_frame_id: int
    tool_joint: int
    tool_placement: FloatArray
    max_radius: float

    @property
    def angular(self) -> tuple[bool, ...]:
        """Per active joint: True for an angle (revolute, continuous), False for a length."""
        prismatic = np.zeros(self.dim, dtype=bool)
        prismatic[self.chain_column[self.chain_kind == _PRISMATIC]] = True
        return tuple(bool(not p) for p in prismatic)

    @property
    def dim(self) -> int:
        """Number of active joints (columns of a configuration)."""
        return len(self.joint_names)


@dataclass(frozen=True)
class IkResult:
    """Outcome of :func:`ik`.

    Parameters
    ----------
    q
        Best configuration found (``(dim,)``, radians/metres), the solution when
        ``success``; ``None`` only when no attempt ran.
    success
        Whether ``q`` reaches the target within the tolerances (and passed ``valid``).
    position_error
        Distance (metres) from the tool frame's origin at ``q`` to the target's.
    rotation_error
        Angle (radians) of the rotation from the tool frame at ``q`` to the target's.
    iterations
        Iterations over all attempts.
    message
        One line: how it ended.
    """

    q: FloatArray | None
    success: bool
    position_error: float
    rotation_error: float
    iterations: int
    message: str


# --------------------------------------------------------------------------- bundled arms


@lru_cache(maxsize=1)
def _robots_dir() -> Path:
    """The ``robots`` folder of example-robot-data (a data-only package)."""
    dist = importlib.metadata.distribution("example-robot-data")
    return Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))


def bundled(name: str) -> tuple[Path, Path | None, Path]:
    """URDF, SRDF and package directory of an arm shipped with example-robot-data.

    Parameters
    ----------
    name
        ``"ur5"`` or ``"panda"``.

    Returns
    -------
    tuple
        ``(urdf, srdf, package_dir)``; ``package_dir`` resolves the
        ``package://example-robot-data/...`` URIs of the URDF.

    Raises
    ------
    ArgumentError
        For an unknown name (the message lists the known ones).
    """
    if name not in _BUNDLED:
        known = ", ".join(sorted(_BUNDLED))
        raise ArgumentError([Problem("name", f"unknown bundled arm {name!r}; known: {known}")])
    urdf, srdf, _tool = _BUNDLED[name]
    robots = _robots_dir()
    return robots / urdf, robots / srdf, robots.parent.parent


# --------------------------------------------------------------------------- loading


@contextlib.contextmanager
def _native_stderr_silenced() -> Iterator[None]:
    """Hold file descriptor 2 while Pinocchio parses: urdfdom prints its parse errors
    straight to it, beside the one line cellplan makes of the exception."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)


def _urdf_path(urdf: str | Path) -> Path:
    """A bundled arm's URDF, or the path as given."""
    if isinstance(urdf, str) and urdf in _BUNDLED and not Path(urdf).exists():
        return bundled(urdf)[0]
    return Path(urdf)


class JointKind(NamedTuple):
    """A movable joint of a URDF: its kind and limits (radians or metres)."""

    kind: str
    """``"revolute"``, ``"continuous"``, ``"prismatic"`` or ``"other"`` (floating, planar)"""
    lower: float
    upper: float


def joint_kinds(urdf: str | Path, *, field: str = "robot") -> dict[str, JointKind]:
    """The movable joints of a URDF (or a bundled arm), in Pinocchio's order, with their
    kinds and limits (continuous joints: ``-pi, pi``). The kinematics only, without
    meshes: what a caller needs to check and convert file units (degrees for angles)
    before :func:`load_arm`.

    Raises
    ------
    ScenarioError
        One line naming ``{field}.urdf`` when the file is missing or does not parse.
    """
    path = _urdf_path(urdf)
    _check_xml(path, f"{field}.urdf", "URDF")
    try:
        with _native_stderr_silenced():
            model = pin.buildModelFromUrdf(str(path))
    except (ValueError, RuntimeError) as exc:
        raise ScenarioError([Problem(f"{field}.urdf", _one_line(exc))]) from None
    out: dict[str, JointKind] = {}
    for jid in range(1, model.njoints):
        kind = _JOINT_KINDS.get(model.joints[jid].shortname())
        name = str(model.names[jid])
        if kind is None:
            out[name] = JointKind("other", -math.inf, math.inf)
            continue
        lo, hi, continuous = _joint_limits(model, jid)
        if kind[0] == _PRISMATIC:
            out[name] = JointKind("prismatic", lo, hi)
        else:
            out[name] = JointKind("continuous" if continuous else "revolute", lo, hi)
    return out


def load_arm(
    urdf: str | Path,
    *,
    srdf: str | Path | None = None,
    base: ArrayLike | None = None,
    tool: str | None = None,
    joints: Sequence[str] | None = None,
    locked: Mapping[str, float] | None = None,
    package_dirs: Sequence[Path] = (),
    field: str = "robot",
    max_radius: float = DEFAULT_MAX_RADIUS,
) -> Arm:
    """Load a URDF arm, reduce it to its active joints and cover it with spheres.

    Parameters
    ----------
    urdf
        Path of the URDF, or a bundled name (:func:`bundled`): ``"ur5"``, ``"panda"``.
    srdf
        SRDF whose ``disable_collisions`` pairs are never tested (and whose
        ``end_effector parent_link`` is the default tool). A bundled arm uses its own.
    base
        ``(4, 4)`` world pose of the URDF root (identity by default).
    tool
        Pinocchio frame (a URDF link or joint name) whose pose :func:`tool_pose` and
        :func:`ik` use. Default: the bundled arm's tool, else the SRDF end effector,
        else the last body frame of the model.
    joints
        Active joints in the order of the configuration's columns. Default: every
        non-fixed joint, in Pinocchio's order.
    locked
        Value (radians/metres) of joints that are not active. Default for each: 0, or
        the limit nearest 0 when 0 is outside the limits.
    package_dirs
        Folders resolving ``package://`` URIs (example-robot-data's is always added).
    field
        Name of the scenario field the arm comes from: problems are reported as
        ``{field}.urdf``, ``{field}.joints[i]``, ``{field}.locked.NAME``, ...
    max_radius
        Largest sphere of the cover (metres), a target: a mesh stops being split at
        64 spheres.

    Returns
    -------
    Arm
        ``spheres`` covers the links carried by an active joint; links fixed to the
        root are in ``fixed_spheres``/``fixed_links``. ``self_pairs`` holds the sphere
        pairs on two links that are neither on the same body, nor on a parent and child
        body (one joint apart), nor disabled by the SRDF.

    Raises
    ------
    ScenarioError
        One :class:`~cellplan.errors.Problem` per mistake: a URDF that does not parse, a
        missing or flat mesh, an unknown joint or frame, a locked value outside the
        limits, a joint both active and locked or listed twice, an unsupported joint
        type (floating, planar, spherical ...) among the active joints.
    """
    tool_default: str | None = None
    dirs = [Path(p) for p in package_dirs]
    if isinstance(urdf, str) and urdf in _BUNDLED and not Path(urdf).exists():
        bundled_urdf, bundled_srdf, share = bundled(urdf)
        tool_default = _BUNDLED[urdf][2]
        arm_name = urdf
        urdf_path = bundled_urdf
        if srdf is None:
            srdf = bundled_srdf
    else:
        urdf_path = Path(urdf)
        share = _robots_dir().parent.parent
        arm_name = ""
    dirs.append(share)

    _check_xml(urdf_path, f"{field}.urdf", "URDF")
    try:
        with _native_stderr_silenced():
            full = pin.buildModelFromUrdf(str(urdf_path))
        full_geom = pin.buildGeomFromUrdf(
            full, str(urdf_path), pin.GeometryType.COLLISION, package_dirs=[str(d) for d in dirs]
        )
    except (ValueError, RuntimeError) as exc:
        raise ScenarioError([Problem(f"{field}.urdf", _one_line(exc))]) from None
    arm_name = arm_name or full.name or urdf_path.stem

    base_m = _check_pose(base, f"{field}.base", ScenarioError)
    disabled, srdf_tool = _read_srdf(srdf, f"{field}.srdf")

    movable = [str(n) for n in full.names][1:]
    active, problems = _active_joints(full, movable, joints, field)

    q_ref = pin.neutral(full)
    locked_values: dict[str, float] = {}
    given = dict(locked or {})
    for j, value in given.items():
        where = f"{field}.locked.{j}"
        if j not in movable:
            problems.append(Problem(where, _unknown("joint", j, movable)))
            continue
        if j in active:
            problems.append(Problem(where, f"joint {j!r} is both active and locked"))
            continue
        problem = _set_locked(full, j, value, q_ref, where)
        if problem is not None:
            problems.append(problem)
        else:
            locked_values[j] = float(value)
    for j in movable:
        if j not in active and j not in given:
            default = _default_locked(full, j, q_ref)
            if default is not None:
                locked_values[j] = default
    if problems:
        raise ScenarioError(problems)

    lock_ids = [full.getJointId(j) for j in movable if j not in active]
    try:
        model, geoms = pin.buildReducedModel(full, [full_geom], lock_ids, q_ref)
    except (ValueError, RuntimeError) as exc:
        raise ScenarioError([Problem(f"{field}.urdf", _one_line(exc))]) from None
    geometry = geoms[0]
    geometry.removeAllCollisionPairs()

    chain = _chain(model, active, f"{field}.urdf")
    (parent, placement, kind, axis, column, q_index, v_index, lower, upper, periodic, vel) = chain
    frame_names = tuple(str(n) for n in model.names[1:])

    tool_name = tool or tool_default or srdf_tool or _last_body_frame(model)
    tool_field = f"{field}.tool"
    frame_list = [str(f.name) for f in model.frames]
    if tool_name not in frame_list:
        raise ScenarioError([Problem(tool_field, _unknown("frame", tool_name, frame_list))])
    tool_id = int(model.getFrameId(tool_name))
    tool_frame = model.frames[tool_id]
    if int(tool_frame.parentJoint) == 0:
        raise ScenarioError(
            [Problem(tool_field, f"frame {tool_name!r} does not move with any active joint")]
        )

    moving, fixed, moving_geometry = _cover_geometry(model, geometry, max_radius, field)
    body_of_link = _bodies(model)
    self_pairs, fixed_pairs, geometry_pairs = _pairs(
        model, geometry, moving, fixed, parent, body_of_link, disabled
    )
    return Arm(
        name=arm_name,
        joint_names=tuple(active),
        lower=lower,
        upper=upper,
        periodic=periodic,
        velocity_limit=vel,
        base=base_m,
        tool_frame=tool_name,
        locked=locked_values,
        spheres=moving,
        self_pairs=self_pairs,
        fixed_spheres=fixed,
        fixed_links=tuple(sorted(set(fixed.link))),
        fixed_pairs=fixed_pairs,
        frame_names=frame_names,
        model=model,
        geometry=geometry,
        geometry_pairs=geometry_pairs,
        moving_geometry=moving_geometry,
        disabled=disabled,
        chain_parent=parent,
        chain_placement=placement,
        chain_kind=kind,
        chain_axis=axis,
        chain_column=column,
        pin_q_index=q_index,
        pin_v_index=v_index,
        tool_frame_id=tool_id,
        tool_joint=int(tool_frame.parentJoint) - 1,
        tool_placement=np.asarray(tool_frame.placement.homogeneous, dtype=float).copy(),
        max_radius=float(max_radius),
    )


def _one_line(exc: BaseException) -> str:
    """The first non-empty line of an exception's message (Pinocchio appends C++ context)."""
    for line in str(exc).splitlines():
        if line.strip():
            return line.strip()
    return type(exc).__name__


def _unknown(what: str, name: str, known: Sequence[str]) -> str:
    """``unknown joint 'x'; joints: a, b, c, ... (12 in all)``, kept to one short line."""
    shown = ", ".join(known[:8])
    more = f", ... ({len(known)} in all)" if len(known) > 8 else ""
    return f"unknown {what} {name!r}; {what}s: {shown}{more}"


def _check_xml(path: Path, where: str, kind: str) -> None:
    """Refuse a missing or malformed file before Pinocchio (whose parser prints to stderr)."""
    try:
        mode = path.stat().st_mode
    except ValueError:  # a NUL character: no file can have that name
        raise ScenarioError(
            [Problem(where, f"{kind} file {str(path)!r} is not a file name (it holds a NUL)")]
        ) from None
    except OSError as exc:
        hint = f" (bundled arms: {', '.join(sorted(_BUNDLED))})" if kind == "URDF" else ""
        reason = "does not exist" if isinstance(exc, FileNotFoundError) else exc.strerror
        raise ScenarioError(
            [Problem(where, f"{kind} file {str(path)!r}: {reason}{hint}")]
        ) from None
    if not stat.S_ISREG(mode):
        raise ScenarioError(
            [Problem(where, f"{kind} file {str(path)!r} is {kind_of(mode)}, not a regular file")]
        )
    try:
        ET.parse(path)
    except ET.ParseError as exc:
        raise ScenarioError(
            [Problem(where, f"{kind} {str(path)!r} is not valid XML: {exc}")]
        ) from None
    except OSError as exc:
        raise ScenarioError([Problem(where, f"cannot read {kind} {str(path)!r}: {exc}")]) from None


def _read_srdf(srdf: str | Path | None, where: str) -> tuple[frozenset[frozenset[str]], str | None]:
    """Disabled link pairs and end-effector link of an SRDF (MoveIt's format)."""
    if srdf is None:
        return frozenset(), None
    path = Path(srdf)
    _check_xml(path, where, "SRDF")
    root = ET.parse(path).getroot()
    pairs = set()
    for element in root.iter("disable_collisions"):
        a, b = element.get("link1"), element.get("link2")
        if a is None or b is None:
            raise ScenarioError([Problem(where, "disable_collisions needs link1 and link2")])
        pairs.add(frozenset((a, b)))
    effector = root.find("end_effector")
    tool = effector.get("parent_link") if effector is not None else None
    return frozenset(pairs), tool


def _check_pose(value: ArrayLike | None, where: str, error: type[Exception]) -> FloatArray:
    """A ``(4, 4)`` rigid transform (rotation orthonormal to 1e-6, last row 0 0 0 1)."""
    if value is None:
        return np.eye(4)
    try:
        m = real_array(value, where, "a 4x4 pose matrix")
    except ArgumentError as exc:
        raise error(list(exc.problems)) from None
    if m.shape != (4, 4):
        raise error([Problem(where, f"expected a 4x4 pose matrix, got shape {m.shape}")])
    if not np.all(np.isfinite(m)):
        raise error([Problem(where, "contains NaN or infinite values")])
    rot = m[:3, :3]
    if (
        not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6)
        or np.linalg.det(rot) < 0
        or not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0])
    ):
        raise error([Problem(where, "not a rigid transform (rotation not orthonormal)")])
    if np.abs(m[:3, 3]).max() > COORD_LIMIT:
        raise error([Problem(where, f"translation beyond {COORD_LIMIT:g}")])
    return m.copy()


def _joint_limits(model: Any, jid: int) -> tuple[float, float, bool]:
    """``(lower, upper, continuous)`` of a one-dof joint in the angle/metre convention."""
    joint = model.joints[jid]
    continuous = _JOINT_KINDS.get(joint.shortname(), (0, None, False))[2]
    if continuous:
        return -math.pi, math.pi, True
    return (
        float(model.lowerPositionLimit[joint.idx_q]),
        float(model.upperPositionLimit[joint.idx_q]),
        False,
    )


def _set_locked(model: Any, name: str, value: Any, q_ref: FloatArray, where: str) -> Problem | None:
    """Write a locked joint's value into Pinocchio's ``q_ref``; a Problem if it is refused."""
    jid = model.getJointId(name)
    joint = model.joints[jid]
    if joint.shortname() not in _JOINT_KINDS:
        return Problem(
            where,
            f"joint {name!r} has {joint.nq} coordinates; it cannot be locked "
            "at one value (it is locked at its neutral configuration by default)",
        )
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        return Problem(where, f"expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        return Problem(where, f"must be finite, got {v}")
    lo, hi, continuous = _joint_limits(model, jid)
    if continuous:
        q_ref[joint.idx_q] = math.cos(v)
        q_ref[joint.idx_q + 1] = math.sin(v)
        return None
    if not lo - 1e-12 <= v <= hi + 1e-12:
        return Problem(where, f"{v:g} is outside the limits [{lo:g}, {hi:g}] (radians/metres)")
    q_ref[joint.idx_q] = v
    return None


def _default_locked(model: Any, name: str, q_ref: FloatArray) -> float | None:
    """0, or the limit nearest 0, written into ``q_ref``; None for a multi-dof joint
    (left at Pinocchio's neutral configuration)."""
    jid = model.getJointId(name)
    joint = model.joints[jid]
    if joint.shortname() not in _JOINT_KINDS:
        return None
    lo, hi, continuous = _joint_limits(model, jid)
    v = 0.0 if continuous else min(max(0.0, lo), hi)
    _set_locked(model, name, v, q_ref, "")
    return v


def _active_joints(
    model: Any, movable: Sequence[str], joints: Sequence[str] | None, field: str
) -> tuple[list[str], list[Problem]]:
    """The active joints (validated) and the problems found."""
    problems: list[Problem] = []
    if joints is None:
        listed = list(movable)
    elif isinstance(joints, str):
        return [], [Problem(f"{field}.joints", "expected a list of joint names")]
    else:
        listed = list(joints)
    active: list[str] = []
    for i, j in enumerate(listed):
        where = f"{field}.joints[{i}]" if joints is not None else f"{field}.urdf"
        if j not in movable:
            problems.append(Problem(where, _unknown("joint", str(j), movable)))
            continue
        if j in active:
            problems.append(Problem(where, f"joint {j!r} is listed twice"))
            continue
        active.append(j)
        shortname = model.joints[model.getJointId(j)].shortname()
        if shortname not in _JOINT_KINDS:
            problems.append(
                Problem(
                    where,
                    f"joint {j!r} is a {shortname.removeprefix('JointModel')} joint; only "
                    "revolute, continuous and prismatic joints can be active (lock it)",
                )
            )
    if not listed and not problems:
        problems.append(Problem(f"{field}.joints", "the arm has no active joint"))
    return active, problems


def _chain(model: Any, active: Sequence[str], where: str) -> tuple[Any, ...]:
    """Flat arrays of the reduced model's chain for the numba kernels, and the limits."""
    n = model.njoints - 1
    parent = np.empty(n, dtype=np.int64)
    placement = np.empty((n, 4, 4))
    kind = np.empty(n, dtype=np.int64)
    axis = np.empty((n, 3))
    column = np.empty(n, dtype=np.int64)
    dim = len(active)
    q_index = np.empty(dim, dtype=np.int64)
    v_index = np.empty(dim, dtype=np.int64)
    lower = np.empty(dim)
    upper = np.empty(dim)
    periodic = np.zeros(dim, dtype=bool)
    vel = np.empty(dim)
    problems = []
    for jid in range(1, model.njoints):
        f = jid - 1
        joint = model.joints[jid]
        name = str(model.names[jid])
        k, ax, continuous = _JOINT_KINDS[joint.shortname()]
        if ax is None:
            ax_arr = np.asarray(joint.extract().axis, dtype=float)
        else:
            ax_arr = np.array(ax)
        parent[f] = model.parents[jid] - 1
        placement[f] = model.jointPlacements[jid].homogeneous
        kind[f] = k
        axis[f] = ax_arr / np.linalg.norm(ax_arr)
        c = active.index(name)
        column[f] = c
        q_index[c] = joint.idx_q
        v_index[c] = joint.idx_v
        lo, hi, cont = _joint_limits(model, jid)
        lower[c], upper[c], periodic[c] = lo, hi, cont
        vel[c] = float(model.velocityLimit[joint.idx_v])
        if not continuous and not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            problems.append(Problem(where, f"joint {name!r} has no finite limits"))
    if problems:
        raise ScenarioError(problems)
    return parent, placement, kind, axis, column, q_index, v_index, lower, upper, periodic, vel


def _last_body_frame(model: Any) -> str:
    """Name of the last BODY frame attached to a moving joint (the chain's end)."""
    for frame in reversed(list(model.frames)):
        if frame.type == pin.FrameType.BODY and frame.parentJoint > 0:
            return str(frame.name)
    return str(model.frames[len(model.frames) - 1].name)


def _bodies(model: Any) -> dict[str, int]:
    """Moving frame (``-1``: root) of every link, i.e. of every BODY frame."""
    return {
        str(f.name): int(f.parentJoint) - 1 for f in model.frames if f.type == pin.FrameType.BODY
    }


# --------------------------------------------------------------------------- sphere cover


def _primitive_points(geom: Any) -> tuple[FloatArray | None, list[tuple[FloatArray, float]]]:
    """Points whose convex hull contains a coal shape, plus exact spheres to add.

    A circle is replaced by its circumscribed polygon (vertices at ``r / cos(pi/n)``),
    so the polygon, and hence the cover, contains it.
    """
    name = type(geom).__name__
    if name == "Box":
        h = np.asarray(geom.halfSide, dtype=float)
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        return corners * h, []
    if name == "Sphere":
        return None, [(np.zeros(3), float(geom.radius))]
    if name == "Ellipsoid":
        h = np.asarray(geom.radii, dtype=float)
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        return corners * h, []
    if name in ("Cylinder", "Capsule", "Cone"):
        r, hl = float(geom.radius), float(geom.halfLength)
        angles = 2.0 * np.pi * np.arange(_CIRCLE_SIDES) / _CIRCLE_SIDES
        rho = r / math.cos(math.pi / _CIRCLE_SIDES)
        ring = np.column_stack([rho * np.cos(angles), rho * np.sin(angles)])
        top = np.column_stack([ring, np.full(_CIRCLE_SIDES, hl)])
        bottom = np.column_stack([ring, np.full(_CIRCLE_SIDES, -hl)])
        if name == "Cone":
            # coal's cone: base circle at z = -halfLength, apex at +halfLength.
            return np.vstack([bottom, [[0.0, 0.0, hl]]]), []
        if name == "Capsule":
            caps = [(np.array([0.0, 0.0, hl]), r), (np.array([0.0, 0.0, -hl]), r)]
            if hl <= 0.0:
                return None, caps[:1]
            return np.vstack([top, bottom]), caps
        return np.vstack([top, bottom]), []
    if isinstance(geom, coal.ConvexBase):
        return np.asarray(geom.points(), dtype=float), []
    if isinstance(geom, coal.BVHModelBase):
        vertices = np.asarray(geom.vertices(), dtype=float)
        faces = np.array([[t[0], t[1], t[2]] for t in _triangles(geom)], dtype=np.int64)
        if len(faces):
            vertices = vertices[np.unique(faces)]
        return vertices, []
    raise ArgumentError([Problem("geometry", f"unsupported collision shape {name}")])


def _triangles(geom: Any) -> list[Any]:
    return [geom.tri_indices(i) for i in range(geom.num_tris)]


@dataclass(frozen=True, eq=False)
class LinkMesh:
    """One collision geometry of the arm as a triangle mesh, for drawing.

    ``frame`` is the moving frame carrying it (an index of :func:`forward`'s frames), or
    ``-1`` for a link fixed to the base; ``placement`` is its ``(4, 4)`` pose in that
    frame (in the URDF root's frame when fixed).
    """

    name: str
    link: str
    frame: int
    placement: FloatArray
    vertices: FloatArray
    faces: IntArray


def link_meshes(arm: Arm) -> list[LinkMesh]:
    """The arm's collision geometry as triangle meshes (primitives by their convex hull,
    a sphere by a 162-point hull), one per geometry object."""
    out = []
    for obj in arm.geometry.geometryObjects:
        geom = obj.geometry
        if isinstance(geom, coal.BVHModelBase):
            vertices = np.asarray(geom.vertices(), dtype=float)
            faces = np.array([[t[0], t[1], t[2]] for t in _triangles(geom)], dtype=np.int64)
        else:
            points, balls = _primitive_points(geom)
            clouds = [] if points is None else [points]
            for centre, radius in balls:
                clouds.append(centre + radius * _unit_sphere_points(162))
            vertices = np.vstack(clouds)
            faces = np.asarray(ConvexHull(vertices).simplices, dtype=np.int64)
        out.append(
            LinkMesh(
                name=str(obj.name),
                link=str(arm.model.frames[obj.parentFrame].name),
                frame=int(obj.parentJoint) - 1,
                placement=np.asarray(obj.placement.homogeneous, dtype=float),
                vertices=vertices,
                faces=faces.reshape(-1, 3),
            )
        )
    return out


def _unit_sphere_points(n: int) -> FloatArray:
    """``n`` points spread over the unit sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    rho = np.sqrt(1.0 - z * z)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def _cover_geometry(
    model: Any, geometry: Any, max_radius: float, field: str
) -> tuple[Spheres, Spheres, IntArray]:
    """Sphere covers of every geometry object, split into moving and fixed ones."""
    frames: list[int] = []
    centers: list[FloatArray] = []
    radii: list[FloatArray] = []
    links: list[str] = []
    moving_geometry = []
    for gid, obj in enumerate(geometry.geometryObjects):
        link = str(model.frames[obj.parentFrame].name)
        geom = obj.geometry
        try:
            points, balls = _primitive_points(geom)
            if points is not None:
                c, r = _cover_points(points, max_radius)
            else:
                c, r = np.empty((0, 3)), np.empty(0)
        except ArgumentError as exc:
            message = exc.problems[0].message
            raise ScenarioError(
                [Problem(f"{field}.urdf", f"link {link!r}, {obj.name}: {message}")]
            ) from None
        if balls:
            c = np.vstack([c, [b[0] for b in balls]])
            r = np.concatenate([r, [b[1] for b in balls]])
        swept = float(geom.getSweptSphereRadius()) if hasattr(geom, "getSweptSphereRadius") else 0
        r = r + swept
        # Geometry placements are relative to the parent joint frame (Pinocchio's
        # GeometryObject::placement), which is the frame the kernels transform.
        m = np.asarray(obj.placement.homogeneous, dtype=float)
        c = c @ m[:3, :3].T + m[:3, 3]
        frame = int(obj.parentJoint) - 1
        if frame >= 0:
            moving_geometry.append(gid)
        frames.extend([frame] * len(r))
        centers.append(c)
        radii.append(r)
        links.extend([link] * len(r))
    all_frames = np.array(frames, dtype=np.int64)
    all_centers = np.vstack(centers) if centers else np.empty((0, 3))
    all_radii = np.concatenate(radii) if radii else np.empty(0)
    is_moving = all_frames >= 0

    def pick(mask: BoolArray) -> Spheres:
        return Spheres(
            frame=np.ascontiguousarray(all_frames[mask]),
            centers=np.ascontiguousarray(all_centers[mask]),
            radii=np.ascontiguousarray(all_radii[mask]),
            link=tuple(link for link, m in zip(links, mask, strict=True) if m),
        )

    return pick(is_moving), pick(~is_moving), np.array(moving_geometry, dtype=np.int64)


def cover_mesh(
    vertices: ArrayLike,
    faces: ArrayLike,
    max_radius: float,
    *,
    max_spheres: int = _MAX_SPHERES_PER_MESH,
) -> tuple[FloatArray, FloatArray]:
    """Spheres whose union contains the convex hull of a triangle mesh.

    Method (provably conservative). Let ``P`` be the convex hull of the vertices the
    faces use, expressed in its principal axes. Start from one box ``B`` around ``P``.
    The polytope ``P ∩ B`` is the convex hull of its vertices, and each vertex of
    ``P ∩ B`` lies on three independent planes among the facet planes of ``P`` and the
    six face planes of ``B``; so it is one of: a vertex of ``P`` in ``B``; a point where
    an edge of ``P`` (an edge of its triangulated facets) crosses a face plane of ``B``;
    a point where an edge of ``B`` crosses a facet plane of ``P``; a corner of ``B`` in
    ``P``. All four families are collected (with a small tolerance that can only add
    points), and one sphere encloses them: its centre is a near-minimal enclosing
    ball's (Badoiu-Clarkson steps), then moved to stick out of ``P`` less (see
    ``_less_protrusion``); whatever the centre, the radius is the farthest distance to
    the points, so the ball contains their hull, hence ``P ∩ B``. While the largest
    sphere exceeds ``max_radius`` (and fewer than ``max_spheres`` exist), its cell is
    shrunk to the bounding box of its points and cut in two halves, across the side
    that gives the smaller balls; the halves cover the cell, so the union still
    contains ``P``.

    Parameters
    ----------
    vertices
        ``(V, 3)`` vertex coordinates.
    faces
        ``(T, 3)`` vertex indices of the triangles (only referenced vertices count;
        an empty array means all vertices).
    max_radius
        Target largest radius (> 0).
    max_spheres
        Stop splitting at this many spheres even if some radius exceeds ``max_radius``.

    Returns
    -------
    centers, radii
        ``(K, 3)`` and ``(K,)``.

    Raises
    ------
    ArgumentError
        Bad shapes, non-finite values, or a mesh with no volume (flat or degenerate).
    """
    v = real_array(vertices, "vertices")
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise ArgumentError([Problem("vertices", "expected a finite (V, 3) array")])
    f = real_array(faces, "faces")
    if f.size:
        if f.ndim != 2 or f.shape[1] != 3 or np.any(f != np.round(f)):
            raise ArgumentError([Problem("faces", "expected a (T, 3) array of vertex indices")])
        idx = f.astype(np.int64)
        if idx.min() < 0 or idx.max() >= len(v):
            raise ArgumentError([Problem("faces", "vertex index out of range")])
        v = v[np.unique(idx)]
    radius = float(max_radius)
    if not radius > 0.0 or not math.isfinite(radius):
        raise ArgumentError([Problem("max_radius", "must be a positive number")])
    return _cover_points(v, radius, max_spheres)


def _cover_points(
    points: FloatArray,
    max_radius: float,
    max_spheres: int = _MAX_SPHERES_PER_MESH,
) -> tuple[FloatArray, FloatArray]:
    """Cover of the convex hull of ``points`` (see :func:`cover_mesh`)."""
    mean = points.mean(axis=0)
    centred = points - mean
    scale = float(np.abs(centred).max()) if len(points) else 0.0
    if len(points) < 4 or scale == 0.0:
        raise ArgumentError([Problem("vertices", "the mesh has no volume (flat or degenerate)")])
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    local = centred @ vt.T
    try:
        hull = ConvexHull(local)
    except QhullError:
        raise ArgumentError(
            [Problem("vertices", "the mesh has no volume (flat or degenerate)")]
        ) from None
    if hull.volume <= 1e-12 * scale**3:
        raise ArgumentError([Problem("vertices", "the mesh has no volume (flat or degenerate)")])
    hv = local[hull.vertices]
    simplices = hull.simplices
    edges = np.unique(
        np.sort(np.vstack([simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [0, 2]]]), 1),
        axis=0,
    )
    ea, eb = local[edges[:, 0]], local[edges[:, 1]]
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]
    eps = 1e-9 * scale
    geometry = (hv, ea, eb, normals, offsets, eps)

    def badness(cell: _Cell) -> float:
        return cell.radius / max_radius

    first = _cell_sphere(geometry, hv.min(axis=0), hv.max(axis=0), max_radius)
    if first is None:  # unreachable for a full-dimensional hull
        raise ArgumentError([Problem("vertices", "the mesh has no volume (flat or degenerate)")])
    heap: list[tuple[float, int, _Cell]] = [(-badness(first), 0, first)]
    done: list[_Cell] = []
    counter = 0
    while heap:
        neg_bad, _, cell = heapq.heappop(heap)
        if -neg_bad <= 1.0 or len(heap) + len(done) + 2 > max_spheres:
            done.append(cell)
            continue
        # Cut across the side whose halves are best (slabs for a tube, not quarters).
        best: tuple[float, list[_Cell]] | None = None
        for axis in range(3):
            mid = 0.5 * (cell.lo[axis] + cell.hi[axis])
            children = []
            for side in (0, 1):
                c_lo, c_hi = cell.lo.copy(), cell.hi.copy()
                if side == 0:
                    c_hi[axis] = mid
                else:
                    c_lo[axis] = mid
                child = _cell_sphere(geometry, c_lo, c_hi, max_radius)
                if child is not None:
                    children.append(child)
            if not children:
                continue
            worst = (
                max(badness(c) for c in children)
                + 1e-3 * sum(c.radius**3 for c in children) / cell.radius**3
            )
            if best is None or worst < best[0]:
                best = (worst, children)
        if best is None:  # numerically impossible; keep the parent sphere
            done.append(cell)
            continue
        for child in best[1]:
            counter += 1
            heapq.heappush(heap, (-badness(child), counter, child))
    centers_local = np.array([c.centre for c in done])
    radii = np.array([c.radius for c in done])
    # Back from principal axes; pad by a relative 1e-9 for the rounding of the rotation.
    centers = centers_local @ vt + mean
    return centers, radii + 1e-9 * scale


@dataclass(frozen=True, eq=False)
class _Cell:
    """A box of the cover's subdivision: its tight bounds and enclosing ball."""

    lo: FloatArray
    hi: FloatArray
    centre: FloatArray
    radius: float


def _cell_sphere(
    geometry: tuple[Any, ...], lo: FloatArray, hi: FloatArray, max_radius: float
) -> _Cell | None:
    """The cell of hull ∩ box ``[lo, hi]`` shrunk to its bounds, with its ball; None if empty."""
    hv, ea, eb, normals, offsets, eps = geometry
    pts = _cell_points(hv, ea, eb, normals, offsets, eps, lo, hi)
    if len(pts) == 0:
        return None
    t_lo, t_hi = pts.min(axis=0), pts.max(axis=0)
    centre, radius = _enclosing_ball(pts, 0.5 * (t_lo + t_hi))
    centre = _less_protrusion(pts, normals, offsets, centre, max(radius, max_radius))
    radius = float(np.sqrt(((pts - centre) ** 2).sum(axis=1).max()))
    return _Cell(t_lo, t_hi, centre, radius)


@njit(cache=True)
def _cell_points(
    hv: FloatArray,
    ea: FloatArray,
    eb: FloatArray,
    normals: FloatArray,
    offsets: FloatArray,
    eps: float,
    lo: FloatArray,
    hi: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled
    """A superset of the vertices of (convex hull) ∩ (box [lo, hi]) (see cover_mesh).

    The four families of vertices are collected with tolerance ``eps``, which can only
    admit extra points (harmless: the ball grows).
    """
    nf = normals.shape[0]
    cap = hv.shape[0] + 6 * ea.shape[0] + 8 + 12 * nf
    out = np.empty((cap, 3))
    k = 0
    p = np.empty(3)
    for i in range(hv.shape[0]):
        if _in_box(hv[i], lo, hi, eps):
            _put(out, k, hv[i])
            k += 1
    for e in range(ea.shape[0]):
        for ax in range(3):
            d = eb[e, ax] - ea[e, ax]
            if d == 0.0:
                continue
            for side in range(2):
                plane = lo[ax] if side == 0 else hi[ax]
                t = (plane - ea[e, ax]) / d
                if t < 0.0 or t > 1.0:
                    continue
                for c in range(3):
                    p[c] = ea[e, c] + t * (eb[e, c] - ea[e, c])
                p[ax] = plane
                if _in_box(p, lo, hi, eps):
                    _put(out, k, p)
                    k += 1
    for cx in range(2):
        for cy in range(2):
            for cz in range(2):
                p[0] = lo[0] if cx == 0 else hi[0]
                p[1] = lo[1] if cy == 0 else hi[1]
                p[2] = lo[2] if cz == 0 else hi[2]
                if _in_hull(p, normals, offsets, eps):
                    _put(out, k, p)
                    k += 1
    for ax in range(3):
        o1 = (ax + 1) % 3
        o2 = (ax + 2) % 3
        for s1 in range(2):
            for s2 in range(2):
                a = lo[o1] if s1 == 0 else hi[o1]
                b = lo[o2] if s2 == 0 else hi[o2]
                for f in range(nf):
                    nk = normals[f, ax]
                    if abs(nk) < 1e-12:
                        continue
                    x = -(offsets[f] + normals[f, o1] * a + normals[f, o2] * b) / nk
                    if x < lo[ax] - eps or x > hi[ax] + eps:
                        continue
                    p[ax] = x
                    p[o1] = a
                    p[o2] = b
                    if _in_hull(p, normals, offsets, eps):
                        _put(out, k, p)
                        k += 1
    res = np.empty((k, 3))
    for i in range(k):
        _put(res, i, out[i])
    return res


@njit(cache=True, inline="always")
def _put(dest: FloatArray, row: int, src: FloatArray) -> None:  # pragma: no cover - compiled
    # Element-wise: numba compiles a row assignment ``dest[row] = src`` seconds slower.
    # Inlined: called apart, numba compiled it twice, for a literal row 0 and an int.
    for c in range(3):
        dest[row, c] = src[c]


@njit(cache=True)
def _in_box(p: FloatArray, lo: FloatArray, hi: FloatArray, eps: float) -> bool:  # pragma: no cover
    for c in range(3):
        if p[c] < lo[c] - eps or p[c] > hi[c] + eps:
            return False
    return True


@njit(cache=True)
def _in_hull(
    p: FloatArray, normals: FloatArray, offsets: FloatArray, eps: float
) -> bool:  # pragma: no cover - compiled
    for f in range(normals.shape[0]):
        if normals[f, 0] * p[0] + normals[f, 1] * p[1] + normals[f, 2] * p[2] + offsets[f] > eps:
            return False
    return True


@njit(cache=True)
def _enclosing_ball(points: FloatArray, start: FloatArray) -> tuple[FloatArray, float]:
    """A small ball containing ``points``: Badoiu-Clarkson steps from ``start``.

    Each step moves the centre toward the farthest point by ``1/(i+1)`` of the way; the
    best centre seen is kept and its radius is the exact farthest distance, so the ball
    contains every point whatever the convergence.
    """  # pragma: no cover - compiled
    centre = start.copy()
    best_c = centre.copy()
    best_r2 = np.inf
    for i in range(1, 200):
        far = 0
        r2 = -1.0
        for j in range(points.shape[0]):
            d = 0.0
            for c in range(3):
                d += (points[j, c] - centre[c]) ** 2
            if d > r2:
                r2 = d
                far = j
        if r2 < best_r2:
            best_r2 = r2
            for c in range(3):
                best_c[c] = centre[c]
        for c in range(3):
            centre[c] += (points[far, c] - centre[c]) / (i + 1)
    return best_c, math.sqrt(best_r2)


@njit(cache=True)
def _less_protrusion(
    points: FloatArray, normals: FloatArray, offsets: FloatArray, start: FloatArray, limit: float
) -> FloatArray:  # pragma: no cover - compiled
    """A ball centre that sticks out of the hull less, its radius kept within ``limit``.

    The protrusion of the ball enclosing ``points`` from centre ``c`` is at most
    ``max_j |c - p_j| + max_i (n_i . c + b_i)`` (radius minus the depth of ``c`` in the
    hull), a convex function of ``c``: subgradient steps decrease it. The radius is
    convex too, so on the segment from ``start`` (radius <= limit) to the minimiser the
    admissible centres form an interval starting at ``start``, found by bisection. Any
    centre is valid: the caller recomputes the radius from it.
    """
    n = points.shape[0]
    scale = 0.0
    for j in range(n):
        for k in range(3):
            scale = max(scale, abs(points[j, k] - start[k]))
    if scale == 0.0:
        return start.copy()
    c = start.copy()
    best = start.copy()
    best_f = np.inf
    g = np.empty(3)
    for it in range(300):
        far = 0
        r2 = -1.0
        for j in range(n):
            d = (points[j, 0] - c[0]) ** 2 + (points[j, 1] - c[1]) ** 2 + (points[j, 2] - c[2]) ** 2
            if d > r2:
                r2 = d
                far = j
        r = math.sqrt(r2)
        face = 0
        height = -np.inf
        for i in range(normals.shape[0]):
            v = normals[i, 0] * c[0] + normals[i, 1] * c[1] + normals[i, 2] * c[2] + offsets[i]
            if v > height:
                height = v
                face = i
        f = r + height
        if f < best_f:
            best_f = f
            for k in range(3):
                best[k] = c[k]
        for k in range(3):
            g[k] = (c[k] - points[far, k]) / max(r, 1e-300) + normals[face, k]
        gn = math.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2)
        if gn < 1e-12:
            break
        step = 0.3 * scale / math.sqrt(it + 1.0)
        for k in range(3):
            c[k] -= step * g[k] / gn
    if _max_dist2(points, best) <= limit * limit:
        return best
    lo_t = 0.0
    hi_t = 1.0
    trial = np.empty(3)
    for _ in range(40):
        t = 0.5 * (lo_t + hi_t)
        for k in range(3):
            trial[k] = start[k] + t * (best[k] - start[k])
        if _max_dist2(points, trial) <= limit * limit:
            lo_t = t
        else:
            hi_t = t
    for k in range(3):
        trial[k] = start[k] + lo_t * (best[k] - start[k])
    return trial


@njit(cache=True)
def _max_dist2(points: FloatArray, c: FloatArray) -> float:  # pragma: no cover - compiled
    r2 = 0.0
    for j in range(points.shape[0]):
        d = (points[j, 0] - c[0]) ** 2 + (points[j, 1] - c[1]) ** 2 + (points[j, 2] - c[2]) ** 2
        r2 = max(r2, d)
    return r2


# --------------------------------------------------------------------------- pairs


def _pairs(
    model: Any,
    geometry: Any,
    moving: Spheres,
    fixed: Spheres,
    parent: IntArray,
    body_of_link: Mapping[str, int],
    disabled: frozenset[frozenset[str]],
) -> tuple[IntArray, IntArray, IntArray]:
    """Sphere pairs (moving/moving, moving/fixed) and geometry pairs of the self check."""

    def allowed(link_a: str, link_b: str) -> bool:
        if link_a == link_b or frozenset((link_a, link_b)) in disabled:
            return False
        a, b = body_of_link[link_a], body_of_link[link_b]
        if a == b:  # rigidly attached: their distance never changes
            return False
        parent_a = int(parent[a]) if a >= 0 else -2
        parent_b = int(parent[b]) if b >= 0 else -2
        return parent_a != b and parent_b != a

    links = sorted(set(moving.link) | set(fixed.link))
    ok = {(a, b): allowed(a, b) for a in links for b in links}
    m_link = np.array(moving.link, dtype=object)
    f_link = np.array(fixed.link, dtype=object)
    self_pairs = [
        (i, j)
        for i in range(len(m_link))
        for j in range(i + 1, len(m_link))
        if ok[(m_link[i], m_link[j])]
    ]
    fixed_pairs = [
        (i, j) for i in range(len(m_link)) for j in range(len(f_link)) if ok[(m_link[i], f_link[j])]
    ]
    objects = list(geometry.geometryObjects)
    obj_link = [str(model.frames[o.parentFrame].name) for o in objects]
    geometry_pairs = [
        (i, j)
        for i in range(len(objects))
        for j in range(i + 1, len(objects))
        if (objects[i].parentJoint > 0 or objects[j].parentJoint > 0)
        and ok.get((obj_link[i], obj_link[j]), False)
    ]
    return (
        np.array(self_pairs, dtype=np.int64).reshape(-1, 2),
        np.array(fixed_pairs, dtype=np.int64).reshape(-1, 2),
        np.array(geometry_pairs, dtype=np.int64).reshape(-1, 2),
    )


# --------------------------------------------------------------------------- kernels


@njit(cache=True)
def _fk_into(
    q: FloatArray,
    parent: IntArray,
    placement: FloatArray,
    kind: IntArray,
    axis: FloatArray,
    column: IntArray,
    base: FloatArray,
    out: FloatArray,
) -> None:  # pragma: no cover - compiled
    """Poses ``(F, 3, 4)`` (rotation | translation) of the moving frames for one ``q``.

    ``T_i = T_parent(i) @ jointPlacement_i @ M_joint(q_i)`` (Pinocchio's forward pass),
    with ``T_-1 = base``; parents precede children in Pinocchio's joint order.
    """
    a = np.empty((3, 4))
    for i in range(parent.shape[0]):
        p = parent[i]
        m = placement[i]
        # a = T_parent @ M (3x4 affine product)
        for r in range(3):
            for c in range(4):
                if p < 0:
                    s = base[r, 0] * m[0, c] + base[r, 1] * m[1, c] + base[r, 2] * m[2, c]
                    if c == 3:
                        s += base[r, 3]
                else:
                    t = out[p]
                    s = t[r, 0] * m[0, c] + t[r, 1] * m[1, c] + t[r, 2] * m[2, c]
                    if c == 3:
                        s += t[r, 3]
                a[r, c] = s
        x = axis[i, 0]
        y = axis[i, 1]
        z = axis[i, 2]
        qi = q[column[i]]
        o = out[i]
        if kind[i] == 0:
            # Rodrigues: R = cI + s[a]x + (1-c) a a^T
            cq = math.cos(qi)
            sq = math.sin(qi)
            v = 1.0 - cq
            r00 = cq + v * x * x
            r01 = v * x * y - sq * z
            r02 = v * x * z + sq * y
            r10 = v * x * y + sq * z
            r11 = cq + v * y * y
            r12 = v * y * z - sq * x
            r20 = v * x * z - sq * y
            r21 = v * y * z + sq * x
            r22 = cq + v * z * z
            for r in range(3):
                a0 = a[r, 0]
                a1 = a[r, 1]
                a2 = a[r, 2]
                o[r, 0] = a0 * r00 + a1 * r10 + a2 * r20
                o[r, 1] = a0 * r01 + a1 * r11 + a2 * r21
                o[r, 2] = a0 * r02 + a1 * r12 + a2 * r22
                o[r, 3] = a[r, 3]
        else:
            for r in range(3):
                o[r, 0] = a[r, 0]
                o[r, 1] = a[r, 1]
                o[r, 2] = a[r, 2]
                o[r, 3] = a[r, 3] + qi * (a[r, 0] * x + a[r, 1] * y + a[r, 2] * z)


@njit(cache=True)
def _forward_kernel(
    qs: FloatArray,
    parent: IntArray,
    placement: FloatArray,
    kind: IntArray,
    axis: FloatArray,
    column: IntArray,
    base: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled
    n = qs.shape[0]
    f = parent.shape[0]
    out = np.zeros((n, f, 4, 4))
    buf = np.empty((f, 3, 4))
    for k in range(n):
        _fk_into(qs[k], parent, placement, kind, axis, column, base, buf)
        for i in range(f):
            for r in range(3):
                for c in range(4):
                    out[k, i, r, c] = buf[i, r, c]
            out[k, i, 3, 3] = 1.0
    return out


@njit(cache=True)
def _centres_into(
    poses: FloatArray, base: FloatArray, frame: IntArray, local: FloatArray, out: FloatArray
) -> None:  # pragma: no cover - compiled
    """World centres of spheres given in their frame (frame -1: the base)."""
    for s in range(frame.shape[0]):
        f = frame[s]
        t = base if f < 0 else poses[f]
        x = local[s, 0]
        y = local[s, 1]
        z = local[s, 2]
        for r in range(3):
            out[s, r] = t[r, 0] * x + t[r, 1] * y + t[r, 2] * z + t[r, 3]


@njit(cache=True)
def _sphere_kernel(
    qs: FloatArray,
    parent: IntArray,
    placement: FloatArray,
    kind: IntArray,
    axis: FloatArray,
    column: IntArray,
    base: FloatArray,
    frame: IntArray,
    local: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled
    n = qs.shape[0]
    out = np.empty((n, frame.shape[0], 3))
    buf = np.empty((parent.shape[0], 3, 4))
    for k in range(n):
        _fk_into(qs[k], parent, placement, kind, axis, column, base, buf)
        _centres_into(buf, base, frame, local, out[k])
    return out


@njit(cache=True)
def _collide_kernel(
    qs: FloatArray,
    parent: IntArray,
    placement: FloatArray,
    kind: IntArray,
    axis: FloatArray,
    column: IntArray,
    base: FloatArray,
    frame: IntArray,
    local: FloatArray,
    radii: FloatArray,
    pairs: IntArray,
) -> BoolArray:  # pragma: no cover - compiled
    """Whether any pair of spheres overlaps (centre distance <= sum of radii)."""
    n = qs.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    buf = np.empty((parent.shape[0], 3, 4))
    centres = np.empty((frame.shape[0], 3))
    for k in range(n):
        _fk_into(qs[k], parent, placement, kind, axis, column, base, buf)
        _centres_into(buf, base, frame, local, centres)
        for p in range(pairs.shape[0]):
            i = pairs[p, 0]
            j = pairs[p, 1]
            dx = centres[i, 0] - centres[j, 0]
            dy = centres[i, 1] - centres[j, 1]
            dz = centres[i, 2] - centres[j, 2]
            rr = radii[i] + radii[j]
            if dx * dx + dy * dy + dz * dz <= rr * rr:
                out[k] = True
                break
    return out


# --------------------------------------------------------------------------- public kernels


def _configs(arm: Arm, q: ArrayLike, name: str = "q") -> FloatArray:
    """``q`` as a C-contiguous ``(N, dim)`` float array, or an ArgumentError.

    Angles beyond two turns are refused as the likely sign of degrees; prismatic
    coordinates beyond the workcell limit likewise.
    """
    arr = real_array(q, name)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != arm.dim:
        raise ArgumentError(
            [Problem(name, f"expected shape (N, {arm.dim}) or ({arm.dim},), got {np.shape(q)}")]
        )
    if not np.all(np.isfinite(arr)):
        raise ArgumentError([Problem(name, "contains NaN or infinite values")])
    if arr.size:
        prismatic = np.zeros(arm.dim, dtype=bool)
        prismatic[arm.chain_column[arm.chain_kind == _PRISMATIC]] = True
        limit = np.where(prismatic, COORD_LIMIT, ANGLE_LIMIT + 1e-9)
        bad = np.abs(arr) > limit
        if bad.any():
            row, col = np.argwhere(bad)[0]
            joint = arm.joint_names[col]
            hint = (
                " (beyond any workcell)"
                if prismatic[col]
                else "; angles are radians here (use cellplan.units.radians)"
            )
            raise ArgumentError(
                [
                    Problem(
                        name,
                        f"{joint}={arr[row, col]:g} is outside [-{limit[col]:g}, "
                        f"{limit[col]:g}]{hint}",
                    )
                ]
            )
    return np.ascontiguousarray(arr)


def forward(arm: Arm, Q: ArrayLike) -> FloatArray:
    """World poses of the arm's moving frames.

    Parameters
    ----------
    arm
        The arm.
    Q
        ``(N, dim)`` or ``(dim,)`` configurations (radians/metres).

    Returns
    -------
    FloatArray
        ``(N, F, 4, 4)``: frame ``f`` is Pinocchio joint ``f + 1`` of the reduced model,
        ``arm.base @ data.oMi[f + 1]``.
    """
    qs = _configs(arm, Q)
    out: FloatArray = _forward_kernel(
        qs,
        arm.chain_parent,
        arm.chain_placement,
        arm.chain_kind,
        arm.chain_axis,
        arm.chain_column,
        arm.base,
    )
    return out


def sphere_centers(arm: Arm, Q: ArrayLike) -> FloatArray:
    """World centres ``(N, S, 3)`` of ``arm.spheres`` (FK fused in; nothing else stored)."""
    qs = _configs(arm, Q)
    out: FloatArray = _sphere_kernel(
        qs,
        arm.chain_parent,
        arm.chain_placement,
        arm.chain_kind,
        arm.chain_axis,
        arm.chain_column,
        arm.base,
        arm.spheres.frame,
        arm.spheres.centers,
    )
    return out


def tool_pose(arm: Arm, Q: ArrayLike) -> FloatArray:
    """World pose ``(N, 4, 4)`` of the tool frame ``arm.tool_frame``."""
    poses = forward(arm, Q)[:, arm.tool_joint]
    out: FloatArray = poses @ arm.tool_placement
    return out


def self_collides(
    arm: Arm, Q: ArrayLike, margin: float | ArrayLike = 0.0, extra: Spheres | None = None
) -> BoolArray:
    """Whether the sphere cover self-collides, per configuration.

    Tested: ``arm.self_pairs`` (moving/moving), ``arm.fixed_pairs`` (moving/fixed) and,
    with ``extra`` (e.g. a held part, on the arm's moving frames), every extra sphere
    against the arm's spheres on frames other than its own and its parent's and
    children's (the part touches what holds it), and against the fixed spheres unless
    its frame is the first one.

    Parameters
    ----------
    arm
        The arm.
    Q
        ``(N, dim)`` or ``(dim,)`` configurations.
    margin
        Extra clearance each sphere must keep (metres, >= 0): one for all, or one per
        sphere of ``arm.spheres`` (the fixed spheres do not move and keep none). A pair
        collides when its centres are within ``r1 + r2 + m1 + m2``. A motion check whose
        samples let each sphere move its margin either way certifies the pairs between
        samples this way.
    extra
        Spheres attached to the arm's moving frames.

    Returns
    -------
    BoolArray
        ``(N,)``: True where some pair overlaps (centre distance <= r1 + r2 + 2 margin).
    """
    qs = _configs(arm, Q)
    m = real_array(margin, "margin")
    moving = len(arm.spheres)
    if m.shape not in ((), (moving,)) or not np.all(np.isfinite(m)) or np.any(m < 0):
        raise ArgumentError(
            [Problem("margin", f"expected one finite number >= 0 or {moving} of them")]
        )
    frame, local, radii, pairs = _collision_set(arm, extra)
    radii = radii.copy()
    radii[:moving] += m
    if extra is not None:
        radii[len(radii) - len(extra) :] += m.max() if m.size else 0.0
    out: BoolArray = _collide_kernel(
        qs,
        arm.chain_parent,
        arm.chain_placement,
        arm.chain_kind,
        arm.chain_axis,
        arm.chain_column,
        arm.base,
        frame,
        local,
        radii,
        pairs,
    )
    return out


def _collision_set(
    arm: Arm, extra: Spheres | None
) -> tuple[IntArray, FloatArray, FloatArray, IntArray]:
    """One sphere set (moving, fixed, extra) and its tested index pairs."""
    m, f = arm.spheres, arm.fixed_spheres
    nm, nf = len(m), len(f)
    pairs = [arm.self_pairs, arm.fixed_pairs + np.array([0, nm])]
    frames = [m.frame, f.frame]
    centres = [m.centers, f.centers]
    radii = [m.radii, f.radii]
    if extra is not None:
        _check_spheres(arm, extra)
        offset = nm + nf
        for e in range(len(extra)):
            fe = int(extra.frame[e])
            near = {fe, int(arm.chain_parent[fe])}
            near.update(int(c) for c in np.flatnonzero(arm.chain_parent == fe))
            idx = np.flatnonzero(~np.isin(m.frame, list(near)))
            pairs.append(np.column_stack([idx, np.full(len(idx), offset + e)]))
            if arm.chain_parent[fe] >= 0 and nf:
                fi = np.arange(nf) + nm
                pairs.append(np.column_stack([fi, np.full(nf, offset + e)]))
        frames.append(extra.frame)
        centres.append(extra.centers)
        radii.append(extra.radii)
    return (
        np.ascontiguousarray(np.concatenate(frames).astype(np.int64)),
        np.ascontiguousarray(np.vstack(centres).astype(float)),
        np.ascontiguousarray(np.concatenate(radii).astype(float)),
        np.ascontiguousarray(np.vstack([p.reshape(-1, 2) for p in pairs]).astype(np.int64)),
    )


def _check_spheres(arm: Arm, s: Spheres) -> None:
    n = len(s.radii)
    frames = np.asarray(s.frame)
    centres = np.asarray(s.centers, dtype=float)
    radii = np.asarray(s.radii, dtype=float)
    if frames.shape != (n,) or centres.shape != (n, 3) or len(s.link) != n:
        raise ArgumentError([Problem("extra", "frame, centers, radii, link lengths differ")])
    if n and (frames.min() < 0 or frames.max() >= len(arm.chain_parent)):
        raise ArgumentError(
            [Problem("extra", f"frame indices must be in [0, {len(arm.chain_parent)})")]
        )
    if not (np.all(np.isfinite(centres)) and np.all(np.isfinite(radii)) and np.all(radii >= 0)):
        raise ArgumentError([Problem("extra", "centres and radii must be finite, radii >= 0")])


# --------------------------------------------------------------------------- lever arms


def lever_arms(arm: Arm, points_in_tool: ArrayLike | None = None) -> FloatArray:
    """Per-joint bound on how far any point of the robot moves per unit of joint motion.

    Guarantee: along the straight joint-space segment ``q(t) = q + t dq``, ``t in [0,1]``,
    no point of any sphere of ``arm.spheres`` (the whole ball, not only its centre) nor
    any of ``points_in_tool`` (rigidly attached to the tool frame) moves farther from its
    starting position than ``sum_j lever[j] * |dq_j|``.

    Derivation. A point ``x`` rigidly attached to moving frame ``f`` has velocity
    ``dx/dt = sum_j v_j(x) dq_j`` over the joints ``j`` on the path from the root to
    ``f``, with ``v_j = a_j x (x - o_j)`` for a revolute joint (unit axis ``a_j``
    through the joint origin ``o_j``) and ``v_j = a_j`` for a prismatic one. So
    ``|dx/dt| <= sum_j L_j |dq_j|`` where ``L_j`` bounds, over every configuration,
    the distance from axis ``j`` to any point it carries (1 for a prismatic joint);
    integrating over ``t`` bounds the path length, hence the displacement. For a
    point on sphere ``(c, r)`` of frame ``f`` and the path ``j = k0, k1, ..., km = f``:
    ``dist(x, axis_j) <= dist(o_k1, axis_j) + sum_{i>=2} |o_ki - o_k(i-1)| + |c| + r``
    (triangle inequality). In joint ``j``'s frame the axis is fixed and
    ``o_k1 - o_j = t_k1 + R_k1 a_k1 q_k1`` (``t``, ``R``: the joint placement; the last
    term only for a prismatic ``k1``), so ``dist(o_k1, axis_j) <= |perp_j(t_k1)| +
    |q_k1|max``; likewise ``|o_ki - o_k(i-1)| <= |t_ki| + |q_ki|max``. For a sphere on
    ``j``'s own frame the bound is ``|perp_j(c)| + r``. None of these terms depends on
    the configuration.

    Parameters
    ----------
    arm
        The arm.
    points_in_tool
        ``(P, 3)`` points in the tool frame's coordinates (e.g. a held part's corners).

    Returns
    -------
    FloatArray
        ``(dim,)`` per configuration column: metres per radian (revolute) or 1
        (prismatic).
    """
    pts = None
    if points_in_tool is not None:
        pts = real_array(points_in_tool, "points_in_tool")
        if pts.ndim == 1:
            pts = pts[None, :]
        if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
            raise ArgumentError([Problem("points_in_tool", "expected a finite (P, 3) array")])
    rows = sphere_levers(arm, pts, None if pts is None else np.zeros(len(pts)))
    out: FloatArray = rows.max(axis=0) if len(rows) else np.zeros(arm.dim)
    return out


def sphere_levers(
    arm: Arm, centres_in_tool: ArrayLike | None = None, radii: ArrayLike | None = None
) -> FloatArray:
    """:func:`lever_arms` sphere by sphere: ``(S + P, dim)``, one row per sphere of
    ``arm.spheres`` and then per extra sphere given in the tool frame (a held part's).

    Row ``k`` bounds how far any point of sphere ``k`` moves along the segment
    ``q + t dq``: at most ``row_k . |dq|``. A sphere near the base moves far less than
    the tool when the first joint turns, so a check that gives each sphere its own
    margin (certified motions, conservative bitmaps) is much less conservative than one
    that gives every sphere the largest.
    """
    frames = list(arm.spheres.frame)
    centres = list(arm.spheres.centers)
    radius_list = list(arm.spheres.radii)
    if centres_in_tool is not None:
        pts = np.atleast_2d(real_array(centres_in_tool, "centres_in_tool"))
        rad = np.zeros(len(pts)) if radii is None else real_array(radii, "radii")
        if pts.shape[1] != 3 or rad.shape != (len(pts),):
            raise ArgumentError([Problem("centres_in_tool", "expected (P, 3) and P radii")])
        m = arm.tool_placement
        for p, r in zip(pts @ m[:3, :3].T + m[:3, 3], rad, strict=True):
            frames.append(arm.tool_joint)
            centres.append(p)
            radius_list.append(float(r))
    parent = arm.chain_parent
    nf = len(parent)
    extent = np.zeros(nf)
    for f in range(nf):
        if arm.chain_kind[f] == _PRISMATIC:
            c = arm.chain_column[f]
            extent[f] = max(abs(arm.lower[c]), abs(arm.upper[c]))
    offset = np.linalg.norm(arm.chain_placement[:, :3, 3], axis=1) + extent
    lever = np.zeros((len(frames), nf))
    for j in range(nf):
        a = arm.chain_axis[j]
        for i, (f, c, r) in enumerate(zip(frames, centres, radius_list, strict=True)):
            path = []
            k = int(f)
            while k >= 0 and k != j:
                path.append(k)
                k = int(parent[k])
            if k != j:
                continue  # joint j does not carry this sphere
            if arm.chain_kind[j] == _PRISMATIC:
                lever[i, j] = 1.0
            elif not path:
                lever[i, j] = _perp(c, a) + r
            else:
                k1 = path[-1]
                first = _perp(arm.chain_placement[k1, :3, 3], a) + extent[k1]
                lever[i, j] = first + float(offset[path[:-1]].sum()) + float(np.linalg.norm(c)) + r
    out = np.empty((len(frames), arm.dim))
    out[:, arm.chain_column] = lever
    return out


def _perp(v: FloatArray, a: FloatArray) -> float:
    """Distance from ``v`` to the line through the origin along unit ``a``."""
    return float(np.linalg.norm(v - np.dot(v, a) * a))


# --------------------------------------------------------------------------- exact checks


def _pin_q(arm: Arm, q: FloatArray) -> FloatArray:
    """A configuration (angles) as Pinocchio's ``q`` (cos/sin for continuous joints)."""
    out = np.empty(arm.model.nq)
    for c in range(arm.dim):
        i = arm.pin_q_index[c]
        if arm.periodic[c]:
            out[i] = math.cos(q[c])
            out[i + 1] = math.sin(q[c])
        else:
            out[i] = q[c]
    return out


def _obstacle_model(
    arm: Arm, obstacles: Sequence[tuple[Any, ArrayLike]], self_pairs: bool
) -> tuple[Any, int]:
    """The arm's geometry plus the obstacles (on the universe) and the pairs to test."""
    geom = arm.geometry.copy()
    geom.removeAllCollisionPairs()
    inv_base = np.linalg.inv(arm.base)
    first = int(geom.ngeoms)
    for k, item in enumerate(obstacles):
        where = f"obstacles[{k}]"
        if not isinstance(item, tuple | list) or len(item) != 2:
            raise ArgumentError([Problem(where, "expected (coal geometry, 4x4 pose)")])
        shape, pose = item
        if not isinstance(shape, coal.CollisionGeometry):
            raise ArgumentError([Problem(where, "expected a coal.CollisionGeometry")])
        m = _check_pose(pose, where, ArgumentError)
        # Pinocchio works in the URDF root's frame: world poses are moved into it.
        local = inv_base @ m
        placement = pin.SE3(local[:3, :3], local[:3, 3])
        geom.addGeometryObject(pin.GeometryObject(f"obstacle_{k}", 0, 0, placement, shape))
    for i in arm.moving_geometry:
        for k in range(first, int(geom.ngeoms)):
            geom.addCollisionPair(pin.CollisionPair(int(i), k))
    if self_pairs:
        for i, j in arm.geometry_pairs:
            geom.addCollisionPair(pin.CollisionPair(int(i), int(j)))
    return geom, first


def fixed_collides(arm: Arm, obstacles: Sequence[tuple[Any, ArrayLike]]) -> bool:
    """Whether a link fixed to the base (its own collision mesh) touches an obstacle.

    These links never move, so a workcell checks them once, exactly, when it is built
    (a base standing on a table must not count as a collision through the slack of
    its sphere cover).
    """
    geom, first = _obstacle_model(arm, obstacles, self_pairs=False)
    geom.removeAllCollisionPairs()
    fixed = [i for i in range(first) if geom.geometryObjects[i].parentJoint == 0]
    for i in fixed:
        for k in range(first, int(geom.ngeoms)):
            geom.addCollisionPair(pin.CollisionPair(i, k))
    data = arm.model.createData()
    gdata = pin.GeometryData(geom)
    q = _pin_q(arm, np.zeros(arm.dim))
    return bool(pin.computeCollisions(arm.model, data, geom, gdata, q, True))


def exact_collides(
    arm: Arm,
    Q: ArrayLike,
    obstacles: Sequence[tuple[Any, ArrayLike]] = (),
) -> BoolArray:
    """Reference check on the URDF's own collision geometry (Pinocchio + coal).

    Pairs: every geometry on a moving link against every obstacle, and the self pairs
    of ``arm.geometry_pairs`` (the link pairs of ``self_pairs``/``fixed_pairs``). A
    Python loop over configurations: the oracle and speed baseline of the sphere check.

    Parameters
    ----------
    arm
        The arm.
    Q
        ``(N, dim)`` or ``(dim,)`` configurations.
    obstacles
        ``(coal geometry, (4, 4) world pose)`` pairs.

    Returns
    -------
    BoolArray
        ``(N,)``.
    """
    qs = _configs(arm, Q)
    geom, _ = _obstacle_model(arm, obstacles, self_pairs=True)
    data = arm.model.createData()
    gdata = pin.GeometryData(geom)
    out = np.zeros(len(qs), dtype=bool)
    for k, q in enumerate(qs):
        out[k] = pin.computeCollisions(arm.model, data, geom, gdata, _pin_q(arm, q), True)
    return out


def exact_min_distance(
    arm: Arm,
    Q: ArrayLike,
    obstacles: Sequence[tuple[Any, ArrayLike]],
) -> FloatArray:
    """Smallest distance (metres) between the arm's moving links and the obstacles.

    Negative values are penetration depths as coal reports them; ``inf`` without
    obstacles. Self-distances are not included.
    """
    qs = _configs(arm, Q)
    geom, _ = _obstacle_model(arm, obstacles, self_pairs=False)
    out = np.full(len(qs), np.inf)
    if not len(geom.collisionPairs):
        return out
    data = arm.model.createData()
    gdata = pin.GeometryData(geom)
    for k, q in enumerate(qs):
        pin.computeDistances(arm.model, data, geom, gdata, _pin_q(arm, q))
        out[k] = min(r.min_distance for r in gdata.distanceResults)
    return out


# --------------------------------------------------------------------------- IK


def _jacobian(model: Any, data: Any, fid: int, frame: Any) -> FloatArray:
    """A frame Jacobian as ``(6, nv)``: eigenpy returns a one-column matrix as a vector."""
    return np.reshape(pin.getFrameJacobian(model, data, fid, frame), (6, model.nv))


def _nearest_turn(arm: Arm, q: FloatArray, ref: FloatArray) -> FloatArray:
    """``q`` with each revolute joint whose limits span more than a turn moved by whole
    turns as close to ``ref`` as its limits allow (the same pose, the shortest motion)."""
    out = q.copy()
    angular = np.array(arm.angular) & ~np.asarray(arm.periodic)
    span = arm.upper - arm.lower
    for c in np.flatnonzero(angular & (span >= 2.0 * np.pi)):
        turns = np.round((ref[c] - q[c]) / (2.0 * np.pi))
        for k in (turns, turns - 1, turns + 1, 0.0):
            v = q[c] + k * 2.0 * np.pi
            if arm.lower[c] <= v <= arm.upper[c]:
                out[c] = v
                break
    return out


def _wrap(q: FloatArray, periodic: BoolArray) -> FloatArray:
    """Periodic coordinates into (-pi, pi]."""
    out = q.copy()
    out[periodic] = math.pi - np.mod(math.pi - q[periodic], 2.0 * math.pi)
    return out


def ik(
    arm: Arm,
    target: ArrayLike,
    *,
    q0: ArrayLike | None = None,
    restarts: int = 8,
    seed: int = 0,
    position_only: bool = False,
    tol_pos: float = 1e-4,
    tol_rot: float = 1e-3,
    max_iter: int = 200,
    valid: Callable[[FloatArray], bool] | None = None,
) -> IkResult:
    """Inverse kinematics of the tool frame by damped least squares.

    Each iteration solves ``J dq = -e`` in the damped sense,
    ``dq = -J^T (J J^T + lambda^2 I)^-1 e``, with Pinocchio's frame Jacobian: for a full
    pose ``e = log6(oMf^-1 oMd)`` and ``J = -Jlog6(iMd^-1) J_local`` (Pinocchio's IK
    example); for ``position_only`` ``e`` is the position error and ``J`` the
    translational rows in ``LOCAL_WORLD_ALIGNED``. Steps are capped, clipped into the
    limits, periodic joints wrapped into (-pi, pi]; a joint whose limits span more than a
    turn is moved by whole turns as near ``q0`` as they allow (the same tool pose, the
    shortest motion from ``q0``). The first attempt starts at ``q0``
    (else the middle of the limits, 0 for a periodic joint), then ``restarts`` attempts
    from uniform random configurations (``numpy.random.default_rng(seed)``).

    Parameters
    ----------
    arm
        The arm.
    target
        ``(4, 4)`` world pose of the tool frame.
    q0
        First starting configuration.
    restarts
        Random restarts after the first attempt.
    seed
        Seed of the restarts.
    position_only
        Reach the target's position only.
    tol_pos, tol_rot
        Success tolerances: metres, radians.
    max_iter
        Iterations per attempt.
    valid
        Optional acceptance test (e.g. collision-free); a converged configuration it
        refuses does not count and the restarts go on.

    Returns
    -------
    IkResult
        The first accepted solution, or the best configuration found with
        ``success=False``.
    """
    goal = _check_pose(target, "target", ArgumentError)
    if restarts < 0 or max_iter < 1:
        raise ArgumentError([Problem("restarts", "restarts must be >= 0 and max_iter >= 1")])
    if not (tol_pos > 0 and tol_rot > 0):
        raise ArgumentError([Problem("tol_pos", "tolerances must be positive")])
    local_goal = np.linalg.inv(arm.base) @ goal
    o_m_d = pin.SE3(local_goal[:3, :3], local_goal[:3, 3])
    lo, hi = arm.lower, arm.upper
    if q0 is None:
        start = np.where(arm.periodic, 0.0, 0.5 * (lo + hi))
    else:
        start = _configs(arm, q0, "q0")[0]
        start = _wrap(np.clip(start, lo, hi), arm.periodic)
    rng = np.random.default_rng(seed)
    model = arm.model
    data = model.createData()
    fid = arm.tool_frame_id
    damping2 = 1e-6
    max_step = 0.5
    total = 0
    best: tuple[float, FloatArray, float, float] | None = None
    rejected = 0
    for attempt in range(restarts + 1):
        q = start.copy() if attempt == 0 else _wrap(rng.uniform(lo, hi), arm.periodic)
        for _ in range(max_iter):
            total += 1
            qp = _pin_q(arm, q)
            pin.computeJointJacobians(model, data, qp)
            pin.updateFramePlacement(model, data, fid)
            o_m_f = data.oMf[fid]
            pos_err = float(np.linalg.norm(o_m_f.translation - o_m_d.translation))
            rot_err = float(np.linalg.norm(pin.log3(o_m_f.rotation.T @ o_m_d.rotation)))
            converged = pos_err <= tol_pos and (position_only or rot_err <= tol_rot)
            score = (
                pos_err / tol_pos if position_only else max(pos_err / tol_pos, rot_err / tol_rot)
            )
            if converged:
                q = _nearest_turn(arm, q, start)
                if valid is None or valid(q.copy()):
                    return IkResult(q.copy(), True, pos_err, rot_err, total, "converged")
                rejected += 1
            if best is None or score < best[0]:
                best = (score, q.copy(), pos_err, rot_err)
            if converged:
                break
            if position_only:
                jac = _jacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
                err = o_m_f.translation - o_m_d.translation
            else:
                i_m_d = o_m_f.actInv(o_m_d)
                err = pin.log6(i_m_d).vector
                jac = -pin.Jlog6(i_m_d.inverse()) @ _jacobian(model, data, fid, pin.LOCAL)
            jac = jac[:, arm.pin_v_index]
            dq = -jac.T @ np.linalg.solve(jac @ jac.T + damping2 * np.eye(len(err)), err)
            norm = float(np.linalg.norm(dq))
            if norm > max_step:
                dq *= max_step / norm
            q_new = _wrap(np.clip(q + dq, lo, hi), arm.periodic)
            if float(np.abs(q_new - q).max()) < 1e-12:
                break  # stuck against the limits or at a singular point
            q = q_new
    assert best is not None
    _, q_best, pos_best, rot_best = best
    message = f"no solution within tolerance after {restarts + 1} attempts"
    if rejected:
        message += f" ({rejected} converged configuration(s) refused by valid)"
    return IkResult(q_best, False, pos_best, rot_best, total, message)

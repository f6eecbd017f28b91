"""3-D solids with poses: exact batched distances, triangle meshes, and region tests.

A :class:`Solid` is a box, cylinder, sphere, capsule or triangle mesh placed by a rigid
pose (a ``(4, 4)`` world-from-local transform; lengths in metres, angles in radians).
Sizes follow URDF: a box's ``size`` is its full edge lengths, a cylinder's or capsule's
axis is the local ``z`` axis and ``length`` is the full length of the axis segment (a
capsule's total extent along ``z`` is ``length + 2 radius``), all centred at the local
origin.

Signed distance
    :func:`distances` gives the signed distance from points to each solid: the Euclidean
    distance to the surface, negated inside. For the primitives it is analytic and exact.
    For a mesh the magnitude is the exact distance to its triangles and the sign follows
    the *winding-number rule*: a point is inside when its generalised winding number
    ``w`` (the signed solid angle the triangles subtend, over ``4 pi``) has ``|w| > 1/2``.
    For a closed mesh (every edge used as often in one direction as in the other, after
    welding equal vertices) ``w`` is an integer off the surface, so this is the exact
    inside test, whichever way the faces are oriented. A mesh with small holes is still
    classified sensibly (the inside of a box missing one face has ``w = 5/6``), but its
    "inside" ends at the holes in a way no distance to the triangles can see: keep
    collision meshes closed. ``w`` is evaluated with a bounding-volume hierarchy whose
    far clusters are summed as dipoles (Barill et al., *Fast winding numbers*, 2018);
    the approximation error is far below the ``1/2`` margin of a closed mesh.

Sphere clearance
    :func:`sphere_gaps` bounds the clearance between a union of spheres (a robot's
    collision spheres, ``N`` configurations at once) and the solids from below, in
    compiled code with no Python loop over configurations: exact for the primitives,
    conservative for meshes. A :class:`SolidSet` prepares the solids once: flat arrays
    of kinds, inverse poses and sizes, and for each mesh a distance grid over its padded
    local bounding box holding the exact signed distance at every node. Signed distance
    is 1-Lipschitz, so for a point ``p`` and any node ``c``, ``g(c) - |p - c|`` is a
    lower bound and ``g(c) + |p - c|`` an upper bound; a lookup takes the best over the
    8 corners of the cell holding ``p`` (never worse than the nearest node minus half
    the cell diagonal), and outside the grid also the distance to the grid's box (the
    mesh lies inside it). For open meshes the winding-number sign can switch in free
    space near a hole, where the Lipschitz argument, and so the bound, does not hold.

Mesh grids
    Node spacing ``mesh_spacing`` (5 mm by default), padded two and a fraction cells
    beyond the mesh's box; a grid over :data:`MAX_GRID_NODES` (4M nodes, 32 MB) is
    coarsened until it fits, and the memory is checked (:func:`cellplan.budget.require`)
    before anything is allocated. Each node's distance is an exact nearest-triangle
    query; a closed mesh's sign is carried up each column of nodes by counting signed
    crossings of the surface, and evaluated afresh only where a crossing is unsure;
    an open mesh's sign is evaluated at every node. A build costs about 0.5 to 6 us a
    node on one core (more for round meshes, whose inner points are nearly equidistant
    from many triangles): seconds to half a minute for a 4M-node grid.

Regions
    :func:`inside_gaps` says how deep spheres lie inside a container solid (an
    enclosure test for a carried part), :func:`bounds_gaps` how deep they lie inside an
    axis-aligned box.

Meshes are read by :func:`load_mesh` through coal's assimp loader (STL, OBJ, DAE), the
same loader Pinocchio uses for collision models, after checks that refuse in one line
what cannot be loaded. Like Pinocchio's, the loader ignores a DAE's ``<unit>`` and
``<up_axis>``: give the scale (URDF ``<mesh scale>``) explicitly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, TypeVar

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellplan import budget
from cellplan.errors import ArgumentError, Problem, ScenarioError, printable

if TYPE_CHECKING:
    import coal

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
_A = TypeVar("_A", bound=NDArray[Any])

__all__ = [
    "MAX_GRID_NODES",
    "MAX_MESH_BYTES",
    "SOLID_KINDS",
    "Solid",
    "SolidSet",
    "bounds_gaps",
    "box",
    "capsule",
    "cylinder",
    "distances",
    "inside_gaps",
    "load_mesh",
    "mesh",
    "pose_matrix",
    "sphere",
    "sphere_gaps",
    "sphere_gaps_each",
]

SOLID_KINDS = ("box", "cylinder", "sphere", "capsule", "mesh")
_BOX, _CYLINDER, _SPHERE, _CAPSULE, _MESH = range(5)
_SIZE_LENGTHS = MappingProxyType({"box": 3, "cylinder": 2, "sphere": 1, "capsule": 2, "mesh": 3})

#: Mesh files larger than this (bytes) are refused before loading.
MAX_MESH_BYTES = 200 * 10**6

#: Memory one loaded triangle costs (bytes): assimp's scene, coal's BVH (two OBBRSS
#: nodes a triangle) and the numpy copies, rounded up.
MESH_BYTES_PER_TRIANGLE = 1000

#: File bytes per triangle assumed for text formats (OBJ, DAE, ASCII STL), on the small
#: side of real exports so the memory estimate errs high.
TEXT_BYTES_PER_TRIANGLE = 20

#: A mesh's distance grid has at most this many nodes (32 MB of float64); a finer
#: requested spacing is coarsened until the grid fits.
MAX_GRID_NODES = 4 * 1024 * 1024

#: Bytes a grid node costs while the grid is built and kept.
_GRID_BYTES_PER_NODE = 8

#: Bytes a triangle costs in the distance hierarchy (sorted triangles and two nodes).
_BVH_BYTES_PER_TRIANGLE = 400

#: How far a pose's rotation may be from orthonormal: distances are computed through
#: the transposed rotation, which is only the inverse of a rigid rotation.
RIGID_TOLERANCE = 1e-9

#: Grid padding around a mesh's bounding box, in cells: boundary nodes are then outside
#: the mesh for sure, which is where each column's sign starts.
_GRID_PAD_CELLS = 2

#: Extra fraction of a cell before the first node, so that nodes miss the planes of the
#: faces at a mesh's extremes and at round distances from them (a node on a face makes
#: the crossings of its column unsure, and its sign is then evaluated afresh).
_GRID_SHIFT = 0.3819660112501051  # 2 minus the golden ratio: far from simple fractions

#: A BVH cluster farther than this many of its radii from the query point is summed as
#: a dipole in the winding number (Barill et al. use 2).
_WINDING_BETA = 2.0

_LEAF_SIZE = 4
_STACK_SIZE = 256  # the hierarchy is balanced: its depth is log2(triangles / leaf size)

_MESH_SUFFIXES = (".stl", ".obj", ".dae")


# --- poses -----------------------------------------------------------------------------------


def pose_matrix(xyz: ArrayLike, rpy_radians: ArrayLike) -> FloatArray:
    """World-from-local transform ``(4, 4)`` of a URDF ``<origin xyz rpy>``.

    Parameters
    ----------
    xyz
        Translation (metres).
    rpy_radians
        Roll, pitch, yaw (radians), URDF's fixed-axis convention:
        ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Returns
    -------
    FloatArray
        The homogeneous transform.
    """
    t = _finite_vector(xyz, 3, "xyz")
    roll, pitch, yaw = _finite_vector(rpy_radians, 3, "rpy")
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    pose = np.eye(4)
    pose[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    pose[:3, 3] = t
    return pose


def _finite_vector(value: ArrayLike, length: int, field: str) -> FloatArray:
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError(f"expected {length} numbers", field) from None
    if array.shape != (length,) or not np.all(np.isfinite(array)):
        raise ArgumentError(f"expected {length} finite numbers, got {array.tolist()}", field)
    return array


def _rigid(value: ArrayLike, field: str) -> FloatArray:
    """``value`` as a rigid transform ``(4, 4)`` (ArgumentError naming ``field`` if not)."""
    try:
        pose = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError("expected a 4x4 transform", field) from None
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ArgumentError("expected a 4x4 transform of finite numbers", field)
    rotation = pose[:3, :3]
    if (
        np.max(np.abs(pose[3] - [0.0, 0.0, 0.0, 1.0])) > 0
        or np.max(np.abs(rotation.T @ rotation - np.eye(3))) > RIGID_TOLERANCE
        or np.linalg.det(rotation) < 0
    ):
        raise ArgumentError(
            "expected a rigid transform (orthonormal rotation, last row 0 0 0 1)", field
        )
    return pose


def _frozen(array: _A) -> _A:
    array.setflags(write=False)
    return array


# --- solids ----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Solid:
    """One solid placed in the world.

    Parameters
    ----------
    kind
        One of :data:`SOLID_KINDS`.
    pose
        World-from-local rigid transform ``(4, 4)``.
    size
        ``box``: full edge lengths ``(3,)`` centred at the local origin (URDF
        ``<box size>``); ``cylinder`` and ``capsule``: ``(radius, length)``, axis along
        local ``z``, centred (``length`` is the full length of the axis segment, so a
        capsule reaches ``length / 2 + radius`` along ``z``); ``sphere``: ``(radius,)``;
        ``mesh``: the scale ``(x, y, z)`` its vertices were loaded with (a record only:
        the vertices are already scaled).
    vertices
        Mesh only: local vertices ``(V, 3)``.
    faces
        Mesh only: vertex indices of the triangles ``(T, 3)``.

    Notes
    -----
    The arrays are read-only (copies of writeable input). Solids compare by identity
    (arrays have no single truth value). :meth:`transformed` shares the mesh arrays, and
    a :class:`SolidSet` builds one distance grid for all solids sharing them.
    """

    kind: str
    pose: FloatArray
    size: FloatArray
    vertices: FloatArray | None = None
    faces: IntArray | None = None

    def __post_init__(self) -> None:
        if self.kind not in SOLID_KINDS:
            raise ArgumentError(
                f"unknown solid kind {self.kind!r}; expected one of {', '.join(SOLID_KINDS)}",
                "kind",
            )
        object.__setattr__(self, "pose", _frozen(_rigid(self.pose, "pose")))
        size = _finite_vector(self.size, _SIZE_LENGTHS[self.kind], "size")
        if self.kind == "mesh":
            if np.any(size == 0):
                raise ArgumentError(f"a mesh's scale must not be zero, got {size.tolist()}", "size")
        elif np.any(size <= 0):
            raise ArgumentError(
                f"a {self.kind}'s dimensions must be positive, got {size.tolist()}", "size"
            )
        object.__setattr__(self, "size", _frozen(size))
        if self.kind != "mesh":
            if self.vertices is not None or self.faces is not None:
                raise ArgumentError(f"a {self.kind} has no vertices or faces", "vertices")
            return
        vertices, faces = _mesh_arrays(self.vertices, self.faces)
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)

    @property
    def rotation(self) -> FloatArray:
        """World-from-local rotation ``(3, 3)``."""
        return self.pose[:3, :3]

    @property
    def translation(self) -> FloatArray:
        """Position of the local origin in the world ``(3,)``."""
        return self.pose[:3, 3]

    def transformed(self, T: FloatArray) -> Solid:
        """The solid moved by the rigid transform ``T`` (new pose ``T @ pose``)."""
        return Solid(self.kind, _rigid(T, "T") @ self.pose, self.size, self.vertices, self.faces)

    def aabb(self) -> tuple[FloatArray, FloatArray]:
        """World axis-aligned bounding box ``(lo, hi)``.

        Exact for the primitives (the extreme points of a rotated box, disc rim or
        hemisphere), the extremes of the vertices for a mesh.
        """
        rotation, centre = self.rotation, self.translation
        if self.kind == "mesh":
            assert self.vertices is not None
            world = self.vertices @ rotation.T + centre
            return world.min(axis=0), world.max(axis=0)
        if self.kind == "box":
            half = np.abs(rotation) @ (self.size / 2)
        elif self.kind == "sphere":
            half = np.full(3, self.size[0])
        else:
            radius, half_length = self.size[0], self.size[1] / 2
            axis = rotation[:, 2]
            if self.kind == "cylinder":
                # A disc of radius r normal to unit a reaches r sqrt(1 - a_i^2) along axis i.
                rim = radius * np.sqrt(np.clip(1.0 - axis**2, 0.0, 1.0))
            else:
                rim = np.full(3, radius)
            half = half_length * np.abs(axis) + rim
        return centre - half, centre + half

    def triangles(self, resolution: int = 24) -> tuple[FloatArray, IntArray]:
        """World-space triangle mesh for drawing: ``(vertices (V, 3), faces (T, 3))``.

        Primitives are tessellated with ``resolution`` segments around each circle
        (vertices on the true surface, faces wound counter-clockwise seen from outside);
        a mesh gives its own triangles.
        """
        if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 3:
            raise ArgumentError(
                f"expected an integer of at least 3, got {resolution!r}", "resolution"
            )
        if self.kind == "mesh":
            assert self.vertices is not None and self.faces is not None
            local, faces = self.vertices, self.faces.copy()
        else:
            local, faces = _tessellate(self.kind, self.size, resolution)
        return local @ self.rotation.T + self.translation, faces

    def to_coal(self) -> coal.CollisionGeometry:
        """The same shape as a coal collision geometry (in its local frame).

        coal takes URDF's conventions: ``Box(x, y, z)`` full edge lengths,
        ``Cylinder(radius, length)`` and ``Capsule(radius, length)`` with the full
        length (``halfLength = length / 2``); a mesh becomes a ``BVHModelOBBRSS``.
        """
        import coal

        if self.kind == "box":
            return coal.Box(*(float(v) for v in self.size))
        if self.kind == "cylinder":
            return coal.Cylinder(float(self.size[0]), float(self.size[1]))
        if self.kind == "sphere":
            return coal.Sphere(float(self.size[0]))
        if self.kind == "capsule":
            return coal.Capsule(float(self.size[0]), float(self.size[1]))
        assert self.vertices is not None and self.faces is not None
        model = coal.BVHModelOBBRSS()
        model.beginModel(len(self.faces), len(self.vertices))
        model.addVertices(np.ascontiguousarray(self.vertices))
        model.addTriangles(np.ascontiguousarray(self.faces))
        model.endModel()
        return model

    @property
    def volume(self) -> float:
        """Volume (cubic metres); a mesh's is the divergence-theorem volume, exact when
        it is closed."""
        if self.kind == "box":
            return float(np.prod(self.size))
        if self.kind == "sphere":
            return 4.0 / 3.0 * math.pi * float(self.size[0]) ** 3
        if self.kind in ("cylinder", "capsule"):
            radius, length = float(self.size[0]), float(self.size[1])
            extra = 4.0 / 3.0 * math.pi * radius**3 if self.kind == "capsule" else 0.0
            return math.pi * radius**2 * length + extra
        assert self.vertices is not None and self.faces is not None
        return abs(_signed_volume(self.vertices, self.faces))


def _pose_or_identity(pose: ArrayLike | None) -> FloatArray:
    return np.eye(4) if pose is None else np.asarray(pose, dtype=float)


def box(size: ArrayLike, pose: ArrayLike | None = None) -> Solid:
    """A box of full edge lengths ``size`` ``(3,)`` centred at its local origin."""
    return Solid("box", _pose_or_identity(pose), np.asarray(size, dtype=float))


def cylinder(radius: float, length: float, pose: ArrayLike | None = None) -> Solid:
    """A cylinder of ``radius`` and full ``length`` along its local ``z`` axis, centred."""
    return Solid("cylinder", _pose_or_identity(pose), np.array([radius, length], dtype=float))


def sphere(radius: float, pose: ArrayLike | None = None) -> Solid:
    """A sphere of ``radius`` centred at its local origin."""
    return Solid("sphere", _pose_or_identity(pose), np.array([radius], dtype=float))


def capsule(radius: float, length: float, pose: ArrayLike | None = None) -> Solid:
    """The points within ``radius`` of the local ``z`` segment of full ``length``, centred."""
    return Solid("capsule", _pose_or_identity(pose), np.array([radius, length], dtype=float))


def mesh(
    vertices: ArrayLike,
    faces: ArrayLike,
    pose: ArrayLike | None = None,
    *,
    scale: Sequence[float] = (1.0, 1.0, 1.0),
) -> Solid:
    """A triangle mesh from local (already scaled) ``vertices`` ``(V, 3)`` and ``faces``
    ``(T, 3)``.

    A closed mesh whose faces wind inwards (negative volume) has them reversed, so
    normals point out; the inside test does not depend on it. ``scale`` is only recorded
    (as the solid's ``size``).
    """
    v, f = _mesh_arrays(vertices, faces)
    if _is_closed(v, f) and _signed_volume(v, f) < 0:
        f = f[:, ::-1].copy()
    return Solid("mesh", _pose_or_identity(pose), np.asarray(scale, dtype=float), v, f)


def _mesh_arrays(
    vertices: ArrayLike | None, faces: ArrayLike | None
) -> tuple[FloatArray, IntArray]:
    """Checked read-only arrays. Arrays already read-only, contiguous and of the right
    type are kept rather than copied, so placements of a mesh share them (and a
    :class:`SolidSet` one grid); writeable ones are copied, so no caller can change a
    solid after the fact."""
    if vertices is None or faces is None:
        raise ArgumentError("a mesh needs vertices and faces", "vertices")
    try:
        v = np.asarray(vertices, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError("expected vertices as (V, 3) numbers", "vertices") from None
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.all(np.isfinite(v)):
        raise ArgumentError("expected vertices as finite (V, 3) numbers", "vertices")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ArgumentError("expected at least one triangle as (T, 3) vertex indices", "faces")
    if f.dtype.kind not in "iu":
        raise ArgumentError("expected integer vertex indices", "faces")
    if f.min() < 0 or f.max() >= len(v):
        raise ArgumentError(f"vertex indices must lie in 0..{len(v) - 1}", "faces")
    return _read_only(v, np.float64), _read_only(f, np.int64)


def _read_only(array: NDArray[Any], dtype: type[np.generic]) -> NDArray[Any]:
    if array.dtype != dtype or array.flags.writeable or not array.flags.c_contiguous:
        array = np.array(array, dtype=dtype, order="C")
    return _frozen(array)


def _signed_volume(vertices: FloatArray, faces: IntArray) -> float:
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    # Relative to the centroid, so a mesh far from its origin keeps its digits.
    centre = vertices.mean(axis=0)
    a, b, c = a - centre, b - centre, c - centre
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def _is_closed(vertices: FloatArray, faces: IntArray) -> bool:
    """Whether every edge is used as often in one direction as in the other, once equal
    vertices are welded: then the winding number is an integer off the surface."""
    _, inverse = np.unique(vertices, axis=0, return_inverse=True)
    welded = inverse.reshape(-1)[faces]
    tails = welded.reshape(-1)
    heads = welded[:, [1, 2, 0]].reshape(-1)
    keep = tails != heads
    tails, heads = tails[keep], heads[keep]
    n = len(vertices)
    return bool(np.array_equal(np.sort(tails * n + heads), np.sort(heads * n + tails)))


def _tessellate(kind: str, size: FloatArray, resolution: int) -> tuple[FloatArray, IntArray]:
    """Local triangles of a primitive, vertices on its surface, faces wound outwards."""
    if kind == "box":
        half = size / 2
        corners = np.array(
            [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float
        )
        vertices = corners * half
        faces_list = []
        for axis in range(3):
            other = [q for q in range(3) if q != axis]
            for sign in (-1, 1):
                ring = []
                for s0, s1 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                    corner = np.zeros(3)
                    corner[axis], corner[other[0]], corner[other[1]] = sign, s0, s1
                    ring.append(int(np.flatnonzero(np.all(corners == corner, axis=1))[0]))
                faces_list += [[ring[0], ring[1], ring[2]], [ring[0], ring[2], ring[3]]]
        return _outward(vertices, np.array(faces_list, dtype=np.int64))
    radius = float(size[0])
    if kind == "sphere":
        phi = np.linspace(-np.pi / 2, np.pi / 2, max(2, resolution // 2) + 1)
        r, z = radius * np.cos(phi), radius * np.sin(phi)
    elif kind == "cylinder":
        half_length = float(size[1]) / 2
        r = np.array([0.0, radius, radius, 0.0])
        z = np.array([-half_length, -half_length, half_length, half_length])
    else:
        half_length = float(size[1]) / 2
        phi = np.linspace(-np.pi / 2, 0.0, max(1, resolution // 4) + 1)
        r = np.concatenate([radius * np.cos(phi), radius * np.cos(phi[::-1])])
        z = np.concatenate(
            [-half_length + radius * np.sin(phi), half_length - radius * np.sin(phi[::-1])]
        )
    r[0] = r[-1] = 0.0
    return _outward(*_lathe(r, z, resolution))


def _lathe(r: FloatArray, z: FloatArray, segments: int) -> tuple[FloatArray, IntArray]:
    """Surface of revolution about ``z`` of a profile from pole ``(0, z[0])`` to pole
    ``(0, z[-1])``."""
    angles = 2 * np.pi * np.arange(segments) / segments
    rings = len(r) - 2
    ring_xyz = np.stack(
        [
            np.outer(r[1:-1], np.cos(angles)),
            np.outer(r[1:-1], np.sin(angles)),
            np.repeat(z[1:-1, None], segments, axis=1),
        ],
        axis=-1,
    ).reshape(-1, 3)
    vertices = np.vstack([[0.0, 0.0, z[0]], ring_xyz, [0.0, 0.0, z[-1]]])
    top = len(vertices) - 1
    k = np.arange(segments)
    k1 = (k + 1) % segments
    faces = [np.stack([np.zeros(segments, dtype=np.int64), 1 + k1, 1 + k], axis=1)]
    for i in range(rings - 1):
        a, b = 1 + i * segments + k, 1 + i * segments + k1
        c, d = b + segments, a + segments
        faces += [np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]
    last = 1 + (rings - 1) * segments
    faces.append(np.stack([np.full(segments, top), last + k, last + k1], axis=1))
    return vertices, np.vstack(faces).astype(np.int64)


def _outward(vertices: FloatArray, faces: IntArray) -> tuple[FloatArray, IntArray]:
    """Faces wound so normals point away from the origin: the primitives are convex and
    hold their origin inside, so this is the outside."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    faces = faces.copy()
    faces[inward] = faces[inward][:, ::-1]
    return vertices, faces


# --- mesh files ------------------------------------------------------------------------------


def load_mesh(
    path: Path, scale: Sequence[float] = (1.0, 1.0, 1.0), *, field: str
) -> tuple[FloatArray, IntArray]:
    """Read a mesh file (STL, OBJ or DAE) through coal's assimp loader.

    Parameters
    ----------
    path
        The file.
    scale
        Per-axis scale applied to the vertices (URDF ``<mesh scale>``); a negative
        product mirrors the mesh, so its faces are reversed to keep their winding.
    field
        The scenario field that names the file, for error messages.

    Returns
    -------
    tuple[FloatArray, IntArray]
        Vertices ``(V, 3)`` (scaled) and faces ``(T, 3)``.

    Raises
    ------
    ScenarioError
        With one problem naming ``field``: no such file, not a regular file, empty,
        over :data:`MAX_MESH_BYTES`, an unknown extension, too big for the memory left
        (about :data:`MESH_BYTES_PER_TRIANGLE` a triangle, triangles counted from a
        binary STL's header or guessed at one per :data:`TEXT_BYTES_PER_TRIANGLE` bytes
        of text), unreadable, no triangles, or no volume (all vertices in one plane, or
        a closed mesh enclosing nothing).
    """
    path = Path(path)
    shown = printable(str(path))

    def refuse(message: str) -> ScenarioError:
        return ScenarioError([Problem(field, message)])

    try:
        factors = np.array(scale, dtype=float)
    except (TypeError, ValueError):
        factors = np.array([np.nan])
    if factors.shape != (3,) or not np.all(np.isfinite(factors)) or np.any(factors == 0):
        raise refuse(f"mesh scale must be 3 finite non-zero numbers, got {printable(str(scale))}")
    if not path.exists():
        raise refuse(f"no such mesh file: {shown}")
    if not path.is_file():
        raise refuse(f"mesh {shown} is not a regular file")
    suffix = path.suffix.lower()
    if suffix not in _MESH_SUFFIXES:
        raise refuse(
            f"mesh {shown}: unknown format {printable(path.suffix or '(no extension)')!s}; "
            "expected STL, OBJ or DAE"
        )
    size = path.stat().st_size
    if size == 0:
        raise refuse(f"mesh {shown} is empty")
    if size > MAX_MESH_BYTES:
        raise refuse(
            f"mesh {shown} is {budget.format_bytes(size)}; meshes over "
            f"{budget.format_bytes(MAX_MESH_BYTES)} are refused"
        )
    triangles = _binary_stl_triangles(path, size) if suffix == ".stl" else None
    if triangles is None:
        triangles = size // TEXT_BYTES_PER_TRIANGLE + 1
    budget.require(
        triangles * MESH_BYTES_PER_TRIANGLE,
        field,
        f"to load mesh {shown}",
        error=ScenarioError,
    )
    import coal

    try:
        model = coal.MeshLoader().load(str(path), factors)
        vertices = np.array(model.vertices(), dtype=float).reshape(-1, 3)
        count = int(model.num_tris)
        faces = np.empty((count, 3), dtype=np.int64)
        for i in range(count):
            tri = model.tri_indices(i)
            faces[i] = (tri[0], tri[1], tri[2])
    except (ValueError, RuntimeError, OSError, MemoryError) as exc:
        raise refuse(f"cannot read mesh {shown}: {_one_line(str(exc))}") from None
    if count == 0:
        raise refuse(f"mesh {shown} has no triangles")
    if np.prod(factors) < 0:
        faces = faces[:, ::-1].copy()
    if not np.all(np.isfinite(vertices)):
        raise refuse(f"mesh {shown} has vertices that are not finite numbers")
    if _flat(vertices):
        raise refuse(f"mesh {shown} has no volume: its vertices lie in one plane")
    if _is_closed(vertices, faces) and _no_volume(vertices, faces):
        raise refuse(f"mesh {shown} has no volume: its closed surface encloses nothing")
    return vertices, faces


def _binary_stl_triangles(path: Path, size: int) -> int | None:
    """The triangle count a binary STL's header gives, if the file is one (its size is
    then exactly 84 + 50 per triangle); None for ASCII STL."""
    if size < 84:
        return None
    with path.open("rb") as stream:
        header = stream.read(84)
    count = int.from_bytes(header[80:84], "little")
    return count if size == 84 + 50 * count else None


def _one_line(message: str) -> str:
    """coal's exception text (file, function, line, message, hint) as one line."""
    kept = []
    for line in message.splitlines():
        line = line.strip()
        line = line.removeprefix("message:").strip()
        # The path is already in the caller's message.
        if not line or line.startswith(
            ("From file:", "in function:", "at line:", "Hint:", "Could not load resource")
        ):
            continue
        kept.append(line)
    return printable(" ".join(kept) or "the loader failed")


def _flat(vertices: FloatArray) -> bool:
    """All vertices on one plane (or line, or point), to a relative 1e-9."""
    centred = vertices - vertices.mean(axis=0)
    if len(vertices) < 4:
        return True
    singular = np.linalg.svd(centred, compute_uv=False)
    return bool(singular[0] == 0 or singular[2] <= 1e-9 * singular[0])


def _no_volume(vertices: FloatArray, faces: IntArray) -> bool:
    extent = float(np.max(vertices.max(axis=0) - vertices.min(axis=0)))
    return abs(_signed_volume(vertices, faces)) <= 1e-12 * extent**3


# --- compiled geometry -----------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def _primitive_sd(kind: int, x: float, y: float, z: float, a: float, b: float, c: float) -> float:
    """Signed distance from local point ``(x, y, z)`` to a primitive of parameters
    ``(a, b, c)``: box half edges; cylinder or capsule radius and half length; sphere
    radius."""
    if kind == _BOX:
        qx, qy, qz = abs(x) - a, abs(y) - b, abs(z) - c
        ox, oy, oz = max(qx, 0.0), max(qy, 0.0), max(qz, 0.0)
        return math.sqrt(ox * ox + oy * oy + oz * oz) + min(max(qx, max(qy, qz)), 0.0)
    if kind == _CYLINDER:
        dr = math.sqrt(x * x + y * y) - a
        dz = abs(z) - b
        ox, oz = max(dr, 0.0), max(dz, 0.0)
        return math.sqrt(ox * ox + oz * oz) + min(max(dr, dz), 0.0)
    if kind == _SPHERE:
        return math.sqrt(x * x + y * y + z * z) - a
    dz = z - min(max(z, -b), b)
    return math.sqrt(x * x + y * y + dz * dz) - a


@nb.njit(cache=True)
def _segment_sq(
    px: float,
    py: float,
    pz: float,
    ax: float,
    ay: float,
    az: float,
    bx: float,
    by: float,
    bz: float,
) -> float:
    ux, uy, uz = bx - ax, by - ay, bz - az
    length_sq = ux * ux + uy * uy + uz * uz
    t = 0.0
    if length_sq > 0.0:
        t = min(max(((px - ax) * ux + (py - ay) * uy + (pz - az) * uz) / length_sq, 0.0), 1.0)
    dx, dy, dz = px - ax - t * ux, py - ay - t * uy, pz - az - t * uz
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True)
def _triangle_sq(px: float, py: float, pz: float, tris: FloatArray, t: int) -> float:
    """Squared distance from a point to triangle ``t`` (Ericson's Voronoi-region walk,
    *Real-Time Collision Detection* 5.1.5); degenerate triangles fall back to their
    edges."""
    ax, ay, az = tris[t, 0, 0], tris[t, 0, 1], tris[t, 0, 2]
    bx, by, bz = tris[t, 1, 0], tris[t, 1, 1], tris[t, 1, 2]
    cx, cy, cz = tris[t, 2, 0], tris[t, 2, 1], tris[t, 2, 2]
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return _segment_sq(px, py, pz, ax, ay, az, bx, by, bz)
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return _segment_sq(px, py, pz, ax, ay, az, cx, cy, cz)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        return _segment_sq(px, py, pz, bx, by, bz, cx, cy, cz)
    denom = va + vb + vc
    if not denom > 0.0:
        return min(
            _segment_sq(px, py, pz, ax, ay, az, bx, by, bz),
            min(
                _segment_sq(px, py, pz, bx, by, bz, cx, cy, cz),
                _segment_sq(px, py, pz, cx, cy, cz, ax, ay, az),
            ),
        )
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    # The projection falls inside: the distance to the plane, which keeps its digits for
    # a point just above the face (a barycentric residual would carry their rounding).
    h = apx * nx + apy * ny + apz * nz
    return h * h / (nx * nx + ny * ny + nz * nz)


@nb.njit(cache=True)
def _solid_angle(px: float, py: float, pz: float, tris: FloatArray, t: int) -> float:
    """Signed solid angle triangle ``t`` subtends at the point (Van Oosterom and
    Strackee 1983)."""
    ax, ay, az = tris[t, 0, 0] - px, tris[t, 0, 1] - py, tris[t, 0, 2] - pz
    bx, by, bz = tris[t, 1, 0] - px, tris[t, 1, 1] - py, tris[t, 1, 2] - pz
    cx, cy, cz = tris[t, 2, 0] - px, tris[t, 2, 1] - py, tris[t, 2, 2] - pz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = (
        la * lb * lc
        + (ax * bx + ay * by + az * bz) * lc
        + (ax * cx + ay * cy + az * cz) * lb
        + (bx * cx + by * cy + bz * cz) * la
    )
    return 2.0 * math.atan2(det, den)


@nb.njit(cache=True)
def _box_sq(px: float, py: float, pz: float, lo: FloatArray, hi: FloatArray, i: int) -> float:
    dx = max(lo[i, 0] - px, 0.0, px - hi[i, 0])
    dy = max(lo[i, 1] - py, 0.0, py - hi[i, 1])
    dz = max(lo[i, 2] - pz, 0.0, pz - hi[i, 2])
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True)
def _nearest_sq(
    px: float,
    py: float,
    pz: float,
    tris: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    left: IntArray,
    right: IntArray,
    start: IntArray,
    count: IntArray,
    best: float,
    best_tri: int,
    stack: IntArray,
) -> tuple[float, int]:
    """Squared distance to the nearest triangle and its index, starting from an upper
    bound ``best`` (the distance to ``best_tri``, or infinity)."""
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if _box_sq(px, py, pz, lo, hi, node) >= best:
            continue
        if left[node] < 0:
            for t in range(start[node], start[node] + count[node]):
                d = _triangle_sq(px, py, pz, tris, t)
                if d < best:
                    best, best_tri = d, t
            continue
        a, b = left[node], right[node]
        da, db = _box_sq(px, py, pz, lo, hi, a), _box_sq(px, py, pz, lo, hi, b)
        # The nearer child is popped first, so the bound tightens early.
        if da <= db:
            a, b, da, db = b, a, db, da
        if da < best:
            stack[top] = a
            top += 1
        if db < best:
            stack[top] = b
            top += 1
    return best, best_tri


@nb.njit(cache=True)
def _winding(
    px: float,
    py: float,
    pz: float,
    tris: FloatArray,
    left: IntArray,
    right: IntArray,
    start: IntArray,
    count: IntArray,
    normal: FloatArray,
    centre: FloatArray,
    radius: FloatArray,
    beta: float,
    stack: IntArray,
) -> float:
    """Generalised winding number at the point; clusters farther than ``beta`` radii
    are summed as dipoles."""
    total = 0.0
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        dx = centre[node, 0] - px
        dy = centre[node, 1] - py
        dz = centre[node, 2] - pz
        d2 = dx * dx + dy * dy + dz * dz
        reach = beta * radius[node]
        if d2 > reach * reach and d2 > 0.0:
            total += (normal[node, 0] * dx + normal[node, 1] * dy + normal[node, 2] * dz) / (
                d2 * math.sqrt(d2)
            )
        elif left[node] < 0:
            for t in range(start[node], start[node] + count[node]):
                total += _solid_angle(px, py, pz, tris, t)
        else:
            stack[top] = left[node]
            stack[top + 1] = right[node]
            top += 2
    return total / (4.0 * math.pi)


@nb.njit(cache=True)
def _mesh_sd_points(
    points: FloatArray,
    tris: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    left: IntArray,
    right: IntArray,
    start: IntArray,
    count: IntArray,
    normal: FloatArray,
    centre: FloatArray,
    radius: FloatArray,
    beta: float,
) -> FloatArray:
    out = np.empty(points.shape[0])
    stack = np.empty(_STACK_SIZE, dtype=np.int64)
    for m in range(points.shape[0]):
        px, py, pz = points[m, 0], points[m, 1], points[m, 2]
        d2, _ = _nearest_sq(px, py, pz, tris, lo, hi, left, right, start, count, np.inf, -1, stack)
        w = _winding(
            px, py, pz, tris, left, right, start, count, normal, centre, radius, beta, stack
        )
        d = math.sqrt(d2)
        out[m] = -d if abs(w) > 0.5 else d
    return out


@nb.njit(cache=True)
def _orient_certain(
    ax: float, ay: float, bx: float, by: float, px: float, py: float
) -> tuple[float, bool]:
    """Twice the signed area of ``(a, b, p)`` in the plane and whether its sign is sure:
    Shewchuk's error bound of this expression, with a thousandfold margin."""
    left = (bx - ax) * (py - ay)
    right = (by - ay) * (px - ax)
    e = left - right
    return e, abs(e) > 1e-12 * (abs(left) + abs(right))


@nb.njit(cache=True)
def _column_crossings(
    x: float,
    y: float,
    z0: float,
    z1: float,
    tris: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    left: IntArray,
    right: IntArray,
    start: IntArray,
    count: IntArray,
    stack: IntArray,
) -> tuple[int, bool]:
    """Signed count of the triangles the segment from ``(x, y, z0)`` up to ``(x, y, z1)``
    crosses (+1 where the triangle's normal points up), and whether the count is sure:
    not when the segment passes near an edge or vertex, or ends near a triangle."""
    tol = 1e-9 * (z1 - z0) + 1e-12 * (abs(z0) + abs(z1))
    change = 0
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if (
            x < lo[node, 0]
            or x > hi[node, 0]
            or y < lo[node, 1]
            or y > hi[node, 1]
            or z1 < lo[node, 2]
            or z0 > hi[node, 2]
        ):
            continue
        if left[node] >= 0:
            stack[top] = left[node]
            stack[top + 1] = right[node]
            top += 2
            continue
        for t in range(start[node], start[node] + count[node]):
            ax, ay, az = tris[t, 0, 0], tris[t, 0, 1], tris[t, 0, 2]
            bx, by, bz = tris[t, 1, 0], tris[t, 1, 1], tris[t, 1, 2]
            cx, cy, cz = tris[t, 2, 0], tris[t, 2, 1], tris[t, 2, 2]
            e_ab, sure_ab = _orient_certain(ax, ay, bx, by, x, y)
            e_bc, sure_bc = _orient_certain(bx, by, cx, cy, x, y)
            e_ca, sure_ca = _orient_certain(cx, cy, ax, ay, x, y)
            positive = (sure_ab and e_ab > 0) or (sure_bc and e_bc > 0) or (sure_ca and e_ca > 0)
            negative = (sure_ab and e_ab < 0) or (sure_bc and e_bc < 0) or (sure_ca and e_ca < 0)
            if positive and negative:
                continue  # surely outside the triangle's shadow
            if not (sure_ab and sure_bc and sure_ca):
                return 0, False
            # Surely inside the shadow: the edge functions are barycentric weights.
            area = e_ab + e_bc + e_ca
            zc = (e_bc * az + e_ca * bz + e_ab * cz) / area
            if abs(zc - z0) <= tol or abs(zc - z1) <= tol:
                return 0, False
            if z0 < zc < z1:
                change += 1 if area > 0 else -1
    return change, True


@nb.njit(cache=True)
def _fill_grid(
    values: FloatArray,
    ox: float,
    oy: float,
    oz: float,
    h: float,
    nx: int,
    ny: int,
    nz: int,
    tris: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    left: IntArray,
    right: IntArray,
    start: IntArray,
    count: IntArray,
    normal: FloatArray,
    centre: FloatArray,
    radius: FloatArray,
    beta: float,
    closed: bool,
) -> None:
    """Exact signed distance at every grid node, ``values[(i * ny + j) * nz + k]``.

    Each node starts its search from the previous node's nearest triangle. Boundary
    nodes lie outside the mesh's box, hence outside. In a closed mesh the winding number
    is an integer that changes only where the surface is crossed, so each column carries
    it up from its boundary node: unchanged between neighbours whose distances sum to
    more than their spacing (no surface fits between them), else changed by the signed
    crossings of the segment between them, else (a crossing near an edge or vertex)
    evaluated afresh. Open meshes evaluate every node.
    """
    stack = np.empty(_STACK_SIZE, dtype=np.int64)
    tri = 0
    no_crossing = h * (1.0 + 1e-9)
    for i in range(nx):
        x = ox + i * h
        for j in range(ny):
            y = oy + j * h
            previous = 0.0
            wind = 0
            for k in range(nz):
                z = oz + k * h
                bound = _triangle_sq(x, y, z, tris, tri)
                d2, tri = _nearest_sq(
                    x, y, z, tris, lo, hi, left, right, start, count, bound, tri, stack
                )
                d = math.sqrt(d2)
                if i == 0 or j == 0 or k == 0 or i == nx - 1 or j == ny - 1 or k == nz - 1:
                    wind = 0
                elif not closed:
                    w = _winding(
                        x,
                        y,
                        z,
                        tris,
                        left,
                        right,
                        start,
                        count,
                        normal,
                        centre,
                        radius,
                        beta,
                        stack,
                    )
                    wind = 1 if abs(w) > 0.5 else 0
                elif previous + d <= no_crossing:
                    z_below = oz + (k - 1) * h
                    change, sure = _column_crossings(
                        x, y, z_below, z, tris, lo, hi, left, right, start, count, stack
                    )
                    if sure:
                        # Going up through a face whose normal points up leaves the solid.
                        wind -= change
                    else:
                        w = _winding(
                            x,
                            y,
                            z,
                            tris,
                            left,
                            right,
                            start,
                            count,
                            normal,
                            centre,
                            radius,
                            beta,
                            stack,
                        )
                        wind = round(w)
                values[(i * ny + j) * nz + k] = -d if wind != 0 else d
                previous = d


@nb.njit(cache=True)
def _grid_bound(
    values: FloatArray,
    offset: int,
    nx: int,
    ny: int,
    nz: int,
    ox: float,
    oy: float,
    oz: float,
    h: float,
    x: float,
    y: float,
    z: float,
    upper: bool,
) -> float:
    """Lower (or upper) bound of a mesh's signed distance at a local point from its grid:
    the best of ``g(c) -+ |p - c|`` over the corners ``c`` of the (clamped) cell holding
    the point; the lower bound also takes the distance to the grid's box when the point
    lies outside it."""
    fx = min(max((x - ox) / h, 0.0), nx - 2.0)
    fy = min(max((y - oy) / h, 0.0), ny - 2.0)
    fz = min(max((z - oz) / h, 0.0), nz - 2.0)
    i0, j0, k0 = int(fx), int(fy), int(fz)
    best = np.inf if upper else -np.inf
    for i in range(i0, i0 + 2):
        dx = x - (ox + i * h)
        for j in range(j0, j0 + 2):
            dy = y - (oy + j * h)
            for k in range(k0, k0 + 2):
                dz = z - (oz + k * h)
                gap = math.sqrt(dx * dx + dy * dy + dz * dz)
                v = values[offset + (i * ny + j) * nz + k]
                if upper:
                    best = min(best, v + gap)
                else:
                    best = max(best, v - gap)
    if not upper:
        ex = max(ox - x, 0.0, x - (ox + (nx - 1) * h))
        ey = max(oy - y, 0.0, y - (oy + (ny - 1) * h))
        ez = max(oz - z, 0.0, z - (oz + (nz - 1) * h))
        outside = math.sqrt(ex * ex + ey * ey + ez * ez)
        if outside > 0.0:
            best = max(best, outside)
    return best


@nb.njit(cache=True)
def _mesh_row(
    centers: FloatArray,
    n: int,
    reach: FloatArray,
    sign: float,
    r: FloatArray,
    values: FloatArray,
    offset: int,
    shape: IntArray,
    origin: FloatArray,
    h: float,
    out: FloatArray,
) -> None:
    """:func:`_primitive_row` for a mesh, through its grid: lower bounds of the signed
    distance for ``sign = 1``, upper bounds for ``sign = -1``."""
    for s in range(centers.shape[1]):
        x, y, z = centers[n, s, 0], centers[n, s, 1], centers[n, s, 2]
        lx = r[0, 0] * x + r[0, 1] * y + r[0, 2] * z + r[0, 3]
        ly = r[1, 0] * x + r[1, 1] * y + r[1, 2] * z + r[1, 3]
        lz = r[2, 0] * x + r[2, 1] * y + r[2, 2] * z + r[2, 3]
        bound = _grid_bound(
            values,
            offset,
            shape[0],
            shape[1],
            shape[2],
            origin[0],
            origin[1],
            origin[2],
            h,
            lx,
            ly,
            lz,
            sign < 0,
        )
        out[s] = sign * bound - reach[s]


@nb.njit(cache=True, inline="always")
def _primitive_row(
    kind: int,
    centers: FloatArray,
    n: int,
    reach: FloatArray,
    sign: float,
    r: FloatArray,
    a: float,
    b: float,
    c: float,
    out: FloatArray,
) -> None:
    """``out[s] = sign * sd - reach[s]`` for sphere ``s`` of configuration ``n`` and one
    primitive."""
    for s in range(centers.shape[1]):
        x, y, z = centers[n, s, 0], centers[n, s, 1], centers[n, s, 2]
        lx = r[0, 0] * x + r[0, 1] * y + r[0, 2] * z + r[0, 3]
        ly = r[1, 0] * x + r[1, 1] * y + r[1, 2] * z + r[1, 3]
        lz = r[2, 0] * x + r[2, 1] * y + r[2, 2] * z + r[2, 3]
        out[s] = sign * _primitive_sd(kind, lx, ly, lz, a, b, c) - reach[s]


@nb.njit(cache=True)
def _gaps_kernel(
    centers: FloatArray,
    reach: FloatArray,
    sign: float,
    kinds: IntArray,
    inverse: FloatArray,
    params: FloatArray,
    grid_index: IntArray,
    g_origin: FloatArray,
    g_spacing: FloatArray,
    g_shape: IntArray,
    g_offset: IntArray,
    g_values: FloatArray,
    reduce: bool,
) -> FloatArray:
    """Per configuration the minimum over spheres of ``sign * sd(centre) - reach``, per
    solid or (``reduce``) over all solids. ``sign = 1``: clearance, meshes by their
    grids' lower bounds; ``sign = -1``: depth inside, meshes by the upper bounds.
    ``reach`` is ``(1, S)`` for every configuration or ``(N, S)``, one row each."""
    n_configs, n_spheres = centers.shape[0], centers.shape[1]
    per_config = reach.shape[0] > 1
    n_solids = kinds.shape[0]
    out = np.full((n_configs, 1 if reduce else n_solids), np.inf)
    gaps = np.empty(n_spheres)
    for n in range(n_configs):
        row = reach[n] if per_config else reach[0]
        for k in range(n_solids):
            kind = kinds[k]
            a, b, c = params[k, 0], params[k, 1], params[k, 2]
            # A literal kind per call lets the compiler drop the other shapes' branches
            # from the hot loop (about a quarter faster than one generic loop). The row
            # and the distance are inlined here, so that costs no compile of their own per
            # kind (8 compiles less on a first run, issue 34).
            if kind == _BOX:
                _primitive_row(_BOX, centers, n, row, sign, inverse[k], a, b, c, gaps)
            elif kind == _CYLINDER:
                _primitive_row(_CYLINDER, centers, n, row, sign, inverse[k], a, b, c, gaps)
            elif kind == _SPHERE:
                _primitive_row(_SPHERE, centers, n, row, sign, inverse[k], a, b, c, gaps)
            elif kind == _CAPSULE:
                _primitive_row(_CAPSULE, centers, n, row, sign, inverse[k], a, b, c, gaps)
            else:
                g = grid_index[k]
                _mesh_row(
                    centers,
                    n,
                    row,
                    sign,
                    inverse[k],
                    g_values,
                    g_offset[g],
                    g_shape[g],
                    g_origin[g],
                    g_spacing[g],
                    gaps,
                )
            column = 0 if reduce else k
            best = out[n, column]
            for s in range(n_spheres):
                if gaps[s] < best:
                    best = gaps[s]
            out[n, column] = best
    return out


@nb.njit(cache=True)
def _bounds_kernel(
    lo: FloatArray, hi: FloatArray, centers: FloatArray, radii: FloatArray
) -> FloatArray:
    n_configs, n_spheres = centers.shape[0], centers.shape[1]
    per_config = radii.shape[0] > 1
    out = np.full(n_configs, np.inf)
    for n in range(n_configs):
        row = radii[n] if per_config else radii[0]
        best = np.inf
        for s in range(n_spheres):
            for q in range(3):
                c = centers[n, s, q]
                best = min(best, min(c - lo[q], hi[q] - c) - row[s])
        out[n] = best
    return out


# --- prepared solid sets ---------------------------------------------------------------------


def _spread_bits(q: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """The low 21 bits of each value spread to every third bit (for Morton codes)."""
    q = q & np.uint64(0x1FFFFF)
    for shift, mask in (
        (32, 0x1F00000000FFFF),
        (16, 0x1F0000FF0000FF),
        (8, 0x100F00F00F00F00F),
        (4, 0x10C30C30C30C30C3),
        (2, 0x1249249249249249),
    ):
        q = (q | (q << np.uint64(shift))) & np.uint64(mask)
    return q


@dataclass(frozen=True, eq=False)
class _MeshIndex:
    """A mesh's triangles (local frame) with a bounding-volume hierarchy over them.

    Node 0 is the root. Per node: its box (``lo``, ``hi``), its children (``left``,
    ``right``; ``-1`` for a leaf, which holds triangles ``start .. start + count``), and
    the dipole terms of the winding number: the area-weighted normal sum, the
    area-weighted centroid, and the radius of a ball about it holding the node's
    triangles.
    """

    tris: FloatArray
    lo: FloatArray
    hi: FloatArray
    left: IntArray
    right: IntArray
    start: IntArray
    count: IntArray
    normal: FloatArray
    centre: FloatArray
    radius: FloatArray
    closed: bool

    @staticmethod
    def build(vertices: FloatArray, faces: IntArray) -> _MeshIndex:
        """Leaves of :data:`_LEAF_SIZE` triangles in Morton order of their centroids,
        merged pairwise level by level: a balanced tree built in vectorised numpy (no
        compiled builder to wait for), about as good for nearest queries as a median
        split."""
        raw = vertices[faces]
        centroid = raw.mean(axis=1)
        low, high = centroid.min(axis=0), centroid.max(axis=0)
        span = np.where(high > low, high - low, 1.0)
        cells = ((centroid - low) / span * (2**21 - 1)).astype(np.uint64)
        code = (
            _spread_bits(cells[:, 0])
            | (_spread_bits(cells[:, 1]) << np.uint64(1))
            | (_spread_bits(cells[:, 2]) << np.uint64(2))
        )
        order = np.argsort(code, kind="stable")
        tris = np.ascontiguousarray(raw[order])
        centroid = centroid[order]
        n_tris = len(tris)

        starts = np.arange(0, n_tris, _LEAF_SIZE)
        n_leaves = len(starts)
        capacity = 2 * n_leaves - 1
        lo = np.empty((capacity, 3))
        hi = np.empty((capacity, 3))
        left = np.full(capacity, -1, dtype=np.int64)
        right = np.full(capacity, -1, dtype=np.int64)
        start = np.zeros(capacity, dtype=np.int64)
        count = np.zeros(capacity, dtype=np.int64)
        normal = np.empty((capacity, 3))
        centre = np.empty((capacity, 3))
        radius = np.empty(capacity)
        area = np.empty(capacity)

        leaves = slice(0, n_leaves)
        start[leaves] = starts
        count[leaves] = np.minimum(_LEAF_SIZE, n_tris - starts)
        lo[leaves] = np.minimum.reduceat(tris.min(axis=1), starts, axis=0)
        hi[leaves] = np.maximum.reduceat(tris.max(axis=1), starts, axis=0)
        tri_normal = 0.5 * np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        tri_area = np.linalg.norm(tri_normal, axis=1)
        normal[leaves] = np.add.reduceat(tri_normal, starts, axis=0)
        area[leaves] = np.add.reduceat(tri_area, starts)
        weighted = np.add.reduceat(tri_area[:, None] * centroid, starts, axis=0)
        plain = np.add.reduceat(centroid, starts, axis=0) / count[leaves, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            centre[leaves] = np.where(area[leaves, None] > 0, weighted / area[leaves, None], plain)
        owner = np.arange(n_tris) // _LEAF_SIZE
        reach = np.linalg.norm(tris - centre[owner][:, None, :], axis=2).max(axis=1)
        radius[leaves] = np.maximum.reduceat(reach, starts)

        level = np.arange(n_leaves)
        size = n_leaves
        while len(level) > 1:
            pairs = len(level) // 2
            a, b = level[0 : 2 * pairs : 2], level[1 : 2 * pairs : 2]
            new = np.arange(size, size + pairs)
            left[new], right[new] = a, b
            lo[new] = np.minimum(lo[a], lo[b])
            hi[new] = np.maximum(hi[a], hi[b])
            normal[new] = normal[a] + normal[b]
            area[new] = area[a] + area[b]
            with np.errstate(invalid="ignore", divide="ignore"):
                centre[new] = np.where(
                    area[new, None] > 0,
                    (area[a, None] * centre[a] + area[b, None] * centre[b]) / area[new, None],
                    0.5 * (centre[a] + centre[b]),
                )
            radius[new] = np.maximum(
                np.linalg.norm(centre[a] - centre[new], axis=1) + radius[a],
                np.linalg.norm(centre[b] - centre[new], axis=1) + radius[b],
            )
            # An odd node out rises to the next level unchanged.
            level = np.concatenate([new, level[2 * pairs :]])
            size += pairs

        # Renumber so the root (created last) is node 0.
        renumber = np.arange(capacity)[::-1]
        left = np.where(left >= 0, renumber[np.maximum(left, 0)], -1)[::-1].copy()
        right = np.where(right >= 0, renumber[np.maximum(right, 0)], -1)[::-1].copy()
        return _MeshIndex(
            tris,
            lo[::-1].copy(),
            hi[::-1].copy(),
            left,
            right,
            start[::-1].copy(),
            count[::-1].copy(),
            normal[::-1].copy(),
            centre[::-1].copy(),
            radius[::-1].copy(),
            _is_closed(vertices, faces),
        )

    def signed(self, points: FloatArray) -> FloatArray:
        """Exact signed distance (winding-number sign) at local points ``(M, 3)``."""
        return np.asarray(
            _mesh_sd_points(
                np.ascontiguousarray(points, dtype=float),
                self.tris,
                self.lo,
                self.hi,
                self.left,
                self.right,
                self.start,
                self.count,
                self.normal,
                self.centre,
                self.radius,
                _WINDING_BETA,
            )
        )


def _grid_plan(
    lo: FloatArray, hi: FloatArray, spacing: float, max_nodes: int
) -> tuple[FloatArray, float, IntArray]:
    """Origin, spacing and node counts of a grid over ``[lo, hi]`` padded by at least
    :data:`_GRID_PAD_CELLS` cells, the spacing coarsened until at most ``max_nodes``."""
    extent = hi - lo

    def shape_for(h: float) -> FloatArray:
        # Floats: a tiny spacing over a large mesh would overflow an integer product.
        return np.ceil(extent / h + 2 * _GRID_PAD_CELLS + _GRID_SHIFT) + 1

    h = spacing
    shape = shape_for(h)
    while float(np.prod(shape)) > max_nodes:
        h *= max(1.01, (float(np.prod(shape)) / max_nodes) ** (1 / 3))
        shape = shape_for(h)
    return lo - (_GRID_PAD_CELLS + _GRID_SHIFT) * h, h, shape.astype(np.int64)


@dataclass(frozen=True, eq=False)
class SolidSet:
    """Solids prepared for the compiled kernels.

    Flat arrays of kinds, inverse poses and sizes, and for each mesh a distance grid
    (exact signed distances at the nodes of a regular grid over its padded local box)
    and a triangle hierarchy for exact queries. Build with :meth:`build`.

    Attributes
    ----------
    solids
        The solids, in column order.
    kinds
        Index of each solid's kind in :data:`SOLID_KINDS` ``(K,)``.
    inverse
        Local-from-world transforms, top three rows ``(K, 3, 4)``.
    params
        Box half edges; cylinder or capsule ``(radius, half length, 0)``; sphere
        ``(radius, 0, 0)``; zeros for meshes ``(K, 3)``.
    grid_index
        Each solid's grid (``-1`` for primitives) ``(K,)``.
    grid_origin, grid_spacing, grid_shape, grid_offset
        Each grid's first node (local frame), spacing, node counts and offset into
        ``grid_values`` (nodes ordered ``x``-major, ``z`` fastest).
    grid_values
        All grids' node values, concatenated.
    meshes
        Each grid's triangle hierarchy.
    """

    solids: tuple[Solid, ...]
    kinds: IntArray
    inverse: FloatArray
    params: FloatArray
    grid_index: IntArray
    grid_origin: FloatArray
    grid_spacing: FloatArray
    grid_shape: IntArray
    grid_offset: IntArray
    grid_values: FloatArray
    meshes: tuple[_MeshIndex, ...]

    def __len__(self) -> int:
        return len(self.solids)

    @staticmethod
    def build(
        solids: Sequence[Solid],
        *,
        mesh_spacing: float = 0.005,
        max_grid_nodes: int = MAX_GRID_NODES,
        names: Sequence[str] | None = None,
    ) -> SolidSet:
        """Prepare ``solids`` for :func:`sphere_gaps` and :func:`distances`.

        Parameters
        ----------
        solids
            The solids.
        mesh_spacing
            Node spacing (metres) of each mesh's distance grid. A grid that would
            have more than ``max_grid_nodes`` nodes gets a coarser spacing instead (at
            most about ``max_grid_nodes``: the default caps a grid at 4M nodes, 32 MB),
            which loosens its bound (by up to one cell diagonal). Solids that share
            mesh arrays (placements from :meth:`Solid.transformed`) share one grid.
        max_grid_nodes
            Node cap of one grid (at least 1000).
        names
            The scenario field of each solid, for errors (default ``solids[i]``).

        Raises
        ------
        ScenarioError
            The grids (with their hierarchies) need more memory than is available,
            naming the first mesh that does not fit; checked before they are allocated.
        """
        solids = tuple(solids)
        for i, solid in enumerate(solids):
            if not isinstance(solid, Solid):
                raise ArgumentError(f"expected a Solid, got {type(solid).__name__}", f"solids[{i}]")
        try:
            spacing = float(mesh_spacing)
        except (TypeError, ValueError):
            spacing = math.nan
        if not (math.isfinite(spacing) and spacing > 0):
            raise ArgumentError(f"expected a positive length, got {mesh_spacing!r}", "mesh_spacing")
        if int(max_grid_nodes) < 1000:
            raise ArgumentError(f"expected at least 1000, got {max_grid_nodes!r}", "max_grid_nodes")
        fields = list(names) if names is not None else [f"solids[{i}]" for i in range(len(solids))]
        if len(fields) != len(solids):
            raise ArgumentError(f"expected {len(solids)} names, got {len(fields)}", "names")
        count = len(solids)
        kinds = np.array([SOLID_KINDS.index(s.kind) for s in solids], dtype=np.int64)
        inverse = np.zeros((count, 3, 4))
        params = np.zeros((count, 3))
        grid_index = np.full(count, -1, dtype=np.int64)
        for k, solid in enumerate(solids):
            rotation_t = solid.rotation.T
            inverse[k, :, :3] = rotation_t
            inverse[k, :, 3] = -rotation_t @ solid.translation
            if solid.kind == "box":
                params[k] = solid.size / 2
            elif solid.kind in ("cylinder", "capsule"):
                params[k, :2] = solid.size[0], solid.size[1] / 2
            elif solid.kind == "sphere":
                params[k, 0] = solid.size[0]

        # Plan every grid and check the memory before building any.
        shared: dict[tuple[int, int], int] = {}
        plans: list[tuple[Solid, FloatArray, float, IntArray]] = []
        need = 0
        for k, solid in enumerate(solids):
            if solid.kind != "mesh":
                continue
            assert solid.vertices is not None and solid.faces is not None
            key = (id(solid.vertices), id(solid.faces))
            if key in shared:
                grid_index[k] = shared[key]
                continue
            origin, h, shape = _grid_plan(
                solid.vertices.min(axis=0),
                solid.vertices.max(axis=0),
                spacing,
                int(max_grid_nodes),
            )
            nodes = int(np.prod(shape))
            need += nodes * _GRID_BYTES_PER_NODE + len(solid.faces) * _BVH_BYTES_PER_TRIANGLE
            budget.require(
                need,
                fields[k],
                f"for mesh distance grids ({nodes} nodes at spacing {h:.3g} m for this one)",
                error=ScenarioError,
            )
            shared[key] = len(plans)
            grid_index[k] = len(plans)
            plans.append((solid, origin, h, shape))

        sizes = [int(np.prod(shape)) for _, _, _, shape in plans]
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        values = np.empty(int(offsets[-1]))
        meshes = []
        for g, (solid, origin, h, shape) in enumerate(plans):
            assert solid.vertices is not None and solid.faces is not None
            index = _MeshIndex.build(solid.vertices, solid.faces)
            _fill_grid(
                values[offsets[g] : offsets[g + 1]],
                origin[0],
                origin[1],
                origin[2],
                h,
                shape[0],
                shape[1],
                shape[2],
                index.tris,
                index.lo,
                index.hi,
                index.left,
                index.right,
                index.start,
                index.count,
                index.normal,
                index.centre,
                index.radius,
                _WINDING_BETA,
                index.closed,
            )
            meshes.append(index)
        return SolidSet(
            solids=solids,
            kinds=_frozen(kinds),
            inverse=_frozen(inverse),
            params=_frozen(params),
            grid_index=_frozen(grid_index),
            grid_origin=_frozen(np.array([p[1] for p in plans], dtype=float).reshape(-1, 3)),
            grid_spacing=_frozen(np.array([p[2] for p in plans], dtype=float)),
            grid_shape=_frozen(np.array([p[3] for p in plans], dtype=np.int64).reshape(-1, 3)),
            grid_offset=_frozen(offsets[:-1].copy()),
            grid_values=_frozen(values),
            meshes=tuple(meshes),
        )


# --- queries ---------------------------------------------------------------------------------


def _points(points: ArrayLike) -> FloatArray:
    array = np.ascontiguousarray(points, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ArgumentError(f"expected points of shape (M, 3), got {array.shape}", "points")
    if not np.all(np.isfinite(array)):
        raise ArgumentError("points must be finite", "points")
    return array


def _spheres(centers: ArrayLike, radii: ArrayLike) -> tuple[FloatArray, FloatArray]:
    c = np.ascontiguousarray(centers, dtype=float)
    r = np.ascontiguousarray(radii, dtype=float)
    if c.ndim != 3 or c.shape[2] != 3:
        raise ArgumentError(f"expected centres of shape (N, S, 3), got {c.shape}", "centers")
    if r.shape != (c.shape[1],):
        raise ArgumentError(f"expected {c.shape[1]} radii, got shape {r.shape}", "radii")
    # A NaN compares false with everything, so it would drop out of the minimum unseen.
    if not np.all(np.isfinite(c)):
        raise ArgumentError("sphere centres must be finite", "centers")
    if not np.all(np.isfinite(r)) or np.any(r < 0):
        raise ArgumentError("radii must be finite and not negative", "radii")
    return c, r


def distances(solids: SolidSet, points: ArrayLike) -> FloatArray:
    """Exact signed distance from each point to each solid, ``(M, len(solids))``.

    Negative inside (minus the depth). Analytic for the primitives; for meshes the exact
    distance to the triangles, negative where the winding-number rule (module docstring)
    says inside. Does not use the grids.
    """
    p = _points(points)
    # The primitives' columns from the sphere kernel (points as zero spheres), which
    # spares compiling a kernel of their own; the grid bounds in the mesh columns are
    # then replaced by exact values.
    out = _kernel(solids, p[:, None, :], np.zeros((1, 1)), 1.0, False)
    for k in np.flatnonzero(solids.kinds == _MESH):
        local = p @ solids.inverse[k, :, :3].T + solids.inverse[k, :, 3]
        out[:, k] = solids.meshes[solids.grid_index[k]].signed(local)
    return out


def _kernel(
    solids: SolidSet, centers: FloatArray, reach: FloatArray, sign: float, reduce: bool
) -> FloatArray:
    return np.asarray(
        _gaps_kernel(
            centers,
            reach,
            sign,
            solids.kinds,
            solids.inverse,
            solids.params,
            solids.grid_index,
            solids.grid_origin,
            solids.grid_spacing,
            solids.grid_shape,
            solids.grid_offset,
            solids.grid_values,
            reduce,
        )
    )


def _reach(radii: FloatArray, margin: float | ArrayLike, n: int | None = None) -> FloatArray:
    """Radius plus margin, ``(1, S)``, or ``(N, S)`` for a margin per configuration."""
    m = np.asarray(margin, dtype=float)
    if m.ndim == 0:
        m = np.full(radii.shape, float(m))
    per_config = m.ndim == 2 and n is not None and m.shape == (n, len(radii))
    if not (m.shape == radii.shape or per_config) or not np.all(np.isfinite(m)):
        raise ArgumentError(
            f"expected a finite margin, one per sphere ({len(radii)}) or one per "
            f"configuration and sphere ({n}, {len(radii)})",
            "margin",
        )
    return np.ascontiguousarray(np.atleast_2d(radii + m))


def sphere_gaps(
    solids: SolidSet, centers: ArrayLike, radii: ArrayLike, margin: float | ArrayLike = 0.0
) -> FloatArray:
    """Lower bound of the clearance between spheres and solids, per configuration.

    Parameters
    ----------
    solids
        The prepared solids.
    centers
        Sphere centres ``(N, S, 3)`` of ``N`` configurations (world frame).
    radii
        Sphere radii ``(S,)``.
    margin
        Extra clearance demanded: one for all spheres, one each ``(S,)``, or one per
        configuration and sphere ``(N, S)``.

    Returns
    -------
    FloatArray
        ``(N,)``: the minimum over spheres and solids of ``signed distance(centre,
        solid) - radius - margin``; positive means every sphere clears every solid by
        its margin. Exact for primitives, a lower bound for meshes (their grids); ``inf``
        with no solids.
    """
    c, r = _spheres(centers, radii)
    return _kernel(solids, c, _reach(r, margin, len(c)), 1.0, True)[:, 0]


def sphere_gaps_each(
    solids: SolidSet, centers: ArrayLike, radii: ArrayLike, margin: float | ArrayLike = 0.0
) -> FloatArray:
    """:func:`sphere_gaps` per solid, ``(N, len(solids))``: which solid is hit."""
    c, r = _spheres(centers, radii)
    return _kernel(solids, c, _reach(r, margin, len(c)), 1.0, False)


def inside_gaps(container: Solid | SolidSet, centers: ArrayLike, radii: ArrayLike) -> FloatArray:
    """How deep spheres lie inside a container, per configuration.

    Parameters
    ----------
    container
        The container; a mesh container needs its grid, so pass a prepared
        ``SolidSet.build([mesh])`` (one solid) to build it once rather than every call.
    centers
        Sphere centres ``(N, S, 3)``.
    radii
        Sphere radii ``(S,)``.

    Returns
    -------
    FloatArray
        ``(N,)``: the minimum over spheres of ``-signed distance(centre) - radius``;
        positive means every sphere lies strictly inside. Exact for primitives, a lower
        bound for a mesh (the grid's upper bound of the signed distance).
    """
    prepared = container if isinstance(container, SolidSet) else SolidSet.build([container])
    if len(prepared) != 1:
        raise ArgumentError(f"expected one container, got {len(prepared)} solids", "container")
    c, r = _spheres(centers, radii)
    return _kernel(prepared, c, r[None, :], -1.0, True)[:, 0]


def bounds_gaps(
    lo: ArrayLike,
    hi: ArrayLike,
    centers: ArrayLike,
    radii: ArrayLike,
    margin: float | ArrayLike = 0.0,
) -> FloatArray:
    """How deep spheres lie inside the axis-aligned box ``[lo, hi]``, per configuration.

    Returns ``(N,)``: the minimum over spheres and walls of the centre's distance to the
    wall (inwards) less the radius and ``margin`` (as in :func:`sphere_gaps`: one, one
    per sphere, or ``(N, S)``); negative when a sphere crosses a wall or is outside.
    """
    low = _finite_vector(lo, 3, "lo")
    high = _finite_vector(hi, 3, "hi")
    if np.any(high < low):
        raise ArgumentError(f"expected lo <= hi, got {low.tolist()} and {high.tolist()}", "hi")
    c, r = _spheres(centers, radii)
    return np.asarray(_bounds_kernel(low, high, c, _reach(r, margin, len(c))))

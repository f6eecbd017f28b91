"""Configuration-space grids and bitmaps.

A :class:`Grid` divides the robot's configuration space into boxes (cells);
cell ``i`` on an axis spans ``[lower + i h, lower + (i + 1) h]`` and its
configuration is the centre. Periodic axes (free rotations, unlimited joints)
span ``[-pi, pi)`` and wrap.

**What a free bitmap guarantees.** :func:`free_bitmap` is conservative: a cell
marked free contains no colliding configuration anywhere in its closed box
(not only at its centre); a cell marked blocked may still contain free
configurations, typically within one cell of a C-obstacle boundary. Three
methods give this guarantee:

* translating and point robots: Kavraki's FFT method (strategies paper,
  reference [18]). The obstacles are rasterised on a workspace grid aligned
  with the C-space cells and refined by an odd factor (a raster cell is set if
  an obstacle touches its closed box); the robot is rasterised as the set of
  offset raster cells that the robot, swept over one C-space cell, can touch;
  the C-obstacle is their correlation, computed by FFT and read at the C-cell
  centres. Any collision inside a C-space cell happens at a point lying in some
  raster cell that both rasters mark, so it is caught.
* rotating robots: the same, once per orientation slice, with the robot swept
  over the slice's angular interval (sampled densely enough, with the sampling
  gap added to the raster test's box).
* arms (and any robot on request, ``method="exact"``): the exact batched check at
  each cell centre, with every body required to keep a clearance equal to the
  largest distance any of its points can move inside the cell
  (:meth:`~cellplan.robots.Robot.body_displacement_bounds`).

Region bitmaps (:func:`region_bitmap`) are exact at cell centres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sp_fft

from cellplan.geometry import BoolArray, FloatArray, ShapeSet, body_gaps, raster_touching
from cellplan.robots import RigidRobot, Robot, as_batch
from cellplan.schema import CELLS_RANGE as _CELLS_RANGE
from cellplan.validity import ValiditySpace
from cellplan.workcell import AvoidSources, RegionTest, Workcell

# Sub-sampling of a rotation slice: the sampling gap may add at most this
# fraction of a translational cell to the robot's raster test box.
_ROTATION_GAP_FRACTION = 0.25
# The FFT method's workspace raster has at least this many cells per axis: coarse
# C-space grids get a finer raster (by an odd factor, so C-cell centres stay raster
# cell centres), which keeps the over-approximation to a fraction of a C-cell.
MIN_RASTER_CELLS = 256

CELLS_RANGE = _CELLS_RANGE
"""Allowed cells per axis (defined once, in :mod:`cellplan.schema`)."""


@dataclass(frozen=True)
class Grid:
    """A regular grid over a box of configuration space.

    Parameters
    ----------
    lower, upper
        Box corners per axis (``-pi, pi`` on periodic axes).
    shape
        Cells per axis.
    periodic
        Whether each axis wraps.
    """

    lower: FloatArray
    upper: FloatArray
    shape: tuple[int, ...]
    periodic: tuple[bool, ...]

    def __post_init__(self) -> None:
        if not (len(self.lower) == len(self.upper) == len(self.shape) == len(self.periodic)):
            raise ValueError("lower, upper, shape and periodic must have one entry per axis")
        if np.any(np.asarray(self.upper) <= np.asarray(self.lower)):
            raise ValueError("upper must exceed lower on every axis")
        if any(n < 1 for n in self.shape):
            raise ValueError("every axis needs at least one cell")

    @staticmethod
    def for_robot(robot: Robot, shape: Sequence[int]) -> Grid:
        """The grid over a robot's configuration space (bounds and joint limits)."""
        return Grid(
            np.array(robot.lower, float),
            np.array(robot.upper, float),
            tuple(int(s) for s in shape),
            robot.periodic,
        )

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def spacing(self) -> FloatArray:
        return (np.asarray(self.upper) - np.asarray(self.lower)) / np.asarray(self.shape)

    def axis(self, i: int) -> FloatArray:
        """Cell centres along axis ``i``."""
        return np.asarray(self.lower[i] + (np.arange(self.shape[i]) + 0.5) * self.spacing[i])

    def points(self) -> FloatArray:
        """All cell centres, ``(size, ndim)``, in C order (last axis fastest)."""
        mesh = np.meshgrid(*[self.axis(i) for i in range(self.ndim)], indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1)

    def coordinates(self, q: FloatArray) -> FloatArray:
        """Continuous cell coordinates of configurations (cell centres are integers)."""
        q = as_batch(q, self.ndim)
        return (q - self.lower) / self.spacing - 0.5

    def index_of(self, q: FloatArray) -> NDArray[np.int64]:
        """Index ``(N, ndim)`` of the cell containing each configuration (wrapped or clipped)."""
        q = as_batch(q, self.ndim)
        idx = np.floor((q - self.lower) / self.spacing).astype(np.int64)
        for i, per in enumerate(self.periodic):
            idx[:, i] = (
                np.mod(idx[:, i], self.shape[i])
                if per
                else np.clip(idx[:, i], 0, self.shape[i] - 1)
            )
        return idx

    def config_of(self, index: NDArray[np.int64]) -> FloatArray:
        """Centre configurations of cells given by integer indices ``(N, ndim)``."""
        index = np.atleast_2d(np.asarray(index))
        return np.asarray(self.lower + (index + 0.5) * self.spacing)


Method = Literal["auto", "fft", "exact"]


def free_bitmap(
    cell: ValiditySpace,
    grid: Grid,
    carrying: str | None = None,
    avoid_sources: AvoidSources = "all",
    method: Method = "auto",
) -> BoolArray:
    """Conservative bitmap of free cells (see the module docstring for the guarantee).

    Parameters
    ----------
    cell
        The workcell.
    grid
        A grid over the robot's configuration space (:meth:`Grid.for_robot`).
    carrying
        The part the robot carries, if any (equation (2)).
    avoid_sources
        Which source regions are obstacles (equations (1)-(3)).
    method
        ``"fft"`` for translating, point and rotating robots; ``"exact"`` for any;
        ``"auto"`` picks FFT where it applies.
    """
    if _method(cell, method) == "exact":
        check_memory(cell, grid, carrying, "exact")
        return ~_exact_bitmap(cell, grid, carrying, avoid_sources)
    planar = _planar(cell)
    return ~obstacle_bitmap(planar, grid, planar.obstacle_set(avoid_sources), carrying, method)


def _planar(cell: ValiditySpace) -> Workcell:
    """The FFT method's workcell: planar, with a rigid robot (:func:`_method` chose it)."""
    if not isinstance(cell, Workcell):
        raise ValueError("the FFT method applies to planar workcells only")
    return cell


def _method(cell: ValiditySpace, method: Method) -> Method:
    """``auto``: the FFT method where it applies (rigid planar robots), else exact."""
    if method == "auto":
        return "fft" if isinstance(cell.robot, RigidRobot) else "exact"
    return method


def obstacle_bitmap(
    cell: Workcell,
    grid: Grid,
    obstacles: ShapeSet,
    carrying: str | None = None,
    method: Method = "auto",
) -> BoolArray:
    """Conservative C-obstacle bitmap of an arbitrary obstacle set (include ``cell.outside``
    to keep the robot within the bounds)."""
    robot = cell.robot
    check_memory(cell, grid, carrying, method)
    method = _method(cell, method)
    if method == "fft":
        if not isinstance(robot, RigidRobot):
            raise ValueError("the FFT method applies to rigid robots only")
        return _fft_bitmap(cell, grid, obstacles, carrying)
    return _exact_obstacle_bitmap(cell, grid, obstacles, carrying)


def region_bitmap(
    cell: ValiditySpace,
    grid: Grid,
    name: str,
    kind: RegionTest = "contact",
    component: int | None = None,
    carrying: str | None = None,
) -> BoolArray:
    """Cells whose centre configuration contacts (or is enclosed in) a region."""
    return cell.in_region(grid.points(), name, kind, component, carrying).reshape(grid.shape)


# --- exact method ----------------------------------------------------------------------------


def _exact_bitmap(
    cell: ValiditySpace, grid: Grid, carrying: str | None, avoid_sources: AvoidSources
) -> BoolArray:
    """Blocked cells by the space's own conservative box test (any workcell)."""
    hit = cell.box_collides(grid.points(), grid.spacing / 2, carrying, avoid_sources)
    return hit.reshape(grid.shape)


def _exact_obstacle_bitmap(
    cell: Workcell, grid: Grid, obstacles: ShapeSet, carrying: str | None
) -> BoolArray:
    """Blocked cells against an arbitrary planar obstacle set."""
    robot = cell.robot
    half = grid.spacing / 2
    margins = list(robot.body_displacement_bounds(half))
    if carrying is not None:
        margins.append(robot.tool_displacement_bound(half, cell.part(carrying).reach()))
    q = grid.points()
    bodies, poses = cell.posed_bodies(q, carrying)
    hit = body_gaps(bodies, poses, obstacles, np.array(margins), exact=False) <= 0.0
    hit |= ~robot.within_limits(q)
    return hit.reshape(grid.shape)


# --- FFT method ------------------------------------------------------------------------------


def _robot_shape(cell: Workcell, carrying: str | None) -> ShapeSet:
    """The rigid robot (and carried part, fixed in its frame) as one local shape set."""
    shapes = list(cell.robot.bodies.bodies)
    if carrying is not None:
        shapes.append(cell.part(carrying))
    return ShapeSet.union(shapes)


def auto_supersample(grid: Grid) -> int:
    """Smallest odd refinement giving the workspace raster ``MIN_RASTER_CELLS`` cells per axis."""
    s = math.ceil(MIN_RASTER_CELLS / min(grid.shape[0], grid.shape[1]))
    return s if s % 2 == 1 else s + 1


@dataclass(frozen=True)
class _FFTSizes:
    """The rasters of :func:`_fft_bitmap` (computed once, for the bitmap and its estimate)."""

    supersample: int
    shape: ShapeSet
    reach: float
    gap: float
    box: tuple[float, float]
    fine: tuple[float, float]
    n: tuple[int, int]
    u: tuple[int, int]
    kernel: tuple[int, int]
    fft: tuple[int, int]


def _fft_sizes(
    cell: Workcell, grid: Grid, carrying: str | None, supersample: int | None = None
) -> _FFTSizes:
    if supersample is None:
        supersample = auto_supersample(grid)
    if supersample < 1 or supersample % 2 == 0:
        raise ValueError("supersample must be a positive odd integer")
    hx, hy = float(grid.spacing[0]), float(grid.spacing[1])
    fx, fy = hx / supersample, hy / supersample
    nx, ny = grid.shape[0] * supersample, grid.shape[1] * supersample
    shape = _robot_shape(cell, carrying)
    reach = shape.reach()
    gap = _ROTATION_GAP_FRACTION * min(fx, fy) if grid.ndim == 3 else 0.0
    box = (hx / 2 + fx / 2 + gap, hy / 2 + fy / 2 + gap)
    ux = math.ceil((reach + box[0]) / fx) + 1
    uy = math.ceil((reach + box[1]) / fy) + 1
    kernel = (2 * ux + 1, 2 * uy + 1)
    full = (nx + 2 * ux + kernel[0] - 1, ny + 2 * uy + kernel[1] - 1)
    fft = (sp_fft.next_fast_len(full[0], real=True), sp_fft.next_fast_len(full[1], real=True))
    return _FFTSizes(supersample, shape, reach, gap, box, (fx, fy), (nx, ny), (ux, uy), kernel, fft)


def estimate_memory(
    cell: ValiditySpace, grid: Grid, carrying: str | None = None, method: Method = "auto"
) -> int:
    """Bytes :func:`free_bitmap` allocates at its peak on ``grid`` (before allocating).

    FFT method: the obstacle raster (bool and its float32 copy), three complex64 spectra
    of the padded FFT shape (obstacle, robot, product), the float32 correlation, the
    blocked slice (bool), the output (bool, the whole grid) and its negation.
    Exact method: the cell centres (``np.meshgrid`` and the stacked copy, float64
    ``(N, d)`` twice, and the checked configurations once more), the body poses
    (float64 ``(N, B, 3)`` and as many temporaries), the gaps (float64 ``(N, B)``) and
    three bool ``(N,)`` masks. ``B`` counts the robot's bodies and the carried part.
    """
    n_total = int(np.prod(grid.shape, dtype=object))
    if _method(cell, method) == "exact":
        return cell.batch_bytes(n_total, carrying)
    sz = _fft_sizes(_planar(cell), grid, carrying)
    raster = (sz.n[0] + 2 * sz.u[0]) * (sz.n[1] + 2 * sz.u[1])
    half = sz.fft[0] * (sz.fft[1] // 2 + 1)
    slice_cells = grid.shape[0] * grid.shape[1]
    return raster * 5 + half * 8 * 3 + sz.fft[0] * sz.fft[1] * 4 + slice_cells + 2 * n_total


def check_memory(
    cell: ValiditySpace,
    grid: Grid,
    carrying: str | None = None,
    method: Method = "auto",
    field: str = "cells",
) -> None:
    """Refuse (``ArgumentError`` naming ``field`` and the cells) a bitmap that cannot fit."""
    from cellplan import budget

    budget.require(
        estimate_memory(cell, grid, carrying, method),
        f"{field} " + ",".join(str(n) for n in grid.shape),
        "for the C-space bitmap",
    )


def _fft_bitmap(
    cell: Workcell,
    grid: Grid,
    obstacles: ShapeSet,
    carrying: str | None,
    supersample: int | None = None,
) -> BoolArray:
    """Kavraki's FFT C-obstacles on a workspace raster ``supersample`` times finer than the grid.

    With fine spacing ``f = h / s`` (odd ``s``, so each C-cell centre is a fine cell
    centre), a C-cell is blocked iff some fine offset cell ``u`` is marked in both
    the obstacle raster (the obstacle meets the fine cell) and the robot raster
    (the robot meets the box of half-width ``h/2 + f/2`` around offset ``u``, i.e.
    the robot swept over the C-cell meets that fine cell). The over-approximation
    beyond the cell box itself is one fine cell; ``supersample=1`` is Kavraki's
    plain method, ``None`` picks :func:`auto_supersample`.
    """
    sz = _fft_sizes(cell, grid, carrying, supersample)
    supersample, shape, reach, gap, box = sz.supersample, sz.shape, sz.reach, sz.gap, sz.box
    fx, fy = sz.fine
    nx, ny = sz.n
    ux, uy = sz.u
    kernel_shape, fft_shape = sz.kernel, sz.fft
    rotating = grid.ndim == 3

    origin = (grid.lower[0] + (0.5 - ux) * fx, grid.lower[1] + (0.5 - uy) * fy)
    obstacle_raster = raster_touching(
        obstacles, origin, (fx, fy), (nx + 2 * ux, ny + 2 * uy), (fx / 2, fy / 2)
    )
    # The obstacle spectrum is shared by every robot raster (slices, carried parts).
    obstacle_spectrum = sp_fft.rfft2(obstacle_raster.astype(np.float32), fft_shape, workers=-1)
    centre = (supersample - 1) // 2

    def blocked_for(robot_shapes: ShapeSet) -> BoolArray:
        raster = raster_touching(robot_shapes, (-ux * fx, -uy * fy), (fx, fy), kernel_shape, box)
        # correlation: blocked[a] = sum_u R[u] * O[a + u]  (convolution with the flipped raster)
        spectrum = sp_fft.rfft2(raster[::-1, ::-1].astype(np.float32), fft_shape, workers=-1)
        conv = sp_fft.irfft2(obstacle_spectrum * spectrum, fft_shape, workers=-1)
        valid = conv[
            kernel_shape[0] - 1 : kernel_shape[0] - 1 + nx,
            kernel_shape[1] - 1 : kernel_shape[1] - 1 + ny,
        ]
        return np.asarray(valid[centre::supersample, centre::supersample] > 0.5)

    if not rotating:
        return blocked_for(shape)

    hth = float(grid.spacing[2])
    # Orientation samples per slice: consecutive samples move no point more than 2 * gap.
    n_sub = max(2, math.ceil(reach * hth / (2 * gap)) + 1) if reach > 0 else 1
    out = np.empty(grid.shape, bool)
    for k in range(grid.shape[2]):
        theta_c = grid.lower[2] + (k + 0.5) * hth
        angles = theta_c + np.linspace(-hth / 2, hth / 2, n_sub)
        swept = ShapeSet.union(shape.transformed((0.0, 0.0, a)) for a in angles)
        out[:, :, k] = blocked_for(swept)
    return out

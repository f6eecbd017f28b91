"""Planar geometry: rigid transforms, shape sets, and exact batched collision and distance.

A :class:`ShapeSet` is a union of convex polygons and discs given in a local
frame. Non-convex polygons are split into triangles (constrained Delaunay), so
every primitive is convex and the tests below are exact:

* polygon / polygon: separating axes (edge normals of both; a segment adds its
  direction) - two closed convex sets are disjoint iff some axis separates them;
* disc / polygon: distance from the centre to the polygon against the radius;
* disc / disc: distance between centres against the sum of radii.

Touching counts as contact (the sets are closed), matching ``shapely.intersects``.

The kernels take a batch of ``N`` configurations as poses of rigid bodies
``(N, B, 3)`` and loop over configurations in compiled code (numba, run in
parallel), so no Python loop over configurations or primitive pairs remains.
Distances use the fact that two disjoint convex polygons are closest at a
vertex of one of them, which makes vertex-to-edge distances exact.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

# Inscribed polygon used where a disc must be approximated by polygons (enclosure
# complements); inscribed, so "inside the polygon" implies "inside the disc".
DISC_POLYGON_SEGMENTS = 64


# --- transforms ------------------------------------------------------------------------------


def transform_points(points: FloatArray, poses: FloatArray) -> FloatArray:
    """Apply poses ``(..., 3)`` = ``(x, y, theta)`` to local points ``(K, 2)``.

    Returns an array of shape ``poses.shape[:-1] + (K, 2)``.
    """
    points = np.asarray(points, dtype=float)
    poses = np.asarray(poses, dtype=float)
    c = np.cos(poses[..., 2])[..., None]
    s = np.sin(poses[..., 2])[..., None]
    x = poses[..., 0, None] + c * points[:, 0] - s * points[:, 1]
    y = poses[..., 1, None] + s * points[:, 0] + c * points[:, 1]
    return np.stack([x, y], axis=-1)


def compose(a: FloatArray, b: FloatArray) -> FloatArray:
    """Pose composition ``a * b`` for broadcastable pose arrays ``(..., 3)``."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            a[..., 2] + b[..., 2],
        ],
        axis=-1,
    )


def wrap_angle(theta: FloatArray | float) -> FloatArray:
    """Wrap angles to (-pi, pi]."""
    wrapped = np.pi - np.mod(np.pi - np.asarray(theta, dtype=float), 2 * np.pi)
    return np.asarray(wrapped)


# --- shape sets ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ShapeSet:
    """A union of convex polygons and discs in one frame.

    Attributes
    ----------
    verts
        ``(M, K, 2)`` polygon vertices, counter-clockwise, padded with zeros past
        ``counts[m]``. A count of 1 is a point, 2 a segment.
    counts
        ``(M,)`` number of vertices of each polygon.
    centres, radii
        ``(D, 2)`` and ``(D,)`` discs.
    """

    verts: FloatArray
    counts: NDArray[np.int64]
    centres: FloatArray
    radii: FloatArray

    @staticmethod
    def empty() -> ShapeSet:
        return ShapeSet(np.zeros((0, 3, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0))

    @staticmethod
    def from_polygons(polygons: Sequence[FloatArray]) -> ShapeSet:
        """From convex vertex lists (any winding; points and segments allowed)."""
        if not polygons:
            return ShapeSet.empty()
        k = max(3, max(len(p) for p in polygons))
        verts = np.zeros((len(polygons), k, 2))
        counts = np.zeros(len(polygons), np.int64)
        for i, p in enumerate(polygons):
            p = np.asarray(p, dtype=float).reshape(-1, 2)
            if len(p) >= 3 and _signed_area(p) < 0:
                p = p[::-1]
            verts[i, : len(p)] = p
            counts[i] = len(p)
        return ShapeSet(verts, counts, np.zeros((0, 2)), np.zeros(0))

    @staticmethod
    def point(x: float = 0.0, y: float = 0.0) -> ShapeSet:
        return ShapeSet.from_polygons([np.array([[x, y]])])

    @staticmethod
    def disc(centre: Sequence[float], radius: float) -> ShapeSet:
        return ShapeSet(
            np.zeros((0, 3, 2)),
            np.zeros(0, np.int64),
            np.array([centre], float),
            np.array([radius], float),
        )

    @staticmethod
    def from_geometry(geom: BaseGeometry) -> ShapeSet:
        """From a shapely (multi)polygon: convex pieces kept whole, others triangulated."""
        pieces: list[FloatArray] = []
        for poly in _polygons_of(geom):
            pieces.extend(convex_pieces(poly))
        return ShapeSet.from_polygons(pieces)

    @staticmethod
    def from_spec(spec: object) -> ShapeSet:
        """From a scenario shape (:mod:`cellplan.schema`): discs stay exact discs."""
        if getattr(spec, "type", None) == "disc":
            return ShapeSet.disc(spec.center, spec.radius)  # type: ignore[attr-defined]
        return ShapeSet.from_geometry(spec.to_shapely())  # type: ignore[attr-defined]

    @staticmethod
    def union(sets: Iterable[ShapeSet]) -> ShapeSet:
        """Concatenate shape sets (the union of the regions they describe)."""
        sets = [s for s in sets if s.n_polygons or s.n_discs]
        if not sets:
            return ShapeSet.empty()
        k = max(s.verts.shape[1] for s in sets)
        verts = np.zeros((sum(s.n_polygons for s in sets), k, 2))
        start = 0
        for s in sets:
            verts[start : start + s.n_polygons, : s.verts.shape[1]] = s.verts
            start += s.n_polygons
        return ShapeSet(
            verts,
            np.concatenate([s.counts for s in sets]),
            np.concatenate([s.centres for s in sets]),
            np.concatenate([s.radii for s in sets]),
        )

    @property
    def n_polygons(self) -> int:
        return int(self.counts.shape[0])

    @property
    def n_discs(self) -> int:
        return int(self.radii.shape[0])

    def transformed(self, pose: Sequence[float]) -> ShapeSet:
        """This set moved by one pose ``(x, y, theta)``."""
        pose_arr = np.asarray(pose, dtype=float)
        verts = transform_points(self.verts.reshape(-1, 2), pose_arr).reshape(self.verts.shape)
        for i, n in enumerate(self.counts):
            verts[i, n:] = 0.0
        centres = transform_points(self.centres, pose_arr) if self.n_discs else self.centres
        return ShapeSet(verts, self.counts, centres, self.radii)

    def reach(self) -> float:
        """Largest distance of any point of the set from the frame origin."""
        r = 0.0
        if self.n_polygons:
            mask = np.arange(self.verts.shape[1])[None, :] < self.counts[:, None]
            r = float(np.max(np.linalg.norm(self.verts, axis=-1)[mask]))
        if self.n_discs:
            r = max(r, float(np.max(np.linalg.norm(self.centres, axis=-1) + self.radii)))
        return r

    def to_shapely(self, disc_segments: int = DISC_POLYGON_SEGMENTS) -> BaseGeometry:
        """The set as one shapely geometry (discs as inscribed polygons); for drawing and tests."""
        parts: list[BaseGeometry] = []
        for i, n in enumerate(self.counts):
            v = self.verts[i, :n]
            if n >= 3:
                parts.append(shapely.Polygon(v))
            elif n == 2:
                parts.append(shapely.LineString(v))
            else:
                parts.append(shapely.Point(v[0]))
        for c, r in zip(self.centres, self.radii, strict=True):
            parts.append(shapely.Point(c).buffer(r, quad_segs=max(1, disc_segments // 4)))
        return shapely.union_all(parts) if parts else shapely.GeometryCollection()


def _signed_area(p: FloatArray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _polygons_of(geom: BaseGeometry) -> list[shapely.Polygon]:
    if isinstance(geom, shapely.Polygon):
        return [geom] if not geom.is_empty else []
    if hasattr(geom, "geoms"):
        return [p for g in geom.geoms for p in _polygons_of(g)]
    return []


def convex_pieces(poly: shapely.Polygon) -> list[FloatArray]:
    """Split a simple polygon (holes allowed) into convex vertex arrays.

    A convex polygon is returned whole (collinear vertices removed); anything
    else is triangulated by shapely's constrained Delaunay triangulation, which
    respects the polygon's edges and holes.
    """
    poly = shapely.Polygon(poly.exterior.coords, [r.coords for r in poly.interiors]).simplify(0.0)
    if poly.is_empty:
        return []
    if not poly.interiors and abs(poly.convex_hull.area - poly.area) <= 1e-12 * max(1.0, poly.area):
        return [np.asarray(poly.exterior.coords)[:-1]]
    tris = shapely.constrained_delaunay_triangles(poly)
    return [np.asarray(t.exterior.coords)[:-1] for t in tris.geoms if t.area > 0]


def frame_outside(bounds: tuple[float, float, float, float], thickness: float) -> ShapeSet:
    """Four boxes around a rectangle: its outside, up to ``thickness`` away."""
    xmin, ymin, xmax, ymax = bounds
    t = thickness
    boxes = [
        (xmin - t, ymin - t, xmin, ymax + t),
        (xmax, ymin - t, xmax + t, ymax + t),
        (xmin - t, ymin - t, xmax + t, ymin),
        (xmin - t, ymax, xmax + t, ymax + t),
    ]
    return ShapeSet.from_polygons(
        [np.array([[a, b], [c, b], [c, d], [a, d]], float) for a, b, c, d in boxes]
    )


def complement_within(region: ShapeSet, box: tuple[float, float, float, float]) -> ShapeSet:
    """``box`` minus ``region``, as convex pieces (discs via inscribed polygons).

    Enclosure tests use it: a body lies inside ``region`` iff it lies in ``box``
    and does not meet the complement's interior. Touching the region's boundary
    from inside therefore counts as leaving it (the test is strict).
    """
    geom = shapely.box(*box).difference(region.to_shapely())
    return ShapeSet.from_geometry(geom)


# --- numba kernels ---------------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def _project(
    vx: NDArray[np.float64], vy: NDArray[np.float64], n: int, ax: float, ay: float
) -> tuple[float, float]:
    lo = vx[0] * ax + vy[0] * ay
    hi = lo
    for i in range(1, n):
        p = vx[i] * ax + vy[i] * ay
        if p < lo:
            lo = p
        elif p > hi:
            hi = p
    return lo, hi


@nb.njit(cache=True)
def _separated_on_edges(
    ax_: NDArray[np.float64],
    ay_: NDArray[np.float64],
    na: int,
    bx: NDArray[np.float64],
    by: NDArray[np.float64],
    nb_: int,
) -> bool:
    # Axes from the edges of A (normals; for a segment also its direction).
    if na == 1:
        return False
    m = na if na >= 3 else 1
    for i in range(m):
        j = (i + 1) % na
        ex = ax_[j] - ax_[i]
        ey = ay_[j] - ay_[i]
        nx, ny = -ey, ex
        lo_a, hi_a = _project(ax_, ay_, na, nx, ny)
        lo_b, hi_b = _project(bx, by, nb_, nx, ny)
        if hi_a < lo_b or hi_b < lo_a:
            return True
        if na == 2:
            lo_a, hi_a = _project(ax_, ay_, na, ex, ey)
            lo_b, hi_b = _project(bx, by, nb_, ex, ey)
            if hi_a < lo_b or hi_b < lo_a:
                return True
    return False


@nb.njit(cache=True)
def _polygons_overlap(
    ax_: NDArray[np.float64],
    ay_: NDArray[np.float64],
    na: int,
    bx: NDArray[np.float64],
    by: NDArray[np.float64],
    nb_: int,
) -> bool:
    if _separated_on_edges(ax_, ay_, na, bx, by, nb_):
        return False
    if _separated_on_edges(bx, by, nb_, ax_, ay_, na):
        return False
    if na == 1 and nb_ == 1:
        return ax_[0] == bx[0] and ay_[0] == by[0]
    return True


@nb.njit(cache=True, inline="always")
def _point_segment_dist(px: float, py: float, x0: float, y0: float, x1: float, y1: float) -> float:
    dx = x1 - x0
    dy = y1 - y0
    ll = dx * dx + dy * dy
    t = 0.0
    if ll > 0.0:
        t = ((px - x0) * dx + (py - y0) * dy) / ll
        t = min(1.0, max(0.0, t))
    ex = x0 + t * dx - px
    ey = y0 + t * dy - py
    return math.sqrt(ex * ex + ey * ey)


@nb.njit(cache=True)
def _point_polygon_dist(
    px: float, py: float, vx: NDArray[np.float64], vy: NDArray[np.float64], n: int
) -> float:
    """Distance from a point to a convex CCW polygon (0 inside)."""
    if n == 1:
        return math.hypot(px - vx[0], py - vy[0])
    if n == 2:
        return _point_segment_dist(px, py, vx[0], vy[0], vx[1], vy[1])
    inside = True
    best = np.inf
    for i in range(n):
        j = (i + 1) % n
        cross = (vx[j] - vx[i]) * (py - vy[i]) - (vy[j] - vy[i]) * (px - vx[i])
        if cross < 0.0:
            inside = False
        d = _point_segment_dist(px, py, vx[i], vy[i], vx[j], vy[j])
        if d < best:
            best = d
    return 0.0 if inside else best


@nb.njit(cache=True)
def _polygon_distance(
    ax_: NDArray[np.float64],
    ay_: NDArray[np.float64],
    na: int,
    bx: NDArray[np.float64],
    by: NDArray[np.float64],
    nb_: int,
) -> float:
    """Distance between two convex polygons (0 when they overlap)."""
    if _polygons_overlap(ax_, ay_, na, bx, by, nb_):
        return 0.0
    best = np.inf
    for i in range(na):
        d = _point_polygon_dist(ax_[i], ay_[i], bx, by, nb_)
        if d < best:
            best = d
    for i in range(nb_):
        d = _point_polygon_dist(bx[i], by[i], ax_, ay_, na)
        if d < best:
            best = d
    return best


def _gap_impl(
    poses: NDArray[np.float64],  # (N, B, 3)
    pv: NDArray[np.float64],  # (P, K, 2) robot polygons, local
    pc: NDArray[np.int64],  # (P,)
    pb: NDArray[np.int64],  # (P,) body of each polygon
    dc: NDArray[np.float64],  # (Dr, 2) robot discs, local
    dr: NDArray[np.float64],  # (Dr,)
    db: NDArray[np.int64],  # (Dr,)
    margin: NDArray[np.float64],  # (B,) clearance each body must keep
    ov: NDArray[np.float64],  # (M, Ko, 2) obstacle polygons, world
    oc: NDArray[np.int64],  # (M,)
    obox: NDArray[np.float64],  # (M, 4) their bounding boxes
    odc: NDArray[np.float64],  # (Do, 2) obstacle discs
    odr: NDArray[np.float64],  # (Do,)
    exact: bool,  # False: stop at the first contact (a boolean test)
) -> NDArray[np.float64]:
    """Smallest (distance - margin) between the posed robot and the obstacles, per pose.

    With ``exact=False`` the value is only guaranteed to have the right sign
    (<= 0 means contact within the margin); the scan stops at the first contact
    and skips pairs whose bounding boxes are farther apart than the margin.
    """
    n_cfg = poses.shape[0]
    out = np.empty(n_cfg)
    kmax = pv.shape[1]
    for q in nb.prange(n_cfg):
        # Strided views, as the obstacles' ov[m, :, 0] are: the polygon helpers then see
        # one array layout and numba compiles each once (issue 34, first run)
        w = np.empty((kmax, 2))
        wx = w[:, 0]
        wy = w[:, 1]
        best = np.inf
        done = False
        for p in range(pv.shape[0]):
            if done:
                break
            b = pb[p]
            x0 = poses[q, b, 0]
            y0 = poses[q, b, 1]
            c = math.cos(poses[q, b, 2])
            s = math.sin(poses[q, b, 2])
            n = pc[p]
            xmin = np.inf
            xmax = -np.inf
            ymin = np.inf
            ymax = -np.inf
            for i in range(n):
                lx = pv[p, i, 0]
                ly = pv[p, i, 1]
                wx[i] = x0 + c * lx - s * ly
                wy[i] = y0 + s * lx + c * ly
                xmin = min(xmin, wx[i])
                xmax = max(xmax, wx[i])
                ymin = min(ymin, wy[i])
                ymax = max(ymax, wy[i])
            m_b = margin[b]
            for m in range(ov.shape[0]):
                gx = max(obox[m, 0] - xmax, xmin - obox[m, 2])
                gy = max(obox[m, 1] - ymax, ymin - obox[m, 3])
                box_gap = max(gx, gy, 0.0) - m_b
                if box_gap > 0.0 and (not exact or box_gap >= best):
                    continue
                if not exact and m_b == 0.0:
                    if _polygons_overlap(wx, wy, n, ov[m, :, 0], ov[m, :, 1], oc[m]):
                        best = -1.0
                        done = True
                        break
                    continue
                d = _polygon_distance(wx, wy, n, ov[m, :, 0], ov[m, :, 1], oc[m]) - m_b
                if d < best:
                    best = d
                    if best <= 0.0 and not exact:
                        done = True
                        break
            if done:
                break
            for m in range(odc.shape[0]):
                d = _point_polygon_dist(odc[m, 0], odc[m, 1], wx, wy, n) - odr[m] - m_b
                if d < best:
                    best = d
                    if best <= 0.0 and not exact:
                        done = True
                        break
        for k in range(dc.shape[0]):
            if done:
                break
            b = db[k]
            c = math.cos(poses[q, b, 2])
            s = math.sin(poses[q, b, 2])
            cx = poses[q, b, 0] + c * dc[k, 0] - s * dc[k, 1]
            cy = poses[q, b, 1] + s * dc[k, 0] + c * dc[k, 1]
            m_b = margin[b]
            for m in range(ov.shape[0]):
                d = _point_polygon_dist(cx, cy, ov[m, :, 0], ov[m, :, 1], oc[m]) - dr[k] - m_b
                if d < best:
                    best = d
                    if best <= 0.0 and not exact:
                        done = True
                        break
            for m in range(odc.shape[0]):
                if done:
                    break
                d = math.hypot(cx - odc[m, 0], cy - odc[m, 1]) - dr[k] - odr[m] - m_b
                if d < best:
                    best = d
                    if best <= 0.0 and not exact:
                        done = True
        out[q] = best
    return out


# Small batches run serially: thread start-up would cost more than the work.
_gap_serial = nb.njit(cache=True)(_gap_impl)
_gap_parallel = nb.njit(cache=True, parallel=True)(_gap_impl)
PARALLEL_THRESHOLD = 4096


@nb.njit(cache=True)
def _raster_kernel(
    pv: NDArray[np.float64],
    pc: NDArray[np.int64],
    dc: NDArray[np.float64],
    dr: NDArray[np.float64],
    x0: float,
    y0: float,
    fx: float,
    fy: float,
    nx: int,
    ny: int,
    hx: float,
    hy: float,
) -> NDArray[np.bool_]:
    out = np.zeros((nx, ny), np.bool_)
    # Strided views, as pv[m, :, 0] is: one layout, so one compile of the helpers
    b4 = np.empty((4, 2))
    bx = b4[:, 0]
    by = b4[:, 1]
    for m in range(pv.shape[0]):
        n = pc[m]
        xmin = pv[m, 0, 0]
        xmax = xmin
        ymin = pv[m, 0, 1]
        ymax = ymin
        for i in range(1, n):
            xmin = min(xmin, pv[m, i, 0])
            xmax = max(xmax, pv[m, i, 0])
            ymin = min(ymin, pv[m, i, 1])
            ymax = max(ymax, pv[m, i, 1])
        a0 = max(0, int(math.floor((xmin - hx - x0) / fx)))
        a1 = min(nx - 1, int(math.ceil((xmax + hx - x0) / fx)))
        b0 = max(0, int(math.floor((ymin - hy - y0) / fy)))
        b1 = min(ny - 1, int(math.ceil((ymax + hy - y0) / fy)))
        for a in range(a0, a1 + 1):
            cx = x0 + a * fx
            for b in range(b0, b1 + 1):
                if out[a, b]:
                    continue
                cy = y0 + b * fy
                bx[0] = cx - hx
                bx[1] = cx + hx
                bx[2] = cx + hx
                bx[3] = cx - hx
                by[0] = cy - hy
                by[1] = cy - hy
                by[2] = cy + hy
                by[3] = cy + hy
                # bx.shape[0], not the literal 4: a literal argument makes numba compile
                # _polygons_overlap a second time, for no gain (issue 34, first run)
                if _polygons_overlap(bx, by, bx.shape[0], pv[m, :, 0], pv[m, :, 1], n):
                    out[a, b] = True
    for k in range(dc.shape[0]):
        r = dr[k]
        a0 = max(0, int(math.floor((dc[k, 0] - r - hx - x0) / fx)))
        a1 = min(nx - 1, int(math.ceil((dc[k, 0] + r + hx - x0) / fx)))
        b0 = max(0, int(math.floor((dc[k, 1] - r - hy - y0) / fy)))
        b1 = min(ny - 1, int(math.ceil((dc[k, 1] + r + hy - y0) / fy)))
        for a in range(a0, a1 + 1):
            cx = x0 + a * fx
            ex = max(abs(dc[k, 0] - cx) - hx, 0.0)
            for b in range(b0, b1 + 1):
                cy = y0 + b * fy
                ey = max(abs(dc[k, 1] - cy) - hy, 0.0)
                if ex * ex + ey * ey <= r * r:
                    out[a, b] = True
    return out


def raster_touching(
    shapes: ShapeSet,
    origin: tuple[float, float],
    step: tuple[float, float],
    shape: tuple[int, int],
    half: tuple[float, float],
) -> BoolArray:
    """Raster of the closed boxes that meet ``shapes``.

    Box ``(a, b)`` is centred at ``origin + (a, b) * step`` with half-widths
    ``half``; the work is proportional to the boxes inside each primitive's
    bounding box, not to the whole raster.
    """
    return _raster_kernel(
        np.ascontiguousarray(shapes.verts),
        shapes.counts,
        shapes.centres,
        shapes.radii,
        float(origin[0]),
        float(origin[1]),
        float(step[0]),
        float(step[1]),
        int(shape[0]),
        int(shape[1]),
        float(half[0]),
        float(half[1]),
    )


# --- public batched queries ------------------------------------------------------------------


@dataclass(frozen=True)
class RigidBodies:
    """Robot geometry as bodies: one local :class:`ShapeSet` per body.

    The kernels see all polygons and discs flattened, each tagged with its body,
    so one array of poses ``(N, B, 3)`` places everything at once.
    """

    bodies: tuple[ShapeSet, ...]

    @functools.cached_property
    def flat(
        self,
    ) -> tuple[
        FloatArray, NDArray[np.int64], NDArray[np.int64], FloatArray, FloatArray, NDArray[np.int64]
    ]:
        merged = ShapeSet.union(self.bodies)
        poly_body = np.concatenate(
            [np.full(s.n_polygons, i, np.int64) for i, s in enumerate(self.bodies)]
            or [np.zeros(0, np.int64)]
        )
        disc_body = np.concatenate(
            [np.full(s.n_discs, i, np.int64) for i, s in enumerate(self.bodies)]
            or [np.zeros(0, np.int64)]
        )
        return merged.verts, merged.counts, poly_body, merged.centres, merged.radii, disc_body


@dataclass(frozen=True)
class Obstacles:
    """A fixed world-frame :class:`ShapeSet` prepared for the kernels (bounding boxes)."""

    shapes: ShapeSet

    @functools.cached_property
    def boxes(self) -> FloatArray:
        s = self.shapes
        if s.n_polygons == 0:
            return np.zeros((0, 4))
        mask = np.arange(s.verts.shape[1])[None, :] < s.counts[:, None]
        x = np.where(mask, s.verts[..., 0], np.nan)
        y = np.where(mask, s.verts[..., 1], np.nan)
        return np.stack(
            [np.nanmin(x, 1), np.nanmin(y, 1), np.nanmax(x, 1), np.nanmax(y, 1)], axis=1
        )


def body_gaps(
    bodies: RigidBodies,
    poses: FloatArray,
    obstacles: ShapeSet | Obstacles,
    margins: FloatArray | None = None,
    exact: bool = True,
) -> FloatArray:
    """Per pose: smallest distance from the posed bodies to ``obstacles``, minus each body's margin.

    Parameters
    ----------
    bodies
        The robot's bodies in their local frames.
    poses
        ``(N, B, 3)`` pose of every body for each of ``N`` configurations.
    obstacles
        World-frame shapes (wrap them in :class:`Obstacles` once to reuse the
        prepared bounding boxes across calls).
    margins
        ``(B,)`` clearance each body must keep (default 0).
    exact
        True: the true signed value (0 or less on contact). False: only its sign
        is meaningful, which is faster (early exit).

    Returns
    -------
    ``(N,)`` array; ``inf`` when there are no obstacles.
    """
    poses = np.ascontiguousarray(poses, dtype=float)
    if poses.ndim != 3 or poses.shape[1] != len(bodies.bodies) or poses.shape[2] != 3:
        raise ValueError(f"poses must be (N, {len(bodies.bodies)}, 3), got {poses.shape}")
    # A fresh contiguous array: numba handles read-only broadcast views very slowly.
    margin_arr = np.zeros(len(bodies.bodies)) if margins is None else np.array(margins, dtype=float)
    pv, pc, pb, dc, dr, db = bodies.flat
    prepared = obstacles if isinstance(obstacles, Obstacles) else Obstacles(obstacles)
    o = prepared.shapes
    kernel = _gap_parallel if len(poses) >= PARALLEL_THRESHOLD else _gap_serial
    return kernel(
        poses,
        pv,
        pc,
        pb,
        dc,
        dr,
        db,
        margin_arr,
        o.verts,
        o.counts,
        prepared.boxes,
        o.centres,
        o.radii,
        exact,
    )


def bodies_collide(
    bodies: RigidBodies,
    poses: FloatArray,
    obstacles: ShapeSet | Obstacles,
    margins: FloatArray | None = None,
) -> BoolArray:
    """Per pose: do the posed bodies touch ``obstacles`` (within ``margins``)?"""
    return body_gaps(bodies, poses, obstacles, margins, exact=False) <= 0.0

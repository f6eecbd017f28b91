"""The workcell model: robot, obstacles, parts, sources and destinations, with batched queries.

Built from a validated :class:`~cellplan.scenario.Scenario` by
:meth:`Workcell.from_scenario`, which also checks what needs geometry (the
start configuration must be collision-free and inside the bounds).

Which obstacles count depends on the assembly mode (strategies paper,
equations (1)-(3)): in NR every source region is an obstacle; while waiting for
or carrying a part from source s, every *other* source is. ``avoid_sources``
selects this: ``"all"``, ``"none"``, or the names of the sources to avoid
(:meth:`Workcell.sources_except` builds the latter). The workcell's outside
always counts as an obstacle: robots stay inside the bounds.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

from cellplan import budget, units
from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.geometry import (
    BoolArray,
    FloatArray,
    Obstacles,
    RigidBodies,
    ShapeSet,
    body_gaps,
    complement_within,
    frame_outside,
)
from cellplan.robots import PlanarArm, Robot, robot_from_spec
from cellplan.scenario import Scenario, load_scenario
from cellplan.scenario3d import planar, planar_workcell
from cellplan.schema import COORD_LIMIT
from cellplan.validity import AvoidSources, RegionTest, avoided_sources

IntArray = NDArray[np.int64]

DEFAULT_CELLS = {"point": (128, 128), "translating": (128, 128), "rotating": (64, 64, 32)}
DEFAULT_ARM_CELLS_PER_JOINT = 64

MAX_MOTION_SAMPLES = 2**40
"""Most samples one :meth:`Workcell.motion_collides` call may check, whatever memory says.

It keeps every count exact in float64 and int64 (a step of 1e-300 once made
``ceil(travel / step)`` wrap to a negative int64 and the motion through a wall pass as
free); below it, the memory estimate (:func:`cellplan.budget.require`) decides."""

_MOTION_BYTES_UNCHECKED = 16 * 2**20
"""Motion checks estimated below this many bytes skip the memory check: asking the system
(:func:`cellplan.budget.available_memory` reads ``/proc``) takes about 90 us, longer
than a short motion's whole check, and 16 MiB fits wherever cellplan runs."""


@dataclass(frozen=True)
class Region:
    """A source or destination: disjoint components, each a :class:`ShapeSet`."""

    name: str
    role: Literal["source", "destination"]
    components: tuple[ShapeSet, ...]
    geometries: tuple[BaseGeometry, ...]
    complements: tuple[ShapeSet, ...]

    @property
    def shapes(self) -> ShapeSet:
        """All components as one set."""
        return ShapeSet.union(self.components)


def cell_repr(
    kind: str,
    name: str,
    robot: str,
    bounds: str,
    obstacles: Mapping[str, Any],
    parts: Mapping[str, Any],
    sources: Mapping[str, int],
    destinations: Mapping[str, int],
) -> str:
    """The repr of a workcell (2-D or 3-D): names and counts, never arrays.

    ``sources`` and ``destinations`` map each region to its number of components; empty
    groups are left out.
    """

    def names(items: Mapping[str, Any]) -> str:
        return "[" + ", ".join(items) + "]"

    def regions(items: Mapping[str, int]) -> str:
        return "[" + ", ".join(f"{n} ({c})" for n, c in items.items()) + "]"

    fields = [repr(name), f"robot={robot}", f"bounds={bounds}"]
    fields += [f"obstacles={names(obstacles)}"] if obstacles else []
    fields += [f"parts={names(parts)}"] if parts else []
    fields += [f"sources={regions(sources)}"] if sources else []
    fields += [f"destinations={regions(destinations)}"] if destinations else []
    return f"{kind}({', '.join(fields)})"


@dataclass(frozen=True)
class Workcell:
    """A workcell: bounds, named obstacles, one robot, parts, sources, destinations."""

    name: str
    bounds: tuple[float, float, float, float]
    obstacles: Mapping[str, ShapeSet]
    obstacle_geometries: Mapping[str, BaseGeometry]
    robot: Robot
    parts: Mapping[str, ShapeSet]
    part_geometries: Mapping[str, BaseGeometry]
    sources: Mapping[str, Region]
    destinations: Mapping[str, Region]
    default_cells: tuple[int, ...]
    outside: ShapeSet
    extent: tuple[float, float, float, float]
    # Memo of prepared obstacle sets by avoided sources; derived data, never part of equality.
    _obstacle_cache: dict[tuple[tuple[str, ...], bool], Obstacles] = field(
        default_factory=dict, compare=False, repr=False
    )
    # Memo of the robot's bodies with each carried part (their flattened arrays are cached).
    _carrying_cache: dict[str, RigidBodies] = field(default_factory=dict, compare=False, repr=False)

    # --- construction ------------------------------------------------------------------------

    @staticmethod
    def from_scenario(sc: Scenario) -> Workcell:
        """Build the model; raises :class:`ScenarioError` if the start is not free."""
        if sc.robot is None:
            raise ScenarioError(
                [Problem("robot", "this scenario has no robot; a workcell model needs one")]
            )
        spec = planar_workcell(sc)
        b = spec.bounds
        bounds = (b.xmin, b.ymin, b.xmax, b.ymax)
        robot = robot_from_spec(sc.robot, bounds)
        parts = {name: ShapeSet.from_spec(planar(p.shape)) for name, p in sc.parts.items()}
        reach = _robot_reach(robot) + max([p.reach() for p in parts.values()] + [0.0])
        pad = reach + max(b.xmax - b.xmin, b.ymax - b.ymin) + 1.0
        extent = (b.xmin - pad, b.ymin - pad, b.xmax + pad, b.ymax + pad)

        def region(name: str, role: Literal["source", "destination"], spec: object) -> Region:
            shapes = [planar(c) for c in spec.components]  # type: ignore[attr-defined]
            comps = tuple(ShapeSet.from_spec(c) for c in shapes)
            geoms = tuple(c.to_shapely() for c in shapes)
            return Region(
                name, role, comps, geoms, tuple(complement_within(c, extent) for c in comps)
            )

        cells = tuple(sc.cspace.cells) if sc.cspace.cells else default_cells(robot)
        cell = Workcell(
            name=sc.name,
            bounds=bounds,
            obstacles={n: ShapeSet.from_spec(s) for n, s in spec.planar_obstacles.items()},
            obstacle_geometries={n: s.to_shapely() for n, s in spec.planar_obstacles.items()},
            robot=robot,
            parts=parts,
            part_geometries={n: planar(p.shape).to_shapely() for n, p in sc.parts.items()},
            sources={n: region(n, "source", r) for n, r in sc.sources.items()},
            destinations={n: region(n, "destination", r) for n, r in sc.destinations.items()},
            default_cells=cells,
            outside=frame_outside(bounds, pad),
            extent=extent,
        )
        cell.check_start()
        return cell

    def check_start(self) -> None:
        """Raise a :class:`ScenarioError` naming what the start configuration hits."""
        q = self.robot.start[None, :]
        shown = (
            "(" + ", ".join(f"{v:.4g}" for v in _display_config(self.robot, self.robot.start)) + ")"
        )
        problems = []
        if not self.robot.within_limits(q)[0]:
            problems.append(
                Problem("robot.start", f"configuration {shown} violates the joint limits")
            )
        bodies, poses = self.posed_bodies(q, None)
        if _gap(bodies, poses, self.outside)[0] <= 0:
            problems.append(
                Problem("robot.start", f"configuration {shown} leaves the workcell bounds")
            )
        for name, obs in self.obstacles.items():
            if _gap(bodies, poses, obs)[0] <= 0:
                problems.append(
                    Problem("robot.start", f"configuration {shown} collides with obstacle '{name}'")
                )
        if problems:
            raise ScenarioError(problems)

    def with_obstacles(self, obstacles: Mapping[str, ShapeSet]) -> Workcell:
        """A copy of this workcell with another set of named obstacles (environment changes).

        The start configuration is not re-checked: a changed workcell may well
        block where the robot once started.
        """
        return dataclasses.replace(
            self,
            obstacles=dict(obstacles),
            obstacle_geometries={n: s.to_shapely() for n, s in obstacles.items()},
            _obstacle_cache={},
        )

    # --- obstacle sets -----------------------------------------------------------------------

    def sources_except(self, source: str | None) -> list[str]:
        """Names of the sources to avoid while serving ``source`` (equations (1)-(2))."""
        return [s for s in self.sources if s != source]

    def obstacle_set(
        self, avoid_sources: AvoidSources = "all", include_outside: bool = True
    ) -> ShapeSet:
        """Static obstacles, the chosen sources, and (by default) the outside of the bounds."""
        return self.prepared_obstacles(avoid_sources, include_outside).shapes

    def prepared_obstacles(
        self, avoid_sources: AvoidSources = "all", include_outside: bool = True
    ) -> Obstacles:
        """:meth:`obstacle_set` prepared for the kernels, memoised per choice of sources."""
        key = (tuple(self._avoided(avoid_sources)), include_outside)
        if key not in self._obstacle_cache:
            sets = list(self.obstacles.values())
            sets += [self.sources[s].shapes for s in key[0]]
            if include_outside:
                sets.append(self.outside)
            self._obstacle_cache[key] = Obstacles(ShapeSet.union(sets))
        return self._obstacle_cache[key]

    def _avoided(self, avoid_sources: AvoidSources) -> list[str]:
        return avoided_sources(avoid_sources, self.sources)

    # --- batched queries ---------------------------------------------------------------------

    def configurations(self, q: FloatArray, name: str = "q") -> FloatArray:
        """``q`` as a checked ``(N, dim)`` float64 array: real numbers of the right shape,
        finite, positions within :data:`cellplan.schema.COORD_LIMIT`, angles in radians.

        Every public query calls this first, so a configuration written in degrees (a
        joint angle of 90) is refused with one line saying angles are radians here
        (:func:`cellplan.units.check_configurations`) instead of silently wrapping.
        """
        return units.check_configurations(q, self.robot.axis_names, name)

    def posed_bodies(self, q: FloatArray, carrying: str | None) -> tuple[RigidBodies, FloatArray]:
        """Bodies (robot, then the carried part) and their poses ``(N, B, 3)``."""
        return self._posed_bodies(self.configurations(q), carrying)

    def _posed_bodies(self, q: FloatArray, carrying: str | None) -> tuple[RigidBodies, FloatArray]:
        # ``q`` checked by the caller: the queries check it once per call.
        poses = self.robot.body_poses(q)
        bodies = self.robot.bodies
        if carrying is not None:
            if carrying not in self._carrying_cache:
                self._carrying_cache[carrying] = RigidBodies((*bodies.bodies, self.part(carrying)))
            bodies = self._carrying_cache[carrying]
            poses = np.concatenate([poses, self.robot.tool_pose(q)[:, None, :]], axis=1)
        return bodies, poses

    def part(self, name: str) -> ShapeSet:
        """A part's shape in the gripper frame."""
        try:
            return self.parts[name]
        except KeyError:
            raise ArgumentError(
                f"unknown part {name!r}; known: {list(self.parts)}", "carrying"
            ) from None

    def collides(
        self,
        q: FloatArray,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
        margin: float | FloatArray = 0.0,
    ) -> BoolArray:
        """``(N,)``: does the robot (with the carried part) touch an obstacle or leave the bounds?

        Configurations outside the joint limits count as colliding. ``margin``
        (a number, or one per body with the part last; finite and not negative) demands
        extra clearance. Angles are radians (see :func:`configurations`). Bad arguments
        raise :class:`~cellplan.errors.ArgumentError`.
        """
        return self._collides(self.configurations(q), carrying, avoid_sources, margin)

    def _collides(
        self,
        q: FloatArray,
        carrying: str | None,
        avoid_sources: AvoidSources,
        margin: float | FloatArray,
    ) -> BoolArray:
        # ``q`` checked by the caller (:meth:`collides`, or samples between checked ends).
        bodies, poses = self._posed_bodies(q, carrying)
        margins = _margins(margin, len(bodies.bodies))
        hit = (
            body_gaps(bodies, poses, self.prepared_obstacles(avoid_sources), margins, exact=False)
            <= 0.0
        )
        return hit | ~self.robot.within_limits(q)

    def free(
        self, q: FloatArray, carrying: str | None = None, avoid_sources: AvoidSources = "all"
    ) -> BoolArray:
        """``(N,)``: the negation of :meth:`collides`."""
        return ~self.collides(q, carrying, avoid_sources)

    def clearance(
        self, q: FloatArray, carrying: str | None = None, avoid_sources: AvoidSources = "all"
    ) -> FloatArray:
        """``(N,)`` distance from the robot (and carried part) to the nearest obstacle or the
        workcell boundary; 0 on contact and outside the joint limits."""
        q = self.configurations(q)
        bodies, poses = self._posed_bodies(q, carrying)
        gap = body_gaps(bodies, poses, self.prepared_obstacles(avoid_sources), exact=True)
        gap = np.maximum(gap, 0.0)
        gap[~self.robot.within_limits(q)] = 0.0
        return gap

    def motion_collides(
        self,
        q0: FloatArray,
        q1: FloatArray,
        step: float,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
        certified: bool = True,
    ) -> BoolArray:
        """``(N,)``: does the straight C-space motion ``q0[i] -> q1[i]`` collide?

        The segment is sampled so that no point of the robot moves more than
        ``step`` (workspace units) between samples. With ``certified`` the samples
        are checked with a clearance margin of ``step / 2``, so a motion reported
        free is free everywhere along the segment, not only at the samples.
        Periodic axes take the short way round.

        ``step`` must be a finite positive number. The number of samples and their memory
        are estimated before anything is allocated: more than :data:`MAX_MOTION_SAMPLES`,
        or more memory than is available (:func:`cellplan.budget.require`), raises an
        :class:`~cellplan.errors.ArgumentError` naming ``step``.
        """
        q0 = self.configurations(q0, "q0")
        q1 = self.configurations(q1, "q1")
        step = units.real_number(step, "step")
        if step <= 0:
            raise ArgumentError([Problem("step", f"must be positive, got {step:g}")])
        if len(q0) != len(q1):
            raise ArgumentError([Problem("q1", f"has {len(q1)} configurations; q0 has {len(q0)}")])
        d = self.robot.difference(q0, q1)
        reach = self.part(carrying).reach() if carrying is not None else 0.0
        travel = self.robot.workspace_step(d, reach)
        counts = self._sample_counts(travel, step, carrying)
        seg = np.repeat(np.arange(len(q0)), counts)
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        t = (np.arange(counts.sum()) - np.repeat(offsets, counts)) / np.repeat(counts - 1, counts)
        samples = self.robot.wrap(q0[seg] + t[:, None] * d[seg])
        margin = step / 2 if certified else 0.0
        hit = self._collides(samples, carrying, avoid_sources, margin)
        return np.logical_or.reduceat(hit, offsets)

    def _sample_counts(self, travel: FloatArray, step: float, carrying: str | None) -> IntArray:
        """Samples per motion (both ends included), refused before any allocation when
        their number or their memory is too large (see :meth:`motion_collides`)."""
        # Float arithmetic first: ceil(travel / step) may be inf or beyond int64.
        with np.errstate(over="ignore"):
            counts = np.maximum(1.0, np.ceil(travel / step)) + 1.0
        total = float(counts.sum()) if len(counts) else 0.0
        if not total <= MAX_MOTION_SAMPLES:
            longest = float(travel.max())
            raise ArgumentError(
                [
                    Problem(
                        "step",
                        f"{step:g} needs more than {MAX_MOTION_SAMPLES:,} samples (the longest "
                        f"motion moves {longest:.4g} units); use a larger step",
                    )
                ]
            )
        bodies = len(self.robot.bodies.bodies) + (carrying is not None)
        # Per sample, float64 values alive at once at worst: the index and parameter
        # arrays (5), the interpolated configuration and its temporaries (5 per axis),
        # and the posed bodies with their copies (3 per body, three times over).
        per_sample = 8 * (5 + 5 * self.robot.dim + 9 * (bodies + 1))
        need = total * per_sample
        if need > _MOTION_BYTES_UNCHECKED:
            what = f"to check {total:,.0f} samples of {len(counts)} motion(s)"
            budget.require(need, "step", what)
        return counts.astype(np.int64)

    def in_region(
        self,
        q: FloatArray,
        name: str,
        kind: RegionTest = "contact",
        component: int | None = None,
        carrying: str | None = None,
        offset: Sequence[float] | None = None,
    ) -> BoolArray:
        """``(N,)``: contact with or enclosure in a source or destination region.

        For rigid robots the robot body (and carried part) is tested; for arms,
        the end-effector point (and carried part), as the strategies paper does
        for problems 5-6. Contact means touching; enclosure means entirely inside
        one component (touching its boundary from inside does not count).
        ``component`` restricts the test to one component (an index, ``0 <= component <
        len(components)``). ``offset`` moves the region by ``(dx, dy)`` (a region on a
        conveyor belt, Section VI-1 of the strategies paper), each finite and within
        :data:`cellplan.schema.COORD_LIMIT`.
        """
        region = self.region(name)
        if kind not in ("contact", "enclosure"):
            raise ArgumentError(f"must be 'contact' or 'enclosure', not {kind!r}", "kind")
        q = self.configurations(q)
        indices = range(len(region.components)) if component is None else [component]
        if component is not None:
            _check_component(component, len(region.components))
        shift = None if offset is None else _offset(offset)
        bodies, poses = self._region_bodies(q, carrying)
        if shift is not None:
            # Moving the region by d is moving every posed body by -d.
            poses = poses.copy()
            poses[..., 0] -= shift[0]
            poses[..., 1] -= shift[1]
        out = np.zeros(len(q), bool)
        for i in indices:
            if kind == "contact":
                out |= _gap(bodies, poses, region.components[i]) <= 0.0
            else:
                out |= _gap(bodies, poses, region.complements[i]) > 0.0
        return out

    def _region_bodies(self, q: FloatArray, carrying: str | None) -> tuple[RigidBodies, FloatArray]:
        if not isinstance(self.robot, PlanarArm):
            return self._posed_bodies(q, carrying)
        tool = self.robot.tool_pose(q)[:, None, :]
        shapes: tuple[ShapeSet, ...] = (ShapeSet.point(),)
        poses = tool
        if carrying is not None:
            shapes = (*shapes, self.part(carrying))
            poses = np.concatenate([tool, tool], axis=1)
        return RigidBodies(shapes), poses

    def region(self, name: str) -> Region:
        """A source or destination by name."""
        if name in self.sources:
            return self.sources[name]
        if name in self.destinations:
            return self.destinations[name]
        raise ArgumentError(
            f"unknown region {name!r}; known: {[*self.sources, *self.destinations]}", "name"
        )

    # --- in a console and a notebook -----------------------------------------------------------

    def __repr__(self) -> str:
        """Short: name, robot (kind, dimension), bounds and the names of what the cell
        holds (region names with their component counts); no arrays."""
        xmin, ymin, xmax, ymax = self.bounds
        return cell_repr(
            "Workcell",
            self.name,
            f"{self.robot.kind}, dim {self.robot.dim}",
            f"[{xmin:g}, {xmax:g}] x [{ymin:g}, {ymax:g}]",
            self.obstacles,
            self.parts,
            {n: len(r.components) for n, r in self.sources.items()},
            {n: len(r.components) for n, r in self.destinations.items()},
        )

    def _repr_png_(self) -> bytes:
        """The workcell with the robot at its start (:func:`cellplan.plots.workcell_figure`)
        as PNG bytes, for notebooks."""
        import io

        from cellplan.plots import workcell_figure

        buffer = io.BytesIO()
        workcell_figure(self).savefig(buffer, format="png", dpi=90)
        return buffer.getvalue()

    # --- the rest of the validity interface (cellplan.validity) ------------------------------

    @property
    def dimension(self) -> int:
        """2: a planar workcell."""
        return 2

    @property
    def geometry(self) -> str:
        """The checks test the exact polygons and discs."""
        return "exact"

    def box_collides(
        self,
        q: FloatArray,
        half_widths: FloatArray,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
    ) -> BoolArray:
        """``(N,)``: False only when every configuration within ``q[i] +- half_widths`` is
        free: each body must keep a clearance equal to the largest distance any of its
        points can move inside the box (:meth:`~cellplan.robots.Robot.body_displacement_bounds`),
        and the whole box must lie within the joint limits."""
        q = self.configurations(q)
        half = units.real_array(half_widths, "half_widths")
        if half.shape != (self.robot.dim,) or not np.all(np.isfinite(half)) or np.any(half < 0):
            raise ArgumentError(
                [Problem("half_widths", f"expected {self.robot.dim} finite numbers >= 0")]
            )
        margins = list(self.robot.body_displacement_bounds(half))
        if carrying is not None:
            margins.append(self.robot.tool_displacement_bound(half, self.part(carrying).reach()))
        bodies, poses = self._posed_bodies(q, carrying)
        obstacles = self.prepared_obstacles(avoid_sources)
        hit = body_gaps(bodies, poses, obstacles, np.array(margins), exact=False) <= 0.0
        return hit | ~self.robot.within_limits(q)

    def batch_bytes(self, count: int, carrying: str | None = None) -> int:
        """Bytes of a batched check of ``count`` configurations at its peak, per
        configuration: the configuration (float64 ``(d,)`` three times), the body poses
        (float64 ``(B, 3)`` and as many temporaries), the gaps (float64 ``(B,)``) and
        three bool masks; ``B`` counts the robot's bodies and the carried part."""
        bodies = len(self.robot.bodies.bodies) + (carrying is not None)
        return count * (24 * self.robot.dim + 48 * bodies + 8 * bodies + 3)

    def tool_position(self, q: FloatArray) -> FloatArray:
        """``(N, 2)``: the gripper's position."""
        return self.robot.tool_pose(self.configurations(q))[:, :2]

    def sample(self, n: int, rng: np.random.Generator) -> FloatArray:
        """``(n, dim)`` configurations uniform within the limits (periodic axes over the
        full turn); collisions are not checked."""
        lo = np.where(self.robot.periodic, -np.pi, self.robot.lower)
        hi = np.where(self.robot.periodic, np.pi, self.robot.upper)
        return self.robot.wrap(rng.uniform(lo, hi, size=(n, self.robot.dim)))

    # --- geometry for drawing ----------------------------------------------------------------

    def robot_shapes(
        self, q: FloatArray, carrying: str | None = None
    ) -> tuple[list[BaseGeometry], BaseGeometry | None]:
        """Shapely geometry of the robot's bodies and of the carried part at one configuration."""
        q = self.configurations(q)
        if len(q) != 1:
            raise ArgumentError([Problem("q", f"expected one configuration, got {len(q)}")])
        bodies, poses = self.posed_bodies(q, carrying)
        geoms = [
            b.transformed(p).to_shapely() for b, p in zip(bodies.bodies, poses[0], strict=True)
        ]
        if carrying is None:
            return geoms, None
        return geoms[:-1], geoms[-1]


def _margins(margin: float | FloatArray, count: int) -> FloatArray:
    """``margin`` (one number, or one per body) as ``(count,)`` finite, non-negative values."""
    if isinstance(margin, float) and math.isfinite(margin) and margin >= 0.0:
        # One plain number (the default 0.0): checked without numpy, which costs a
        # single-configuration query about a fifth of its time.
        return np.full(count, margin)
    arr = units.real_array(margin, "margin", "a number or one number per body")
    if arr.ndim > 1 or (arr.ndim == 1 and len(arr) not in (1, count)):
        raise ArgumentError(
            [Problem("margin", f"expected one number or {count} (one per body), got {arr.shape}")]
        )
    if not np.all(np.isfinite(arr)):
        raise ArgumentError([Problem("margin", "contains NaN or infinite values")])
    if np.any(arr < 0):
        raise ArgumentError([Problem("margin", "must not be negative (it is extra clearance)")])
    return np.array(np.broadcast_to(arr, (count,)))


def _check_component(component: int, count: int) -> None:
    """Refuse a component index that is not a whole number in ``[0, count)``."""
    if isinstance(component, bool) or not isinstance(component, int | np.integer):
        raise ArgumentError([Problem("component", f"expected an index, got {component!r}")])
    if not 0 <= component < count:
        raise ArgumentError(
            [
                Problem(
                    "component",
                    f"{component} is not in [0, {count - 1}]: the region has "
                    f"{count} component{'s' if count > 1 else ''}",
                )
            ]
        )


def _offset(offset: Sequence[float]) -> FloatArray:
    """``offset`` as two finite numbers within :data:`cellplan.schema.COORD_LIMIT`."""
    arr = units.real_array(offset, "offset", "(dx, dy)")
    if arr.shape != (2,):
        raise ArgumentError([Problem("offset", f"expected (dx, dy), got shape {arr.shape}")])
    if not np.all(np.isfinite(arr)) or np.abs(arr).max() > COORD_LIMIT:
        raise ArgumentError(
            [
                Problem(
                    "offset",
                    f"each value must be finite and within [-{COORD_LIMIT:g}, {COORD_LIMIT:g}]",
                )
            ]
        )
    return arr


def _gap(bodies: RigidBodies, poses: FloatArray, obstacles: ShapeSet) -> FloatArray:
    return body_gaps(bodies, poses, obstacles, exact=False)


def _robot_reach(robot: Robot) -> float:
    if isinstance(robot, PlanarArm):
        return float(robot.lengths.sum() + robot.widths.max())
    return float(max(b.reach() for b in robot.bodies.bodies))


def _display_config(robot: Robot, q: FloatArray) -> list[float]:
    """Configuration as the user wrote it (degrees for angles)."""
    return [float(v) for v in units.config_to_file(robot.axis_names, q)]


def default_cells(robot: Robot) -> tuple[int, ...]:
    """Default bitmap resolution for a robot kind."""
    if robot.kind in DEFAULT_CELLS:
        return DEFAULT_CELLS[robot.kind]
    return (DEFAULT_ARM_CELLS_PER_JOINT,) * robot.dim


def load_workcell(path: str | Path) -> tuple[Scenario, Workcell]:
    """Load and validate a scenario file and build its workcell model."""
    sc = load_scenario(path)
    return sc, Workcell.from_scenario(sc)

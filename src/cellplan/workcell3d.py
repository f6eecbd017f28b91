"""A 3-D workcell: a URDF arm among solid obstacles, parts and regions (metres, radians).

:class:`Workcell3D` implements the validity interface (:mod:`cellplan.validity`) that the
planar :class:`~cellplan.workcell.Workcell` implements, so planners use either without
asking which. Its checks test a conservative sphere cover of the arm's collision meshes
(:mod:`cellplan.arm`) and of the carried part against exact solids (:mod:`cellplan.solids`):

* **collides** is never False for a configuration where the URDF's own meshes touch an
  obstacle, an avoided source or the bounds' walls, or two links the SRDF allows to
  collide (self-collision); it may be True a little before the meshes touch;
* **clearance** is a lower bound on the distance from the cover to the obstacles;
* **motion_collides** (certified) is the 2-D guarantee: a segment reported free is free
  everywhere along it. No point of the cover moves more than
  ``sum_j lever[j] |dq_j|`` along a straight joint-space segment (:func:`cellplan.arm.lever_arms`),
  so samples spaced so that no point moves more than ``step`` between them, each with
  clearance above ``step / 2``, cover the whole segment; see docs/arms.md.

Links fixed to the base do not move: they are checked once, when the cell is built,
against the obstacles with the exact meshes (a base standing on a table touches it
through the cover's slack, not through its mesh).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellplan import arm as arms
from cellplan import budget, solids, units
from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.scenario import Scenario
from cellplan.scenario3d import Bounds3, Pose
from cellplan.validity import AvoidSources, BoolArray, FloatArray, RegionTest, avoided_sources
from cellplan.workcell import cell_repr

__all__ = ["DEFAULT_CELLS_3D", "PART_SPHERE_RADIUS", "Region3D", "UrdfRobot", "Workcell3D"]

DEFAULT_CELLS_3D = 48
"""Default bitmap cells per active joint of a 3-D arm (the strategies paper's 3-D examples
use 48 to 64 per axis)."""

PART_SPHERE_RADIUS = 0.02
"""Largest sphere of a carried part's cover (metres): small enough that the cover of a
5 cm part adds under a centimetre."""

_IK_RESTARTS = 32
"""Random restarts of inverse kinematics when a region's reachability is checked."""

MAX_MOTION_SAMPLES = 2**40
"""Most samples one :meth:`Workcell3D.motion_collides` call may take."""

_MOTION_BYTES_UNCHECKED = 16 * 2**20
"""Sample memory below which a motion check does not ask :mod:`cellplan.budget`."""

_CHUNK = 8192
"""Configurations per batch of a check, so its temporaries stay a few megabytes."""


@dataclass(frozen=True)
class UrdfRobot:
    """A URDF arm as planners see it (:class:`cellplan.validity.RobotModel`)."""

    arm: arms.Arm
    start: FloatArray
    kind: str = "urdf"

    @property
    def axis_names(self) -> tuple[str, ...]:
        """The active joints' names."""
        return self.arm.joint_names

    @property
    def dim(self) -> int:
        """Number of active joints."""
        return self.arm.dim

    @property
    def lower(self) -> FloatArray:
        """Lower joint limits (``-pi`` on continuous joints)."""
        return np.where(self.arm.periodic, -np.pi, self.arm.lower)

    @property
    def upper(self) -> FloatArray:
        """Upper joint limits (``pi`` on continuous joints)."""
        return np.where(self.arm.periodic, np.pi, self.arm.upper)

    @property
    def periodic(self) -> tuple[bool, ...]:
        """Continuous joints wrap."""
        return tuple(bool(p) for p in self.arm.periodic)

    @property
    def angular(self) -> tuple[bool, ...]:
        """Revolute and continuous joints are angles; prismatic ones are lengths."""
        return self.arm.angular

    def within_limits(self, q: FloatArray) -> BoolArray:
        """``(N,)``: every bounded joint within its limits."""
        q = np.atleast_2d(q)
        bounded = ~np.asarray(self.arm.periodic)
        ok = (q[:, bounded] >= self.arm.lower[bounded]) & (q[:, bounded] <= self.arm.upper[bounded])
        return np.asarray(ok.all(axis=1))

    def wrap(self, q: FloatArray) -> FloatArray:
        """Continuous joints into ``(-pi, pi]``."""
        out = np.array(q, dtype=float, copy=True)
        per = np.asarray(self.arm.periodic)
        out[..., per] = np.pi - np.mod(np.pi - out[..., per], 2 * np.pi)
        return out

    def difference(self, q0: FloatArray, q1: FloatArray) -> FloatArray:
        """``q1 - q0``, the short way round on continuous joints."""
        d = np.asarray(q1, float) - np.asarray(q0, float)
        per = np.asarray(self.arm.periodic)
        d[..., per] = np.mod(d[..., per] + np.pi, 2 * np.pi) - np.pi
        return d

    def tool_pose(self, q: FloatArray) -> FloatArray:
        """``(N, 4, 4)``: the tool frame in the world."""
        return arms.tool_pose(self.arm, np.atleast_2d(q))

    def workspace_step(self, dq: FloatArray, tool_reach: float = 0.0) -> FloatArray:
        """``(N,)`` bound on how far any point of the arm, or any point within
        ``tool_reach`` of the tool frame's origin, moves along the joint steps ``dq``.

        The bound of :func:`cellplan.arm.lever_arms` (per joint, over every sphere and the
        tool origin), plus ``tool_reach`` times the turn of the tool frame, which is at
        most the sum of the revolute joints' steps. As the planar robots'
        ``workspace_step``: samples this far apart along a motion are dense in the
        workspace (the strategies simulator's exact collision test uses it).
        """
        dq = np.abs(np.atleast_2d(np.asarray(dq, float)))
        levers = arms.lever_arms(self.arm, np.zeros((1, 3)))
        turn = dq[:, np.asarray(self.arm.angular, bool)].sum(axis=1)
        return np.asarray(dq @ levers + float(tool_reach) * turn)


@dataclass(frozen=True)
class Region3D:
    """A source or destination: disjoint solid components."""

    name: str
    role: str
    components: tuple[solids.Solid, ...]
    prepared: solids.SolidSet


@dataclass(frozen=True)
class _Part:
    solid: solids.Solid
    centers: FloatArray  # (K, 3) in the tool frame
    radii: FloatArray  # (K,)


@dataclass(frozen=True)
class Workcell3D:
    """A 3-D workcell (see the module docstring); build it with :meth:`from_scenario`."""

    name: str
    lo: FloatArray
    hi: FloatArray
    obstacles: Mapping[str, solids.Solid]
    robot: UrdfRobot
    parts: Mapping[str, _Part]
    sources: Mapping[str, Region3D]
    destinations: Mapping[str, Region3D]
    default_cells: tuple[int, ...]
    # Memos of derived data (prepared obstacle sets, lever rows); never part of equality.
    _prepared: dict[tuple[str, ...], solids.SolidSet] = field(
        default_factory=dict, compare=False, repr=False
    )
    _lever_cache: dict[str | None, FloatArray] = field(
        default_factory=dict, compare=False, repr=False
    )

    def __repr__(self) -> str:
        """Short: name, arm (name, joints), bounds in metres and the names of what the cell
        holds (:func:`cellplan.workcell.cell_repr`); no arrays."""
        lo, hi = self.lo, self.hi
        bounds = " x ".join(f"[{a:g}, {b:g}]" for a, b in zip(lo, hi, strict=True)) + " m"
        return cell_repr(
            "Workcell3D",
            self.name,
            f"{self.robot.arm.name} ({self.robot.kind}), dim {self.robot.dim}",
            bounds,
            self.obstacles,
            self.parts,
            {n: len(r.components) for n, r in self.sources.items()},
            {n: len(r.components) for n, r in self.destinations.items()},
        )

    # --- construction ------------------------------------------------------------------------

    @staticmethod
    def from_scenario(sc: Scenario, folder: Path | None = None) -> Workcell3D:
        """Build the model of a 3-D scenario; relative paths are found in ``folder``.

        Raises :class:`ScenarioError` (one line per problem) for a URDF or mesh that does
        not load, unknown joint or frame names, locked or start values outside their
        limits, a base that puts fixed links inside an obstacle, and a start that collides.
        """
        if sc.robot is None:
            raise ScenarioError([Problem("robot", "this scenario has no robot")])
        where = folder if folder is not None else Path.cwd()
        spec = sc.robot
        obstacles = {
            name: scenario_solid(o, where, f"workcell.obstacles.{name}")
            for name, o in sc.workcell.obstacles.items()
        }
        arm = _load_arm(spec, where)
        start = units.config_from_file(arm.joint_names, spec.start, arm.angular)
        robot = UrdfRobot(arm, start)
        problems = _start_problems(spec.start, robot)
        parts = {}
        for name, p in sc.parts.items():
            solid = scenario_solid(p.shape, where, f"parts.{name}.shape")
            vertices, faces = solid.triangles()
            try:
                centers, radii = arms.cover_mesh(vertices, faces, PART_SPHERE_RADIUS)
            except ArgumentError as exc:
                # The cover's own field ("vertices") means nothing in a scenario file.
                raise ScenarioError(
                    [
                        Problem(
                            f"parts.{name}.shape",
                            f"cannot be covered for the collision check: {p.message}",
                        )
                        for p in exc.problems
                    ]
                ) from None
            parts[name] = _Part(solid, centers, radii)

        def region(name: str, role: str, spec: Any) -> Region3D:
            comps = tuple(
                scenario_solid(c, where, f"{role}s.{name}.components[{i}]")
                for i, c in enumerate(spec.components)
            )
            return Region3D(name, role, comps, solids.SolidSet.build(comps))

        b = sc.workcell.bounds
        if not isinstance(b, Bounds3):
            raise TypeError("Workcell3D.from_scenario takes a 3-D scenario")
        cells = tuple(sc.cspace.cells) if sc.cspace.cells else (DEFAULT_CELLS_3D,) * arm.dim
        cell = Workcell3D(
            name=sc.name,
            lo=np.array(b.lo, float),
            hi=np.array(b.hi, float),
            obstacles=obstacles,
            robot=robot,
            parts=parts,
            sources={n: region(n, "source", r) for n, r in sc.sources.items()},
            destinations={n: region(n, "destination", r) for n, r in sc.destinations.items()},
            default_cells=cells,
        )
        problems += cell._base_problems()
        if not problems:
            problems += cell._start_collisions()
        if problems:
            raise ScenarioError(problems)
        return cell

    def _base_problems(self) -> list[Problem]:
        """Fixed links inside an obstacle (exact meshes), one line per obstacle."""
        problems = []
        for name, solid in self.obstacles.items():
            if arms.fixed_collides(self.robot.arm, [(solid.to_coal(), solid.pose)]):
                problems.append(
                    Problem("robot.base", f"puts the robot's base inside obstacle '{name}'")
                )
        return problems

    def _start_collisions(self) -> list[Problem]:
        q = self.robot.start[None, :]
        shown = ", ".join(
            f"{v:.4g}"
            for v in units.config_to_file(self.robot.axis_names, q[0], self.robot.angular)
        )
        problems = []
        centers = arms.sphere_centers(self.robot.arm, q)
        radii = self.robot.arm.spheres.radii
        for name, solid in self.obstacles.items():
            one = solids.SolidSet.build([solid])
            if solids.sphere_gaps(one, centers, radii)[0] <= 0.0:
                problems.append(
                    Problem(
                        "robot.start", f"configuration ({shown}) collides with obstacle '{name}'"
                    )
                )
        if solids.bounds_gaps(self.lo, self.hi, centers, radii)[0] <= 0.0:
            problems.append(
                Problem("robot.start", f"configuration ({shown}) leaves the workcell bounds")
            )
        if arms.self_collides(self.robot.arm, q)[0]:
            problems.append(Problem("robot.start", f"configuration ({shown}) collides with itself"))
        return problems

    def with_obstacles(self, obstacles: Mapping[str, solids.Solid]) -> Workcell3D:
        """A copy with another set of named obstacles (a changed workcell); the start is
        not re-checked."""
        return Workcell3D(
            self.name,
            self.lo,
            self.hi,
            dict(obstacles),
            self.robot,
            self.parts,
            self.sources,
            self.destinations,
            self.default_cells,
        )

    # --- the validity interface --------------------------------------------------------------

    @property
    def dimension(self) -> int:
        """3: a 3-D cell."""
        return 3

    @property
    def geometry(self) -> str:
        """The checks test a conservative sphere cover of the collision meshes."""
        return "spheres"

    def configurations(self, q: FloatArray, name: str = "q") -> FloatArray:
        """``q`` as a checked ``(N, dim)`` array (:func:`cellplan.units.check_configurations`)."""
        return units.check_configurations(q, self.robot.axis_names, name, self.robot.angular)

    def region(self, name: str) -> Region3D:
        """A source or destination by name."""
        if name in self.sources:
            return self.sources[name]
        if name in self.destinations:
            return self.destinations[name]
        raise ArgumentError(
            f"unknown region {name!r}; known: {[*self.sources, *self.destinations]}", "name"
        )

    def part(self, name: str) -> _Part:
        """A part (its solid in the tool frame and its sphere cover)."""
        try:
            return self.parts[name]
        except KeyError:
            raise ArgumentError(
                f"unknown part {name!r}; known: {list(self.parts)}", "carrying"
            ) from None

    def obstacle_set(self, avoid_sources: AvoidSources = "all") -> solids.SolidSet:
        """Obstacles and the avoided sources (equations (1)-(3)), prepared once per choice."""
        key = tuple(self._avoided(avoid_sources))
        if key not in self._prepared:
            members = list(self.obstacles.values())
            for s in key:
                members += list(self.sources[s].components)
            self._prepared[key] = solids.SolidSet.build(members)
        return self._prepared[key]

    def _avoided(self, avoid_sources: AvoidSources) -> list[str]:
        return avoided_sources(avoid_sources, self.sources)

    def _spheres(self, q: FloatArray, carrying: str | None) -> tuple[FloatArray, FloatArray]:
        """World centres ``(N, S, 3)`` and radii ``(S,)`` of the arm's cover and the part's."""
        centers = arms.sphere_centers(self.robot.arm, q)
        radii = self.robot.arm.spheres.radii
        if carrying is None:
            return centers, radii
        part = self.part(carrying)
        tool = arms.tool_pose(self.robot.arm, q)
        # A batched matmul: numpy's einsum took 0.3 s a chunk here (strategies_ur5's
        # bitmaps spent 19 of their 38 s in it), the matmul 0.02 s.
        attached = (tool[:, :3, :3] @ part.centers.T).transpose(0, 2, 1) + tool[:, None, :3, 3]
        return np.concatenate([centers, attached], axis=1), np.concatenate([radii, part.radii])

    def _gaps(
        self,
        q: FloatArray,
        carrying: str | None,
        avoid_sources: AvoidSources,
        margin: float | FloatArray,
        rows: NDArray[np.int64] | None = None,
    ) -> FloatArray:
        """``(N,)`` lower bound on the clearance of the cover, less each sphere's margin;
        -inf for a self-collision or a configuration outside the limits. ``q`` is
        checked by the caller and taken in chunks.

        ``margin`` is one number, one per sphere ``(S,)``, or, with ``rows``, a table
        ``(M, S)`` whose row ``rows[i]`` holds configuration ``i``'s margins (the
        samples of one motion share their segment's row).
        """
        obstacles = self.obstacle_set(avoid_sources)
        arm_spheres = len(self.robot.arm.spheres.radii)
        out = np.empty(len(q))
        for start in range(0, len(q), _CHUNK):
            part = q[start : start + _CHUNK]
            m = np.asarray(margin, float)
            if rows is not None:
                m = m[rows[start : start + _CHUNK]]
            centers, radii = self._spheres(part, carrying)
            gap = np.minimum(
                solids.sphere_gaps(obstacles, centers, radii, m) if len(obstacles) else np.inf,
                solids.bounds_gaps(self.lo, self.hi, centers, radii, m),
            )
            # Pairs inside the arm: each sphere keeps its own margin (the largest over the
            # chunk's rows, for a table).
            own = m if m.ndim < 2 else m.max(axis=0)
            own = own if own.ndim == 0 else own[:arm_spheres]
            bad = arms.self_collides(self.robot.arm, part, own)
            bad |= ~self.robot.within_limits(part)
            out[start : start + _CHUNK] = np.where(bad, -np.inf, gap)
        return out

    def collides(
        self,
        q: FloatArray,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
        margin: float | FloatArray = 0.0,
    ) -> BoolArray:
        """``(N,)``: the cover (with the carried part) touches an obstacle, an avoided source
        or a wall, two links collide, or a joint leaves its limits. ``margin`` (one finite
        number >= 0, metres) demands extra clearance."""
        q = self.configurations(q)
        return self._gaps(q, carrying, avoid_sources, _margin(margin)) <= 0.0

    def free(
        self, q: FloatArray, carrying: str | None = None, avoid_sources: AvoidSources = "all"
    ) -> BoolArray:
        """``(N,)``: the negation of :meth:`collides`."""
        return ~self.collides(q, carrying, avoid_sources)

    def clearance(
        self, q: FloatArray, carrying: str | None = None, avoid_sources: AvoidSources = "all"
    ) -> FloatArray:
        """``(N,)`` lower bound on the distance from the robot (and carried part) to the
        nearest obstacle or wall; 0 on contact, self-collision and outside the limits."""
        q = self.configurations(q)
        return np.maximum(self._gaps(q, carrying, avoid_sources, 0.0), 0.0)

    def collides_within(
        self,
        q: FloatArray,
        radius: float,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
    ) -> BoolArray:
        """``(N,)``: could a configuration within joint-space distance ``radius`` of ``q[i]``
        (Euclidean) collide? False certifies that whole ball free.

        Along ``q + dq`` a point of sphere ``s`` moves at most ``lever_s . |dq|`` (the lever
        rows of :func:`cellplan.arm.sphere_levers`), which is at most ``|lever_s| radius``
        by Cauchy-Schwarz; each sphere is checked with that clearance, each pair with the
        sum of theirs. A sampled straight segment whose samples are ``2 radius`` apart is
        then free everywhere when every sample passes (a certified local planner).
        """
        q = self.configurations(q)
        r = _margin(radius)
        margins = np.linalg.norm(self._levers(carrying), axis=1) * r
        return self._gaps(q, carrying, avoid_sources, margins) <= 0.0

    def _levers(self, carrying: str | None) -> FloatArray:
        """``(S, dim)``: per sphere (the arm's, then the part's), how far its points move
        per unit of each joint (:func:`cellplan.arm.sphere_levers`), computed once."""
        if carrying not in self._lever_cache:
            if carrying is None:
                rows = arms.sphere_levers(self.robot.arm)
            else:
                part = self.part(carrying)
                rows = arms.sphere_levers(self.robot.arm, part.centers, part.radii)
            self._lever_cache[carrying] = rows
        return self._lever_cache[carrying]

    def motion_collides(
        self,
        q0: FloatArray,
        q1: FloatArray,
        step: float,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
        certified: bool = True,
    ) -> BoolArray:
        """``(N,)``: does the straight joint-space motion ``q0[i] -> q1[i]`` collide?

        The segment is sampled so that no point of the robot's cover moves more than
        ``step`` metres between samples (by the lever bounds); with ``certified`` each
        sphere must keep, at each sample, half of what it can move between samples (at
        most ``step / 2``, far less near the base), and each sphere pair the sum of
        theirs, so a motion reported free is free everywhere along it.
        Continuous joints take the short way round.
        """
        q0 = self.configurations(q0, "q0")
        q1 = self.configurations(q1, "q1")
        step = units.real_number(step, "step")
        if step <= 0:
            raise ArgumentError([Problem("step", f"must be positive, got {step:g}")])
        if len(q0) != len(q1):
            raise ArgumentError([Problem("q1", f"has {len(q1)} configurations; q0 has {len(q0)}")])
        if len(q0) == 0:
            return np.zeros(0, bool)
        d = self.robot.difference(q0, q1)
        # travel[i, s]: the farthest any point of sphere s moves along segment i.
        travel = np.abs(d) @ self._levers(carrying).T
        with np.errstate(over="ignore"):
            counts_f = np.maximum(1.0, np.ceil(travel.max(axis=1) / step)) + 1.0
        total = float(counts_f.sum())
        if not total <= MAX_MOTION_SAMPLES:
            raise ArgumentError(
                [
                    Problem(
                        "step",
                        f"{step:g} needs more than {MAX_MOTION_SAMPLES:,} samples; "
                        "use a larger step",
                    )
                ]
            )
        # The samples (configuration, parameter, index: 8 (dim + 2) bytes each) are
        # held whole; the checks take them in chunks.
        need = total * 8 * (self.robot.dim + 2) + self.batch_bytes(_CHUNK, carrying)
        if need > _MOTION_BYTES_UNCHECKED:
            budget.require(need, "step", f"to check {total:,.0f} samples of {len(q0)} motion(s)")
        counts = counts_f.astype(np.int64)
        seg = np.repeat(np.arange(len(q0)), counts)
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        t = (np.arange(counts.sum()) - np.repeat(offsets, counts)) / np.repeat(counts - 1, counts)
        samples = self.robot.wrap(q0[seg] + t[:, None] * d[seg])
        # Between two samples sphere s moves at most travel / (count - 1), so every point
        # between them lies within half of that of the nearer sample.
        margins = travel / (2.0 * (counts[:, None] - 1)) if certified else np.zeros_like(travel)
        hit = self._gaps(samples, carrying, avoid_sources, margins, seg) <= 0.0
        return np.logical_or.reduceat(hit, offsets)

    def box_collides(
        self,
        q: FloatArray,
        half_widths: FloatArray,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
    ) -> BoolArray:
        """``(N,)``: False only when every configuration within ``q[i] +- half_widths`` is
        free: at the centre each sphere must keep a clearance of ``sum_j lever[s, j]
        half_widths[j]``, the farthest any of its points moves inside the box, and the
        box must lie within the joint limits."""
        q = self.configurations(q)
        half = units.real_array(half_widths, "half_widths")
        if half.shape != (self.robot.dim,) or not np.all(np.isfinite(half)) or np.any(half < 0):
            raise ArgumentError(
                [Problem("half_widths", f"expected {self.robot.dim} finite numbers >= 0")]
            )
        margin = self._levers(carrying) @ half
        hit = self._gaps(q, carrying, avoid_sources, margin) <= 0.0
        bounded = ~np.asarray(self.robot.arm.periodic)
        outside = (q[:, bounded] - half[bounded] < self.robot.arm.lower[bounded]) | (
            q[:, bounded] + half[bounded] > self.robot.arm.upper[bounded]
        )
        return hit | outside.any(axis=1)

    def batch_bytes(self, count: int, carrying: str | None = None) -> int:
        """Bytes of a check of ``count`` configurations at its peak. The whole batch holds
        its configurations (float64, three times: given, checked, a cell's centres) and a
        few float64 and bool values each; a chunk of at most 8,192 at a time holds the
        sphere centres (float64 ``(S, 3)``, twice with the part's), their margins
        (float64 ``(S,)``) and the frame poses (float64 ``(F, 4, 4)``)."""
        spheres = len(self.robot.arm.spheres.radii)
        if carrying is not None:
            spheres += len(self.part(carrying).radii)
        frames = self.robot.dim + 1
        per_chunk_row = 2 * 24 * spheres + 8 * spheres + 128 * frames
        return count * (24 * self.robot.dim + 32) + min(count, _CHUNK) * per_chunk_row

    def in_region(
        self,
        q: FloatArray,
        name: str,
        kind: RegionTest = "contact",
        component: int | None = None,
        carrying: str | None = None,
        offset: Sequence[float] | None = None,
    ) -> BoolArray:
        """``(N,)``: contact with, or enclosure in, a source or destination (Section III of
        the strategies paper, for the tool point and the carried part).

        Contact: the tool point, or the carried part's cover, touches a component.
        Enclosure: the tool point and every sphere of the carried part's cover lie
        strictly inside one component (the cover contains the part, so the part is
        inside). ``offset`` moves the region by ``(dx, dy, dz)`` metres.
        """
        region = self.region(name)
        if kind not in ("contact", "enclosure"):
            raise ArgumentError(f"must be 'contact' or 'enclosure', not {kind!r}", "kind")
        q = self.configurations(q)
        indices = range(len(region.components)) if component is None else [component]
        if component is not None and not (
            isinstance(component, int) and 0 <= component < len(region.components)
        ):
            raise ArgumentError(
                [Problem("component", f"{component!r} is not in [0, {len(region.components) - 1}]")]
            )
        shift = np.zeros(3)
        if offset is not None:
            shift = units.real_array(offset, "offset", "(dx, dy, dz)")
            if shift.shape != (3,) or not np.all(np.isfinite(shift)):
                raise ArgumentError(
                    [Problem("offset", f"expected (dx, dy, dz), got {shift.shape}")]
                )
        radii = np.zeros(1)
        if carrying is not None:
            radii = np.concatenate([radii, self.part(carrying).radii])
        # Each component is prepared once; the configurations go in chunks, so the posed
        # spheres ((N, S, 3) float64, 550 MB carrying a part on strategies_ur5's grid) and
        # the kernel's temporaries stay a few megabytes (batch_bytes counts one chunk).
        prepared = [solids.SolidSet.build([region.components[i]]) for i in indices]
        out = np.zeros(len(q), bool)
        for start in range(0, len(q), _CHUNK):
            part_q = q[start : start + _CHUNK]
            tool = arms.tool_pose(self.robot.arm, part_q)
            centers = tool[:, None, :3, 3]
            if carrying is not None:
                part = self.part(carrying)
                # A batched matmul, as in _spheres (numpy's einsum is ten times slower).
                attached = (tool[:, :3, :3] @ part.centers.T).transpose(0, 2, 1) + centers
                centers = np.concatenate([centers, attached], axis=1)
            centers = centers - shift
            hit = out[start : start + _CHUNK]
            for one in prepared:
                if kind == "contact":
                    hit |= solids.sphere_gaps(one, centers, radii) <= 0.0
                else:
                    hit |= solids.inside_gaps(one, centers, radii) > 0.0
        return out

    def reach_region(self, name: str, seed: int = 0) -> list[FloatArray | None]:
        """For each component of a region, a collision-free configuration whose tool point
        lies inside it (inverse kinematics on the component's centre, the tool pointing
        down or horizontally away from the base, with restarts; the centre alone for an
        arm with fewer than six active joints), or ``None`` where none was found. The other
        sources are obstacles, as when a part is picked there (equation (1))."""
        region = self.region(name)
        avoid = self.sources_except(name) if region.role == "source" else "all"
        found: list[FloatArray | None] = []
        for i, solid in enumerate(region.components):

            def valid(q: FloatArray, i: int = i) -> bool:
                q = q[None, :]
                inside = self.in_region(q, name, "contact", component=i)[0]
                return bool(inside and not self.collides(q, avoid_sources=avoid)[0])

            answer = None
            # Fewer than six active joints cannot hold the tool at a chosen orientation
            # (a UR5 with its wrist locked): such an arm is asked for the point only.
            position_only = self.robot.dim < 6
            approaches = self._approaches(solid.pose[:3, 3])
            for target in approaches[:1] if position_only else approaches:
                result = arms.ik(
                    self.robot.arm,
                    target,
                    q0=self.robot.start,
                    restarts=_IK_RESTARTS,
                    seed=seed,
                    position_only=position_only,
                    valid=valid,
                )
                if result.success:
                    answer = result.q
                    break
            found.append(answer)
        return found

    def _approaches(self, point: FloatArray) -> list[FloatArray]:
        """Tool poses at ``point`` worth trying first: the tool's z axis pointing down (a
        pick from above), then horizontal, away from the robot's base (a reach into a
        shelf)."""
        down = np.eye(4)
        down[:3, :3] = np.diag([1.0, -1.0, -1.0])
        down[:3, 3] = point
        away = point[:2] - self.robot.arm.base[:2, 3]
        yaw = math.atan2(away[1], away[0])
        c, s = math.cos(yaw), math.sin(yaw)
        out = [down]
        # The tool's z axis along ``away``, rolled about it by quarter turns (a hand is
        # wider one way than the other, and joint limits favour some rolls).
        z = np.array([c, s, 0.0])
        for x in ([0.0, 0.0, -1.0], [-s, c, 0.0], [0.0, 0.0, 1.0], [s, -c, 0.0]):
            forward = np.eye(4)
            forward[:3, 0] = x
            forward[:3, 1] = np.cross(z, x)
            forward[:3, 2] = z
            forward[:3, 3] = point
            out.append(forward)
        return out

    def sources_except(self, source: str | None) -> list[str]:
        """Names of the sources to avoid while serving ``source`` (equations (1)-(2))."""
        return [s for s in self.sources if s != source]

    def tool_position(self, q: FloatArray) -> FloatArray:
        """``(N, 3)``: the tool frame's origin."""
        return arms.tool_pose(self.robot.arm, self.configurations(q))[:, :3, 3]

    def sample(self, n: int, rng: np.random.Generator) -> FloatArray:
        """``(n, dim)`` configurations uniform within the joint limits."""
        return rng.uniform(self.robot.lower, self.robot.upper, size=(n, self.robot.dim))


# --- helpers ---------------------------------------------------------------------------------


def _margin(margin: float | FloatArray) -> float:
    value = units.real_number(margin, "margin")
    if value < 0:
        raise ArgumentError([Problem("margin", "must not be negative (it is extra clearance)")])
    return value


def _pose(pose: Pose) -> FloatArray:
    xyz, rpy = units.pose_from_file(pose.xyz, pose.rpy)
    return solids.pose_matrix(xyz, rpy)


def scenario_solid(spec: Any, folder: Path | None, field: str) -> solids.Solid:
    """A scenario solid as a :class:`cellplan.solids.Solid` (meshes loaded from ``folder``;
    without one, a mesh is refused)."""
    pose = _pose(spec.pose)
    if spec.type == "box":
        return solids.box(spec.size, pose)
    if spec.type == "cylinder":
        return solids.cylinder(spec.radius, spec.length, pose)
    if spec.type == "sphere":
        return solids.sphere(spec.radius, pose)
    if spec.type == "capsule":
        return solids.capsule(spec.radius, spec.length, pose)
    if folder is None:
        raise ArgumentError(f"a {spec.type} needs the scenario's folder to load from", field)
    vertices, faces = solids.load_mesh(folder / spec.path, spec.scale, field=f"{field}.path")
    return solids.mesh(vertices, faces, pose)


def _load_arm(spec: Any, folder: Path) -> arms.Arm:
    """Load the URDF arm of a robot spec, converting its file units (degrees) to radians."""
    bundled = spec.urdf in arms.BUNDLED
    urdf = spec.urdf if bundled else folder / spec.urdf
    srdf = None if spec.srdf is None else folder / spec.srdf
    kinds = arms.joint_kinds(urdf, field="robot")
    locked = {}
    problems = []
    for name, value in spec.locked.items():
        field = f"robot.locked.{name}"
        if name not in kinds:
            problems.append(
                Problem(field, f"no such movable joint; the URDF has {', '.join(kinds)}")
            )
            continue
        joint = kinds[name]
        angular = [joint.kind != "prismatic"]
        q = float(units.config_from_file([name], [value], angular)[0])
        if joint.kind != "continuous" and not joint.lower - 1e-9 <= q <= joint.upper + 1e-9:
            lo, hi = units.config_to_file([name] * 2, [joint.lower, joint.upper], angular * 2)
            unit = "degrees" if angular[0] else "metres"
            problems.append(
                Problem(field, f"{value:g} is outside the limits [{lo:.6g}, {hi:.6g}] ({unit})")
            )
        locked[name] = q
    if problems:
        raise ScenarioError(problems)
    arm = arms.load_arm(
        urdf,
        srdf=srdf,
        base=_pose(spec.base),
        tool=spec.tool,
        joints=spec.joints,
        locked=locked,
        field="robot",
    )
    arm = _narrowed(arm, spec.limits, {n: k.kind for n, k in kinds.items()})
    if len(spec.start) != arm.dim:
        raise ScenarioError(
            [
                Problem(
                    "robot.start",
                    f"has {len(spec.start)} values; the robot has {arm.dim} active joints "
                    f"({', '.join(arm.joint_names)})",
                )
            ]
        )
    return arm


def _narrowed(
    arm: arms.Arm, limits: Mapping[str, tuple[float, float]], kinds: Mapping[str, str]
) -> arms.Arm:
    """The arm with the scenario's narrower limits (``robot.limits``, file units); a
    continuous joint given limits is no longer periodic."""
    if not limits:
        return arm
    lower, upper = arm.lower.copy(), arm.upper.copy()
    periodic = np.array(arm.periodic, dtype=bool)
    problems = []
    for name, (lo_file, hi_file) in limits.items():
        field = f"robot.limits.{name}"
        if name not in arm.joint_names:
            active = ", ".join(arm.joint_names)
            problems.append(Problem(field, f"is not an active joint (active: {active})"))
            continue
        i = arm.joint_names.index(name)
        angular = kinds.get(name) != "prismatic"
        lo, hi = units.config_from_file([name] * 2, [lo_file, hi_file], [angular] * 2)
        urdf_lo, urdf_hi = (-np.pi, np.pi) if periodic[i] else (arm.lower[i], arm.upper[i])
        if not lo < hi:
            problems.append(Problem(field, f"lower {lo_file:g} is not below upper {hi_file:g}"))
        elif lo < urdf_lo - 1e-9 or hi > urdf_hi + 1e-9:
            shown = units.config_to_file([name] * 2, [urdf_lo, urdf_hi], [angular] * 2)
            problems.append(
                Problem(
                    field,
                    f"[{lo_file:g}, {hi_file:g}] reaches beyond the URDF's limits "
                    f"[{shown[0]:.6g}, {shown[1]:.6g}]",
                )
            )
        else:
            lower[i], upper[i], periodic[i] = lo, hi, False
    if problems:
        raise ScenarioError(problems)
    return dataclasses.replace(arm, lower=lower, upper=upper, periodic=periodic)


def _start_problems(values: Sequence[float], robot: UrdfRobot) -> list[Problem]:
    problems = []
    q = robot.start
    for i, (v, name) in enumerate(zip(values, robot.axis_names, strict=True)):
        if robot.arm.periodic[i]:
            continue
        if not robot.arm.lower[i] - 1e-12 <= q[i] <= robot.arm.upper[i] + 1e-12:
            lo, hi = units.config_to_file(
                [name] * 2, [robot.arm.lower[i], robot.arm.upper[i]], [robot.angular[i]] * 2
            )
            problems.append(
                Problem(
                    f"robot.start[{i}]",
                    f"{name} = {v:g} is outside its limits [{lo:.6g}, {hi:.6g}]",
                )
            )
    return problems

"""The one validity interface every planner uses, for 2-D and 3-D workcells alike.

In OMPL's terms this is the state space (dimension, bounds, periodic axes), the state
validity checker (:meth:`ValiditySpace.collides`, :meth:`~ValiditySpace.clearance`) and
the motion validator (:meth:`~ValiditySpace.motion_collides`), with the workcell's
regions (:meth:`~ValiditySpace.in_region`) and the tool's position. Two classes
implement it: :class:`cellplan.workcell.Workcell` (planar robots, exact polygon and disc
geometry) and :class:`cellplan.workcell3d.Workcell3D` (URDF arms, conservative sphere
covers against exact solids). A planner takes a ``ValiditySpace`` and never asks which
one it has; :func:`check_space` is the conformance test both pass.

Every query is batched: configurations are ``(N, dim)`` float64 arrays in radians and
workcell units (metres in 3-D), and each answer has one entry per configuration.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from cellplan.errors import ArgumentError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
AvoidSources = Literal["all", "none"] | Collection[str]
"""Which sources are obstacles (equations (1)-(3) of the strategies paper)."""
RegionTest = Literal["contact", "enclosure"]

__all__ = [
    "AvoidSources",
    "RegionTest",
    "RobotModel",
    "ValiditySpace",
    "avoided_sources",
    "check_space",
]


def avoided_sources(avoid_sources: AvoidSources, sources: Collection[str]) -> list[str]:
    """The names ``avoid_sources`` stands for (equations (1)-(3) of the strategies paper):
    every source, none, or the listed ones; an unknown name is one line naming it."""
    if avoid_sources == "all":
        return list(sources)
    if avoid_sources == "none":
        return []
    names = list(avoid_sources)
    unknown = [s for s in names if s not in sources]
    if unknown:
        raise ArgumentError(f"unknown sources {unknown}; known: {list(sources)}", "avoid_sources")
    return names


@runtime_checkable
class RobotModel(Protocol):
    """What planners read of a robot: its configuration space and limits."""

    @property
    def kind(self) -> str:
        """``point``, ``translating``, ``rotating``, ``arm`` or ``urdf``."""
        ...

    @property
    def axis_names(self) -> tuple[str, ...]:
        """One name per configuration axis (joint names for URDF arms)."""
        ...

    @property
    def lower(self) -> FloatArray:
        """Lower limits (``-pi`` on periodic axes)."""
        ...

    @property
    def upper(self) -> FloatArray:
        """Upper limits (``pi`` on periodic axes)."""
        ...

    @property
    def periodic(self) -> tuple[bool, ...]:
        """Which axes wrap."""
        ...

    @property
    def start(self) -> FloatArray:
        """The start configuration."""
        ...

    @property
    def dim(self) -> int:
        """Number of configuration axes."""
        ...

    @property
    def angular(self) -> tuple[bool, ...]:
        """Which axes are angles (radians in code, degrees in files)."""
        ...

    def within_limits(self, q: FloatArray) -> BoolArray:
        """``(N,)``: each configuration lies within the limits (periodic axes always do)."""
        ...

    def wrap(self, q: FloatArray) -> FloatArray:
        """Periodic axes into ``(-pi, pi]``."""
        ...

    def difference(self, q0: FloatArray, q1: FloatArray) -> FloatArray:
        """``q1 - q0``, the short way round on periodic axes."""
        ...


@runtime_checkable
class ValiditySpace(Protocol):
    """A workcell as planners see it (see the module docstring)."""

    @property
    def name(self) -> str:
        """The scenario's name."""
        ...

    @property
    def robot(self) -> Any:
        """The robot, a :class:`RobotModel` (typed ``Any`` so each workcell keeps its own)."""
        ...

    @property
    def sources(self) -> Mapping[str, Any]:
        """Source regions by name."""
        ...

    @property
    def destinations(self) -> Mapping[str, Any]:
        """Destination regions by name."""
        ...

    @property
    def parts(self) -> Mapping[str, Any]:
        """Parts by name."""
        ...

    @property
    def default_cells(self) -> tuple[int, ...]:
        """Bitmap cells per configuration axis."""
        ...

    def sources_except(self, source: str | None) -> list[str]:
        """The sources to avoid while serving ``source`` (equations (1)-(2))."""
        ...

    @property
    def dimension(self) -> int:
        """2 for a planar workcell, 3 for a 3-D cell."""
        ...

    @property
    def geometry(self) -> str:
        """What the collision checks test: ``"exact"`` (2-D) or ``"spheres"`` (3-D: a
        conservative sphere cover of the URDF's collision meshes)."""
        ...

    def configurations(self, q: FloatArray, name: str = "q") -> FloatArray:
        """``q`` checked (shape, finite, radians) as ``(N, dim)``."""
        ...

    def collides(
        self,
        q: FloatArray,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
        margin: float | FloatArray = 0.0,
    ) -> BoolArray:
        """``(N,)``: touches an obstacle (or an avoided source), leaves the bounds, or
        violates the joint limits; never False for a colliding configuration."""
        ...

    def free(
        self, q: FloatArray, carrying: str | None = None, avoid_sources: AvoidSources = "all"
    ) -> BoolArray:
        """``(N,)``: the negation of :meth:`collides`."""
        ...

    def clearance(
        self, q: FloatArray, carrying: str | None = None, avoid_sources: AvoidSources = "all"
    ) -> FloatArray:
        """``(N,)``: distance to the nearest obstacle or wall (a lower bound in 3-D);
        0 on contact and outside the limits."""
        ...

    def motion_collides(
        self,
        q0: FloatArray,
        q1: FloatArray,
        step: float,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
        certified: bool = True,
    ) -> BoolArray:
        """``(N,)``: does the straight motion ``q0[i] -> q1[i]`` collide? With
        ``certified``, a motion reported free is free everywhere along it."""
        ...

    def box_collides(
        self,
        q: FloatArray,
        half_widths: FloatArray,
        carrying: str | None = None,
        avoid_sources: AvoidSources = "all",
    ) -> BoolArray:
        """``(N,)``: False only when every configuration of the box ``q[i] +- half_widths``
        is free (the conservative cell test of configuration-space bitmaps)."""
        ...

    def batch_bytes(self, count: int, carrying: str | None = None) -> int:
        """Bytes a batched check of ``count`` configurations holds at its peak (what a
        bitmap's memory estimate charges before allocating)."""
        ...

    def in_region(
        self,
        q: FloatArray,
        name: str,
        kind: RegionTest = "contact",
        component: int | None = None,
        carrying: str | None = None,
        offset: Sequence[float] | None = None,
    ) -> BoolArray:
        """``(N,)``: the tool (and carried part) touches, or is enclosed in, a region."""
        ...

    def tool_position(self, q: FloatArray) -> FloatArray:
        """``(N, dimension)``: where the tool is."""
        ...

    def sample(self, n: int, rng: np.random.Generator) -> FloatArray:
        """``(n, dim)`` configurations uniform within the limits (collision not checked)."""
        ...


def check_space(space: ValiditySpace, rng: np.random.Generator, n: int = 64) -> None:
    """Conformance test of a :class:`ValiditySpace` (Gymnasium's ``check_env`` in spirit).

    Raises ``AssertionError`` naming the first broken rule: shapes and dtypes of every
    query, ``free == ~collides``, clearance 0 exactly where a configuration collides and
    positive elsewhere, samples within the limits, a configuration's motion to itself
    agreeing with the configuration, a cell holding a colliding centre never free, and
    the start configuration clear of the obstacles.
    """
    robot = space.robot
    assert isinstance(robot, RobotModel), "space.robot lacks part of the RobotModel protocol"
    dim = robot.dim
    q = space.sample(n, rng)
    assert q.shape == (n, dim) and q.dtype == np.float64, f"sample gave {q.shape} {q.dtype}"
    assert robot.within_limits(q).all(), "sample left the limits"
    hit = space.collides(q)
    assert hit.shape == (n,) and hit.dtype == np.bool_, "collides must give (N,) booleans"
    assert np.array_equal(space.free(q), ~hit), "free is not the negation of collides"
    gap = space.clearance(q)
    assert gap.shape == (n,) and np.all(gap >= 0.0), "clearance must be (N,) and >= 0"
    assert np.all(gap[hit] == 0.0), "a colliding configuration has positive clearance"
    assert np.all(gap[~hit] > 0.0), "a free configuration has zero clearance"
    assert np.all(space.motion_collides(q, q, step=1e-2)[hit]), (
        "a motion to itself is free although its configuration collides"
    )
    start = robot.start[None, :]
    # The start may lie in a source (a part is picked there), never in an obstacle.
    assert not space.collides(start, avoid_sources="none")[0], "the start configuration collides"
    pos = space.tool_position(q)
    assert pos.shape == (n, space.dimension), "tool_position must be (N, dimension)"
    box = space.box_collides(q, np.full(dim, 1e-3))
    assert np.all(box[hit]), "a cell holding a colliding centre was reported free"
    for name in [*space.sources, *space.destinations]:
        inside = space.in_region(q, name)
        assert inside.shape == (n,) and inside.dtype == np.bool_, f"in_region({name!r}) shape"


if TYPE_CHECKING:
    # mypy checks here that both workcells implement the interface.
    from cellplan.workcell import Workcell
    from cellplan.workcell3d import Workcell3D

    def _conforms(planar: Workcell, solid: Workcell3D) -> tuple[ValiditySpace, ValiditySpace]:
        return planar, solid

"""The ``discs:`` scenario section: a sphere assembly (Whitcomb & Koditschek 1991, Section 2).

Discs in a planar workcell (format version 1), or spheres in a 3-D one (version 2,
bounds with ``zmin``/``zmax``): the paper's navigation function holds in any dimension.
Every start, goal and boundary centre has as many coordinates as the workcell has axes.

A workspace boundary (a disc, or the workcell rectangle), and either an explicit list
of discs (radius, start, goal) or a seeded generator of random legal starts, random
permutations of the goal positions, and packed goal patterns of chosen difficulty
(the paper's ``beta(d)`` of equation (4), Section 5.2.2). The navigation-function
parameters ``k`` (equations (2), (6)) and ``epsilon`` (Section 3.3) live here too; their
defaults here are the only ones (planner options and CLI flags default to "the
section's value").

Legality (no two discs touch, every disc strictly inside the boundary; Section 2) is
checked by :meth:`DiscsSection.check`, one problem per offending disc.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, model_validator

from cellplan.errors import Problem
from cellplan.schema import COORD_LIMIT, Coord, Length, PositiveFloat, StrictModel

#: A point of the workspace: ``[x, y]`` in a planar cell, ``[x, y, z]`` in a 3-D one.
Point = Annotated[tuple[Coord, ...], Field(min_length=2, max_length=3)]

if TYPE_CHECKING:
    from cellplan.scenario import Scenario


class DiscBoundary(StrictModel):
    """A circular (3-D: spherical) workspace of the given centre and radius."""

    type: Literal["disc"]
    """boundary kind"""
    center: Point = (0.0, 0.0)
    """centre of the circular workspace (workcell units; 3 coordinates in a 3-D cell, the
    origin when left out)"""
    radius: Length
    """its radius (workcell units)"""


class WorkcellBoundary(StrictModel):
    """The workcell rectangle (``workcell.bounds``) is the workspace."""

    type: Literal["workcell"]
    """boundary kind: the workcell rectangle"""


Boundary = Annotated[DiscBoundary | WorkcellBoundary, Field(discriminator="type")]


class DiscSpec(StrictModel):
    """One disc (a sphere in a 3-D cell): radius, start and goal of its centre."""

    radius: Length
    """disc radius (workcell units)"""
    start: Point
    """start of the centre (workcell units; [x, y], or [x, y, z] in a 3-D cell)"""
    goal: Point
    """goal of the centre (workcell units; [x, y], or [x, y, z] in a 3-D cell)"""


#: Most discs of a problem, listed or generated: the flows' work grows with the pairs of discs (and
#: the implicit integrator's with the cube of the dimension). Measured on a shared 2-core
#: machine (docs/reliability.md): 10 discs 19 s, 60 discs 58 s, 100 discs 12 minutes;
#: beyond that a run takes hours.
MAX_DISCS = 100


class GeneratorSpec(StrictModel):
    """A seeded random problem.

    ``pattern`` picks the goal layout: ``hex`` (a triangular-lattice cluster around the
    boundary centre, the paper's Fig. 5 kind; in a 3-D cell the close-packed cluster of
    :func:`layout.close_packed_pattern`), ``random`` (random legal goals) or ``stack``
    (3-D only: the two-layer stack of :func:`layout.stack_pattern`).
    ``log10_beta_goal`` sets the difficulty of a ``hex`` pattern: the gap between
    neighbouring goals is chosen so that log10 of the pairwise product beta(d) of
    equation (4) equals it (the paper's Fig. 5 spans -2 to -44); without it the gap is
    ``gap``. ``starts`` is ``random`` (random legal positions) or ``permutation`` (a
    random permutation of the goals, the paper's hard case of Section 5.2.2).
    """

    n: Annotated[int, Field(ge=1, le=MAX_DISCS)]
    """number of discs (at most MAX_DISCS)"""
    seed: Annotated[int, Field(ge=0)] = 0
    """seed of the generator"""
    radius: Annotated[float, Field(ge=1e-6, le=COORD_LIMIT, allow_inf_nan=False)] = 1.0
    """disc radius (workcell units; at least 1e-6, so the workspace has an area)"""
    pattern: Literal["hex", "random", "stack"] = "hex"
    """goal layout: hex (a packed cluster; close-packed in 3-D), random, or stack (3-D: a
    two-layer stack)"""
    gap: Length = 0.1
    """gap between neighbouring hex goals (workcell units)"""
    log10_beta_goal: float | None = None
    """hex goals: log10 of the pairwise product beta(d) of eq. (4) (sets the gap)"""
    starts: Literal["random", "permutation"] = "random"
    """random legal starts, or a permutation of the goals (Sec. 5.2.2)"""
    min_start_gap: Length = 0.05
    """smallest gap between random starts (workcell units)"""


class DiscsSection(StrictModel):
    """Settings of the ``discs:`` section (a disc assembly problem and its parameters)."""

    boundary: Boundary = Field(default_factory=lambda: WorkcellBoundary(type="workcell"))
    """the workspace: the workcell rectangle or a disc"""
    discs: list[DiscSpec] | None = Field(default=None, min_length=1, max_length=MAX_DISCS)
    """the discs, listed (or use generate); at most MAX_DISCS"""
    generate: GeneratorSpec | None = None
    """a seeded random problem (or list discs)"""
    # k: None means the rule of layout.rule_k (docs/assembly.md, "The default k"), the one
    # default of files, `assemble --random` and the planners called without k.
    k: PositiveFloat | None = Field(
        default=None,
        description="navigation-function exponent k, eq. (2) (default: chosen from n and the "
        "workspace, docs/assembly.md 'The default k')",
    )
    epsilon: PositiveFloat = Field(default=1e-3, description="normalisation epsilon, Sec. 3.3")
    tolerance: PositiveFloat = Field(
        default=1e-3, description="success when ||b - d|| (R^2n) is below this"
    )

    @model_validator(mode="after")
    def _exactly_one_source(self) -> DiscsSection:
        if (self.discs is None) == (self.generate is None):
            raise ValueError("give exactly one of 'discs' (a list) and 'generate'")
        return self

    def check(self, scenario: Scenario) -> list[Problem]:
        """Coordinates of the workcell's dimension, then legality of starts and goals
        (Section 2): inside the boundary, no contact."""
        from cellplan.assembly.layout import (
            boundary_from_section,
            legality_problems,
            scenario_dimension,
        )

        problems = self.dimension_problems(scenario_dimension(scenario))
        if problems:
            return problems
        boundary = boundary_from_section(self, scenario)
        if self.discs is not None:
            import numpy as np

            radii = np.array([d.radius for d in self.discs])
            for which in ("start", "goal"):
                pos = np.array([getattr(d, which) for d in self.discs], dtype=float)
                for i, msg in legality_problems(pos, radii, boundary, "discs.discs"):
                    problems.append(Problem(f"discs.discs[{i}].{which}", msg))
        else:
            from cellplan.assembly.layout import generator_problems

            assert self.generate is not None
            problems.extend(generator_problems(self.generate, boundary))
        return problems

    def dimension_problems(self, dim: int) -> list[Problem]:
        """Points with another number of coordinates than the workcell's ``dim`` axes.

        A section written for the other kind of cell (every point with the other count:
        planar discs in a 3-D cell, or the reverse) is one line; otherwise one line per
        point.
        """
        points: list[tuple[str, tuple[float, ...]]] = []
        if self.boundary.type == "disc" and "center" in self.boundary.model_fields_set:
            points.append(("discs.boundary.center", self.boundary.center))
        for i, d in enumerate(self.discs or []):
            points += [(f"discs.discs[{i}].start", d.start), (f"discs.discs[{i}].goal", d.goal)]
        wrong = [(field, p) for field, p in points if len(p) != dim]
        if not wrong:
            return []
        kind = {2: "2d", 3: "3d"}
        if len(wrong) == len(points) and len({len(p) for _, p in wrong}) == 1:
            other = len(wrong[0][1])
            return [
                Problem(
                    "discs",
                    f"the points have {other} coordinates, for {kind[other]} workcells; "
                    f"this one is {kind[dim]} (give {dim}: "
                    f"{'[x, y, z]' if dim == 3 else '[x, y]'})",
                )
            ]
        return [
            Problem(field, f"has {len(p)} coordinates; this workcell is {kind[dim]} (give {dim})")
            for field, p in wrong
        ]

"""The ``discs:`` scenario section: a 2-D sphere assembly (Whitcomb & Koditschek 1991, Section 2).

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
from cellplan.schema import COORD_LIMIT, Length, PositiveFloat, StrictModel, Vec2

if TYPE_CHECKING:
    from cellplan.scenario import Scenario


class DiscBoundary(StrictModel):
    """A circular workspace of the given centre and radius."""

    type: Literal["disc"]
    """boundary kind"""
    center: Vec2 = (0.0, 0.0)
    """centre of the circular workspace (workcell units)"""
    radius: Length
    """its radius (workcell units)"""


class WorkcellBoundary(StrictModel):
    """The workcell rectangle (``workcell.bounds``) is the workspace."""

    type: Literal["workcell"]
    """boundary kind: the workcell rectangle"""


Boundary = Annotated[DiscBoundary | WorkcellBoundary, Field(discriminator="type")]


class DiscSpec(StrictModel):
    """One disc: radius, start and desired (goal) position of its centre."""

    radius: Length
    """disc radius (workcell units)"""
    start: Vec2
    """start of the centre (workcell units)"""
    goal: Vec2
    """goal of the centre (workcell units)"""


#: Most discs of a problem, listed or generated: the flows' work grows with the pairs of discs (and
#: the implicit integrator's with the cube of the dimension). Measured on a shared 2-core
#: machine (docs/reliability.md): 10 discs 19 s, 60 discs 58 s, 100 discs 12 minutes;
#: beyond that a run takes hours.
MAX_DISCS = 100


class GeneratorSpec(StrictModel):
    """A seeded random problem.

    ``pattern`` picks the goal layout: ``hex`` (a triangular-lattice cluster around the
    boundary centre, the paper's Fig. 5 kind) or ``random`` (random legal goals).
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
    pattern: Literal["hex", "random"] = "hex"
    """goal layout: hex (a packed cluster) or random"""
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
        """Legality of starts and goals (Section 2): inside the boundary, no contact."""
        from cellplan.assembly.layout import boundary_from_section, legality_problems

        problems: list[Problem] = []
        boundary = boundary_from_section(self, scenario)
        if self.discs is not None:
            import numpy as np

            radii = np.array([d.radius for d in self.discs])
            for which in ("start", "goal"):
                pos = np.array([getattr(d, which) for d in self.discs], dtype=float)
                for i, msg in legality_problems(pos, radii, boundary):
                    problems.append(Problem(f"discs.discs[{i}].{which}", msg))
        else:
            from cellplan.assembly.layout import generator_problems

            assert self.generate is not None
            problems.extend(generator_problems(self.generate, boundary))
        return problems

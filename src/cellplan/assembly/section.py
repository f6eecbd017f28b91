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
from cellplan.schema import PositiveFloat, StrictModel, Vec2

if TYPE_CHECKING:
    from cellplan.scenario import Scenario


class DiscBoundary(StrictModel):
    """A circular workspace of the given centre and radius."""

    type: Literal["disc"]
    center: Vec2 = (0.0, 0.0)
    radius: PositiveFloat


class WorkcellBoundary(StrictModel):
    """The workcell rectangle (``workcell.bounds``) is the workspace."""

    type: Literal["workcell"]


Boundary = Annotated[DiscBoundary | WorkcellBoundary, Field(discriminator="type")]


class DiscSpec(StrictModel):
    """One disc: radius, start and desired (goal) position of its centre."""

    radius: PositiveFloat
    start: Vec2
    goal: Vec2


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

    n: Annotated[int, Field(ge=1, le=500)]
    seed: Annotated[int, Field(ge=0)] = 0
    radius: PositiveFloat = 1.0
    pattern: Literal["hex", "random"] = "hex"
    gap: PositiveFloat = 0.1
    log10_beta_goal: float | None = None
    starts: Literal["random", "permutation"] = "random"
    min_start_gap: PositiveFloat = 0.05


class DiscsSection(StrictModel):
    """Settings of the ``discs:`` section (a disc assembly problem and its parameters)."""

    boundary: Boundary = Field(default_factory=lambda: WorkcellBoundary(type="workcell"))
    discs: list[DiscSpec] | None = Field(default=None, min_length=1)
    generate: GeneratorSpec | None = None
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

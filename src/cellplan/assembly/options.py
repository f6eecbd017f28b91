"""Options of the assembly planners: the one source of each option's default and range.

Light to import (pydantic only): :mod:`cellplan.assembly.plugin` registers the planners
with these models, the CLI passes an option on only when it is given, and the planners
read the defaults from here. ``k``, ``epsilon`` and ``tolerance`` default to ``None``,
meaning the scenario's ``discs:`` section value, whose own default
(:class:`~cellplan.assembly.section.DiscsSection`) is then the single source.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from cellplan.core import Options
from cellplan.schema import PositiveFloat

#: Smallest goal tolerance of the sequential paper rule when the caller gives none: its T
#: map (equations (13)-(16)) approaches d only asymptotically, one disc at a time, so the
#: rule ends when ``||x - d|| < max(discs.tolerance, SEQUENTIAL_TOLERANCE)`` in R^2n.
SEQUENTIAL_TOLERANCE = 1e-2

#: The implicit step's largest step in R^2n: ``FlowSettings().step_max`` (what the
#: Section 5 experiments use) and the floor of the planner's rule
#: ``max(STEP_MAX_FLOOR, STEP_MAX_PER_SQRT_DISC sqrt(n))`` (:func:`flows.step_max_rule`).
STEP_MAX_FLOOR = 0.05
#: The rule's constant, fitted on the fitting grid (``benchmarks/fit_assembly_step.py``,
#: docs/assembly.md "The step length").
STEP_MAX_PER_SQRT_DISC = 0.02
STEP_MAX_RULE = f"max({STEP_MAX_FLOOR:g}, {STEP_MAX_PER_SQRT_DISC:g} sqrt(n))"

Escapes = Annotated[int, Field(ge=0, le=20)]


class DiscOptions(Options):
    """What every assembly planner takes: the navigation function's ``k`` and the tolerance."""

    k: PositiveFloat | None = Field(
        default=None,
        description="navigation-function exponent k, eq. (2) (default: the scenario's discs.k, "
        "else chosen from n and the workspace)",
    )
    tolerance: PositiveFloat | None = Field(
        default=None,
        description="success when ||b - d|| (R^2n) is below this (default: discs.tolerance)",
    )


class FlowOptions(DiscOptions):
    """Options of the flows of the navigation function (gradient and sequential algorithms)."""

    epsilon: PositiveFloat | None = Field(
        default=None,
        description="normalisation epsilon, Sec. 3.3; sets only the reported flow time "
        "(default: discs.epsilon)",
    )
    escapes: Escapes = Field(
        default=6,
        description="times k may be halved after a stuck stage (Sec. 3.2: escape halve-k, "
        "paper rule); 0: no escape at all (k alone)",
    )


class GradientOptions(FlowOptions):
    """Options of ``assembly.gradient`` (Section 4.1)."""

    escape: Literal["place", "halve-k"] = Field(
        default="place",
        description="what a run stuck at a spurious minimum does: place (the place rule "
        "finishes from there) or halve-k (k halved, at most `escapes` times; Sec. 3.2); "
        "escapes=0: neither",
    )
    integrator: Literal["auto", "implicit", "rk4"] = Field(
        default="auto",
        description="step of the flow: implicit (linearly implicit, resolves stiff contacts), "
        "rk4, or auto (chosen from the problem, docs/assembly.md 'The integrator')",
    )
    step_max: PositiveFloat | None = Field(
        default=None,
        description=f"implicit step: largest step in R^2n (default: {STEP_MAX_RULE}, "
        "docs/assembly.md 'The step length')",
    )


class SequentialOptions(FlowOptions):
    """Options of ``assembly.sequential`` (Section 4.2).

    ``tolerance`` (paper rule) defaults to ``max(discs.tolerance, SEQUENTIAL_TOLERANCE)``;
    ``escapes`` applies to the paper rule only (the place rule does not lower k).
    """

    tolerance: PositiveFloat | None = Field(
        default=None,
        description="paper rule: success when ||x - d|| (R^2n) is below this "
        f"(default: max(discs.tolerance, {SEQUENTIAL_TOLERANCE:g}))",
    )
    rule: Literal["paper", "place"] = Field(
        default="paper",
        description="high-level rule: paper (the map T, eqs. (13)-(16)) or place (ours)",
    )
    finish: Literal["place", "none"] = Field(
        default="place",
        description="what a run that stopped short (paper rule: after its k-stages) does: "
        "place (the place rule finishes from there, after spreading the discs if needed, as "
        "the gradient planner's escape) or none",
    )


class ControlOptions(DiscOptions):
    """Options of ``assembly.control`` (Section 3.4)."""

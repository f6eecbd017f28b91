"""Options of ``assembly.robot`` (light to import: the plugin registers the planner with them)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from cellplan.core import Options
from cellplan.schema import PositiveFloat

__all__ = ["RobotAssemblyOptions"]


class RobotAssemblyOptions(Options):
    """Options of ``assembly.robot``: the sequential rule, the tool's height, Adapt's repair."""

    k: PositiveFloat | None = Field(
        default=None,
        description="navigation-function exponent k, eq. (2) (default: the scenario's discs.k, "
        "else chosen from n and the workspace)",
    )
    rule: Literal["paper", "place"] = Field(
        default="place",
        description="high-level rule of the sequential algorithm: paper (eqs. (13)-(16)) or "
        "place (ours, fewer grasps)",
    )
    hover: PositiveFloat = Field(
        default=0.1, description="height of the tool frame above a disc's centre (m)"
    )
    lift: PositiveFloat = Field(
        default=0.15, description="how far the tool rises over a pick and a place (m)"
    )
    repair: Literal["A0", "A1", "A2", "A3"] = Field(
        default="A3", description="repair strategy of the experience graph (Chen, Sec. 2.5)"
    )
    seed: int = Field(default=0, ge=0, description="seed of the experience planner's Solve")

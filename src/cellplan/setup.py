"""A loaded scenario with its workcell: what :func:`cellplan.load` returns.

Like OMPL's ``SimpleSetup``, a :class:`Setup` bundles what every planner needs, so that
callers pass one object instead of a scenario and the workcell built from it. The
workcell is built on first use (a disc-assembly scenario has none).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellplan.errors import Problem, ScenarioError

if TYPE_CHECKING:
    from cellplan.scenario import Scenario
    from cellplan.workcell import Workcell


class Setup:
    """A validated scenario and, built when first asked for, its :class:`Workcell`.

    Parameters
    ----------
    scenario
        The validated scenario.
    source
        Where it came from (a path or a bundled name), for messages.
    """

    def __init__(self, scenario: Scenario, source: str = "") -> None:
        self.scenario = scenario
        self.source = source or scenario.name or "<scenario>"

    @property
    def name(self) -> str:
        """The scenario's name (its file stem for bundled scenarios)."""
        return self.scenario.name or Path(self.source).stem

    @functools.cached_property
    def workcell(self) -> Workcell:
        """The workcell model (robot, obstacles, regions), built and checked on first use."""
        from cellplan.workcell import Workcell

        if self.scenario.robot is None:
            raise ScenarioError(
                [Problem("robot", "this scenario has no robot (no workcell model)")]
            )
        return Workcell.from_scenario(self.scenario)

    @property
    def has_robot(self) -> bool:
        """True when the scenario defines a robot (and so a workcell model)."""
        return self.scenario.robot is not None

    def section(self, key: str) -> Any:
        """The scenario's ``key:`` section, or a :class:`ScenarioError` saying it is missing."""
        value = getattr(self.scenario, key, None)
        if value is None:
            raise ScenarioError([Problem(key, f"this scenario has no '{key}:' section")])
        return value

    def __repr__(self) -> str:
        return f"Setup({self.name!r}, sections={self.scenario.section_names()})"


def as_setup(value: Setup | Scenario | str | Path) -> Setup:
    """A :class:`Setup` from a setup, a scenario, or a path / bundled name."""
    from cellplan.scenario import ScenarioBase, load_scenario

    if isinstance(value, Setup):
        return value
    if isinstance(value, ScenarioBase):
        return Setup(value)
    if isinstance(value, str | Path):
        return Setup(load_scenario(value), str(value))
    raise TypeError(f"expected a Setup, a Scenario or a path, got {type(value).__name__}")

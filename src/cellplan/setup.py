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
    from cellplan.validity import ValiditySpace
    from cellplan.workcell import Workcell


class Setup:
    """A validated scenario and, built when first asked for, its :class:`Workcell`.

    Parameters
    ----------
    scenario
        The validated scenario.
    source
        Where it came from (a path or a bundled name), for messages.
    folder
        Where its relative paths (meshes, URDFs) are found: the scenario file's folder
        (default: the current folder).
    """

    def __init__(self, scenario: Scenario, source: str = "", folder: Path | None = None) -> None:
        self.scenario = scenario
        self.source = source or scenario.name or "<scenario>"
        self.folder = folder

    @property
    def name(self) -> str:
        """The scenario's name (its file stem for bundled scenarios)."""
        return self.scenario.name or Path(self.source).stem

    @functools.cached_property
    def workcell(self) -> ValiditySpace:
        """The workcell model (robot, obstacles, regions), built and checked on first use:
        a :class:`~cellplan.workcell.Workcell` in 2-D, a
        :class:`~cellplan.workcell3d.Workcell3D` in 3-D; planners see only the validity
        interface both implement (:class:`cellplan.validity.ValiditySpace`)."""
        from cellplan.scenario3d import is_3d
        from cellplan.workcell import Workcell

        if self.scenario.robot is None:
            raise ScenarioError(
                [Problem("robot", "this scenario has no robot (no workcell model)")]
            )
        if is_3d(self.scenario):
            from cellplan.workcell3d import Workcell3D

            return Workcell3D.from_scenario(self.scenario, self.folder)
        return Workcell.from_scenario(self.scenario)

    @property
    def planar_workcell(self) -> Workcell:
        """The workcell of a 2-D scenario, for what only planar geometry can do (drawing
        with shapely, the FFT bitmaps); a 3-D scenario gets one line saying so."""
        from cellplan.workcell import Workcell

        cell = self.workcell
        if not isinstance(cell, Workcell):
            raise ScenarioError([Problem("workcell", "this needs a 2-D workcell; this one is 3-D")])
        return cell

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

    def _repr_png_(self) -> bytes:
        """The scenario's picture in a notebook (:func:`cellplan.drawing.draw`)."""
        from cellplan.drawing import png_bytes

        return png_bytes(self)


def as_setup(value: Setup | Scenario | str | Path) -> Setup:
    """A :class:`Setup` from a setup, a scenario, or a path / bundled name."""
    from cellplan.scenario import ScenarioBase, load_scenario

    if isinstance(value, Setup):
        return value
    if isinstance(value, ScenarioBase):
        return Setup(value)
    if isinstance(value, str | Path):
        from cellplan.registry import resolve_scenario_path

        folder = resolve_scenario_path(value).parent
        return Setup(load_scenario(value), str(value), folder)
    raise TypeError(f"expected a Setup, a Scenario or a path, got {type(value).__name__}")

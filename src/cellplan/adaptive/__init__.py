"""Adaptive path planning with an experience graph (P. C. Chen, 1994).

``cellplan.adaptive.ExperiencePlanner``
(:class:`cellplan.adaptive.experience.ExperiencePlanner`, imported on first use so that
loading a scenario stays light) answers ``plan(start, goal)`` against its experience
graph and takes workcell changes; the ``adaptive`` planner of :func:`cellplan.plan`
drives it through a scenario's task list. See docs/adaptive.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cellplan.adaptive.experience import ExperiencePlanner as ExperiencePlanner


def __getattr__(name: str) -> Any:
    # Imported on first use: this package's plugin is loaded with every scenario and
    # must stay light.
    if name == "ExperiencePlanner":
        from cellplan.adaptive.experience import ExperiencePlanner

        return ExperiencePlanner
    raise AttributeError(f"module 'cellplan.adaptive' has no attribute {name!r}")

"""The planning API: load a scenario, list planners, make one, plan.

::

    import cellplan
    setup = cellplan.load("my_cell.yaml")          # or a bundled scenario's name
    result = cellplan.plan(setup, "PLANNER")        # any name from cellplan.planners()
    result.status, result.message, result.trajectory.save("motion.csv")

:func:`plan` runs any registered planner and returns the common
:class:`~cellplan.core.Result`; :func:`make` builds a :class:`Planner` (a planner bound
to a problem and validated options) without running it, as Gymnasium's ``make`` does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellplan.core import Options, PlannerSpec, Progress, Result
from cellplan.errors import Problem, ScenarioError
from cellplan.registry import parse_options, planner
from cellplan.registry import planners as _registered
from cellplan.setup import Setup, as_setup

if TYPE_CHECKING:
    from cellplan.scenario import Scenario


def load(path_or_name: str | Path) -> Setup:
    """Read and validate a scenario file (or a bundled scenario by name).

    Raises
    ------
    ScenarioError
        One problem per mistake in the file, each naming its field.
    """
    return as_setup(path_or_name)


def loads(text: str | Mapping[str, Any]) -> Setup:
    """Validate a scenario given as YAML text, or as a mapping already parsed.

    Raises
    ------
    ScenarioError
        One problem per mistake, each naming its field; anything but text or a mapping
        is one line.
    """
    from cellplan.scenario import loads_scenario, scenario_from_data

    if isinstance(text, Mapping):
        return Setup(scenario_from_data(dict(text), "<mapping>"), "<mapping>")
    if not isinstance(text, str):
        raise ScenarioError(
            [Problem("<input>", f"expected YAML text or a mapping, got {type(text).__name__}")]
        )
    return Setup(loads_scenario(text), "<string>")


def planners() -> dict[str, PlannerSpec]:
    """Every registered planner by name (``spec.option_table()`` lists its options)."""
    return dict(_registered())


@dataclass(frozen=True)
class Planner:
    """A registered planner bound to one problem and validated options."""

    spec: PlannerSpec
    setup: Setup
    options: Options

    @property
    def name(self) -> str:
        """The planner's registry name."""
        return self.spec.name

    def __repr__(self) -> str:
        # The options a caller set; the rest are the documented defaults.
        given = {k: getattr(self.options, k) for k in sorted(self.options.model_fields_set)}
        return f"Planner({self.name!r}, setup={self.setup.name!r}, options={given})"

    def solve(self, progress: Progress | None = None) -> Result:
        """Run the planner; ``progress(done, total, text)`` is called as it goes."""
        result = self.spec.run(self.setup, self.options, progress)
        return dataclasses.replace(
            result, planner=self.spec.name, options=self.options.model_dump()
        )


def make(setup: Setup | Scenario | str | Path, name: str, /, **options: Any) -> Planner:
    """Build planner ``name`` for a problem, validating every option.

    The arguments come in the order of :func:`plan`: the problem, then the planner.

    Raises
    ------
    ArgumentError
        An unknown planner or option (with a suggestion), or an option out of range.
    ScenarioError
        The scenario lacks the section the planner needs.
    """
    spec = planner(name)
    opts = parse_options(spec, options)
    setup = as_setup(setup)
    if spec.section is not None and getattr(setup.scenario, spec.section, None) is None:
        raise ScenarioError(
            [
                Problem(
                    spec.section,
                    f"this scenario has no '{spec.section}:' section, which "
                    f"planner {spec.name} needs",
                )
            ]
        )
    return Planner(spec, setup, opts)


def plan(
    setup: Setup | Scenario | str | Path,
    name: str,
    /,
    *,
    progress: Progress | None = None,
    **options: Any,
) -> Result:
    """Run planner ``name`` on a problem and return its :class:`~cellplan.core.Result`.

    ``options`` are the planner's options (``cellplan.planners()[name].option_table()``);
    an unknown or out-of-range option raises :class:`~cellplan.errors.ArgumentError`
    naming it. A planner that runs but does not solve returns a result whose ``status``
    and ``message`` say why; it does not raise.
    """
    return make(setup, name, **options).solve(progress)

"""The compiled problem: the ``strategy:`` section read once into a frozen specification.

:meth:`cellplan.strategies.section.StrategySection.compile` builds a :class:`ProblemSpec`
from a checked scenario, once per model build: the request list with its probabilities,
the per-stage probabilities of equation (4), and the active Section VI variants. The
model build (:func:`~cellplan.strategies.model.mdp.build_model`), the memory estimate and
the live-state checks read the specification, and they learn what differs from Section V
only through the hooks of ``variants`` (:class:`~cellplan.strategies.variants.base.Variant`):
the model never imports a variant.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from cellplan.errors import Problem, ScenarioError
from cellplan.strategies.model.actions import ActionSet

if TYPE_CHECKING:
    from cellplan.strategies.model.layered import Geometry, LayeredMDP

Request = tuple[str, str, str, float]

#: Longest fine motion (and rework time, Section VI-3), in stages: ``t_f`` at any point of
#: the workcell at most this many stage times (measured on strategies_tiny: 1e6 stages
#: solve in a second, 1e9 in seconds, 1e12 no longer converges, 1e308 overflows).
MAX_FMP_STAGES = 10**6


@dataclass(frozen=True)
class Process:
    """The stochastic assembly process per stage (Section III-B, equation (4)): the stage
    time, the arrival probability ``P`` in NR (type 1), and the probabilities of a
    destination change while carrying (type 2) and of a source change while waiting
    (type 3)."""

    stage_time: float
    arrival: float
    destination_change: float = 0.0
    source_change: float = 0.0


@dataclass(frozen=True)
class Motions:
    """The action sets (equation (5)) while empty and while carrying each part."""

    empty: ActionSet
    carrying: Mapping[str, ActionSet]


@dataclass(frozen=True)
class ModeTables:
    """The per-mode arrays of a model under construction (``finish_model`` adds the move
    tables and the live states): the modes, their move classes (``classes``: a
    :class:`~.layered.MoveClasses`, ``vcls``: the class of each mode), the loss per stage,
    the FMP successor and fine-motion time field of each mode (or FMP option), the
    branches ``(ptr, layer, prob)``, the FMP outcomes (None: Section V's) and the FMP
    options (None: one per mode)."""

    modes: list[Any]
    classes: Any
    vcls: np.ndarray
    cost: np.ndarray
    fmp_next: np.ndarray
    tf: np.ndarray
    branches: tuple[Sequence[int], Sequence[int], Sequence[float]]
    outcomes: Any = None
    opt_ptr: np.ndarray | None = None


@dataclass(frozen=True)
class LayerCounts:
    """The size of a model before it is built (``Variant.layers``): ``modes`` per phase,
    FMP ``options`` per phase, move ``classes``, ``phases`` of the period, ``landings``
    per move, and ``branches`` (the sum over the modes of one phase of their branches)."""

    modes: int
    options: int
    classes: int
    phases: int = 1
    landings: int = 1
    branches: int = 0


class ModelRules(Protocol):
    """The hooks of a variant that the model calls (the whole of
    :class:`~cellplan.strategies.variants.base.Variant` satisfies it)."""

    @property
    def name(self) -> str: ...

    def obstacle_exempt(self, section: Any) -> frozenset[str]: ...

    def actions(
        self, section: Any, robot: Any, empty: ActionSet, carrying: Mapping[str, ActionSet]
    ) -> tuple[ActionSet, dict[str, ActionSet]]: ...

    def assemble(self, build: Build) -> LayeredMDP | None: ...

    def extend(self, build: Build, mdp: LayeredMDP) -> LayeredMDP: ...

    def build_problems(self, build: Build, mdp: LayeredMDP) -> list[Problem] | None: ...

    def live(self, mdp: LayeredMDP) -> bool: ...

    def problems(self, mdp: LayeredMDP) -> list[Problem] | None: ...

    def layers(self, section: Any, requests: Sequence[Any], counts: LayerCounts) -> LayerCounts: ...


@dataclass(frozen=True)
class ProblemSpec:
    """The ``strategy:`` section of one scenario, compiled (read-only).

    ``section`` is the checked section itself (its sub-models are read by the variants
    that own them); ``requests`` the ``(part, source, destination, probability)`` in
    model order; ``arrival``, ``destination_change`` and ``source_change`` the per-stage
    probabilities of Section III-B (equation (4)); ``variants`` the active Section VI
    variants in registry order (empty: the Section V model).
    """

    section: Any
    requests: tuple[Request, ...]
    stage_time: float
    arrival: float
    destination_change: float
    source_change: float
    variants: tuple[ModelRules, ...]
    # The scenario it was compiled from (its workcell-side fields: grid, robot, regions).
    scenario: Any = None

    @property
    def parts(self) -> list[str]:
        return sorted({p for p, *_ in self.requests})

    @property
    def sources(self) -> list[str]:
        return sorted({s for _, s, *_ in self.requests})

    @property
    def process(self) -> Process:
        return Process(self.stage_time, self.arrival, self.destination_change, self.source_change)

    def variant_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.variants)


def compiled(problem: Any) -> ProblemSpec:
    """``problem`` itself when it is a :class:`ProblemSpec`, else the compiled ``strategy:``
    section of the scenario ``problem``: the model build, the memory estimate and the
    planner take either, so that one solve compiles the section once and hands it on.

    Raises
    ------
    ScenarioError
        When the scenario has no ``strategy:`` section.
    """
    if isinstance(problem, ProblemSpec):
        return problem
    section = problem.strategy
    if section is None:
        raise ScenarioError([Problem("strategy", "the scenario has no strategy section")])
    spec: ProblemSpec = section.compile(problem)
    return spec


@dataclass(frozen=True)
class Build:
    """The pieces of a model under construction, as
    :func:`~cellplan.strategies.model.mdp.build_model` hands them to a variant's hooks.

    ``grid`` is the C-space grid (:class:`cellplan.cspace.Grid`), ``geometry`` the bitmaps
    of equations (1)-(3), ``empty`` and ``carrying`` the action sets (after every
    variant's ``actions``); ``in_region(name, carrying)`` is the cached region bitmap of a
    source or destination and ``tf_of(name)`` its fine-motion time field.
    """

    spec: ProblemSpec
    scenario: Any
    cell: Any
    grid: Any
    geometry: Geometry
    empty: ActionSet
    carrying: Mapping[str, ActionSet]
    in_region: Callable[[str, str | None], np.ndarray]
    tf_of: Callable[[str], np.ndarray]


def config_dimension(robot: object) -> int:
    """The C-space dimension of a robot spec (the strategy grid's axes)."""
    kind = getattr(robot, "type", "")
    if kind in ("point", "translating"):
        return 2
    if kind == "rotating":
        return 3
    if kind == "urdf":  # checked to list 1 to MAX_ARM_JOINTS joints before this is read
        return len(getattr(robot, "joints", None) or [])
    return len(getattr(robot, "links", []))

"""The registry of the Section VI variants: name -> :class:`~.base.Variant`.

Registry order is the order in which the model build applies the variants' hooks (the
first variant that assembles a model of its own wins; the others extend it). Adding a
variant is one module with a subclass of :class:`~.base.Variant` and one entry here
(docs/strategies.md, "How to add a variant").
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from cellplan.errors import Problem
from cellplan.strategies.variants.base import Variant
from cellplan.strategies.variants.conveyors import TIME_VARYING
from cellplan.strategies.variants.failures import FAILURES
from cellplan.strategies.variants.noise import NOISE
from cellplan.strategies.variants.simultaneous import SIMULTANEOUS

#: Every variant by name (read-only).
VARIANTS: Mapping[str, Variant] = MappingProxyType(
    {v.name: v for v in (SIMULTANEOUS, FAILURES, NOISE, TIME_VARYING)}
)


def active_variants(section: Any) -> tuple[Variant, ...]:
    """The variants a ``strategy:`` section asks for, in registry order (none: Section V)."""
    return tuple(v for v in VARIANTS.values() if v.active(section))


def model_variants(mdp: Any) -> tuple[Variant, ...]:
    """The variants of a model: those it was built with (``mdp.variants``), else, for a
    model read from a strategy file, those whose structure it has (``Variant.in_model``),
    in registry order. The simulator and the strategy's queries call their hooks."""
    if mdp.variants:
        return tuple(mdp.variants)
    return tuple(v for v in VARIANTS.values() if v.in_model(mdp))


def variant_problems(section: Any, scenario: Any) -> list[Problem]:
    """Every variant's scenario checks, in the order of :data:`CHECK_ORDER`."""
    problems: list[Problem] = []
    for name in CHECK_ORDER:
        problems.extend(VARIANTS[name].check(section, scenario))
    return problems


#: The order of the variants' checks in ``cellplan validate``'s list (as before the seam).
CHECK_ORDER = ("failures", "noise", "simultaneous", "time_varying")

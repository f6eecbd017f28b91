"""Simultaneous requests (Section VI-2 of the strategies paper): the variant.

Requests keep arriving while the robot serves one, up to ``max_pending`` open at once,
and the loss counts the open requests per stage, weighted by ``urgency``. The model is
assembled by :func:`cellplan.strategies.variants.pending.assemble_pending` (its module
docstring lists the choices where the paper is silent); the runs by
:mod:`cellplan.strategies.variants.pending_sim`. This module holds what the scenario
schema needs (limits, checks) and the :class:`~.base.Variant`, and imports no kernels.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from cellplan.errors import Problem
from cellplan.strategies.model.spec import Build, LayerCounts, Motions
from cellplan.strategies.variants.base import Variant, not_combined
from cellplan.strategies.variants.request_sets import (
    MAX_PENDING,
    MAX_PENDING_MODES,
    PENDING_POLICIES,
    mode_counts,
    option_count,
    pending_modes,
)

#: Re-exported: the limits and counts of the modes are reached through the variant.
__all__ = [
    "MAX_PENDING",
    "MAX_PENDING_MODES",
    "PENDING_POLICIES",
    "SIMULTANEOUS",
    "SimultaneousVariant",
    "mode_counts",
    "option_count",
    "pending_modes",
]

if TYPE_CHECKING:
    from cellplan.strategies.model.layered import LayeredMDP


class SimultaneousVariant(Variant):
    """Section VI-2: requests arrive while others are open, up to ``max_pending``."""

    name = "simultaneous"
    paper = "Section VI-2"
    keys = ("max_pending", "urgency")

    def active(self, section: Any) -> bool:
        return bool(section.max_pending > 1 or section.urgency)

    def in_model(self, mdp: LayeredMDP) -> bool:
        return any(m.kind == "Q" for m in mdp.modes)

    def check(self, section: Any, scenario: Any) -> list[Problem]:
        """One line per mistake in ``max_pending`` and ``urgency`` (Section VI-2)."""
        problems = [
            Problem(f"strategy.urgency.{part}", "unknown part")
            for part in section.urgency
            if part not in scenario.parts
        ]
        if not self.active(section):
            return problems
        problems += not_combined(
            "simultaneous requests (max_pending or urgency)",
            {
                "failures": bool(section.failures),
                "destination_change": section.destination_change is not None,
                "source_change": section.source_change is not None,
            },
        )
        if scenario.parts and scenario.sources and scenario.destinations and not problems:
            R = len(section.request_list(scenario))
            M = sum(mode_counts(R, section.max_pending))
            if M > MAX_PENDING_MODES:
                problems.append(
                    Problem(
                        "strategy.max_pending",
                        f"{section.max_pending} open requests of {R} types make {M:,} modes "
                        f"(at most {MAX_PENDING_MODES:,}); lower it or list fewer requests",
                    )
                )
        return problems

    def assemble(self, build: Build) -> LayeredMDP | None:
        # Deferred for start-up time: the scenario schema imports this module, the model
        # build (numba) only runs in a planner. No cycle: .pending imports this module.
        from cellplan.strategies.model.bundles import Grid
        from cellplan.strategies.variants.pending import assemble_pending

        spec, grid = build.spec, build.grid
        shape = np.asarray(grid.shape, np.int64)
        lower = np.asarray(grid.lower, float)
        upper = np.asarray(grid.upper, float)
        return assemble_pending(
            Grid(shape, lower, upper, (upper - lower) / shape, np.asarray(grid.periodic, bool)),
            spec.requests,
            build.geometry,
            Motions(build.empty, build.carrying),
            spec.process,
            spec.section.max_pending,
            spec.section.urgency,
        )

    def build_problems(self, build: Build, mdp: LayeredMDP) -> list[Problem] | None:
        from cellplan.strategies.variants.pending import pending_problems  # start-up time

        return pending_problems(mdp, build.spec.requests)

    def layers(self, section: Any, requests: Any, counts: LayerCounts) -> LayerCounts:
        R, k = len(requests), section.max_pending
        S = len({s for _, s, *_ in requests})
        PS = len({(p, s) for p, s, *_ in requests})
        modes = sum(mode_counts(R, k))
        return LayerCounts(
            modes=modes,
            options=option_count(R, k),
            classes=2 ** min(S, 20) + PS,  # a class per set of sources, per (part, source)
            phases=counts.phases,
            landings=counts.landings,
            branches=modes * (1 + R),  # itself and at most one arrival per request type
        )

    def modes_line(self, mdp: LayeredMDP, section: Any) -> str | None:
        R, k = len(mdp.request_prob), section.max_pending
        empty, carrying = mode_counts(R, k)
        each = ", ".join(f"{i}: {sum(mode_counts(R, i)):,}" for i in range(1, k + 1))
        return (
            f"{mdp.n_modes:,} (Section VI-2: up to {k} open requests of {R} types: {empty:,} "
            f"empty + {carrying:,} carrying; max_pending {each}); states: {int(mdp.live.sum()):,}"
        )

    def file_modes(self, meta: Any, spec: Any, fail: Any) -> bool:
        # Deferred for start-up time (the file checks need numpy only when a file is read).
        from cellplan.strategies.variants.pending_files import check_pending_scenario

        check_pending_scenario(meta, list(spec.requests), spec.section.max_pending, fail)
        return True

    def policies(self) -> tuple[str, ...] | None:
        return PENDING_POLICIES

    def lookahead(self, mdp: LayeredMDP) -> int | None:
        return 1  # the lookahead follows one FMP per mode, not a choice of them

    def fmp_options(self) -> bool:
        return True


SIMULTANEOUS = SimultaneousVariant()

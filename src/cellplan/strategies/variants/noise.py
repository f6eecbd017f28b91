"""Noisy motion (Section VI-4 of the strategies paper, its first step): the variant.

Each move lands at one of several displacements around the commanded one, with given
probabilities. The action sets carry the noisy landings after the commanded moves
(:func:`~cellplan.strategies.model.actions.with_noise`), the model's ``noise_prob`` their
probabilities, and a move is allowed where every landing's swept motion is free.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field

from cellplan import units
from cellplan.errors import Problem
from cellplan.schema import Probability, StrictModel
from cellplan.strategies.model.actions import ActionSet, with_noise
from cellplan.strategies.model.spec import LayerCounts, config_dimension
from cellplan.strategies.variants.base import Variant

if TYPE_CHECKING:
    from cellplan.strategies.model.layered import LayeredMDP

#: Most outcomes of the noise model (each is a stencil per move in the model's tables).
MAX_NOISE_OUTCOMES = 16
_SUM_TOL = 1e-9


class NoiseOutcome(StrictModel):
    """One place a move can land, relative to the commanded one (Section VI-4)."""

    offset: list[float] = Field(
        description="displacement from the commanded landing point: [along, across] the move "
        "(frame: motion), or one value per C-space axis, angles in degrees (frame: world)",
        examples=[[0, 1.5]],
    )
    probability: Probability = Field(description="probability of this outcome")


class NoiseSpec(StrictModel):
    """Noisy motion, the first step of Section VI-4: each move lands at one of several
    displacements around the commanded one with given probabilities."""

    outcomes: Annotated[list[NoiseOutcome], Field(min_length=1, max_length=MAX_NOISE_OUTCOMES)] = (
        Field(description="where a move lands, with probabilities summing to 1")
    )
    frame: Literal["motion", "world"] = Field(
        default="motion",
        description="offsets along and across each move (translating robots), or along the "
        "C-space axes (any robot)",
    )


class NoiseVariant(Variant):
    """Section VI-4: a move lands at one of several displacements (a discrete law)."""

    name = "noise"
    paper = "Section VI-4"
    keys = ("noise",)

    def active(self, section: Any) -> bool:
        return section.noise is not None

    def check(self, section: Any, scenario: Any) -> list[Problem]:
        return check_noise(section.noise, scenario)

    def in_model(self, mdp: LayeredMDP) -> bool:
        return len(mdp.noise_prob) > 1

    def actions(
        self, section: Any, robot: Any, empty: ActionSet, carrying: Mapping[str, ActionSet]
    ) -> tuple[ActionSet, dict[str, ActionSet]]:
        noise = section.noise
        prob = np.array([o.probability for o in noise.outcomes], float)
        given = [o.offset for o in noise.outcomes]
        if noise.frame == "world":  # angles in degrees in the file
            offsets = np.stack([units.config_from_file(robot.axis_names, v) for v in given])
        else:
            offsets = np.array(given, float)
        return (
            with_noise(empty, offsets, prob, noise.frame),
            {p: with_noise(a, offsets, prob, noise.frame) for p, a in carrying.items()},
        )

    def layers(self, section: Any, requests: Any, counts: LayerCounts) -> LayerCounts:
        return LayerCounts(
            counts.modes,
            counts.options,
            counts.classes,
            counts.phases,
            len(section.noise.outcomes),
            counts.branches,
        )

    def facts(self, mdp: LayeredMDP) -> list[tuple[str, str, Any, str]]:
        J = len(mdp.noise_prob)
        if J == 1:  # one landing: the moves are exact after all
            return []
        return [
            (
                "noisy_motion",
                "noisy motion",
                J,
                f"{J} landings per move (Section VI-4), a move allowed "
                f"where every landing is free; states: {int(mdp.live.sum()):,}",
            )
        ]

    def lookahead(self, mdp: LayeredMDP) -> int | None:
        if len(mdp.noise_prob) == 1:  # one landing: the moves are exact after all
            return None
        return 1  # the lookahead follows commanded landings; noisy moves land elsewhere

    def landing(self, mdp: LayeredMDP, rng: np.random.Generator) -> int | None:
        if len(mdp.noise_prob) == 1:  # one landing: nothing to draw (the stream is kept)
            return None
        cum = np.cumsum(mdp.noise_prob)
        return min(int(np.searchsorted(cum, rng.random() * cum[-1], "right")), len(cum) - 1)


def check_noise(noise: NoiseSpec | None, scenario: Any) -> list[Problem]:
    """One line per mistake in ``strategy.noise`` (Section VI-4)."""
    robot = scenario.robot
    if noise is None or robot is None:
        return []
    problems: list[Problem] = []
    total = sum(o.probability for o in noise.outcomes)
    if abs(total - 1.0) > _SUM_TOL:
        problems.append(
            Problem("strategy.noise.outcomes", f"probabilities sum to {total:g}, not 1")
        )
    dim = config_dimension(robot)
    translating = robot.type in ("point", "translating")
    if noise.frame == "motion" and not translating:
        problems.append(
            Problem(
                "strategy.noise.frame",
                f"'motion' (along, across a move) is for translating robots, not "
                f"{robot.type!r}; use 'world'",
            )
        )
    want = 2 if noise.frame == "motion" else dim
    b = scenario.workcell.bounds
    reach = math.hypot(b.xmax - b.xmin, b.ymax - b.ymin)
    for i, o in enumerate(noise.outcomes):
        where = f"strategy.noise.outcomes[{i}].offset"
        if len(o.offset) != want:
            problems.append(Problem(where, f"has {len(o.offset)} values; expected {want}"))
        elif not all(math.isfinite(v) and abs(v) <= reach for v in o.offset):
            problems.append(
                Problem(where, f"values must be finite and at most {reach:.4g} in size")
            )
    return problems


NOISE = NoiseVariant()

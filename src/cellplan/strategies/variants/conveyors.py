"""Time-varying models and conveyors (Section VI-1 of the strategies paper): the variant.

A period of ``T`` stages (``strategy.period``), arrivals that vary over it
(``arrival_profile``) and sources or destinations on conveyor belts (``belts``). The
product model (mode, phase) is assembled by :mod:`cellplan.strategies.variants.periodic`
(its module docstring lists the choices where the paper is silent). This module holds
what the scenario schema needs (limits, the belt spec, checks), the belts' offsets and
the :class:`~.base.Variant`, and imports no kernels.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any

from pydantic import Field

from cellplan.errors import Problem
from cellplan.schema import NonNegativeFloat, StrictModel, Vec2
from cellplan.strategies.model.spec import Build, LayerCounts
from cellplan.strategies.variants.base import Variant, not_combined

if TYPE_CHECKING:
    from cellplan.strategies.model.layered import LayeredMDP

#: Most stages in the period of a time-varying model (Section VI-1).
MAX_PERIOD = 1000
#: Most layers (modes times phases) of a time-varying model: each is a grid of values.
MAX_PERIODIC_LAYERS = 20_000
#: An arrival profile: a factor per phase of the period.
Profile = Annotated[list[NonNegativeFloat], Field(max_length=MAX_PERIOD)]


class BeltSpec(StrictModel):
    """A source or destination on a conveyor belt (Section VI-1, Fig. 16).

    The region moves with constant ``velocity``: at phase ``t`` of the period it lies at
    its scenario position plus ``velocity * t * stage_time``; at the end of each period the
    next part comes in at the scenario position again (a part every ``period`` stages).
    """

    velocity: Vec2 = Field(
        description="workcell units per unit time, [vx, vy]", examples=[[2.0, 0.0]]
    )


def time_varying(section: Any) -> bool:
    """Whether a ``strategy:`` section's model is periodic in time (Section VI-1)."""
    return section.period > 1 or bool(section.belts) or section.arrival_profile is not None


class TimeVaryingVariant(Variant):
    """Section VI-1: a periodic process (arrival profile) and regions on conveyor belts."""

    name = "time_varying"
    paper = "Section VI-1"
    keys = ("period", "arrival_profile", "belts")
    file_keys = ("period", "phases", "belts")

    def active(self, section: Any) -> bool:
        return time_varying(section)

    def in_model(self, mdp: LayeredMDP) -> bool:
        return mdp.period > 1

    def check(self, section: Any, scenario: Any) -> list[Problem]:
        return check_time_varying(section, scenario) if self.active(section) else []

    def obstacle_exempt(self, section: Any) -> frozenset[str]:
        # Regions on a belt are never obstacles (the belt runs under the working plane).
        return frozenset(section.belts)

    def extend(self, build: Build, mdp: LayeredMDP) -> LayeredMDP:
        # Deferred for start-up time: the scenario schema imports this module, the model
        # (numba) only a planner. No cycle: .periodic imports this module, not the reverse.
        from cellplan.strategies.variants.periodic import periodic_model

        return periodic_model(build, mdp)

    def live(self, mdp: LayeredMDP) -> bool:
        from cellplan.strategies.variants.periodic import periodic_live  # start-up time

        periodic_live(mdp)
        return True

    def problems(self, mdp: LayeredMDP) -> list[Problem] | None:
        from cellplan.strategies.variants.periodic import periodic_problems  # start-up time

        return periodic_problems(mdp)

    def check_solver(self, method: str, damping: float) -> list[str]:
        if method == "general" and damping >= 1.0:
            return [
                "relative value iteration (general) cycles with the period of a time-varying "
                "model (every stage advances the phase): set strategy.solver.damping below 1, "
                "or use auto or policy"
            ]
        return []

    def layers(self, section: Any, requests: Any, counts: LayerCounts) -> LayerCounts:
        return LayerCounts(
            counts.modes,
            counts.options,
            counts.classes,
            section.period,
            counts.landings,
            counts.branches,
        )

    def modes_line(self, mdp: LayeredMDP, section: Any) -> str | None:
        belts = sorted(mdp.belts)
        moving = f"belt{'s' if len(belts) > 1 else ''} {', '.join(belts)}" if belts else "no belts"
        return (
            f"{mdp.modes_per_phase:,} x {mdp.period} phases = {mdp.n_modes:,} layers (Section "
            f"VI-1: period {mdp.period} stages, {moving})"
        )

    def file_meta(self, mdp: LayeredMDP) -> dict[str, Any]:
        return {
            "period": mdp.period,
            "phases": [m.phase for m in mdp.modes],
            "belts": {name: [float(v) for v in vel] for name, vel in mdp.belts.items()},
        }

    def region_offset(self, mdp: LayeredMDP, region: str, layer: int) -> tuple[float, float]:
        from cellplan.strategies.variants.periodic import region_offset  # start-up time

        return region_offset(mdp, region, layer) or (0.0, 0.0)


def check_time_varying(sec: Any, scenario: Any) -> list[Problem]:
    """One line per mistake in ``period``, ``arrival_profile`` and ``belts`` (Section VI-1)."""
    problems = []
    T = sec.period
    if T < 2:
        problems.append(
            Problem(
                "strategy.period",
                "belts and arrival_profile need a period of at least 2 stages",
            )
        )
    problems += not_combined(
        "a time-varying model (period, belts, arrival_profile)",
        {
            "failures": bool(sec.failures),
            "noise": sec.noise is not None,
            "max_pending": bool(sec.max_pending > 1 or sec.urgency),
            "destination_change": sec.destination_change is not None,
            "source_change": sec.source_change is not None,
        },
    )
    for where, spec in [("fine_motion", sec.fine_motion)] + [
        (f"fine_motion_regions.{r}", f) for r, f in sec.fine_motion_regions.items()
    ]:
        if spec.point is not None and spec.rate > 0:
            problems.append(
                Problem(
                    f"strategy.{where}",
                    "a time-varying model needs a constant fine-motion time (no point and "
                    "rate): an FMP advances the phase by its time",
                )
            )
    profile = sec.arrival_profile
    if profile is not None:
        base = sec.arrival.per_stage(sec.stage_time)
        if len(profile) != T:
            problems.append(
                Problem(
                    "strategy.arrival_profile",
                    f"has {len(profile)} values; the period has {T} stages",
                )
            )
        elif not any(w * base > 0 for w in profile):
            problems.append(
                Problem("strategy.arrival_profile", "no request ever arrives (all zero)")
            )
        for t, w in enumerate(profile):
            if w * base > 1.0:
                problems.append(
                    Problem(
                        f"strategy.arrival_profile[{t}]",
                        f"{w:g} times the arrival probability {base:g} is {w * base:g}, above 1",
                    )
                )
    b = scenario.workcell.bounds
    for name, belt in sec.belts.items():
        where = f"strategy.belts.{name}"
        region = scenario.sources.get(name) or scenario.destinations.get(name)
        if region is None:
            problems.append(Problem(where, f"unknown source or destination {name!r}"))
            continue
        x0, y0, x1, y1 = _components_box(region)
        travel = (T - 1) * sec.stage_time
        dx, dy = belt.velocity[0] * travel, belt.velocity[1] * travel
        lo_x, hi_x = x0 + min(dx, 0.0), x1 + max(dx, 0.0)
        lo_y, hi_y = y0 + min(dy, 0.0), y1 + max(dy, 0.0)
        if lo_x < b.xmin or hi_x > b.xmax or lo_y < b.ymin or hi_y > b.ymax:
            problems.append(
                Problem(
                    f"{where}.velocity",
                    f"the belt carries {name} outside the workcell: over the period it "
                    f"sweeps x {lo_x:g} to {hi_x:g}, y {lo_y:g} to {hi_y:g}; the workcell "
                    f"is x {b.xmin:g} to {b.xmax:g}, y {b.ymin:g} to {b.ymax:g}",
                )
            )
    if scenario.parts and scenario.sources and scenario.destinations and not problems:
        layers = T * (2 * len(sec.request_list(scenario)) + 1)
        if layers > MAX_PERIODIC_LAYERS:
            problems.append(
                Problem(
                    "strategy.period",
                    f"{T} phases of {layers // T:,} modes make {layers:,} layers (at most "
                    f"{MAX_PERIODIC_LAYERS:,}); shorten the period or list fewer requests",
                )
            )
    return problems


def _components_box(region: object) -> tuple[float, float, float, float]:
    """The bounding box of a region spec's components (workcell units)."""
    boxes = [c.to_shapely().bounds for c in region.components]  # type: ignore[attr-defined]
    return (
        min(b[0] for b in boxes),
        min(b[1] for b in boxes),
        max(b[2] for b in boxes),
        max(b[3] for b in boxes),
    )


TIME_VARYING = TimeVaryingVariant()

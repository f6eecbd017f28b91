"""The ``strategy:`` scenario section: the stochastic assembly process and the solver settings.

Everything the strategies paper (Sharma, LaValle and Hutchinson 1996) needs beyond the
workcell itself: the stage time and speeds of Section III-B, the request distribution
and the three transition types of Section III-B (with probabilities or Poisson rates
converted by equation (4)), contact or enclosure regions and the expected fine-motion
time of Section III-C (equation (7), Fig. 5), the grid and the action set of Section IV.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, model_validator

from cellplan.errors import Problem
from cellplan.schema import (
    Cells,
    Name,
    NonNegativeFloat,
    PositiveFloat,
    Probability,
    StrictModel,
    Vec2,
)
from cellplan.strategies.model.spec import MAX_FMP_STAGES, ProblemSpec, config_dimension
from cellplan.strategies.variants.conveyors import (
    MAX_PERIOD,
    MAX_PERIODIC_LAYERS,
    BeltSpec,
    Profile,
)
from cellplan.strategies.variants.failures import FailureSpec
from cellplan.strategies.variants.noise import MAX_NOISE_OUTCOMES, NoiseOutcome, NoiseSpec
from cellplan.strategies.variants.registry import VARIANTS, active_variants, variant_problems
from cellplan.strategies.variants.simultaneous import MAX_PENDING, MAX_PENDING_MODES, mode_counts

if TYPE_CHECKING:
    from cellplan.scenario import Scenario

_SUM_TOL = 1e-9
#: The variants a 3-D workcell refuses, in the order of their lines (by their first key).
ARM3D_ORDER = ("time_varying", "noise", "failures", "simultaneous")
#: Re-exported: the limits of the variants' keys, for the strategy file format.
__all__ = [
    "MAX_FMP_STAGES",
    "MAX_NOISE_OUTCOMES",
    "MAX_PENDING",
    "MAX_PENDING_MODES",
    "MAX_PERIOD",
    "MAX_PERIODIC_LAYERS",
    "BeltSpec",
    "FailureSpec",
    "NoiseOutcome",
    "NoiseSpec",
    "StrategySection",
    "mode_counts",
]

MAX_REQUESTS = 1000
#: The longest simulated run, in stages (``cellplan simulate``, ``cellplan.simulate`` and
#: the planner's sample run).
MAX_STAGES = 1_000_000
#: Most active joints of a 3-D arm the strategy's grid holds (a grid of 4 joints at the
#: paper's resolution would not fit in memory: 48^4 cells times 2R + 1 layers).
MAX_ARM_JOINTS = 3
#: Smallest arrival probability per stage: the idle stretch between requests lasts
#: ``1 / P`` stages, and the solver takes differences of values of that size; at
#: ``P >= sqrt(eps)`` (float64's ``eps``, so about 1.5e-8) half of float64's digits
#: survive them (measured on strategies_tiny: 1e-9 solves, 1e-12 fails in the solver's
#: least squares). A rate is checked by the probability it gives, ``1 - exp(-rate dt)``.
MIN_ARRIVAL = math.sqrt(2.0**-52)
#: Longest stage (time units) and largest urgency weight (Section VI-2). A stage's loss is
#: at most ``stage_time x urgency x max_pending``, and a strategy file's values are held to
#: ``live states x that loss / the rarest probability`` and to 1e150 (fileformat.py): with
#: both at most 1e6, every value a solve can produce is a value its own file accepts.
MAX_STAGE_TIME = 1e6
MAX_URGENCY = 1e6
"""Most requestable (part, source, destination) triples: ``2R + 1`` modes, each a layer
of the grid. The paper's largest problem has 72; 1,000 requests on the tiny workcell
validate in about 10 s."""


class Rate(StrictModel):
    """A per-stage probability, given directly or as a Poisson rate (equation (4)).

    Exactly one of ``probability`` (per stage) and ``rate`` (events per unit time) is given;
    a rate becomes ``1 - exp(-rate * stage_time)``.
    """

    probability: Probability | None = Field(
        default=None, description="probability per stage, in [0, 1]", examples=[0.1]
    )
    rate: PositiveFloat | None = Field(
        default=None,
        description="events per unit time (Poisson), instead of probability",
        examples=[0.2],
    )

    @model_validator(mode="after")
    def _exactly_one(self) -> Rate:
        if (self.probability is None) == (self.rate is None):
            raise ValueError("give exactly one of 'probability' and 'rate'")
        return self

    def per_stage(self, stage_time: float) -> float:
        """The probability that the event happens within one stage (equation (4))."""
        if self.probability is not None:
            return float(self.probability)
        assert self.rate is not None
        return 1.0 - math.exp(-self.rate * stage_time)


class RequestSpec(StrictModel):
    """One requestable (part, source, destination) and, optionally, its probability."""

    part: Name = Field(description="a part's name", examples=["P1"])
    source: Name = Field(description="a source's name", examples=["S1"])
    destination: Name = Field(description="a destination's name", examples=["D1"])
    probability: Probability | None = Field(
        default=None,
        description="relative probability of this request on arrival (default: uniform)",
        examples=[0.5],
    )


class FineMotionSpec(StrictModel):
    """Expected fine-motion time t_f of Section III-C.

    ``t_f(q) = time + rate * |tool(q) - point|``: a constant when ``rate`` is 0 (or no
    ``point`` is given), otherwise growing with the gripper's workspace distance from a
    preferred contact point (Fig. 5).
    """

    time: NonNegativeFloat = Field(
        default=1.0, description="constant part of t_f (time units)", examples=[1.5]
    )
    point: Vec2 | None = Field(
        default=None, description="preferred contact point (workcell units)", examples=[[15, 26]]
    )
    rate: NonNegativeFloat = Field(
        default=0.0, description="growth of t_f per workcell unit from point", examples=[0.1]
    )


class ActionSpec(StrictModel):
    """The action set (equation (5) and its variants of Section V).

    ``headings`` is K, the number of evenly spaced directions of a translating robot
    (plus stay and FMP). A rotating robot turns by ``turn_speed * stage_time`` either way
    or moves along its axis, forward or backward. An arm moves one joint by
    ``speed * stage_time`` degrees either way.
    """

    headings: Annotated[int, Field(ge=3, le=64)] = Field(
        default=16, description="K, evenly spaced directions of a translating robot", examples=[8]
    )


#: The solver methods (:func:`cellplan.strategies.solve.solver.solve`); the one list of them.
SolverMethod = Literal["auto", "structured", "general", "policy"]


class SolverSpec(StrictModel):
    """Stopping rule and method of the average-cost solver (Section IV)."""

    method: SolverMethod = Field(
        default="auto",
        description="structured (layered shortest paths + NR fixed point; Section V models "
        "only), policy (policy iteration, any model), general (relative value iteration), or "
        "auto (structured where the model allows it, else policy)",
    )
    tolerance: PositiveFloat = Field(
        default=1e-6,
        description="stop when the gain's certified bracket is narrower",
        examples=[1e-6],
    )
    max_sweeps: Annotated[int, Field(ge=1, le=10_000_000)] = Field(
        default=20000, description="give up (not converged) after this many sweeps"
    )
    damping: Annotated[float, Field(gt=0, le=1)] = Field(
        default=1.0, description="relaxation of the outer fixed point on the gain (1: none)"
    )


class StrategySection(StrictModel):
    """Settings of the ``strategy:`` section (the strategies paper)."""

    stage_time: Annotated[PositiveFloat, Field(le=MAX_STAGE_TIME)] = Field(
        default=1.0, description="Delta t, time units per stage"
    )
    speed: PositiveFloat = Field(
        description="translation per unit time (workspace units); for arms, degrees per unit time"
    )
    turn_speed: PositiveFloat | None = Field(
        default=None, description="rotating robot: degrees per unit time"
    )
    carry_speed_factor: dict[Name, PositiveFloat] = Field(
        default_factory=dict, description="per part: speed multiplier while carrying it"
    )
    arrival: Rate = Field(description="request arrival while in NR (transition type 1)")
    requests: Literal["all"] | Annotated[list[RequestSpec], Field(max_length=MAX_REQUESTS)] = Field(
        default="all", description="'all' (every part x source x destination, uniform) or a list"
    )
    destination_change: Rate | None = Field(
        default=None, description="transition type 2, per stage in C"
    )
    source_change: Rate | None = Field(
        default=None, description="transition type 3, per stage in W"
    )
    regions: Literal["contact", "enclosure"] = Field(
        default="contact",
        description="FMP allowed where the carried part (or gripper) touches the region "
        "(contact) or lies inside it (enclosure)",
    )
    fine_motion: FineMotionSpec = Field(
        default_factory=FineMotionSpec,
        description="expected fine-motion time t_f (Sec. III-C)",
    )
    fine_motion_regions: dict[Name, FineMotionSpec] = Field(
        default_factory=dict, description="per source/destination override of fine_motion"
    )
    cells: list[Cells] | None = Field(
        default=None,
        description="grid cells per C-space axis (default: cspace.cells, else the robot "
        "kind's default: 128 x 128 point and translating, 64 x 64 x 32 rotating, 64 per arm joint)",
    )
    actions: ActionSpec = Field(default_factory=ActionSpec, description="the action set, eq. (5)")
    home: list[float] | None = Field(
        default=None,
        description="home configuration of the return-home baseline, angles in degrees "
        "(default: robot.start)",
    )
    solver: SolverSpec = Field(
        default_factory=SolverSpec, description="stopping rule and method of the solver"
    )
    failures: Annotated[list[FailureSpec], Field(max_length=MAX_REQUESTS)] = Field(
        default_factory=list, description="fine motions that can fail (Section VI-3)"
    )
    noise: NoiseSpec | None = Field(
        default=None, description="where moves land: a discrete distribution (Section VI-4)"
    )
    max_pending: Annotated[int, Field(ge=1, le=MAX_PENDING)] = Field(
        default=1,
        description="most requests open at once (Section VI-2); 1: one at a time (Section V)",
    )
    urgency: dict[Name, Annotated[PositiveFloat, Field(le=MAX_URGENCY)]] = Field(
        default_factory=dict,
        description="per part: weight of its open requests in the loss (Section VI-2; default 1)",
    )

    period: Annotated[int, Field(ge=1, le=MAX_PERIOD)] = Field(
        default=1,
        description="stages per period of a time-varying model (Section VI-1); 1: stationary",
    )
    arrival_profile: Profile | None = Field(
        default=None,
        description="per phase of the period, a factor on the arrival probability "
        "(Section VI-1; one value per stage of the period)",
    )
    belts: dict[Name, BeltSpec] = Field(
        default_factory=dict,
        description="sources and destinations that move on a conveyor belt (Section VI-1)",
    )

    def compile(self, scenario: Scenario) -> ProblemSpec:
        """The problem specification of this (checked) section: the requests, the
        per-stage probabilities of equation (4) and the active variants, read once."""
        return ProblemSpec(
            section=self,
            requests=tuple(self.request_list(scenario)),
            stage_time=float(self.stage_time),
            arrival=self.arrival.per_stage(self.stage_time),
            destination_change=(
                self.destination_change.per_stage(self.stage_time)
                if self.destination_change
                else 0.0
            ),
            source_change=(
                self.source_change.per_stage(self.stage_time) if self.source_change else 0.0
            ),
            variants=active_variants(self),
            scenario=scenario,
        )

    def arrival_by_phase(self) -> list[float]:
        """The arrival probability per stage at each phase of the period (Section VI-1)."""
        base = self.arrival.per_stage(self.stage_time)
        profile = self.arrival_profile or [1.0] * self.period
        return [base * w for w in profile]

    def reserved_regions(self) -> set[str]:
        """Destinations an active variant reserves (reject regions, Section VI-3), left out
        of ``requests: all``."""
        reserved: set[str] = set()
        for variant in VARIANTS.values():
            reserved |= variant.reserved_regions(self)
        return reserved

    def request_list(self, scenario: Scenario) -> list[tuple[str, str, str, float]]:
        """The requestable (part, source, destination, probability), in a fixed order."""
        if self.requests == "all":
            bins = self.reserved_regions()
            triples = [
                (p, s, d)
                for p in scenario.parts
                for s in scenario.sources
                for d in scenario.destinations
                if d not in bins
            ]
            n = len(triples)
            return [(p, s, d, 1.0 / n) for p, s, d in triples]
        given = [r.probability for r in self.requests]
        if all(v is None for v in given):
            n = len(self.requests)
            return [(r.part, r.source, r.destination, 1.0 / n) for r in self.requests]
        return [
            (r.part, r.source, r.destination, float(r.probability or 0.0)) for r in self.requests
        ]

    def check(self, scenario: Scenario) -> list[Problem]:
        """Cross-reference checks, one :class:`Problem` per mistake."""
        problems: list[Problem] = []
        robot = scenario.robot
        if robot is None:
            return [Problem("robot", "the strategy section needs a robot")]
        if robot.type == "urdf":
            # The grid of a 3-D arm is its active joints; what is refused here is what the
            # 3-D model does not hold, one line each, before anything is built.
            arm = self._check_arm3d(scenario)
            if arm:
                return arm
        if not scenario.parts:
            problems.append(Problem("parts", "the strategy section needs at least one part"))
        if not scenario.sources:
            problems.append(Problem("sources", "the strategy section needs at least one source"))
        if not scenario.destinations:
            problems.append(
                Problem("destinations", "the strategy section needs at least one destination")
            )
        if robot.type == "rotating" and self.turn_speed is None:
            problems.append(Problem("strategy.turn_speed", "a rotating robot needs a turn speed"))
        if robot.type != "rotating" and self.turn_speed is not None:
            problems.append(
                Problem("strategy.turn_speed", f"only used by a rotating robot, not {robot.type!r}")
            )
        for part in self.carry_speed_factor:
            if part not in scenario.parts:
                problems.append(Problem(f"strategy.carry_speed_factor.{part}", "unknown part"))
        problems.extend(self._check_steps(scenario))
        for region in self.fine_motion_regions:
            if region not in scenario.sources and region not in scenario.destinations:
                problems.append(
                    Problem(
                        f"strategy.fine_motion_regions.{region}", "unknown source or destination"
                    )
                )
        if isinstance(self.requests, list):
            problems.extend(self._check_requests(scenario, self.requests))
        elif scenario.parts and scenario.sources and scenario.destinations:
            n = len(scenario.parts) * len(scenario.sources) * len(scenario.destinations)
            if n > MAX_REQUESTS:
                problems.append(
                    Problem(
                        "strategy.requests",
                        f"'all' makes {n:,} requests (parts x sources x destinations); at "
                        f"most {MAX_REQUESTS:,}: list the requests that occur",
                    )
                )
        dim = config_dimension(robot)
        if self.cells is not None and len(self.cells) != dim:
            problems.append(
                Problem(
                    "strategy.cells",
                    f"has {len(self.cells)} entries; the C-space has dimension {dim}",
                )
            )
        if self.home is not None and len(self.home) != dim:
            problems.append(
                Problem(
                    "strategy.home",
                    f"has {len(self.home)} entries; the C-space has dimension {dim}",
                )
            )
        problems.extend(self._check_magnitudes(scenario))
        problems.extend(variant_problems(self, scenario))
        if self.destination_change is not None and not problems:
            problems.extend(self._check_changes(scenario, "destination"))
        if self.source_change is not None and not problems:
            problems.extend(self._check_changes(scenario, "source"))
        return problems

    def _check_magnitudes(self, scenario: Scenario) -> list[Problem]:
        """Numbers the solver can work with: the arrival probability at least
        :data:`MIN_ARRIVAL`, every fine-motion and rework time at most
        :data:`MAX_FMP_STAGES` stage times (``t_f`` at the workcell corner farthest from its
        point)."""
        problems: list[Problem] = []
        arrival = self.arrival.per_stage(self.stage_time)
        if arrival < MIN_ARRIVAL:
            key = "probability" if self.arrival.probability is not None else "rate"
            problems.append(
                Problem(
                    f"strategy.arrival.{key}",
                    f"gives an arrival probability of {arrival:.3g} per stage; at least "
                    f"{MIN_ARRIVAL:.3g} (a request every {1 / MIN_ARRIVAL:.3g} stages)",
                )
            )
        longest = MAX_FMP_STAGES * self.stage_time
        b = scenario.workcell.bounds
        corners = [(x, y) for x in (b.xmin, b.xmax) for y in (b.ymin, b.ymax)]
        specs = {"strategy.fine_motion": self.fine_motion} | {
            f"strategy.fine_motion_regions.{name}": spec
            for name, spec in self.fine_motion_regions.items()
        }
        for field, spec in specs.items():
            far = 0.0
            if spec.point is not None and spec.rate > 0:
                px, py = spec.point
                far = max(math.hypot(x - px, y - py) for x, y in corners)
            t_f = spec.time + spec.rate * far
            if not t_f <= longest:
                problems.append(
                    Problem(
                        field,
                        f"a fine motion of up to {t_f:.3g} time units; at most {MAX_FMP_STAGES:,} "
                        f"stages of {self.stage_time:g} ({longest:.3g})",
                    )
                )
        return problems

    def _check_steps(self, scenario: Scenario) -> list[Problem]:
        """Refuse a move per stage longer than the workcell (or than a turn, in degrees).

        Such a move leaves the grid from every cell, and at 1e308 it is not even finite,
        so the stencil tables would hold garbage integers.
        """
        robot = scenario.robot
        if robot is None:
            return []
        factor = max([1.0, *self.carry_speed_factor.values()])
        b = scenario.workcell.bounds
        if robot.type in ("arm", "urdf"):
            limit, unit = 360.0, "degrees, a full turn"
        else:
            limit, unit = math.hypot(b.xmax - b.xmin, b.ymax - b.ymin), "the workcell's diagonal"
        out = []
        step = self.speed * self.stage_time * factor
        if not step <= limit:
            out.append(
                Problem(
                    "strategy.speed",
                    f"speed x stage_time{' x carry_speed_factor' if factor > 1 else ''} = "
                    f"{step:.4g} per stage, more than {limit:.4g} ({unit})",
                )
            )
        if self.turn_speed is not None and not self.turn_speed * self.stage_time <= 360.0:
            turn = self.turn_speed * self.stage_time
            out.append(
                Problem(
                    "strategy.turn_speed",
                    f"turn_speed x stage_time = {turn:.4g} degrees per stage, more than a turn",
                )
            )
        return out

    def _check_arm3d(self, scenario: Scenario) -> list[Problem]:
        """A URDF arm in a 3-D cell: 1 to :data:`MAX_ARM_JOINTS` active joints named in
        ``robot.joints`` (the grid's axes, known before the URDF is read), and only the
        Section V model (the Section VI extensions are built and tested on planar cells
        only)."""
        robot = scenario.robot
        joints = getattr(robot, "joints", None)
        problems: list[Problem] = []
        if joints is None or not 1 <= len(joints) <= MAX_ARM_JOINTS:
            given = "lists none" if joints is None else f"lists {len(joints)}"
            problems.append(
                Problem(
                    "robot.joints",
                    f"{given}; the strategies grid holds 1 to {MAX_ARM_JOINTS} active joints of "
                    "a 3-D arm: list them and lock the others (robot.locked)",
                )
            )
        active = {v.name for v in active_variants(self)}
        unsupported = (
            {f"strategy.{VARIANTS[name].keys[0]}": name in active for name in ARM3D_ORDER}
            | {"strategy.fine_motion.point": self.fine_motion.point is not None}
            | {
                f"strategy.fine_motion_regions.{name}.point": spec.point is not None
                for name, spec in self.fine_motion_regions.items()
            }
        )
        problems.extend(
            Problem(field, "is not available in a 3-D workcell yet (the Section V model is)")
            for field, used in unsupported.items()
            if used
        )
        return problems

    def _check_requests(self, scenario: Scenario, requests: list[RequestSpec]) -> list[Problem]:
        problems: list[Problem] = []
        if not requests:
            return [Problem("strategy.requests", "the request list is empty")]
        seen: set[tuple[str, str, str]] = set()
        for i, r in enumerate(requests):
            where = f"strategy.requests[{i}]"
            if r.part not in scenario.parts:
                problems.append(Problem(f"{where}.part", f"unknown part {r.part!r}"))
            if r.source not in scenario.sources:
                problems.append(Problem(f"{where}.source", f"unknown source {r.source!r}"))
            if r.destination not in scenario.destinations:
                problems.append(
                    Problem(f"{where}.destination", f"unknown destination {r.destination!r}")
                )
            key = (r.part, r.source, r.destination)
            if key in seen:
                problems.append(Problem(where, f"request {key} is listed twice"))
            seen.add(key)
        given = [r.probability for r in requests]
        if any(v is not None for v in given):
            if any(v is None for v in given):
                problems.append(
                    Problem("strategy.requests", "give a probability for every request or for none")
                )
            else:
                total = sum(float(v) for v in given if v is not None)
                if abs(total - 1.0) > _SUM_TOL:
                    problems.append(
                        Problem(
                            "strategy.requests", f"request probabilities sum to {total:g}, not 1"
                        )
                    )
        return problems

    def _check_changes(self, scenario: Scenario, kind: str) -> list[Problem]:
        # A change needs somewhere to go: another requestable mode with the same part and
        # the same source (destination change) or destination (source change).
        reqs = {(p, s, d) for p, s, d, _ in self.request_list(scenario)}
        lonely = []
        for p, s, d in sorted(reqs):
            if kind == "destination":
                others = [r for r in reqs if r[0] == p and r[1] == s and r[2] != d]
            else:
                others = [r for r in reqs if r[0] == p and r[2] == d and r[1] != s]
            if not others:
                lonely.append(f"<{p},{s},{d}>")
        if lonely:
            return [
                Problem(
                    f"strategy.{kind}_change",
                    f"no other {kind} to change to for request(s) {', '.join(lonely)}",
                )
            ]
        return []

"""Fine motions that can fail (Section VI-3 of the strategies paper): the variant.

Every FMP of a request that picks at (a source) or delivers to (a destination) a region
named in ``strategy.failures`` fails with a probability. A failure is retried in place
after a rework time, or the part is rejected: carried to a reject region (an ``X`` mode)
and dropped there, after which a replacement is fetched or a new request arrives. The
model's FMP outcomes (:class:`~cellplan.strategies.model.bundles.Outcomes`) hold the split;
the X modes and the outcome table are assembled by
:func:`~cellplan.strategies.model.mdp.assemble` from the :class:`Failures` built here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field

from cellplan.errors import Problem
from cellplan.schema import Name, NonNegativeFloat, Probability, StrictModel
from cellplan.strategies.model.spec import MAX_FMP_STAGES, Build, LayerCounts
from cellplan.strategies.variants.base import SimEvent, Variant

if TYPE_CHECKING:
    from cellplan.strategies.model.layered import LayeredMDP


class FailureSpec(StrictModel):
    """A fine motion that can fail (Section VI-3 of the strategies paper).

    Every FMP of a request that picks at (a source) or delivers to (a destination)
    ``region``, for ``part`` (default: every part), fails with ``probability``. A failure
    is retried in place after ``rework`` time units (``then: retry``), or the part is
    rejected (``then: reject``): the robot carries it to ``reject_region`` (a destination)
    and drops it there, after which it fetches a replacement from the same source
    (``after_reject: fetch``) or a new request for the same part and destination arrives at
    once, its source drawn by the request probabilities (``after_reject: request``). The
    request waits throughout: every stage counts in the loss.
    """

    region: Name = Field(description="source or destination whose FMP can fail", examples=["D1"])
    part: Name | None = Field(default=None, description="only for this part (default: every part)")
    probability: Probability = Field(description="failure probability per FMP attempt")
    then: Literal["retry", "reject"] = Field(
        description="retry in place after the rework time, or reject the part"
    )
    rework: NonNegativeFloat | None = Field(
        default=None, description="retry: time lost before the next attempt (default 0)"
    )
    reject_region: Name | None = Field(
        default=None, description="reject: the destination where rejected parts are dropped"
    )
    after_reject: Literal["fetch", "request"] | None = Field(
        default=None,
        description="reject: fetch a replacement from the same source (default), or a new "
        "request for the part arrives",
    )

    def applies(self, region: str, part: str) -> bool:
        return self.region == region and self.part in (None, part)


class FailuresVariant(Variant):
    """Section VI-3: an FMP fails with a probability; retry in place or reject the part."""

    name = "failures"
    paper = "Section VI-3"
    keys = ("failures",)

    def active(self, section: Any) -> bool:
        return bool(section.failures)

    def check(self, section: Any, scenario: Any) -> list[Problem]:
        return check_failures(section, scenario) if section.failures else []

    def in_model(self, mdp: LayeredMDP) -> bool:
        # X modes, or an FMP option with more than one outcome (a retry).
        if any(m.kind == "X" for m in mdp.modes):
            return True
        return mdp.opt_ptr is None and bool((np.diff(mdp.fmp_outcomes().ptr) > 1).any())

    def reserved_regions(self, section: Any) -> set[str]:
        # The reject regions take no requests of their own.
        return {f.reject_region for f in section.failures if f.reject_region is not None}

    def assemble(self, build: Build) -> LayeredMDP | None:
        """The Section V layout plus the X modes and the split FMP outcomes."""
        # Deferred for start-up time: the scenario schema imports this module, the model
        # (numba) only a planner. No cycle: the model never imports a variant.
        from cellplan.strategies.model.mdp import Failure, Failures, section_v_model

        sec, requests = build.spec.section, build.spec.requests

        def failure(region: str, part: str) -> Failure | None:
            f = failure_at(sec, region, part)
            if f is None:
                return None
            return Failure(
                float(f.probability),
                float(f.rework or 0.0),
                f.reject_region or "",
                f.after_reject or "fetch",
            )

        pick_f: list[Failure | None] = [failure(s, p) for p, s, _, _ in requests]
        drop_f: list[Failure | None] = [failure(d, p) for p, _, d, _ in requests]
        rejected = {
            (requests[r][0], f.reject)
            for r, fs in enumerate(zip(pick_f, drop_f, strict=True))
            for f in fs
            if f is not None and f.reject
        }
        failures = Failures(
            pick_f,
            drop_f,
            {(p, b): build.in_region(b, p) for p, b in rejected},
            {b: build.tf_of(b) for _, b in rejected},
        )
        return section_v_model(build, failures)

    def layers(self, section: Any, requests: Any, counts: LayerCounts) -> LayerCounts:
        x = reject_modes(section, requests)  # an X mode has one branch: itself
        return LayerCounts(
            counts.modes + x,
            counts.options + x,
            counts.classes,
            counts.phases,
            counts.landings,
            counts.branches + x,
        )

    def facts(self, mdp: LayeredMDP) -> list[tuple[str, str, Any, str]]:
        failing = int(sum(np.diff(mdp.fmp_outcomes().ptr) > 1))
        if not failing:
            return []
        return [
            (
                "failure_modes",
                "failure modes",
                failing,
                f"{failing} of the {mdp.n_modes - 1} fine motions can fail (Section VI-3); "
                f"states: {int(mdp.live.sum()):,}",
            )
        ]

    def modes_line(self, mdp: LayeredMDP, section: Any) -> str | None:
        x = sum(1 for m in mdp.modes if m.kind == "X")
        if not x:
            return None
        return (
            f"{mdp.n_modes}: {1 + 2 * mdp.n_requests} of Section III-A ({mdp.n_requests} "
            f"requests) + {x} carrying a rejected part (Section VI-3)"
        )

    def fmp_event(self, mdp: LayeredMDP, layer: int, outcome: int) -> SimEvent | None:
        out = mdp.fmp_outcomes()
        mode = mdp.modes[layer]
        nxt = int(out.layer[outcome])
        if mode.kind == "X":
            return SimEvent("reject", f"{mode.part} at {mode.reject}")
        if outcome == out.ptr[layer] or mode.kind not in ("W", "C"):
            return None
        where = mode.source if mode.kind == "W" else mode.destination
        then = "retry" if nxt == layer else f"reject to {mdp.modes[nxt].reject}"
        return SimEvent("fmp_failed", f"{mode.part} at {where}, {then}")


def failure_at(section: Any, region: str, part: str) -> FailureSpec | None:
    """The failure model of an FMP of ``part`` at ``region`` (None: it never fails)."""
    for f in section.failures:
        if f.applies(region, part) and f.probability > 0.0:
            return f
    return None


def reject_modes(section: Any, requests: Sequence[tuple[str, str, str, float]]) -> int:
    """How many X modes (a rejected part carried to a reject region) the model of these
    requests has: one per (request, reject region, what follows)."""
    keys = set()
    for i, (p, s, d, _) in enumerate(requests):
        for f in (failure_at(section, s, p), failure_at(section, d, p)):
            if f is not None and f.then == "reject":
                keys.add((i, f.reject_region, f.after_reject or "fetch"))
    return len(keys)


def check_failures(sec: Any, scenario: Any) -> list[Problem]:
    """One line per mistake in ``strategy.failures`` (Section VI-3): first the rework
    times longer than :data:`~cellplan.strategies.model.spec.MAX_FMP_STAGES` stages."""
    problems: list[Problem] = []
    longest = MAX_FMP_STAGES * sec.stage_time
    for i, failure in enumerate(sec.failures):
        if failure.rework is not None and not failure.rework <= longest:
            problems.append(
                Problem(
                    f"strategy.failures.{i}.rework",
                    f"{failure.rework:.3g} time units; at most {MAX_FMP_STAGES:,} stages "
                    f"of {sec.stage_time:g} ({longest:.3g})",
                )
            )
    requests = sec.request_list(scenario)
    if sec.requests == "all" and not requests and scenario.destinations:
        problems.append(
            Problem(
                "strategy.requests",
                "'all' leaves no request: every destination is a reject region",
            )
        )
    used = {(p, s) for p, s, _, _ in requests} | {(p, d) for p, _, d, _ in requests}
    seen: dict[tuple[str, str | None], int] = {}
    for i, f in enumerate(sec.failures):
        where = f"strategy.failures[{i}]"
        if f.region not in scenario.sources and f.region not in scenario.destinations:
            problems.append(
                Problem(f"{where}.region", f"unknown source or destination {f.region!r}")
            )
        elif f.part is not None and f.part not in scenario.parts:
            problems.append(Problem(f"{where}.part", f"unknown part {f.part!r}"))
        elif requests and not any(
            r == f.region and (f.part is None or p == f.part) for p, r in used
        ):
            problems.append(
                Problem(
                    f"{where}.region",
                    f"no request picks or delivers at {f.region!r}"
                    + (f" with part {f.part!r}" if f.part else ""),
                )
            )
        if f.probability >= 1.0:
            problems.append(
                Problem(
                    f"{where}.probability",
                    "must be below 1 (an FMP that always fails never serves its request)",
                )
            )
        overlap = [
            j
            for (region, part), j in seen.items()
            if region == f.region and (part is None or f.part is None or part == f.part)
        ]
        if overlap:
            problems.append(
                Problem(where, f"overlaps strategy.failures[{overlap[0]}] (same region and part)")
            )
        seen[(f.region, f.part)] = i
        problems.extend(_check_then(f, where, scenario))
    return problems


def _check_then(f: FailureSpec, where: str, scenario: Any) -> list[Problem]:
    """What follows a failure: retry keys only with retry, a known reject region."""
    problems: list[Problem] = []
    if f.then == "retry":
        for name in ("reject_region", "after_reject"):
            if getattr(f, name) is not None:
                problems.append(Problem(f"{where}.{name}", "only with then: reject"))
        return problems
    if f.rework is not None:
        problems.append(Problem(f"{where}.rework", "only with then: retry"))
    if f.reject_region is None:
        problems.append(Problem(f"{where}.reject_region", "then: reject needs a reject region"))
    elif f.reject_region not in scenario.destinations:
        problems.append(
            Problem(
                f"{where}.reject_region",
                f"unknown region {f.reject_region!r} (declare it under destinations)",
            )
        )
    elif f.reject_region == f.region:
        problems.append(Problem(f"{where}.reject_region", "is the region whose FMP fails"))
    return problems


FAILURES = FailuresVariant()

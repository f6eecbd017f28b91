"""Experiments of the strategies package, for the sweep runner.

``strategies.anticipation`` measures the claim of Section V-C: the optimal strategy,
which moves while no request waits in anticipation of the next one, makes parts wait
less than planning for each request as it arrives. Per bundled problem and seed, the
optimal, reactive (stay still when idle) and return-home (go to the start configuration
when idle) policies run in the same simulator over the same random stream; the report
gives the mean waiting time per request of each with 95% confidence intervals and the
paired reduction. The quick version uses a small two-source cell and short runs.

``strategies.behaviours`` checks the other behaviours Section V reports (the list in
:data:`BEHAVIOURS`), each measured by a function of
:mod:`cellplan.strategies.experiments.behaviours`
from random starts per seed on the bundled problem it is reported for, and decided from
the 95% interval over seeds. The quick version measures those whose problems solve in a
second and says the others were not run.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cellplan.core import (
    MIN_RUNS,
    Claim,
    Experiment,
    ReportPiece,
    RunSpec,
    Scalar,
    decide_interval,
    mean_interval,
)
from cellplan.strategies.experiments import (
    conveyor_experiment,
    failure_experiment,
    noise_experiment,
    pending_experiment,
    ur5_experiment,
)
from cellplan.strategies.experiments.common import (
    Threshold,
    finite_column,
    grids_text,
    half,
    interval_rows,
    seeds_text,
    solved_bundled,
    threshold_claim,
    values_text,
)
from cellplan.strategies.sim.options import SimulationOptions

PROBLEMS = {  # bundled scenario -> grid used here (coarser than the bundled one where slow)
    "strategies_p1": "100,100",
    "strategies_p2": "48,48",
    # At 48 x 48 x 30 the solved route to D1 crosses the left opening by interpolation
    # alone; no real motion follows it (docs/strategies.md), so the gain is unattainable.
    "strategies_p3": "64,64,30",
    "strategies_p4": "48,48",
    "strategies_p5": "40,40,40",
    "strategies_p6": "48,48,48",  # the coarsest grid on which P6's free space stays connected
}
QUICK = {"strategies_tiny": "12,12"}
POLICIES = ("optimal", "reactive", "home")


def make_runs(runs: int, quick: bool) -> list[RunSpec]:
    """One run per (problem, seed); each run simulates all three policies."""
    problems = QUICK if quick else PROBLEMS
    stages = 1500 if quick else 20000
    return [
        RunSpec("strategies.anticipation", {"problem": p, "cells": c, "stages": stages}, seed)
        for p, c in problems.items()
        for seed in range(runs)
    ]


def run(spec: RunSpec) -> dict[str, Scalar]:
    """Mean waiting time, loss per stage and requests served of each policy."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.strategies.sim.simulate import simulate_result

    strategy = solved_bundled(str(spec.params["problem"]), str(spec.params["cells"]))[0]
    row: dict[str, Scalar] = {
        "problem": str(spec.params["problem"]),
        "seed": spec.seed,
        "gain": strategy.gain,
    }
    for policy in POLICIES:
        # From the robot's start, each policy's idle rule going home to the strategy's home.
        sim = simulate_result(
            strategy, int(spec.params["stages"]), spec.seed, SimulationOptions(policy=policy)
        )
        m = sim.solution.metrics()  # NaN where a policy served nothing (stats drop those)
        for key in ("mean_wait", "mean_wait_all", "loss_per_stage", "served", "idle_fraction"):
            row[f"{policy}_{key}"] = m[key]
    return row


def report(rows: list[dict[str, Scalar]], outdir: Any) -> ReportPiece:
    """Table and bar chart of waiting times; one claim per problem."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan import plots as base

    outdir = Path(outdir)
    problems = sorted({str(r["problem"]) for r in rows})
    table = []
    claims = []
    for p in problems:
        rs = [r for r in rows if r["problem"] == p]
        # The long-run loss per stage is the quantity the strategy minimises (its gain).
        loss = {pol: np.array([float(r[f"{pol}_loss_per_stage"]) for r in rs]) for pol in POLICIES}
        # Every request that arrived, those still open at their age so far: a request that
        # is never delivered counts (the delivered-only mean would hide it).
        wait = {pol: np.array([float(r[f"{pol}_mean_wait_all"]) for r in rs]) for pol in POLICIES}
        entry: dict[str, Scalar] = {"problem": p, "runs": len(rs), "gain": float(rs[0]["gain"])}
        for pol in POLICIES:
            m, h = mean_interval(loss[pol])
            entry[f"{pol} loss/stage"] = f"{m:.3f} ± {h:.3f}"
            mw, hw = mean_interval(wait[pol])
            entry[f"{pol} wait"] = f"{mw:.1f} ± {hw:.1f}"
        red = {}
        # Paired per seed. With arrivals only in NR, the loss per stage is W / (W + 1/P) for
        # mean waiting time W, so comparing W compares the minimised criterion, less noisily.
        for other in ("reactive", "home"):
            d = 100.0 * (wait[other] - wait["optimal"]) / wait[other]
            m, h = mean_interval(d)
            red[other] = (m, h)
            entry[f"reduction vs {other} (%)"] = f"{m:.1f} ± {h:.1f}"
        table.append(entry)
        m, h = red["reactive"]
        claims.append(
            Claim(
                claim=f"{p}: anticipation lowers the mean waiting time per request",
                paper="Sec. V-C: savings from anticipatory motion in NR, nearly the NR stages",
                ours=f"{m:.1f}% ± {h:.1f}% less than reactive, "
                f"{red['home'][0]:.1f}% ± {red['home'][1]:.1f}% less than return-home",
                reproduced=decide_interval(m - h, m + h, len(rs), above=0.0),
                detail="mean waiting per request (open ones at their age), paired by seed",
                n=len(rs),
                rule="95% interval of the mean reduction against reactive lies above 0 "
                "(at least 5 seeds)",
                explanation="docs/strategies.md#measured-what-anticipation-buys-section-v-c",
            )
        )
    fig, axes = base.new_figure(size=4.5)
    fig.set_size_inches(max(4.5, 1.6 * len(problems) + 2), 4.0)
    ax = axes[0, 0]
    width = 0.27
    for i, pol in enumerate(POLICIES):
        means, halves = [], []
        for p in problems:
            vals = np.array([float(r[f"{pol}_mean_wait_all"]) for r in rows if r["problem"] == p])
            m, h = mean_interval(vals)
            means.append(m)
            halves.append(half(h))
        ax.bar(
            np.arange(len(problems)) + (i - 1) * width,
            means,
            width,
            yerr=halves,
            label=pol,
            capsize=3,
        )
    ax.set_xticks(np.arange(len(problems)), [p.replace("strategies_", "") for p in problems])
    ax.set_ylabel("mean waiting time per request (stages)")
    ax.legend(fontsize=8)
    ax.set_title("anticipation vs reactive vs return-home", fontsize=9)
    figure = base.save_figure(fig, outdir / "strategies_anticipation.png")
    seeds = len({int(r["seed"]) for r in rows})
    caption = (
        "Mean waiting time per request (stages; open requests at their age) of the optimal, "
        f"reactive and return-home policies, with 95% intervals over {seeds_text(seeds)} "
        f"of {values_text(rows, 'stages')} stages each (grids: {grids_text(rows)})."
    )
    return ReportPiece(
        title="Strategies: what anticipation buys (Section V-C)",
        text=(
            "Optimal strategy vs the reactive and return-home baselines in the same simulator "
            "and random stream; loss per stage is the expected waiting time per stage that "
            "the strategy minimises (its gain)."
        ),
        figures=[figure],
        captions={figure.name: caption},
        tables=[("waiting time per policy", table)],
        claims=claims,
        command="cellplan simulate FILE --strategy S --policy optimal|reactive|home",
    )


# --- the behaviours of Section V ------------------------------------------------------------


@dataclass(frozen=True)
class Behaviour:
    """One behaviour of Section V as a checked claim.

    ``measure`` names a function of :mod:`cellplan.strategies.experiments.behaviours` returning one
    number per seed; the claim holds when the 95% interval of its mean over seeds lies
    above ``above``.
    """

    key: str
    problem: str
    measure: str
    claim: str
    paper: str
    quantity: str
    above: float
    null: str

    @property
    def threshold(self) -> Threshold:
        """The claim's words and bar (:func:`~.common.threshold_claim` decides it)."""
        return Threshold(self.claim, self.paper, self.quantity, self.above, self.null)


BEHAVIOURS = (
    Behaviour(
        "p1_idle",
        "strategies_p1",
        "idle_near_sources",
        "P1: with no request pending, the robot moves to wait near the sources",
        "Sec. V-A, Problem 1, Fig. 9(a), (d), (g): in NR the robot moves to the lower part of the "
        "workcell, near the sources",
        "fraction of random starts from which the no-request policy stops nearer the sources",
        0.5,
        "a policy that ignores where requests come from ends nearer as often as farther",
    ),
    Behaviour(
        "p3_idle",
        "strategies_p3",
        "idle_near_sources",
        "P3: with no request pending, the robot moves to wait near the sources",
        "Sec. V-A, Problem 3, Fig. 11(a): where the robot waits in NR matters, the carried part "
        "being large for the opening",
        "fraction of random starts from which the no-request policy stops nearer the sources",
        0.5,
        "a policy that ignores where requests come from ends nearer as often as farther",
    ),
    Behaviour(
        "p1_opening",
        "strategies_p1",
        "opening_and_detour",
        "P1: empty, the robot passes the narrow opening; carrying, it detours",
        "Sec. V-A, Problem 1, Fig. 9(b)-(d): through the narrow opening empty, the longer route "
        "carrying",
        "fraction of random starts above the wall going down through the opening and back up "
        "through the wide passage",
        0.5,
        "the behaviour holds from at most half the starts",
    ),
    Behaviour(
        "p2_nearer",
        "strategies_p2",
        "nearer_component",
        "P2: the robot delivers to the nearer component of the split destination D1",
        "Sec. V-A, Problem 2, Fig. 10(h)-(i): D1 has two components; the robot delivers to the "
        "one that suits its position",
        "fraction of random carrying starts delivered to the component of D1 nearer the start",
        0.5,
        "choosing a component regardless of distance is right half the time",
    ),
    Behaviour(
        "p4_turn",
        "strategies_p4",
        "turns_to_changed_destination",
        "P4: when the destination changes, the robot turns toward the new one at once",
        "Sec. V-A, Problem 4, Fig. 12(c), (g): when the destination changes, the robot "
        "immediately delivers to the new one",
        "fraction of (random start, change D1<->D3) pairs whose first move heads toward the "
        "new destination and differs from the move toward the old one",
        0.5,
        "a first move in a random direction heads toward the new destination half the time",
    ),
    Behaviour(
        "p6_component",
        "strategies_p6",
        "component_for_destination",
        "P6: the destination decides which component of S1 the arm picks from",
        "Sec. V-B, Problem 6, Fig. 15: the upper component of S1 for the upper destination, the "
        "lower one for the lower, even from starts nearer the other",
        "fraction of random starts picking S1's upper component for D1 (above the arm) "
        "minus that for D2 (below it)",
        0.0,
        "a choice independent of the destination gives the same fraction for both",
    ),
)
QUICK_BEHAVIOURS = ("strategies_p1", "strategies_p2")
"""Problems measured in the quick version (three of the six behaviours): each solves in
about a second; P3, P4 and P6 take several times longer, too long for the demo's budget."""
BEHAVIOUR_STARTS = 40
"""Random starts per behaviour and seed."""
EXPLANATION = "docs/strategies.md#behaviours-of-section-v-as-checked-claims"


def make_behaviour_runs(runs: int, quick: bool) -> list[RunSpec]:
    """One run per (problem, seed), measuring every behaviour of that problem."""
    problems = dict.fromkeys(b.problem for b in BEHAVIOURS)
    if quick:
        problems = {p: None for p in problems if p in QUICK_BEHAVIOURS}
    return [
        RunSpec(
            "strategies.behaviours",
            {"problem": p, "cells": PROBLEMS[p], "starts": BEHAVIOUR_STARTS},
            seed,
        )
        for p in problems
        for seed in range(runs)
    ]


def run_behaviours(spec: RunSpec) -> dict[str, Scalar]:
    """Each behaviour of the run's problem, measured from the seed's random starts."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.strategies.experiments import behaviours

    problem = str(spec.params["problem"])
    strategy, cell, _ = solved_bundled(problem, str(spec.params["cells"]))
    row: dict[str, Scalar] = {"problem": problem, "seed": spec.seed}
    for i, b in enumerate(x for x in BEHAVIOURS if x.problem == problem):
        rng = np.random.default_rng([spec.seed, i])
        measure = getattr(behaviours, b.measure)
        row[b.key] = float(measure(strategy, cell, rng, count=int(spec.params["starts"])))
    return row


def behaviour_claims(rows: list[dict[str, Scalar]]) -> list[Claim]:
    """One claim per behaviour of :data:`BEHAVIOURS`, decided by its 95% interval."""
    return [
        threshold_claim(
            finite_column(rows, b.key),
            b.threshold,
            f"not measured in this run ({b.problem} is measured by the full "
            "cellplan reproduce strategies)",
            "",
            EXPLANATION,
        )
        for b in BEHAVIOURS
    ]


def report_behaviours(rows: list[dict[str, Scalar]], outdir: Any) -> ReportPiece:
    """One claim per behaviour, a table per problem and seed, and a chart of the intervals."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan import plots as base

    outdir = Path(outdir)
    claims = behaviour_claims(rows)
    measured = [(b, c) for b, c in zip(BEHAVIOURS, claims, strict=True) if c.n]
    fig, axes = base.new_figure(size=4.5)
    fig.set_size_inches(7.5, 0.55 * len(BEHAVIOURS) + 1.5)
    ax = axes[0, 0]
    series = [(b.key, finite_column(rows, b.key), b.above) for b in BEHAVIOURS]
    interval_rows(ax, series, "  not measured in this run")
    ax.set_xlabel("measured fraction (P6: difference of fractions)")
    # Deferred for start-up time: the experiment list loads without these.
    from matplotlib.lines import Line2D

    ax.legend(
        handles=[
            Line2D([], [], marker="o", color="#1f77b4", label="mean, 95% interval over seeds"),
            Line2D([], [], marker=".", ls="", color="#8c959f", label="one seed"),
            Line2D([], [], ls="--", color="grey", label="threshold of the claim"),
        ],
        fontsize=8,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
    )
    figure = base.save_figure(fig, outdir / "strategies_behaviours.png")
    seeds = len({int(r["seed"]) for r in rows})
    caption = (
        f"Each behaviour's measure over {seeds_text(seeds)} ({values_text(rows, 'starts')} "
        f"random starts each; grids {grids_text(rows, upper=True)}): grey dots are "
        "seeds, blue the mean with its 95% interval, dashed the threshold the claim must "
        "clear."
    )
    table: list[dict[str, Scalar]] = []
    for r in sorted(rows, key=lambda r: (str(r["problem"]), int(r["seed"]))):
        entry: dict[str, Scalar] = {"problem": str(r["problem"]), "seed": int(r["seed"])}
        entry.update({b.key: float(r[b.key]) for b in BEHAVIOURS if b.key in r})
        table.append(entry)
    return ReportPiece(
        title="Strategies: the behaviours of Section V",
        text=(
            "Each behaviour the paper shows in its sample-path figures, measured from random "
            "starts (drawn per seed among the strategy's live cells) by following the "
            "optimal actions of the solved strategy, as the figures do between mode changes. "
            f"{len(measured)} of {len(BEHAVIOURS)} behaviours measured in this run."
        ),
        figures=[figure],
        captions={figure.name: caption},
        tables=[("measure per problem and seed", table)],
        claims=claims,
        command="cellplan solve strategies_p1 -o p1.npz && "
        "cellplan plot strategies_p1 --strategy p1.npz --mode NR",
    )


EXPERIMENTS: list[Experiment] = [
    Experiment(
        name="strategies.anticipation",
        paper="strategies",
        title="Anticipation vs reactive and return-home strategies",
        make_runs=make_runs,
        run=run,
        report=report,
        demo_runs=MIN_RUNS,
    ),
    Experiment(
        name="strategies.behaviours",
        paper="strategies",
        title="The behaviours Section V reports, on the bundled problems",
        make_runs=make_behaviour_runs,
        run=run_behaviours,
        report=report_behaviours,
        demo_runs=MIN_RUNS,
    ),
    failure_experiment.EXPERIMENT,
    noise_experiment.EXPERIMENT,
    pending_experiment.EXPERIMENT,
    conveyor_experiment.EXPERIMENT,
    ur5_experiment.EXPERIMENT,  # not Section VI: the 3-D arm of issue 31
]

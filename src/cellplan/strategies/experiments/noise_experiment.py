"""The noisy-motion experiment (Section VI-4 of the strategies paper), for the sweep runner.

``strategies.noise`` solves the bundled noise scenario with its noise model and without
it (every move exact, the Section V model) and, per seed, runs each strategy in its own
process: the noisy one in the noisy simulator (its optimal strategy and the reactive
baseline), the exact one in the exact simulator. The behaviour the issue asks for is the
clearance in narrow passages: the mean clearance of the robot's moves that land in the
band of the workcell where the wall with the narrow opening and the wide passage are
(``PASSAGES``), with noise and without, paired by seed. The report also checks that the
noisy strategy's simulated loss agrees with its gain and that it beats the reactive
baseline under noise.
"""

from __future__ import annotations

import functools
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
from cellplan.strategies.experiments.common import (
    agreement_claim,
    beats_reactive_claim,
    column,
    interval_bar,
    plan_on_grid,
    seeds_text,
    values_text,
)
from cellplan.strategies.sim.options import SimulationOptions

PROBLEM = "strategies_noise"
CELLS = "100,100"
QUICK_CELLS = "64,64"
PASSAGES = (1, 45.0, 57.0)
"""Axis and range of the narrow passages of the P1 workcell: the wall across the middle
(y from 48 to 54) and the robot's half size (3), so every landing between 45 and 57 is in
the narrow opening or the wide passage beside it."""
EXPLANATION = "docs/strategies.md#noisy-motion-section-vi-4"


@functools.lru_cache(maxsize=4)
def _solved(cells: str, noisy: bool) -> Any:
    """The noise scenario's strategy, with its noise model or without any."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.api import load

    scenario = load(PROBLEM).scenario
    if not noisy:
        sec = scenario.strategy.model_copy(update={"noise": None})
        scenario = scenario.model_copy(update={"strategy": sec})
    return plan_on_grid(scenario, cells)


def make_runs(runs: int, quick: bool) -> list[RunSpec]:
    """One run per seed (each runs the noisy and the exact strategy)."""
    cells = QUICK_CELLS if quick else CELLS
    stages = 1500 if quick else 10000
    return [
        RunSpec("strategies.noise", {"cells": cells, "stages": stages}, seed)
        for seed in range(runs)
    ]


def run(spec: RunSpec) -> dict[str, Scalar]:
    """Gains, loss and waiting of each policy, and clearances in the passages."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.api import load
    from cellplan.strategies.experiments.behaviours import move_clearances
    from cellplan.strategies.sim.simulate import simulate_result

    cells, stages = str(spec.params["cells"]), int(spec.params["stages"])
    cell = load(PROBLEM).workcell
    axis, lo, hi = PASSAGES
    row: dict[str, Scalar] = {"seed": spec.seed}
    for noisy in (True, False):
        strategy = _solved(cells, noisy)
        tag = "noisy" if noisy else "exact"
        row[f"{tag}_gain"] = strategy.gain
        row[f"{tag}_states"] = int(strategy.mdp.live.sum())
        for policy in ("optimal", "reactive") if noisy else ("optimal",):
            res = simulate_result(
                strategy, stages, spec.seed, SimulationOptions(policy=policy), cell=cell
            )
            m = res.solution.metrics()
            for key in ("loss_per_stage", "mean_wait_all"):
                row[f"{tag}_{policy}_{key}"] = m[key]
            if policy == "optimal":
                q, clear = move_clearances(strategy, cell, res.solution)
                inside = (q[:, axis] > lo) & (q[:, axis] < hi)
                row[f"{tag}_passage_moves"] = int(inside.sum())
                row[f"{tag}_passage_clearance"] = (
                    float(clear[inside].mean()) if inside.any() else float("nan")
                )
                row[f"{tag}_near_misses"] = float(np.mean(clear < 1.0))
    return row


def report(rows: list[dict[str, Scalar]], outdir: Any) -> ReportPiece:
    """Clearance with and without noise, optimal vs reactive under noise, three claims."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan import plots as base

    outdir = Path(outdir)

    n = len(rows)
    noisy_c, exact_c = (
        column(rows, "noisy_passage_clearance"),
        column(rows, "exact_passage_clearance"),
    )
    diff = noisy_c - exact_c
    m, h = mean_interval(diff)
    clearance = Claim(
        claim="noise: the strategy keeps a larger clearance in the narrow passages",
        paper="Sec. VI-4: the uncertainty of motion can be included directly in the model",
        ours=f"mean clearance of the moves landing in the passages {np.nanmean(noisy_c):.2f} "
        f"with noise, {np.nanmean(exact_c):.2f} without ({m:+.2f} ± {h:.2f} paired)",
        reproduced=decide_interval(m - h, m + h, int(np.isfinite(diff).sum()), above=0.0),
        detail="per seed: mean clearance (workcell units) of the optimal strategy's moves "
        f"landing with y in ({PASSAGES[1]:g}, {PASSAGES[2]:g}), noisy minus exact",
        n=int(np.isfinite(diff).sum()),
        rule="95% interval of the paired difference above 0 (at least 5 seeds)",
        explanation=EXPLANATION,
    )
    gain = float(rows[0]["noisy_gain"])
    wait = {
        "optimal": column(rows, "noisy_optimal_mean_wait_all"),
        "reactive": column(rows, "noisy_reactive_mean_wait_all"),
    }
    claims = [
        clearance,
        agreement_claim(
            "noise",
            "Sec. VI-4: a distribution over the next configuration; (9) takes its expectation",
            gain,
            column(rows, "noisy_optimal_loss_per_stage"),
            EXPLANATION,
        ),
        beats_reactive_claim(
            "noise: under noisy motion the optimal strategy makes parts wait less than the "
            "reactive one",
            "Sec. VI-4 with Sec. V-C: anticipation under the extended model",
            wait,
            EXPLANATION,
        ),
    ]
    fig, axes = base.new_figure(ncols=2, size=4.2)
    ax = axes[0, 0]
    for i, (vals, label) in enumerate(((exact_c, "exact motion"), (noisy_c, "noisy motion"))):
        interval_bar(ax, i, vals, label=label)
        ax.plot(np.full(n, i) + 0.15, vals, ".", color="#444444", ms=4)
    ax.set_xticks([0, 1], ["exact", "noisy"])
    ax.set_ylabel("clearance in the passages (workcell units)")
    ax.set_title("moves landing in the passages", fontsize=9)
    ax = axes[0, 1]
    for i, k in enumerate(("optimal", "reactive")):
        interval_bar(ax, i, wait[k])
    ax.set_xticks([0, 1], ["optimal", "reactive"])
    ax.set_ylabel("mean waiting per request (stages)")
    ax.set_title("under noisy motion", fontsize=9)
    figure = base.save_figure(fig, outdir / "strategies_noise.png")
    cells = sorted({str(r["cells"]) for r in rows if "cells" in r})
    caption = (
        f"Left: mean clearance of the moves landing in the narrow passages, exact and noisy "
        f"motion (bars: mean and 95% interval over {seeds_text(n)}; dots: "
        f"seeds). Right: waiting per request under noise. Runs of {values_text(rows, 'stages')} "
        f"stages on {', '.join(c.replace(',', ' x ') for c in cells)} grids."
    )
    table: list[dict[str, Scalar]] = [
        {
            "seed": int(r["seed"]),
            "gain (noisy / exact)": f"{float(r['noisy_gain']):.4f} / {float(r['exact_gain']):.4f}",
            "passage moves (noisy / exact)": f"{r['noisy_passage_moves']} / "
            f"{r['exact_passage_moves']}",
            "clearance (noisy / exact)": f"{float(r['noisy_passage_clearance']):.2f} / "
            f"{float(r['exact_passage_clearance']):.2f}",
            "moves within 1 unit (noisy / exact)": f"{float(r['noisy_near_misses']):.3f} / "
            f"{float(r['exact_near_misses']):.3f}",
        }
        for r in sorted(rows, key=lambda r: int(r["seed"]))
    ]
    return ReportPiece(
        title="Strategies with noisy motion (Section VI-4)",
        text=(
            "Each move lands where commanded or one unit to either side. The optimal strategy "
            "of the noisy model against the same workcell with exact motion, and against the "
            "reactive baseline under noise, in the same simulator and random stream."
        ),
        figures=[figure],
        captions={figure.name: caption},
        tables=[("per seed", table)],
        claims=claims,
        command="cellplan solve strategies_noise -o n.npz && "
        "cellplan simulate strategies_noise --strategy n.npz",
    )


EXPERIMENT = Experiment(
    name="strategies.noise",
    paper="strategies",
    title="Noisy motion: clearance in narrow passages, optimal vs reactive (Section VI-4)",
    make_runs=make_runs,
    run=run,
    report=report,
    demo_runs=MIN_RUNS,
)

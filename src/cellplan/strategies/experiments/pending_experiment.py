"""The simultaneous-requests experiment (Section VI-2 of the strategies paper).

``strategies.pending`` solves the bundled scenario (up to three open requests, part P2's
three times as urgent) and, per seed, runs the optimal strategy and the three baselines
of :mod:`cellplan.strategies.variants.pending_sim` on the same stream of requests: first come
first served, nearest first (both serving one request at a time with the Section V
strategy, and waiting where it waits), and the reactive robot. It reports, per policy
with 95% intervals over the seeds, the loss per stage the model minimises (the weighted
number of open requests), the mean wait of the delivered requests of each part, the mean
number of open requests and the requests turned away; the claims compare the optimal
strategy with each baseline, paired by seed, and its simulated loss with its gain.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from cellplan.core import Claim, Experiment, ReportPiece, RunSpec, Scalar, mean_interval
from cellplan.strategies.experiments.common import (
    agreement_claim,
    ci_column,
    column,
    half,
    interval_bar,
    paired_columns,
    per_policy_piece,
    reduction_claim,
    seeds_text,
    solved_bundled,
    values_text,
)
from cellplan.strategies.sim.options import SimulationOptions

PROBLEM = "strategies_pending"
CELLS = "60,60"
QUICK_CELLS = "50,50"
EXPLANATION = "docs/strategies.md#simultaneous-requests-section-vi-2"
POLICY_NAMES = {
    "optimal": "optimal",
    "fcfs": "first come, first served",
    "nearest": "nearest first",
    "reactive": "reactive (FCFS, idle in place)",
}


@functools.lru_cache(maxsize=2)
def _solved(cells: str) -> Any:
    """The bundled scenario's strategy and the baselines' rules (built once per process)."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.strategies.variants.pending_sim import Rules, single_request_strategy

    strategy = solved_bundled(PROBLEM, cells)[0]
    return strategy, Rules(strategy, single_request_strategy(strategy))


def _urgency() -> dict[str, float]:
    """The bundled scenario's urgency per part (the legend names it)."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.api import load

    return dict(load(PROBLEM).scenario.strategy.urgency)


def make_runs(runs: int, quick: bool) -> list[RunSpec]:
    """One run per seed (each runs every policy on the seed's stream of requests)."""
    cells = QUICK_CELLS if quick else CELLS
    stages = 4000 if quick else 160000
    return [
        RunSpec("strategies.pending", {"cells": cells, "stages": stages}, seed)
        for seed in range(runs)
    ]


def run(spec: RunSpec) -> dict[str, Scalar]:
    """Loss, waiting per part, open requests and turned-away requests of every policy."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.strategies.variants.pending_sim import PENDING_POLICIES, simulate_pending

    cells, stages = str(spec.params["cells"]), int(spec.params["stages"])
    strategy, rules = _solved(cells)
    row: dict[str, Scalar] = {
        "seed": spec.seed,
        "gain": strategy.gain,
        "states": int(strategy.mdp.live.sum()),
        "modes": strategy.mdp.n_modes,
    }
    parts = sorted({m.part for m in strategy.mdp.modes if m.part})
    for policy in PENDING_POLICIES:
        sim = simulate_pending(
            strategy, stages, spec.seed, SimulationOptions(policy=policy), rules=rules
        )
        m = sim.metrics()
        for key in ("loss_per_stage", "mean_wait", "mean_open", "turned_away", "arrivals"):
            row[f"{policy}_{key}"] = m[key]
        for part in parts:
            waits = [r.waiting for r in sim.requests if r.delivery >= 0 and r.part == part]
            row[f"{policy}_wait_{part}"] = float(np.mean(waits)) if waits else float("nan")
    return row


def _beats_claim(rows: list[dict[str, Scalar]], baseline: str) -> Claim:
    """The optimal strategy's loss per stage is below ``baseline``'s, paired by seed."""
    return reduction_claim(
        *paired_columns(rows, "loss_per_stage", baseline),
        claim=f"simultaneous requests: the optimal strategy has a lower loss than "
        f"{POLICY_NAMES[baseline]}",
        paper="Sec. VI-2: the robot chooses the order of service; loss = open requests",
        ours=f"lower loss per stage (weighted open requests) than {POLICY_NAMES[baseline]}",
        detail="loss per stage of each run, the same requests for every policy (paired)",
        rule="95% interval of the mean reduction above 0 (at least 5 seeds)",
        explanation=EXPLANATION,
    )


def report(rows: list[dict[str, Scalar]], outdir: Any) -> ReportPiece:
    """Per-policy table with 95% intervals, a figure, three claims."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan import plots as base
    from cellplan.strategies.variants.pending_sim import PENDING_POLICIES

    outdir = Path(outdir)

    n = len(rows)
    parts = sorted(k.rsplit("_", 1)[1] for k in rows[0] if k.startswith("optimal_wait_"))
    gain = float(rows[0]["gain"])
    claims = [
        agreement_claim(
            "simultaneous requests",
            "Sec. VI-2: the same model, solved over (configuration, open requests, carried)",
            gain,
            column(rows, "optimal_loss_per_stage"),
            EXPLANATION,
        ),
        _beats_claim(rows, "fcfs"),
        _beats_claim(rows, "nearest"),
    ]
    table: list[dict[str, Scalar]] = []
    for policy in PENDING_POLICIES:
        entry: dict[str, Scalar] = {
            "policy": POLICY_NAMES[policy],
            "loss per stage": ci_column(rows, f"{policy}_loss_per_stage"),
            "mean wait (stages)": ci_column(rows, f"{policy}_mean_wait", ".1f"),
        }
        for part in parts:
            entry[f"wait of {part}"] = ci_column(rows, f"{policy}_wait_{part}", ".1f")
        entry["open requests (time average)"] = ci_column(rows, f"{policy}_mean_open")
        arrivals = column(rows, f"{policy}_arrivals").sum()
        entry["turned away"] = (
            f"{100 * column(rows, f'{policy}_turned_away').sum() / arrivals:.1f}%"
        )
        table.append(entry)
    fig, axes = base.new_figure(ncols=2, size=4.2)
    ax = axes[0, 0]
    for i, policy in enumerate(PENDING_POLICIES):
        interval_bar(ax, i, column(rows, f"{policy}_loss_per_stage"))
    ax.axhline(gain, color="#444444", lw=1, ls="--", label=f"gain g = {gain:.3f}")
    ax.set_xticks(range(len(PENDING_POLICIES)), list(PENDING_POLICIES))
    ax.set_ylabel("loss per stage (weighted open requests)")
    ax.legend(fontsize=8)
    ax = axes[0, 1]
    urgency = _urgency()
    width = 0.8 / max(1, len(parts))
    for j, part in enumerate(parts):
        means, halves = [], []
        for policy in PENDING_POLICIES:
            m, h = mean_interval(column(rows, f"{policy}_wait_{part}"))
            means.append(m)
            halves.append(half(h))
        x = np.arange(len(PENDING_POLICIES)) + (j - (len(parts) - 1) / 2) * width
        weight = urgency.get(part, 1.0)
        ax.bar(x, means, width, yerr=halves, capsize=3, label=f"part {part} (urgency {weight:g})")
    ax.set_xticks(range(len(PENDING_POLICIES)), list(PENDING_POLICIES))
    ax.set_ylabel("mean wait per delivered request (stages)")
    ax.legend(fontsize=8)
    figure = base.save_figure(fig, outdir / "strategies_pending.png")
    cells = sorted({str(r["cells"]).replace(",", " x ") for r in rows if "cells" in r})
    caption = (
        f"Left: loss per stage of each policy (the weighted number of open requests, which "
        f"the optimal strategy minimises; dashed: its gain). Right: mean wait of the "
        f"delivered requests per part. Bars: mean and 95% interval over {seeds_text(n)}, "
        f"every policy on the same requests; runs of "
        f"{values_text(rows, 'stages')} stages on {', '.join(cells)} "
        f"grids, {int(rows[0]['modes'])} modes, {int(rows[0]['states']):,} states."
    )
    return per_policy_piece(
        title="Strategies with simultaneous requests (Section VI-2)",
        text=(
            "Requests keep arriving while the robot serves one (up to three open; part P2 "
            "three times as urgent). The optimal strategy chooses which waiting request to "
            "serve; the baselines serve one at a time in arrival order or nearest first."
        ),
        figure=figure,
        caption=caption,
        table=table,
        claims=claims,
        command="cellplan solve strategies_pending -o q.npz && "
        "cellplan simulate strategies_pending --strategy q.npz --policy fcfs",
    )


EXPERIMENT = Experiment(
    name="strategies.pending",
    paper="strategies",
    title="Simultaneous requests: optimal vs first-come-first-served and nearest-first "
    "(Section VI-2)",
    make_runs=make_runs,
    run=run,
    report=report,
    # Not in the demo: its solve (about 16 s per process) on each of the demo's two
    # workers costs more than the demo's budget allows; the demo lists its command instead.
    demo_runs=None,
)

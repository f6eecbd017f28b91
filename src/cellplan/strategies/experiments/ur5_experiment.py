"""The strategies paper on the first three joints of a UR5 (``strategies_ur5``).

``strategies.ur5`` solves the bundled 3-D scenario (a UR5 with its wrist locked, problem
1's request model: two parts, two sources, S2 split in two, two destinations, a gate in
front of the arm with a low passage the empty arm fits through and the loaded arm does
not) on its 48 x 48 x 48 grid, through the validity interface, and measures per seed,
from random starts (:mod:`cellplan.strategies.experiments.arm_behaviours`), the three behaviours the
paper shows on its planar problems:

* idle near the sources (P1, P3): the fraction of starts from which the no-request
  policy stops with the tool nearer the pick places;
* the component of a split source chosen by the destination (P6): the fraction of
  (start, destination) pairs picking from S2's component nearer the destination;
* a detour while carrying where the empty arm fits through (P1): the fraction of starts
  on D2's side of the gate from which the empty arm crosses the gate where the loaded arm
  has no free cell, and the loaded arm's way back takes more stages.

Each becomes a claim decided from the 95% interval of its mean over the seeds. The quick
version measures each seed from 10 starts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellplan.core import Claim, Experiment, ReportPiece, RunSpec, Scalar
from cellplan.strategies.experiments.common import (
    Threshold,
    ci_text,
    column,
    finite_column,
    interval_rows,
    seeds_text,
    solved_bundled,
    threshold_claim,
    values_text,
)

PROBLEM = "strategies_ur5"
CELLS = "48,48,48"
EXPLANATION = "docs/strategies.md#the-first-three-joints-of-a-ur5"
STARTS = 40
"""Random starts per behaviour and seed."""
QUICK_STARTS = 10
"""Random starts per behaviour and seed in the quick version."""
DETOUR_REQUEST = ("P1", "S1", "D2")
"""The request whose way crosses the gate: S1 is on one side, D2 on the other."""
GATE = (0, 0.0)
"""The gate as a joint-space line: shoulder pan (axis 0) at 0 radians, the base's x axis,
where the gate stands."""


def make_runs(runs: int, quick: bool) -> list[RunSpec]:
    """One run per seed (each measures the three behaviours); quick: ``runs`` seeds of
    :data:`QUICK_STARTS` starts each."""
    starts = QUICK_STARTS if quick else STARTS
    return [
        RunSpec("strategies.ur5", {"cells": CELLS, "starts": starts}, seed) for seed in range(runs)
    ]


def run(spec: RunSpec) -> dict[str, Scalar]:
    """The three behaviours from the seed's random starts, and the stages of the empty
    and loaded ways across the gate."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan.strategies.experiments import arm_behaviours as b

    strategy, cell, seconds = solved_bundled(PROBLEM, str(spec.params["cells"]))
    count = int(spec.params["starts"])

    def rng(i: int) -> np.random.Generator:
        return np.random.default_rng([spec.seed, i])

    detours = b.detour_where_empty_fits(strategy, cell, rng(2), count, DETOUR_REQUEST, GATE)
    return {
        "seed": spec.seed,
        "cells": str(spec.params["cells"]),
        "starts": count,
        "gain": strategy.gain,
        "plan_seconds": seconds,
        "idle": b.idle_near_pick_points(strategy, cell, rng(0), count),
        "component": b.component_by_destination(strategy, cell, rng(1), count, "S2"),
        "detour": b.fraction([d.shown for d in detours]),
        "empty_stages": float(np.mean([d.empty_stages for d in detours])),
        "loaded_stages": float(np.mean([d.loaded_stages for d in detours])),
    }


THRESHOLD = 0.5
BEHAVIOURS = (
    (
        "idle",
        Threshold(
            "UR5: with no request pending, the arm moves to wait near the sources",
            "Sec. V-A, Problems 1 and 3, Fig. 9(a): in NR the robot moves near the sources",
            "fraction of random starts from which the no-request policy stops with the tool "
            "nearer the pick places",
            THRESHOLD,
            "a policy that ignores where requests come from ends nearer as often as farther",
        ),
    ),
    (
        "component",
        Threshold(
            "UR5: the destination decides which component of the split source S2 the arm "
            "picks from",
            "Sec. V-B, Problem 6, Fig. 15: the component of S1 that suits the destination",
            "fraction of (random start, destination) pairs picking from S2's component "
            "nearer the destination",
            THRESHOLD,
            "a choice that ignores the destination is right half the time",
        ),
    ),
    (
        "detour",
        Threshold(
            "UR5: carrying, the arm detours; empty, it passes under the gate",
            "Sec. V-A, Problem 1, Fig. 9(b)-(d): through the narrow opening empty, the longer "
            "route carrying",
            "fraction of random starts on D2's side crossing the gate empty where the loaded "
            "arm has no free cell, then taking more stages back loaded",
            THRESHOLD,
            "the behaviour holds from at most half the starts",
        ),
    ),
)
"""Each behaviour's column of the runs and its claim's words and bar."""


def claims(rows: list[dict[str, Scalar]]) -> list[Claim]:
    """One claim per behaviour: reproduced when the 95% interval of the mean over seeds
    lies above :data:`THRESHOLD` (at least 5 seeds)."""
    starts = f"; {values_text(rows, 'starts')} random starts per seed"
    return [
        threshold_claim(finite_column(rows, key), t, "no start measured", starts, EXPLANATION)
        for key, t in BEHAVIOURS
    ]


def report(rows: list[dict[str, Scalar]], outdir: Any) -> ReportPiece:
    """The three claims, a table per seed and a chart of the intervals."""
    # Deferred for start-up time: the experiment list loads without these.
    from cellplan import plots as base

    outdir = Path(outdir)
    found = claims(rows)
    fig, axes = base.new_figure(size=4.5)
    fig.set_size_inches(7.0, 2.8)
    ax = axes[0, 0]
    interval_rows(ax, [(key, finite_column(rows, key), t.above) for key, t in BEHAVIOURS])
    ax.set_xlim(0.0, 1.05)
    ax.set_xlabel("fraction of random starts showing the behaviour")
    figure = base.save_figure(fig, outdir / "strategies_ur5.png")
    starts = values_text(rows, "starts")
    table: list[dict[str, Scalar]] = [
        {
            "seed": int(r["seed"]),
            "idle": float(r["idle"]),
            "component": float(r["component"]),
            "detour": float(r["detour"]),
            "stages empty / loaded": f"{float(r['empty_stages']):.1f} / "
            f"{float(r['loaded_stages']):.1f}",
        }
        for r in sorted(rows, key=lambda r: int(r["seed"]))
    ]
    plan_s = column(rows, "plan_seconds")
    return ReportPiece(
        title="Strategies on the first three joints of a UR5",
        text=(
            f"The bundled 3-D scenario {PROBLEM} (problem 1's request model, 17 modes) "
            f"solved on a {' x '.join(CELLS.split(','))} grid through the validity interface "
            f"(gain {float(rows[0]['gain']):.4f} per stage; the planner, model and solve, "
            f"took {float(np.mean(plan_s)):.0f} s on average over the processes that ran "
            "it), then each "
            "behaviour measured from random starts by driving the arm as the simulator "
            "does. Ways across the gate, empty / loaded: "
            f"{ci_text(column(rows, 'empty_stages'), '.1f')} / "
            f"{ci_text(column(rows, 'loaded_stages'), '.1f')} stages."
        ),
        figures=[figure],
        captions={
            figure.name: f"Each behaviour over {seeds_text(len(rows))} "
            f"({starts} random starts each): grey dots are seeds, blue the mean with its "
            "95% interval, dashed the threshold of the claim."
        },
        tables=[("behaviours per seed", table)],
        claims=found,
        command=f"cellplan solve {PROBLEM} -o ur5.npz && cellplan simulate {PROBLEM} "
        "--strategy ur5.npz -o ur5_run/   (ur5_run/viewer.html plays the motion)",
    )


EXPERIMENT = Experiment(
    name="strategies.ur5",
    paper="strategies",
    title="The strategies paper's behaviours on the first three joints of a UR5",
    make_runs=make_runs,
    run=run,
    report=report,
    # Not in the demo: the 48^3 solve (about 15 s per process) on each of the demo's two
    # workers, beside the showcase's own, costs more than the demo's budget allows; the
    # demo lists its command instead.
    demo_runs=None,
)

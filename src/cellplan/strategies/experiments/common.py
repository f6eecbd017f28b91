"""What every strategies experiment shares: the solve on a grid, a column per run, the
interval's text, the claims decided from paired seeds or against a threshold, and the
pieces of their figures and captions (an experiment module states only what differs).

Every interval here is :func:`cellplan.core.mean_interval` (the Student-t interval of
the project's reports), so the experiment modules import this module and never each
other: :mod:`.paper` lists the experiments, the Section VI modules define them.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cellplan.core import Claim, ReportPiece, Scalar, decide_interval, mean_interval

#: How close the simulated loss per stage must come to the gain (relative, both ways).
AGREEMENT = 0.05


def column(rows: list[dict[str, Scalar]], key: str) -> np.ndarray:
    """One value per run (row) of the experiment."""
    return np.array([float(r[key]) for r in rows])


def ci_text(values: np.ndarray, fmt: str = ".3f") -> str:
    """``mean ± half-width`` of the 95% interval (the mean alone below two values)."""
    m, h = mean_interval(values)
    return f"{m:{fmt}} ± {h:{fmt}}" if np.isfinite(h) else f"{m:{fmt}}"


def ci_column(rows: list[dict[str, Scalar]], key: str, fmt: str = ".3f") -> str:
    """:func:`ci_text` of the column ``key`` of the runs."""
    return ci_text(column(rows, key), fmt)


def reduction_claim(
    optimal: np.ndarray,
    baseline: np.ndarray,
    *,
    claim: str,
    paper: str,
    ours: str,
    detail: str,
    rule: str,
    explanation: str,
) -> Claim:
    """A claim that the optimal strategy's measure is below a baseline's, paired by seed:
    reproduced when the 95% interval of the mean reduction (in percent) lies above 0 (at
    least 5 seeds). ``ours`` follows the reduction in the figure's text
    (``"12.3% ± 1.0% " + ours``)."""
    d = 100.0 * (baseline - optimal) / baseline
    m, h = mean_interval(d)
    n = len(d)
    return Claim(
        claim=claim,
        paper=paper,
        ours=f"{m:.1f}% ± {h:.1f}% {ours}",
        reproduced=decide_interval(m - h, m + h, n, above=0.0),
        detail=detail,
        n=n,
        rule=rule,
        explanation=explanation,
    )


def agreement_claim(
    name: str, paper: str, gain: float, loss: np.ndarray, explanation: str
) -> Claim:
    """The simulated loss per stage (one value per seed) agrees with the solved gain."""
    rel = 100.0 * (loss - gain) / gain
    m, h = mean_interval(rel)
    n = len(loss)
    return Claim(
        claim=f"{name}: the simulated loss per stage agrees with the solved gain",
        paper=paper,
        ours=f"simulated {np.mean(loss):.3f} against g = {gain:.3f} ({m:+.1f}% ± {h:.1f}%)",
        reproduced=decide_interval(m - h, m + h, n, above=-100 * AGREEMENT, below=100 * AGREEMENT),
        detail="relative difference per seed",
        n=n,
        rule=f"95% interval of the relative difference inside ±{100 * AGREEMENT:.0f}% "
        "(at least 5 seeds)",
        explanation=explanation,
    )


def beats_reactive_claim(
    claim: str, paper: str, wait: dict[str, np.ndarray], explanation: str
) -> Claim:
    """The optimal strategy's mean waiting per request is below the reactive one's (paired)."""
    return reduction_claim(
        wait["optimal"],
        wait["reactive"],
        claim=claim,
        paper=paper,
        ours="less waiting per request than reactive",
        detail="mean waiting per request (open ones at their age), paired by seed",
        rule="95% interval of the mean reduction against reactive above 0 (at least 5 seeds)",
        explanation=explanation,
    )


# --- solving and the shared pieces of the reports ---------------------------------------------


def plan_on_grid(source: Any, cells: str) -> Any:
    """The strategy of ``source`` (a bundled problem's name, a setup or a scenario) on the
    grid ``cells`` (``"48,48"``): ``cellplan.plan(..., "strategies")`` with one sample per
    stage, as every experiment solves."""
    # Deferred for start-up time: the experiment list loads without the planner.
    from cellplan.api import load, plan

    grid = [int(v) for v in cells.split(",")]
    setup = load(source) if isinstance(source, str) else source
    return plan(setup, "strategies", cells=grid, sample_stages=1).solution


@functools.lru_cache(maxsize=8)
def solved_bundled(problem: str, cells: str) -> tuple[Any, Any, float]:
    """A bundled problem's strategy on a grid, its workcell and the seconds its planner
    took (model and solve), solved once per process and shared by the experiments."""
    # Deferred for start-up time: the experiment list loads without the planner.
    from cellplan.api import load

    setup = load(problem)
    t0 = time.perf_counter()
    strategy = plan_on_grid(setup, cells)
    return strategy, setup.workcell, time.perf_counter() - t0


def half(h: float) -> float:
    """An interval's half-width for an error bar: 0 where there is none (one value)."""
    return h if np.isfinite(h) else 0.0


def finite_column(rows: list[dict[str, Scalar]], key: str) -> np.ndarray:
    """The finite values of ``key`` over the runs that measured it."""
    values = np.array([float(r[key]) for r in rows if key in r], dtype=float)
    return values[np.isfinite(values)]


def seeds_text(n: int) -> str:
    """``"1 seed"``, ``"5 seeds"``."""
    return f"{n} seed{'s' if n != 1 else ''}"


def values_text(rows: list[dict[str, Scalar]], key: str) -> str:
    """The distinct whole values of ``key`` over the runs, sorted (``"1500, 4000"``)."""
    return ", ".join(map(str, sorted({int(r[key]) for r in rows if key in r})))


def grids_text(rows: list[dict[str, Scalar]], upper: bool = False) -> str:
    """Each (problem, grid) of the runs, ``"p1 100 x 100, p2 48 x 48"``."""
    pairs = sorted({(str(r["problem"]), str(r["cells"])) for r in rows if "cells" in r})
    names = [(p.removeprefix("strategies_"), c) for p, c in pairs]
    return ", ".join(f"{p.upper() if upper else p} {' x '.join(c.split(','))}" for p, c in names)


def interval_bar(ax: Any, x: float, values: np.ndarray, **style: Any) -> None:
    """One bar at ``x``: the mean of ``values`` with its 95% interval as the error bar."""
    m, h = mean_interval(values)
    ax.bar(x, m, yerr=half(h), capsize=4, **style)


def paired_columns(
    rows: list[dict[str, Scalar]], key: str, baseline: str
) -> tuple[np.ndarray, np.ndarray]:
    """``(optimal, baseline)`` values of ``key`` per run, paired by seed, for
    :func:`reduction_claim` (the columns ``optimal_<key>`` and ``<baseline>_<key>``)."""
    return column(rows, f"optimal_{key}"), column(rows, f"{baseline}_{key}")


@dataclass(frozen=True)
class Threshold:
    """A behaviour measured once per seed, claimed when the 95% interval of its mean over
    the seeds lies above ``above``."""

    claim: str
    paper: str
    quantity: str
    """What one value is (the claim's figure names it)."""
    above: float
    null: str
    """Why ``above`` is the bar: what a policy without the behaviour would give."""


def threshold_claim(
    values: np.ndarray, t: Threshold, missing: str, detail: str, explanation: str
) -> Claim:
    """The claim of ``t`` decided from the finite per-seed ``values``; ``missing`` is its
    figure when no seed measured it, ``detail`` follows the interval in its detail."""
    rule = f"95% interval of the mean over seeds above {t.above:g} ({t.null}); at least 5 seeds"
    if not len(values):
        return Claim(t.claim, t.paper, missing, None, "not run", 0, rule, explanation)
    m, h = mean_interval(values)
    low, high = (m - h, m + h) if np.isfinite(h) else (m, m)
    return Claim(
        claim=t.claim,
        paper=t.paper,
        ours=f"{m:.2f} ± {half(h):.2f}: {t.quantity}",
        reproduced=decide_interval(low, high, len(values), above=t.above),
        detail=f"interval [{low:.2f}, {high:.2f}] against {t.above:g}{detail}",
        n=len(values),
        rule=rule,
        explanation=explanation,
    )


def interval_rows(
    ax: Any, series: list[tuple[str, np.ndarray, float]], missing: str | None = None
) -> None:
    """One row per ``(name, finite values, threshold)``: the seeds as grey dots, the mean
    with its 95% interval in blue, the threshold dashed; ``missing`` is written on a row
    without values (nothing where None)."""
    for y, (_, values, above) in enumerate(series):
        ax.plot([above] * 2, [y - 0.4, y + 0.4], ls="--", color="grey", lw=1)
        if len(values):
            m, h = mean_interval(values)
            ax.plot(values, np.full(len(values), y + 0.15), ".", color="#8c959f", ms=4)
            ax.errorbar([m], [y], xerr=[[half(h)]], fmt="o", color="#1f77b4")
        elif missing is not None:
            ax.text(above, y, missing, va="center", fontsize=8)
    ax.set_yticks(range(len(series)), [name for name, *_ in series])
    ax.invert_yaxis()


def per_policy_piece(
    title: str,
    text: str,
    figure: Path,
    caption: str,
    table: list[dict[str, Scalar]],
    claims: list[Claim],
    command: str,
) -> ReportPiece:
    """A report of one figure and one table of the policies (a row each, mean ± 95%
    interval over the seeds), as the Section VI experiments that compare policies give."""
    return ReportPiece(
        title=title,
        text=text,
        figures=[figure],
        captions={figure.name: caption},
        tables=[("per policy (mean ± 95% interval over seeds)", table)],
        claims=claims,
        command=command,
    )

"""What every strategies experiment shares: a column per run, the interval's text, and the
claims decided from paired seeds.

Every interval here is :func:`cellplan.core.mean_interval` (the Student-t interval of
the project's reports), so the experiment modules import this module and never each
other: :mod:`.paper` lists the experiments, the Section VI modules define them.
"""

from __future__ import annotations

import numpy as np

from cellplan.core import Claim, Scalar, decide_interval, mean_interval

#: How close the simulated loss per stage must come to the gain (relative, both ways).
AGREEMENT = 0.05


def column(rows: list[dict[str, Scalar]], key: str) -> np.ndarray:
    """One value per run (row) of the experiment."""
    return np.array([float(r[key]) for r in rows])


def ci_text(values: np.ndarray, fmt: str = ".3f") -> str:
    """``mean ± half-width`` of the 95% interval (the mean alone below two values)."""
    m, h = mean_interval(values)
    return f"{m:{fmt}} ± {h:{fmt}}" if np.isfinite(h) else f"{m:{fmt}}"


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

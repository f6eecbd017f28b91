"""What Section 5 of the paper reports, checked on a few seeds (the full sweeps are experiments).

Sec. 5.2.2: the path-length ratio is nearly independent of the goal's packing beta(d),
and starts that permute packed goals give ratios about double those of random starts.
"""

from __future__ import annotations

import numpy as np

import cellplan
from cellplan.assembly.problems import generated_setup

SEEDS = range(4)


def _mean_ratio(log10_beta: float, starts: str, k: float = 64.0) -> float:
    ratios = []
    for seed in SEEDS:
        setup = generated_setup(
            {"n": 7, "seed": seed, "log10_beta_goal": log10_beta, "starts": starts}
        )
        res = cellplan.plan(setup, "assembly.gradient", k=k)
        assert res.status.ok and res.stats["min_clearance"] > 0
        ratios.append(res.stats["ratio"])
    return float(np.mean(ratios))


def test_ratio_is_nearly_independent_of_goal_packing() -> None:
    # Figs. 6-7: beta(d) = 1e-2 (loose) and 1e-44 (tight) give about the same ratio
    loose, tight = _mean_ratio(-2.0, "random"), _mean_ratio(-44.0, "random")
    assert 1.0 < loose < 1.5 and 1.0 < tight < 1.5
    assert abs(tight / loose - 1.0) < 0.05


def test_permuted_starts_about_double_the_ratio() -> None:
    # Sec. 5.2.2: "path-length ratios nearly double those observed for random starts"
    factor = _mean_ratio(-16.0, "permutation") / _mean_ratio(-16.0, "random")
    assert 1.5 < factor < 2.5

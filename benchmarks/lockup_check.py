"""Issue 35 part 1's measurement: long simultaneous-requests runs agree with the gain.

``.venv/bin/python benchmarks/lockup_check.py STRATEGY.npz [STAGES] [SEEDS...]`` simulates
the bundled ``strategies_pending`` scenario under a solved strategy (``cellplan solve
strategies_pending -o STRATEGY.npz``) with the workcell's exact region tests, one run
per seed, and prints per seed the loss per stage with its 95% batch-means interval (20
batches), the requests served and left open, the refused FMPs and the executor's
corrections; then the mean over the seeds with its 95% t-interval and the verdict of
"the gain lies inside it" (at least :data:`cellplan.core.MIN_RUNS` seeds). A long run is not a
unit test: this is the script behind the figures in docs/strategies.md.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from cellplan.api import load
from cellplan.core import MIN_RUNS, mean_interval
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.sim.simulate import wait_bound
from cellplan.strategies.variants.pending_sim import simulate_pending

BATCHES = 20
DEFAULT_SEEDS = (0, 1234, 1235, 1, 2, 3, 4, 5, 6, 7)


def interval(values: np.ndarray) -> tuple[float, float, float]:
    """Mean and 95% t-interval of ``values`` (:func:`cellplan.core.mean_interval`)."""
    mean, half = mean_interval(values)
    return mean, mean - half, mean + half


def main(argv: list[str]) -> int:
    """Run the check (module docstring); exit 0 when the gain lies in the interval."""
    path = Path(argv[0])
    stages = int(argv[1]) if len(argv) > 1 else 100_000
    seeds = [int(s) for s in argv[2:]] or list(DEFAULT_SEEDS)
    setup = load("strategies_pending")
    strategy = Strategy.load(path, setup.scenario)
    regions = setup.scenario.strategy.regions
    bound = wait_bound(strategy)
    per_seed = []
    print(f"gain {strategy.gain:.6f}; {stages:,} stages per seed; seeds {seeds}")
    for seed in seeds:
        t0 = time.perf_counter()
        sim = simulate_pending(
            strategy, stages, seed, SimulationOptions(regions=regions), cell=setup.workcell
        )
        # The gain is the long-run expected loss per stage of the model (a stage of motion
        # or one FMP), so the runs' figure is the mean loss over their stages.
        loss = float(sim.losses.mean())
        lo, hi = interval(sim.losses.reshape(BATCHES, -1).mean(1))[1:]
        open_now = sum(1 for r in sim.requests if r.delivery < 0)
        longest = max((r.waiting for r in sim.requests), default=0.0)
        late = sum(1 for r in sim.requests if r.waiting > bound)
        per_seed.append(loss)
        print(
            f"seed {seed}: loss/stage {loss:.4f} [{lo:.4f}, {hi:.4f}] "
            f"({100 * (loss / strategy.gain - 1):+.1f}% of the gain), "
            f"served {sum(1 for r in sim.requests if r.delivery >= 0)}, open {open_now}, "
            f"longest wait {longest:.0f} ({late} over the bound {bound:.0f}), "
            f"fmp_refused {sim.fmp_refused}, "
            f"corrections {sim.corrections}, {time.perf_counter() - t0:.0f} s"
        )
    m, lo, hi = interval(np.asarray(per_seed))
    # "The long-run loss per stage is the gain": the gain inside the seeds' interval.
    verdict = lo <= strategy.gain <= hi and len(per_seed) >= MIN_RUNS
    print(
        f"mean over {len(per_seed)} seeds {m:.4f}, 95% interval [{lo:.4f}, {hi:.4f}]; "
        f"gain {strategy.gain:.4f} inside: {verdict}"
    )
    return 0 if verdict else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

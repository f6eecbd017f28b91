"""Where `cellplan simulate` spends its drawing time, and what writing only frames.png saves.

Runs, in one process on the same simulated run of the bundled ``strategies_tiny`` (the
command's default 400 stages, seed of the command), the frame drawing as it was (every
mode segment saved as its own PNG, then ``frames.png``; ``each=True``) and as it is now
(``frames.png`` only, the default; ``--frame-files`` asks for the others), and prints the
seconds of each and their ratio.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_simulate_frames.py
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cellplan
from cellplan.strategies.commands import SIMULATE_SEED, SIMULATE_STAGES
from cellplan.strategies.experiments import plots
from cellplan.strategies.sim.simulate import simulate_result


def main() -> None:
    setup = cellplan.load("strategies_tiny")
    strategy = cellplan.plan(setup, "strategies").solution
    sim = simulate_result(strategy, SIMULATE_STAGES, SIMULATE_SEED, cell=setup.workcell).solution
    with tempfile.TemporaryDirectory() as tmp:
        # Warm matplotlib (imports, fonts) so neither run pays for it.
        plots.plot_frames(strategy, setup.workcell, sim, Path(tmp), max_frames=2)
        t0 = time.perf_counter()
        before = plots.plot_frames(strategy, setup.workcell, sim, Path(tmp), each=True)
        t1 = time.perf_counter()
        after = plots.plot_frames(strategy, setup.workcell, sim, Path(tmp))
        t2 = time.perf_counter()
    print(f"segments drawn: {len(before) - 1}")
    print(f"each segment's PNG + frames.png (before): {t1 - t0:.2f} s, {len(before)} files")
    print(f"frames.png only (now):                    {t2 - t1:.2f} s, {len(after)} file")
    print(f"ratio: {(t1 - t0) / (t2 - t1):.1f}x")


if __name__ == "__main__":
    main()

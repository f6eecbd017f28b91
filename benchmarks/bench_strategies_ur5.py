"""Benchmark of the strategies planner on the first three joints of a UR5.

Run: ``PYTHONPATH=src .venv/bin/python benchmarks/bench_strategies_ur5.py``

Prints, for ``strategies_ur5`` at its bundled 48^3 grid:

* where the planner's time goes: the model (the C-space bitmaps and region bitmaps,
  through the validity interface, then the moves and live states) against the solve;
* the held part's sphere centres in the world, the step the bitmaps of a carrying mode
  repeat for every cell, two ways in the same process: numpy's ``einsum`` (the code
  before issue 31) against the batched matmul ``workcell3d`` now uses, with the ratio
  (both give the same centres to 1e-15 m).

Machine load matters: print ``cat /proc/loadavg`` beside the figures.
"""

from __future__ import annotations

import time

import numpy as np

import cellplan
from cellplan import arm as arms
from cellplan.cspace import Grid
from cellplan.strategies.model.mdp import build_model


def main() -> None:
    setup = cellplan.load("strategies_ur5")
    cell = setup.workcell
    t0 = time.perf_counter()
    build_model(setup.scenario, cell, start=cell.robot.start)
    model_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = cellplan.plan(setup, "strategies", sample_stages=1)
    plan_s = time.perf_counter() - t0
    print(f"model build {model_s:.1f} s; plan (model + solve + 1 stage) {plan_s:.1f} s")
    print(f"solve alone {result.stats['seconds']:.1f} s; {result.message}")

    grid = Grid.for_robot(cell.robot, (48, 48, 48))
    q = grid.points()
    part = cell.part("P1")
    tool = arms.tool_pose(cell.robot.arm, q)
    rot, origin = tool[:, :3, :3], tool[:, None, :3, 3]
    t0 = time.perf_counter()
    before = np.einsum("nij,kj->nki", rot, part.centers) + origin
    einsum_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    after = (rot @ part.centers.T).transpose(0, 2, 1) + origin
    matmul_s = time.perf_counter() - t0
    gap = float(np.abs(before - after).max())
    print(
        f"part centres for {len(q):,} cells x {len(part.radii)} spheres: einsum "
        f"{einsum_s:.2f} s, matmul {matmul_s:.2f} s, ratio {einsum_s / matmul_s:.1f}x "
        f"(largest difference {gap:.1e} m)"
    )


if __name__ == "__main__":
    main()

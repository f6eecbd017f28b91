"""C-space bitmap speed against a per-configuration shapely loop, in the same run.

Run: ``.venv/bin/python benchmarks/bench_cspace.py`` (add ``--quick`` for a smoke run).

The baseline is what one would write without cellplan: for every cell centre,
place the robot polygon with shapely.affinity and test it against the union of
the obstacles (a prepared geometry). It only answers "is the centre free?",
while cellplan's bitmaps certify the whole cell, so the comparison favours the
baseline. For the 3-D cases the baseline is timed on a random sample of cells
and scaled to the full grid (the printout says so).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import shapely
import shapely.affinity

from cellplan.cspace import Grid, free_bitmap
from cellplan.workcell import Workcell, load_workcell


def shapely_loop(cell: Workcell, q: np.ndarray) -> np.ndarray:
    """The baseline: one shapely placement and intersection test per configuration."""
    obstacles = shapely.union_all(
        [
            *cell.obstacle_geometries.values(),
            *(g for r in cell.sources.values() for g in r.geometries),
            shapely.box(*cell.bounds).exterior,
        ]
    )
    shapely.prepare(obstacles)
    out = np.empty(len(q), bool)
    if cell.robot.kind == "arm":
        for i, qi in enumerate(q):
            bodies, _ = cell.robot_shapes(qi)
            out[i] = any(obstacles.intersects(b) for b in bodies)
        return out
    body = cell.robot.bodies.bodies[0].to_shapely()
    for i, qi in enumerate(q):
        g = (
            body
            if len(qi) == 2
            else shapely.affinity.rotate(body, qi[2], origin=(0, 0), use_radians=True)
        )
        out[i] = obstacles.intersects(shapely.affinity.translate(g, qi[0], qi[1]))
    return out


def timed(fn, repeat: int = 1):
    best = math.inf
    result = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def case(name: str, scenario: str, cells: tuple[int, ...], sample: int | None, target: str) -> None:
    _, cell = load_workcell(scenario)
    grid = Grid.for_robot(cell.robot, cells)
    free_bitmap(cell, Grid.for_robot(cell.robot, tuple(4 for _ in cells)))  # compile / warm caches
    t_ours, free = timed(lambda: free_bitmap(cell, grid), repeat=3)
    q = grid.points()
    if sample is not None and sample < len(q):
        q = q[np.random.default_rng(0).choice(len(q), sample, replace=False)]
    t_base, _ = timed(lambda: shapely_loop(cell, q))
    scale = grid.size / len(q)
    t_base_full = t_base * scale
    note = "" if scale == 1 else f" (timed on {len(q)} cells, scaled x{scale:.0f})"
    print(
        f"{name:<28} {' x '.join(map(str, cells)):>14}  cellplan {t_ours:7.3f} s   "
        f"shapely loop {t_base_full:8.2f} s{note}   ratio {t_base_full / t_ours:7.1f}x   "
        f"free {free.mean():.3f}   target: {target}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small grids (smoke run)")
    args = parser.parse_args()
    if args.quick:
        case("translating (FFT)", "strategies_p1", (64, 64), None, "smoke")
        case("rotating (FFT per slice)", "rotating_bar", (32, 32, 16), 2000, "smoke")
        case("3-link arm (exact+margin)", "strategies_p6", (16, 16, 16), 2000, "smoke")
        return
    case("translating (FFT)", "strategies_p1", (256, 256), None, ">= 100x")
    case("rotating (FFT per slice)", "rotating_bar", (128, 128, 64), 20000, "< 5 s")
    case("3-link arm (exact+margin)", "strategies_p6", (64, 64, 64), 10000, "< 10 s")


if __name__ == "__main__":
    main()

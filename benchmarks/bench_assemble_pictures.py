"""Benchmark: drawing against planning in ``cellplan assemble``, pictures by default or asked for.

Run: ``nice .venv/bin/python benchmarks/bench_assemble_pictures.py`` (``--sizes 15``:
fewer problems; ``--commands``: also time the whole command in a subprocess, each way).

For the issue's generated problems (``--random N --seed 1``, N = 15, 25, 50) it plans
once to compile and warm, then, in the same process on the same result:

- the planner (:func:`cellplan.api.plan`, ``assembly.gradient``), wall and CPU seconds;
- the files ``assemble`` wrote by default before (``write_outputs(pictures=True)``:
  ``sequence.png``, the 24-frame ``assembly.gif``, ``trajectory.csv``, ``metrics.json``),
  the first such call also paying matplotlib's import, as every command did;
- the files it writes by default now (``pictures=False``: the trajectory and metrics).

It prints each time and the ratio of the writing time to the planner's, before and after,
CPU seconds beside wall (the machine is shared: CPU seconds are the steadier figure), and
the machine's load before and after.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cellplan import api
from cellplan.assembly.problems import random_setup
from cellplan.assembly.run import write_outputs


def _timed(fn: Callable[[], Any]) -> tuple[float, float]:
    """(wall, CPU) seconds of ``fn()`` in this process."""
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def _command(args: list[str]) -> tuple[float, float]:
    """(wall, CPU) seconds of ``cellplan ARGS`` in a subprocess."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w = time.perf_counter()
    subprocess.run([sys.executable, "-m", "cellplan.cli", *args], check=True, capture_output=True)
    wall = time.perf_counter() - w
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def bench(n: int, folder: Path, first: bool) -> None:
    setup = random_setup(n, 1, None, None, False, None, 2, None)
    api.plan(setup, "assembly.gradient")  # compiles or loads the kernels: not charged
    result = None

    def plan() -> None:
        nonlocal result
        result = api.plan(setup, "assembly.gradient")

    plan_w, plan_c = _timed(plan)
    assert result is not None
    old_w, old_c = _timed(lambda: write_outputs(result, folder / f"old{n}", pictures=True))
    new_w, new_c = _timed(lambda: write_outputs(result, folder / f"new{n}", pictures=False))
    note = " (with matplotlib's import)" if first else ""
    print(f"\n--random {n} --seed 1: {len(result.solution.path)} rows, {result.status.value}")
    print(f"  planner                          wall {plan_w:6.2f} s  CPU {plan_c:6.2f} s")
    print(f"  files, pictures (old default){note}: wall {old_w:6.2f} s  CPU {old_c:6.2f} s")
    print(f"  files, no pictures (new default) wall {new_w:6.2f} s  CPU {new_c:6.2f} s")
    print(
        f"  writing / planner: old {old_w / plan_w:.2f} -> new {new_w / plan_w:.3f} (wall), "
        f"old {old_c / plan_c:.2f} -> new {new_c / plan_c:.3f} (CPU)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--sizes", default="15,25,50", help="disc counts, comma-separated")
    parser.add_argument("--commands", action="store_true", help="also time whole commands")
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    print("load before:", " ".join(f"{v:.2f}" for v in os.getloadavg()))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for i, n in enumerate(sizes):
            bench(n, folder, first=i == 0)
        if args.commands:
            print()
            for n in sizes:
                base = ["assemble", "--random", str(n), "--seed", "1"]
                old_w, old_c = _command([*base, "--pictures", "-o", str(folder / f"c_old{n}")])
                new_w, new_c = _command([*base, "-o", str(folder / f"c_new{n}")])
                print(
                    f"  cellplan {' '.join(base)}: --pictures wall {old_w:.2f} s CPU "
                    f"{old_c:.2f} s; default wall {new_w:.2f} s CPU {new_c:.2f} s "
                    f"(old/new wall {old_w / new_w:.2f}x)"
                )
    print("\nload after:", " ".join(f"{v:.2f}" for v in os.getloadavg()))


if __name__ == "__main__":
    main()

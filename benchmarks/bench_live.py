"""Benchmark of the live-state computation: skipping and sharing layers against every layer.

Run: ``.venv/bin/python benchmarks/bench_live.py`` (``--copies 90``: how many aliased
copies of destination D1 the second problem adds to problem 6).

For problem 6 at its bundled 64^3 grid, and for problem 6 with ``--copies`` aliased copies
of D1 (the slow fuzzer made 100 copies, now over the limit of 100 destinations; 90 give
188 requests and 377 modes), the live states are computed in the same process, from the
same free bitmaps, two ways:

* ``every layer``: the baseline, the previous code: :func:`.domain.live_layer` on every
  layer, pass after pass, until a pass changes nothing (the last pass only confirms);
* ``compute_live``: :func:`cellplan.strategies.model.mdp.compute_live`, which skips a layer
  whose inputs did not change since it settled and copies the result of a layer with the
  same inputs.

It checks that both give the same live sets and prints both times and the ratio
(numba compilation excluded: one warm-up call first).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

import cellplan
from cellplan.registry import resolve_scenario_path
from cellplan.strategies.model.domain import live_layer
from cellplan.strategies.model.mdp import LayeredMDP, build_model, compute_live

D1 = "  D1: {components: [{type: box, min: [44, 84], max: [52, 92]}]}\n"


def every_layer(mdp: LayeredMDP, live: np.ndarray) -> None:
    """The baseline: every layer, every pass, until nothing changes."""
    fmp_ok = mdp.tf < np.inf
    model = mdp.kernel_args()
    while True:
        changed = False
        for m in range(mdp.n_modes):
            changed |= bool(live_layer(live, fmp_ok, model, m))
        if not changed:
            return


def run(label: str, mdp: LayeredMDP) -> None:
    start = np.stack([mdp.free[mdp.vcls[m]] for m in range(mdp.n_modes)])
    base = start.copy()
    t0 = time.perf_counter()
    every_layer(mdp, base)
    t_base = time.perf_counter() - t0
    mdp.live = start.copy()
    t0 = time.perf_counter()
    compute_live(mdp)
    t_new = time.perf_counter() - t0
    same = np.array_equal(base, mdp.live)
    print(
        f"{label:<34} {mdp.n_modes:>5} modes  every layer {t_base:7.2f} s  "
        f"compute_live {t_new:6.2f} s  ratio {t_base / t_new:5.1f}x  same: {same}"
    )
    if not same:
        raise SystemExit("the two live sets differ")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--copies", type=int, default=90)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    text = resolve_scenario_path("strategies_p6").read_text(encoding="utf-8")
    setup = cellplan.load("strategies_p6")
    mdp = build_model(setup.scenario, setup.workcell)  # also compiles the kernel
    run("P6 64^3", mdp)
    aliased = text.replace(
        D1, D1.replace("D1: {", "D1: &d1 {") + "".join(f"  X{i}: *d1\n" for i in range(args.copies))
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "p6_aliased.yaml")
        with open(path, "w", encoding="utf-8") as f:
            f.write(aliased)
        setup = cellplan.load(path)
        mdp = build_model(setup.scenario, setup.workcell)
    run(f"P6 64^3, {args.copies} copies of D1", mdp)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

"""Fit and check the memory estimate's rules for policy iteration's sparse LU factors.

Run: ``.venv/bin/python benchmarks/fit_lu_fill.py`` (``--set fit`` or ``--set held-out``
for one half; the whole run takes about five minutes on two cores).

Policy iteration factorises its recurrent class with SuperLU, whose memory tracemalloc
cannot see, so :func:`cellplan.strategies.model.memory.estimate_memory` bounds the factors by a
rule: :data:`~cellplan.strategies.model.memory.STATIONARY_FILL` entries per place of the
policy's matrix on a stationary model, and :data:`~cellplan.strategies.model.memory.PERIODIC_FILL`
times ``(layers x cells)^(4/3)`` on a time-varying one (Section VI-1). This script solves
each model of the fit set and of the held-out set, records the largest factorisation
(SuperLU's own count of its entries, ``SuperLU.nnz``), and prints the ratio the rule
divides by, per model and the largest per set. The constants were chosen from the fit
set's largest ratio; the held-out set must stay below them.
"""

from __future__ import annotations

import argparse
from typing import Any

import cellplan
from cellplan.registry import scenario_path
from cellplan.scenario import loads_scenario
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.model.memory import PERIODIC_FILL, STATIONARY_FILL, estimate_memory
from cellplan.strategies.solve import policy_iteration
from cellplan.strategies.solve.solver import solve
from cellplan.workcell import Workcell

# The bundled tiny workcell with its grid left open (as the tests use it).
TINY = (
    scenario_path("strategies_tiny").read_text().replace("cells: [12, 12]", "cells: [CELLS, CELLS]")
)

SEEN: list[int] = []
_SPLU = policy_iteration.splu


def _spy(matrix: Any, *args: Any, **kwargs: Any) -> Any:
    lu = _SPLU(matrix, *args, **kwargs)
    SEEN.append(int(lu.nnz))
    return lu


def belt(period: int, cells: int, velocity: float = 1.5) -> tuple[Any, Any]:
    """The tiny cell with S1 on a belt and requests in the first two stages of a period."""
    profile = [1, 1] + [0] * (period - 2)
    text = TINY.replace("CELLS", str(cells)) + (
        f"  period: {period}\n  arrival_profile: {profile}\n"
        f"  belts:\n    S1: {{velocity: [{velocity}, 0]}}\n"
    )
    sc = loads_scenario(text)
    return sc, Workcell.from_scenario(sc)


def tiny(cells: int, extra: str = "") -> tuple[Any, Any]:
    sc = loads_scenario(TINY.replace("CELLS", str(cells)) + extra)
    return sc, Workcell.from_scenario(sc)


def bundled(name: str) -> tuple[Any, Any]:
    setup = cellplan.load(name)
    return setup.scenario, setup.workcell


PENDING = "  max_pending: {k}\n  urgency: {{P1: 2.0}}\n"
MODELS = {
    "fit": [
        ("tiny 32", lambda: tiny(32), None),
        ("tiny 48", lambda: tiny(48), None),
        ("2 open, tiny 24", lambda: tiny(24, PENDING.format(k=2)), None),
        ("3 open, tiny 40", lambda: tiny(40, PENDING.format(k=3)), None),
        ("P1 50", lambda: bundled("strategies_p1"), [50, 50]),
        ("P1 100", lambda: bundled("strategies_p1"), [100, 100]),
        ("strategies_failures 100", lambda: bundled("strategies_failures"), None),
        ("belt T=6 24", lambda: belt(6, 24), None),
        ("belt T=6 40", lambda: belt(6, 40), None),
        ("belt T=6 60", lambda: belt(6, 60), None),
        ("belt T=12 30", lambda: belt(12, 30), None),
        ("belt T=12 40", lambda: belt(12, 40), None),
        ("belt T=12 60", lambda: belt(12, 60), None),
        ("belt T=8 48", lambda: belt(8, 48), None),
        ("belt T=20 32", lambda: belt(20, 32, 0.9), None),
        ("belt T=20 48", lambda: belt(20, 48, 0.9), None),
    ],
    "held-out": [
        ("strategies_noise", lambda: bundled("strategies_noise"), None),
        ("strategies_failures_arm", lambda: bundled("strategies_failures_arm"), None),
        ("strategies_pending 40", lambda: bundled("strategies_pending"), [40, 40]),
        ("strategies_pending 60", lambda: bundled("strategies_pending"), [60, 60]),
        ("strategies_failures 60", lambda: bundled("strategies_failures"), [60, 60]),
        ("belt T=10 56", lambda: belt(10, 56), None),
        ("belt T=16 44", lambda: belt(16, 44), None),
        ("belt T=4 64", lambda: belt(4, 64), None),
        ("belt T=14 36", lambda: belt(14, 36), None),
        ("strategies_conveyor 40", lambda: bundled("strategies_conveyor"), [40, 40]),
        ("strategies_conveyor 50", lambda: bundled("strategies_conveyor"), [50, 50]),
        ("strategies_conveyor 60", lambda: bundled("strategies_conveyor"), [60, 60]),
    ],
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=["fit", "held-out", "both"], default="both")
    args = ap.parse_args()
    policy_iteration.splu = _spy
    for which in ("fit", "held-out"):
        if args.set not in (which, "both"):
            continue
        worst = {"stationary": 0.0, "periodic": 0.0}
        print(f"{which}:")
        for label, make, cells in MODELS[which]:
            sc, cell = make()
            mdp = build_model(sc, cell, cells)
            SEEN.clear()
            solve(mdp, "policy")
            est = estimate_memory(sc, cell, cells, method="policy")
            if mdp.period > 1:
                kind, unit = "periodic", float(mdp.n_modes * mdp.n_cells) ** (4 / 3)
            else:
                # The rule's entries over its constant: the places of the policy's matrix.
                kind, unit = "stationary", est.terms["factors"] / 12 / STATIONARY_FILL
            ratio = max(SEEN) / unit
            worst[kind] = max(worst[kind], ratio)
            print(f"  {label:26s} {kind:10s} entries {max(SEEN):12,d}  ratio {ratio:6.2f}")
        print(
            f"  largest: stationary {worst['stationary']:.2f} (rule {STATIONARY_FILL}), "
            f"time-varying {worst['periodic']:.2f} (rule {PERIODIC_FILL})"
        )


if __name__ == "__main__":
    main()

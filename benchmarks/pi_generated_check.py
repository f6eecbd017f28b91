"""Issue 35's held-out check of policy iteration on generated simultaneous-requests models.

``.venv/bin/python benchmarks/pi_generated_check.py [SEED] [COUNT]`` (defaults 7 and 20)
draws ``COUNT`` variants of the two-part tiny cell (``strategies_tiny`` with P2 from S2,
both parts to D1): arrival probability, ``max_pending``, P2's urgency and the grid, from
the seeded generator. Each is solved by policy iteration and by relative value iteration
(``method: general``, the independent solver of the same model), and the script prints
per variant the status, iterations, seconds, both gains, and how many modes the optimal
policy holds open for ever (:func:`~cellplan.strategies.solve.policy_iteration.stranded_modes`);
then how many variants agree (both solved, gains within 1e-6) and how many optima hold
requests open. The script behind the figures of docs/strategies.md ("A split chain", "A
request turned away costs nothing"); the unit tests take a few of these models
(``tests/strategies/test_strategies_policy_iteration.py``).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from cellplan.registry import scenario_path
from cellplan.scenario import loads_scenario
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.solve.certify import solve_general
from cellplan.strategies.solve.policy_iteration import solve_policy_iteration, stranded_modes
from cellplan.workcell import Workcell

ARRIVALS = (0.01, 0.03, 0.05, 0.08, 0.12, 0.2)
URGENCIES = (1.0, 0.5, 2.0, 3.0, 6.0)
GRIDS = (8, 10, 12)


def variant(arrival: float, k: int, urgency: float, cells: int) -> str:
    """The scenario text of one variant."""
    text = scenario_path("strategies_tiny").read_text()
    text = text.replace(
        "  P1: {shape: {type: box, min: [-2, -0.5], max: [2, 0.5]}}",
        "  P1: {shape: {type: box, min: [-2, -0.5], max: [2, 0.5]}}\n"
        "  P2: {shape: {type: box, min: [-2, -0.5], max: [2, 0.5]}}",
    )
    text = text.replace("arrival: {probability: 0.1}", f"arrival: {{probability: {arrival}}}")
    text = text.replace("cells: [12, 12]", f"cells: [{cells}, {cells}]")
    return text + (
        "  requests:\n"
        "    - {part: P1, source: S1, destination: D1}\n"
        "    - {part: P2, source: S2, destination: D1}\n"
        f"  max_pending: {k}\n"
        f"  urgency: {{P2: {urgency}}}\n"
    )


def main(seed: int, count: int) -> None:
    rng = np.random.default_rng(seed)
    agree = held_any = 0
    for i in range(count):
        arrival = float(rng.choice(ARRIVALS))
        k = int(rng.integers(1, 4))
        urgency = float(rng.choice(URGENCIES))
        cells = int(rng.choice(GRIDS))
        sc = loads_scenario(variant(arrival, k, urgency, cells))
        mdp = build_model(sc, Workcell.from_scenario(sc))
        t0 = time.process_time()
        res = solve_policy_iteration(mdp, tol=1e-9, max_iterations=300)
        cpu = time.process_time() - t0
        ref = solve_general(mdp, 1e-8, 400_000)
        ok = (
            str(res.status) == "solved"
            and str(ref.status) == "solved"
            and abs(res.gain - ref.gain) < 1e-6
        )
        held = len(stranded_modes(mdp, res.policy))
        agree += ok
        held_any += held > 0
        print(
            f"{i:2d} arrival {arrival:<5} k {k} urgency {urgency:<4} cells {cells:2d} "
            f"states {int(mdp.live.sum()):5d}: policy {res.status} in {res.outer_iterations} "
            f"iterations, {cpu:.2f} s CPU, gain {res.gain:.9f}; value iteration {ref.status} "
            f"{ref.gain:.9f}; {'agree' if ok else 'DISAGREE'}; modes held open {held}",
            flush=True,
        )
    print(f"{agree} of {count} agree; {held_any} of {count} optima hold requests open for ever")


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 7, int(sys.argv[2]) if len(sys.argv) > 2 else 20
    )

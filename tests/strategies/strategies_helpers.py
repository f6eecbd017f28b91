"""Small scenarios for the strategies tests (fast to solve)."""

from __future__ import annotations

from cellplan.registry import scenario_path
from cellplan.scenario import loads_scenario
from cellplan.workcell import Workcell

# The bundled tiny workcell with its grid left open: ``TINY.replace("CELLS", "16")``.
TINY = (
    scenario_path("strategies_tiny").read_text().replace("cells: [12, 12]", "cells: [CELLS, CELLS]")
)


def tiny(cells: int = 16, extra: str = "") -> tuple:
    """The tiny scenario (left-right symmetric) and its workcell."""
    sc = loads_scenario(TINY.replace("CELLS", str(cells)) + extra)
    return sc, Workcell.from_scenario(sc)


EMPTY = """
cellplan: 1
name: empty
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 40, ymax: 40}
robot:
  type: translating
  shape: {type: box, min: [-0.5, -0.5], max: [0.5, 0.5]}
  start: [20, 20]
parts:
  P1: {shape: {type: box, min: [-0.5, -0.5], max: [0.5, 0.5]}}
sources:
  S1: {components: [{type: box, min: [1, 1], max: [3, 3]}]}
destinations:
  D1: {components: [{type: box, min: [35, 35], max: [37, 37]}]}
strategy:
  speed: 2.0
  arrival: {probability: 0.05}
  regions: contact
  fine_motion: {time: 3.0}
  cells: [40, 40]
  actions: {headings: 32}
"""


def empty() -> tuple:
    sc = loads_scenario(EMPTY)
    return sc, Workcell.from_scenario(sc)


def tiny_failures(
    probability: float = 0.3, then: str = "reject", cells: int = 12, extra: str = ""
) -> tuple:
    """The tiny scenario with failing deliveries at D1 (Section VI-3) and a reject bin R1.

    ``then`` is ``reject`` (to R1, then fetch a replacement), ``request`` (to R1, then a
    new request for the part) or ``retry`` (in place, rework 2.0).
    """
    text = TINY.replace("CELLS", str(cells)).replace(
        "  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}",
        "  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}\n"
        "  R1: {components: [{type: box, min: [2, 25], max: [6, 28]}]}",
    )
    if then == "retry":
        spec = f"{{region: D1, probability: {probability}, then: retry, rework: 2.0}}"
    else:
        after = "fetch" if then == "reject" else "request"
        spec = (
            f"{{region: D1, probability: {probability}, then: reject, reject_region: R1, "
            f"after_reject: {after}}}"
        )
    sc = loads_scenario(text + f"  failures:\n    - {spec}\n" + extra)
    return sc, Workcell.from_scenario(sc)


def assert_validate_names(cellplan, tmp_path, text: str, expected: str) -> None:
    """``cellplan validate`` on ``text`` exits 2 with a line starting ``error: expected``
    and no traceback (the scenario-key tests of each Section VI extension)."""
    path = tmp_path / "s.yaml"
    path.write_text(text)
    r = cellplan("validate", str(path))
    assert r.returncode == 2, r.stdout
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert any(line.startswith("error: " + expected) for line in lines), lines
    assert "Traceback" not in r.stderr


def lu_entries(monkeypatch) -> list[int]:
    """Record the entries of every sparse LU that policy iteration factorises (SuperLU's
    own count: its factors live in C memory, which tracemalloc does not see)."""
    from cellplan.strategies.solve import policy_iteration

    seen: list[int] = []
    real = policy_iteration.splu

    def spy(matrix, *args, **kwargs):
        lu = real(matrix, *args, **kwargs)
        seen.append(int(lu.nnz))
        return lu

    monkeypatch.setattr(policy_iteration, "splu", spy)
    return seen

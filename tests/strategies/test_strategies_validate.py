"""``cellplan validate`` refuses what ``cellplan solve`` refuses before solving, with the same
line, and prints only the lines of the scenario's sections."""

from __future__ import annotations

import re

import pytest
from strategies_helpers import TINY, tiny

from cellplan.budget import resident_memory

BASE = TINY.replace("CELLS", "24")

# Each variant is refused by the strategies model (cellplan.strategies.model.mdp.build_model)
# for one reason; the expected text is part of the line both commands print.
VARIANTS = {
    # the destination lies under an obstacle: no configuration delivers there
    "destination covered": (
        BASE.replace(
            "middle: {type: box, min: [12, 12], max: [18, 16]}",
            "middle: {type: box, min: [12, 12], max: [18, 16]}\n"
            "    roof: {type: box, min: [11, 23], max: [19, 30]}",
        ),
        "strategy.requests <P1,S1,D1>: part 'P1' cannot be delivered anywhere in destination 'D1'",
    ),
    # the source lies under an obstacle: no configuration picks there
    "source covered": (
        BASE.replace(
            "middle: {type: box, min: [12, 12], max: [18, 16]}",
            "middle: {type: box, min: [12, 12], max: [18, 16]}\n"
            "    lid: {type: box, min: [0, 0], max: [8, 7]}",
        ),
        "part 'P1' cannot be picked up anywhere in source 'S1'",
    ),
    # a wall from floor to ceiling cuts S2 off from D1
    "split free space": (
        BASE.replace(
            "middle: {type: box, min: [12, 12], max: [18, 16]}",
            "middle: {type: box, min: [12, 12], max: [18, 16]}\n"
            "    wall: {type: box, min: [20, 0], max: [22, 30]}",
        ),
        "destinations.D1: after a delivery at D1 the robot cannot reach source S2",
    ),
    # the start is free but boxed in: no request can be served from it
    "start boxed in": (
        BASE.replace(
            "middle: {type: box, min: [12, 12], max: [18, 16]}",
            "middle: {type: box, min: [12, 12], max: [18, 16]}\n"
            "    pen_s: {type: box, min: [10, 3], max: [20, 4]}\n"
            "    pen_n: {type: box, min: [10, 11], max: [20, 12]}\n"
            "    pen_w: {type: box, min: [10, 3], max: [11, 12]}\n"
            "    pen_e: {type: box, min: [19, 3], max: [20, 12]}",
        ),
        "robot.start: lies outside the strategy's domain on the 24 x 24 grid",
    ),
}


def _errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.strip()]


@pytest.mark.parametrize("name", list(VARIANTS))
def test_validate_refuses_what_solve_refuses_with_the_same_line(cellplan, tmp_path, name):
    text, expected = VARIANTS[name]
    path = tmp_path / "s.yaml"
    path.write_text(text)
    solve = cellplan("solve", str(path), "-o", str(tmp_path / "s.npz"))
    validate = cellplan("validate", str(path))
    assert solve.returncode == validate.returncode == 2, (solve.stderr, validate.stderr)
    assert not (tmp_path / "s.npz").exists()
    lines = _errors(validate.stderr)
    assert lines == _errors(solve.stderr)
    assert any(expected in line for line in lines), lines
    assert "Traceback" not in validate.stderr and validate.stdout == ""


def test_validate_prints_the_strategy_lines(cellplan, tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(BASE)
    r = cellplan("validate", str(path))
    assert r.returncode == 0, r.stderr
    assert "assembly modes: 5 (Section III-A; 2 requests)" in r.stdout
    assert "strategy grid: 24 x 24 cells" in r.stdout
    assert "free / live (NR):" in r.stdout


def test_validate_prints_only_the_lines_of_the_scenario_sections(cellplan):
    adaptive = cellplan("validate", "adaptive_fig3").stdout
    assert "adaptive goals" in adaptive
    for other in ("parts", "sources", "destinations", "assembly modes", "NR", "discs"):
        assert other not in adaptive
    discs = cellplan("validate", "discs_seven").stdout
    for other in ("robot", "free fraction", "assembly modes", "adaptive"):
        assert other not in discs


def test_validate_refuses_a_grid_solve_could_not_fit_before_building_it(
    cellplan, tmp_path, monkeypatch
):
    path = tmp_path / "s.yaml"
    path.write_text(TINY.replace("CELLS", "1000"))
    # The limit counts the process's own resident memory (issue 36), which in a test
    # worker grows with the tests run before it: 300 MB above it leaves room for
    # validate's own free-fraction bitmap (5 MB), not for the model (about 750 MB).
    monkeypatch.setenv("CELLPLAN_MEMORY_LIMIT", str(resident_memory() + 300_000_000))
    solve = cellplan("solve", str(path), "-o", str(tmp_path / "s.npz"))
    validate = cellplan("validate", str(path))
    assert solve.returncode == validate.returncode == 2
    lines = _errors(validate.stderr)
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: strategy.cells 1000,1000: needs about "), lines
    assert re.search(r"for 5 modes; this machine has [0-9.]+ MB available$", lines[0]), lines
    assert _errors(solve.stderr)[0].startswith("error: strategy.cells 1000,1000: needs"), solve


def test_a_start_inside_a_source_is_refused_naming_the_source():
    # Issue 34: sources are obstacles while the robot is empty (equation (1)); the line
    # says so and names the region, rather than "outside the strategy's domain" alone.
    from cellplan.errors import ScenarioError
    from cellplan.strategies.model.mdp import build_model

    sc, cell = tiny(16)
    sc = sc.model_copy(update={"robot": sc.robot.model_copy(update={"start": [4.0, 3.5]})})
    with pytest.raises(ScenarioError) as err:
        build_model(sc, cell, start=[4.0, 3.5])
    (problem,) = err.value.problems
    assert problem.field == "robot.start"
    assert (
        "source S1" in problem.message and "obstacles while the robot is empty" in problem.message
    )
    assert "S2" not in problem.message


def test_validate_json_gives_the_strategy_facts_typed(cellplan):
    # Issue 34: the strategies describe hook returns core.Fact values with typed values.
    import json

    payload = json.loads(cellplan("validate", "strategies_tiny", "--json").stdout)
    summary, labels = payload["summary"], payload["labels"]
    assert summary["assembly_modes"] == 5 and type(summary["assembly_modes"]) is int
    assert summary["strategy_grid"] == [12, 12]
    free_live = summary["free_live_nr"]
    assert set(free_live) == {"free", "live"}
    assert all(type(v) is float and 0 < v <= 1 for v in free_live.values())
    assert free_live["live"] <= free_live["free"]
    assert labels["free_live_nr"] == "free / live (NR)"


NARROW = """
cellplan: 1
name: narrow-opening
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 40, ymax: 40}
  obstacles:
    left: {type: box, min: [0, 19], max: [17, 21]}
    right: {type: box, min: [23, 19], max: [40, 21]}
robot:
  type: translating
  shape: {type: box, min: [-1, -1], max: [1, 1]}
  start: [20, 10]
parts:
  P1: {shape: {type: box, min: [-4, -0.5], max: [4, 0.5]}}
  P2: {shape: {type: box, min: [-0.5, -0.5], max: [0.5, 0.5]}}
sources:
  S1: {components: [{type: box, min: [4, 3], max: [8, 6]}]}
  S2: {components: [{type: box, min: [32, 3], max: [36, 6]}]}
destinations:
  D1: {components: [{type: box, min: [8, 32], max: [12, 35]}]}
  D2: {components: [{type: box, min: [28, 32], max: [32, 35]}]}
strategy:
  speed: 2.0
  arrival: {probability: 0.05}
  fine_motion: {time: 2.0}
  cells: [40, 40]
  actions: {headings: 8}
"""


def test_only_the_part_too_wide_for_the_opening_is_named(cellplan, tmp_path):
    # Issue 35 part 5: only P1 (8 wide) cannot pass the 6-wide opening; P2 fits. NR is
    # empty (not every request can be served), which used to empty every layer that ends
    # in NR, so all 8 requests were named, P2's included. Each request is now judged on
    # its own by the live-state rule with NR unconstrained.
    path = tmp_path / "narrow.yaml"
    path.write_text(NARROW)
    r = cellplan("validate", str(path))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert "no configuration in NR can serve every request" in lines[0]
    named = [line for line in lines if "strategy.requests" in line]
    assert len(named) == 4 and all("<P1," in line for line in named)
    assert not any("P2" in line for line in lines)


def test_validate_leaves_a_long_model_build_to_the_solve(cellplan, tmp_path):
    # The scenario fuzzer: strategies_p3 with 4096 cells along x (about 24 min to build
    # the model) kept validate busy for minutes. validate answers in seconds: it gives
    # the modes and the grid, and a note that the solve runs the model's checks.
    import json

    from cellplan.registry import resolve_scenario_path

    text = resolve_scenario_path("strategies_p3").read_text(encoding="utf-8")
    assert text.count("cells: [64, 64, 30]") >= 1
    path = tmp_path / "big.yaml"
    path.write_text(text.replace("cells: [64, 64, 30]", "cells: [4096, 64, 30]"), encoding="utf-8")
    r = cellplan("validate", str(path), "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)["summary"]
    assert summary["strategy_grid"][0] == 4096 and summary["assembly_modes"] == 9
    assert "free_live_nr" not in summary
    notes = [line for line in r.stderr.splitlines() if "were not run" in line]
    assert len(notes) == 1 and "cellplan solve runs them" in notes[0]

"""``validate`` accepts only what ``solve`` can solve, and strategy files that do not match
the scenario's geometry never drive the robot into an obstacle (issue 36).

Every mutant of a strategies scenario that ``validate`` accepts (exit 0) must ``solve``
with exit 0 or 1, never 2 after validation and never 70. The default run tries a few
mutants with a fixed seed; the slow run tries ``CELLPLAN_FUZZ_EXAMPLES``:

    CELLPLAN_FUZZ_EXAMPLES=200 pytest -m slow tests/fuzz/test_fuzz_solve.py
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from fuzz_harness import FailureLog, fuzz_settings, run_cli
from fuzz_mutations import mutated_scenario
from hypothesis import given
from hypothesis import strategies as st

import cellplan

FAST_EXAMPLES = 3
SLOW_EXAMPLES = int(os.environ.get("CELLPLAN_FUZZ_EXAMPLES", "200"))
# The strategies scenario that solves in well under a second (the slow run adds noise).
SOLVE_SCENARIOS = ["strategies_tiny"]
SLOW_SOLVE_SCENARIOS = ["strategies_tiny", "strategies_noise"]
OBSTACLE = "  obstacles:\n    middle: {type: box, min: [12, 12], max: [18, 16]}\n"


def solve_mutant(name: str, content: bytes, where: Path) -> None:
    path = where / f"{name}.yaml"
    path.write_bytes(content)
    checked = run_cli(["validate", str(path)])
    assert checked.code in (0, 2), checked.describe()
    if checked.code != 0:
        return
    solved = run_cli(["solve", str(path), "-o", str(where / "s.npz"), "--sample-stages", "20"])
    assert solved.code in (0, 1), solved.describe()


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz-solve")


@pytest.mark.parametrize("name", SOLVE_SCENARIOS)
def test_validated_mutants_solve(name: str, work: Path) -> None:
    @fuzz_settings(FAST_EXAMPLES)
    @given(content=mutated_scenario(name))
    def check(content: bytes) -> None:
        solve_mutant(name, content, work)

    check()


@pytest.mark.slow
@pytest.mark.parametrize("name", SLOW_SOLVE_SCENARIOS)
def test_validated_mutants_solve_hundreds(name: str, work: Path) -> None:
    log = FailureLog("solve", name)

    @fuzz_settings(SLOW_EXAMPLES)
    @given(content=mutated_scenario(name))
    def check(content: bytes) -> None:
        log.check(lambda: solve_mutant(name, content, work), content)

    check()
    log.finish()


# --- strategy files consistent in themselves that do not match the scenario ------------


@pytest.fixture(scope="module")
def solved(work: Path) -> dict[str, Path]:
    tiny = cellplan.load("strategies_tiny")
    text = (Path(__file__).parents[2] / "scenarios" / "strategies_tiny.yaml").read_text()
    out = {}
    for key, variant in (("real", text), ("open", text.replace(OBSTACLE, ""))):
        result = cellplan.plan(cellplan.loads(variant), "strategies", sample_stages=1)
        out[key] = result.solution.save(work / f"{key}.npz")
    out["scenario"] = work / "tiny.yaml"
    out["scenario"].write_text(text)
    out["digest"] = Path(tiny.scenario.digest())
    return out


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


@st.composite
def mismatched_strategy(draw: st.DrawFn, solved: dict[str, Path]) -> dict[str, np.ndarray]:
    """A strategy of strategies_tiny's shape whose free and live sets are another
    geometry's: shifted by whole cells, or solved without the obstacle, under the real
    digest."""
    kind = draw(st.sampled_from(["shift", "open"]))
    arrays = _arrays(solved["open" if kind == "open" else "real"])
    meta = json.loads(str(arrays["meta"]))
    meta["scenario_digest"] = str(solved["digest"])
    arrays["meta"] = np.array(json.dumps(meta))
    if kind == "shift":
        shape = tuple(meta["grid"]["shape"])
        dx = draw(st.integers(-3, 3))
        dy = draw(st.integers(-3, 3).filter(lambda v: v != 0 or dx != 0))
        for name in ("free", "live", "valid", "values"):
            grid = arrays[name].reshape(len(arrays[name]), *shape)
            arrays[name] = np.roll(grid, (dx, dy), axis=(1, 2)).reshape(len(grid), -1)
        # Keep it consistent in itself: live only where free, values on live only.
        arrays["live"] &= arrays["free"][arrays["vcls"]]
        arrays["values"] = np.where(arrays["live"], np.nan_to_num(arrays["values"]), np.nan)
    return arrays


@pytest.mark.parametrize(
    "examples", [FAST_EXAMPLES, pytest.param(SLOW_EXAMPLES, marks=pytest.mark.slow)]
)
def test_mismatched_strategies_never_collide_with_exit_0(solved, work, examples):
    log = FailureLog("mismatched-strategy", f"strategies_tiny x{examples}")

    @fuzz_settings(examples)
    @given(arrays=mismatched_strategy(solved))
    def draw(arrays: dict[str, np.ndarray]) -> None:
        log.check(lambda: check(arrays))

    def check(arrays: dict[str, np.ndarray]) -> None:
        path = work / "mismatch.npz"
        np.savez_compressed(path, **arrays)
        args = ["simulate", str(solved["scenario"]), "--strategy", str(path), "--no-gif"]
        r = run_cli([*args, "--stages", "200", "-o", str(work / "sim")])
        assert r.code in (0, 1, 2), r.describe()
        if r.code == 0:
            setup = cellplan.load(str(solved["scenario"]))
            traj = np.loadtxt(
                work / "sim" / "trajectory.csv", delimiter=",", skiprows=2, usecols=(2, 3)
            )
            assert not setup.workcell.collides(traj, None, "none").any(), r.describe()

    draw()
    log.finish()

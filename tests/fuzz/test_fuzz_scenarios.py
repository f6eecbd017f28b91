"""Fuzzing ``cellplan validate`` and ``cellplan show`` with mutated bundled scenarios.

Every mutated file must get exit status 0 (still valid) or 2 (one line per problem, each
naming a field or the file), never a traceback, never 70 (a bug), never a hang. The
default run tries a few examples per bundled scenario with a fixed seed; the ``slow``
run tries ``CELLPLAN_FUZZ_EXAMPLES`` per scenario (docs/reliability.md gives the figures):

    CELLPLAN_FUZZ_EXAMPLES=800 pytest -m slow tests/fuzz
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from fuzz_harness import FailureLog, Outcome, bad_lines, fuzz_settings, run_cli
from fuzz_mutations import SCENARIOS, mutated_scenario
from hypothesis import given

from cellplan.scenario import Scenario

FAST_EXAMPLES = 4
SLOW_EXAMPLES = int(os.environ.get("CELLPLAN_FUZZ_EXAMPLES", "800"))
SHOW_EXAMPLES = 3


def top_keys(content: bytes) -> set[str]:
    """The schema's top-level keys and the file's own (where it still parses)."""
    keys = set(Scenario.model_fields)
    try:
        data = yaml.safe_load(content)
    except Exception:  # PyYAML raises plain Python errors on bad tagged values (!!int abc)
        return keys
    if not isinstance(data, dict):
        return keys
    yaml_words = {None: "null", True: "true", False: "false"}
    return keys | {yaml_words[k] if k is None or isinstance(k, bool) else str(k) for k in data}


def check_answer(r: Outcome, path: Path, content: bytes) -> None:
    """Exit 0 (on stderr at most the ``note:`` lines of long accepted work, each once) or 2
    (every line names a field or the file), nothing else."""
    assert r.code in (0, 2), r.describe()
    if r.code == 2:
        bad = bad_lines(r.stderr, files=[str(path)], roots=top_keys(content))
        assert not bad, f"{r.describe()}\nlines not naming a field or the file: {bad[:5]}"
    else:
        lines = r.stderr.splitlines()
        assert all(line.startswith("note: ") for line in lines), r.describe()
        assert len(set(lines)) == len(lines), r.describe()


def validate_mutant(name: str, content: bytes, where: Path, command: str = "validate") -> Outcome:
    path = where / f"{name}.yaml"
    path.write_bytes(content)
    args = [command, str(path)]
    if command == "show":
        args += ["-o", str(where / "shown.png")]
    r = run_cli(args)
    check_answer(r, path, content)
    return r


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz-scenarios")


HEAVY = ("strategies_ur5", "strategies_p6", "strategies_p5")
"""Scenarios whose validation takes 10-13 s a run: their fast fuzzing is in the slow run
(the other scenarios exercise the same validation code)."""


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in HEAVY else n for n in SCENARIOS]
)
def test_validate_mutated_scenarios(name: str, work: Path) -> None:
    @fuzz_settings(FAST_EXAMPLES)
    @given(content=mutated_scenario(name))
    def check(content: bytes) -> None:
        validate_mutant(name, content, work)

    check()


@pytest.mark.parametrize("name", ["strategies_tiny", "discs_swap", "adaptive_fig3"])
def test_show_mutated_scenarios(name: str, work: Path) -> None:
    @fuzz_settings(SHOW_EXAMPLES)
    @given(content=mutated_scenario(name))
    def check(content: bytes) -> None:
        validate_mutant(name, content, work, "show")

    check()


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS)
def test_validate_mutated_scenarios_thousands(name: str, work: Path) -> None:
    log = FailureLog("scenario", name)

    @fuzz_settings(SLOW_EXAMPLES)
    @given(content=mutated_scenario(name))
    def check(content: bytes) -> None:
        log.check(lambda: validate_mutant(name, content, work), content)

    check()
    log.finish()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["strategies_tiny", "discs_swap", "adaptive_fig3", "rotating_bar"])
def test_show_mutated_scenarios_hundreds(name: str, work: Path) -> None:
    log = FailureLog("show", name)

    @fuzz_settings(SLOW_EXAMPLES // 8)
    @given(content=mutated_scenario(name))
    def check(content: bytes) -> None:
        log.check(lambda: validate_mutant(name, content, work, "show"), content)

    check()
    log.finish()

"""The kernel warm-up run by ``make install``, and the note a compile prints in a command."""

from __future__ import annotations

import logging
from pathlib import Path

import numba
import pytest

from cellplan import warmup
from cellplan.cliutil import COMPILE_NOTE, announce_compiles
from cellplan.errors import ScenarioError
from cellplan.registry import scenario_names


def _compile_notes(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage() == COMPILE_NOTE]


def test_a_compile_is_announced_once_per_command(caplog: pytest.LogCaptureFixture) -> None:
    # Fresh functions without a cache: each call below is a real compile.
    @numba.njit(cache=False)
    def first(x: int) -> int:
        return x + 1

    @numba.njit(cache=False)
    def second(x: int) -> int:
        return x + 2

    caplog.set_level(logging.WARNING, logger="cellplan")
    with announce_compiles():
        assert first(1) == 2
        assert second(1) == 3
    assert _compile_notes(caplog) == [COMPILE_NOTE]


def test_a_compiled_kernel_called_again_says_nothing(caplog: pytest.LogCaptureFixture) -> None:
    @numba.njit(cache=False)
    def kernel(x: float) -> float:
        return 2.0 * x

    assert kernel(1.0) == 2.0  # compiled here, outside the context
    caplog.set_level(logging.WARNING, logger="cellplan")
    with announce_compiles():
        assert kernel(2.0) == 4.0
    assert _compile_notes(caplog) == []


def test_the_warm_up_commands_name_bundled_scenarios() -> None:
    names = set(scenario_names())
    used = {command[1] for group in warmup.WARMUP_GROUPS for command in group}
    assert used <= names
    commands = {command[0] for group in warmup.WARMUP_GROUPS for command in group}
    # The commands a newcomer runs first (README), each warmed once.
    assert {"solve", "simulate", "validate", "assemble", "adapt"} <= commands


def test_a_warm_up_group_runs_its_commands(tmp_path: Path) -> None:
    seconds = warmup._run_group(
        [("solve", "strategies_tiny", "-o", "{tmp}/tiny.npz"), ("validate", "strategies_tiny")],
        str(tmp_path / "group"),
    )
    assert seconds > 0
    assert (tmp_path / "group" / "tiny.npz").is_file()


def test_a_failing_warm_up_command_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="no such bundled scenario"):
        warmup._run_group([("validate", "no_such_scenario")], str(tmp_path))


def test_every_file_a_warm_up_command_reads_is_written_before_in_its_group() -> None:
    # Groups run in separate processes at the same time: a strategy file read with
    # --strategy must come from an earlier command of the same group.
    for group in warmup.WARMUP_GROUPS:
        written: set[str] = set()
        for command in group:
            args = list(command)
            if "--strategy" in args:
                assert args[args.index("--strategy") + 1] in written, command
            if "-o" in args:
                written.add(args[args.index("-o") + 1])


def test_the_warm_up_reaches_the_policy_iteration_and_query_kernels() -> None:
    # The kernels a structured solve of strategies_tiny does not compile: policy
    # iteration (models with failures or noise), strategy.action (plot, the demo's
    # pictures) and the reactive baseline. Without them the demo's two sweep workers
    # each compiled them again (issue 34).
    commands = [list(c) for group in warmup.WARMUP_GROUPS for c in group]
    assert any(c[0] == "solve" and "--method" in c and "policy" in c for c in commands)
    assert any(c[0] == "plot" for c in commands)
    assert any(c[0] == "simulate" and "reactive" in c for c in commands)

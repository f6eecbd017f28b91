"""Paths from outside never destroy data (issue 36): outputs, inputs, full disks.

Only regular files are replaced; inputs must be regular files; an output never lands on
an input; a legal long name is written; strict JSON; and a full disk or a failure half-way
leaves an output folder as it was.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from cellplan.cli import main
from cellplan.errors import ArgumentError, PersistenceError
from cellplan.fileio import (
    atomic_path,
    check_distinct,
    name_max,
    open_input,
    staged_folder,
    write_json,
    write_text,
)
from cellplan.registry import scenario_path


def _cellplan(*args: str) -> subprocess.CompletedProcess[str]:
    """Run the command line in this process, as the console script would.

    In-process, because each fresh interpreter pays seconds of imports; the one input
    that could block forever (a FIFO) goes through :func:`_cellplan_process` instead."""
    out, err = io.StringIO(), io.StringIO()
    argv, sys.argv = sys.argv, ["cellplan", *args]
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            main()
    except SystemExit as exc:
        code = int(exc.code or 0)
    finally:
        sys.argv = argv
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


def _cellplan_process(*args: str) -> subprocess.CompletedProcess[str]:
    """Run the command line in a child process, killed after 300 s if it blocks."""
    return subprocess.run(
        [sys.executable, "-m", "cellplan.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def _one_line(r: subprocess.CompletedProcess[str]) -> str:
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    path = tmp_path / "victim.txt"
    path.write_text("precious\n", encoding="utf-8")
    return path


# --- outputs replace regular files only ---------------------------------------------------------


def test_an_output_through_a_symlink_is_refused_and_the_target_kept(
    tmp_path: Path, victim: Path
) -> None:
    link = tmp_path / "out.json"
    link.symlink_to(victim)
    with pytest.raises(ArgumentError, match="symbolic link"):
        write_json(link, {"a": 1})
    assert victim.read_text(encoding="utf-8") == "precious\n" and link.is_symlink()


def test_an_output_onto_a_fifo_is_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "out.txt"
    os.mkfifo(fifo)
    with pytest.raises(ArgumentError, match="pipe"):
        write_text(fifo, "x")
    assert fifo.is_fifo()


def test_show_onto_a_link_to_dev_null_is_refused(tmp_path: Path) -> None:
    link = tmp_path / "cell.png"
    link.symlink_to("/dev/null")
    before = os.stat("/dev/null").st_ino
    r = _cellplan("show", "strategies_tiny", "-o", str(link))
    assert r.returncode == 2
    assert (
        _one_line(r)
        == f"error: --output: {link} is a symbolic link; cellplan replaces only regular files"
    )
    assert os.stat("/dev/null").st_ino == before and link.is_symlink()


def test_a_temporary_file_is_never_left_behind(tmp_path: Path) -> None:
    target = tmp_path / "x.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half", encoding="utf-8")
        raise RuntimeError("the writer failed")
    assert list(tmp_path.iterdir()) == []


# --- long names ---------------------------------------------------------------------------------


def test_the_longest_legal_name_is_written(tmp_path: Path) -> None:
    limit = name_max(tmp_path)
    target = tmp_path / ("a" * (limit - 5) + ".json")
    assert len(target.name) == limit
    write_json(target, {"ok": True})
    assert json.loads(target.read_text(encoding="utf-8")) == {"ok": True}
    assert [p.name for p in tmp_path.iterdir()] == [target.name]


def test_a_name_over_the_limit_is_refused_before_work(tmp_path: Path) -> None:
    target = tmp_path / ("a" * (name_max(tmp_path) - 3) + ".png")
    r = _cellplan("show", "strategies_tiny", "-o", str(target))
    assert r.returncode == 2
    line = _one_line(r)
    assert line.startswith("error: --output: the file name is") and "at most" in line
    assert list(tmp_path.iterdir()) == []


def test_solve_writes_a_strategy_under_a_long_legal_name(tmp_path: Path) -> None:
    target = tmp_path / ("s" * (name_max(tmp_path) - 4) + ".npz")
    r = _cellplan("solve", "strategies_tiny", "-o", str(target))
    assert r.returncode == 0, r.stderr
    assert [p.name for p in tmp_path.iterdir()] == [target.name]


# --- strict JSON --------------------------------------------------------------------------------


def _strict(text: str) -> Any:
    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_json_files_hold_null_where_a_number_is_not_finite(tmp_path: Path) -> None:
    import numpy as np

    data = {"mean_wait": math.nan, "x": [1.0, math.inf, -math.inf], "a": np.array([np.nan, 2.0])}
    path = write_json(tmp_path / "m.json", data)
    assert _strict(path.read_text(encoding="utf-8")) == {
        "mean_wait": None,
        "x": [1.0, None, None],
        "a": [None, 2.0],
    }


def test_a_simulation_that_serves_nothing_writes_strict_json(tmp_path: Path) -> None:
    strat = tmp_path / "s.npz"
    assert _cellplan("solve", "strategies_tiny", "-o", str(strat)).returncode == 0
    out = tmp_path / "sim"
    r = _cellplan(
        "simulate", "strategies_tiny", "--strategy", str(strat), "--stages", "1", "--no-gif",
        "-o", str(out),
    )  # fmt: skip
    assert r.returncode in (0, 1), r.stderr
    metrics = _strict((out / "metrics.json").read_text(encoding="utf-8"))
    assert metrics["metrics"]["served"] == 0
    assert metrics["metrics"]["mean_wait"] is None


# --- inputs are regular files -------------------------------------------------------------------


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_a_strategy_that_is_a_link_to_a_device_is_refused_at_once(
    device: str, tmp_path: Path
) -> None:
    link = tmp_path / "q.npz"
    link.symlink_to(device)
    with pytest.raises(PersistenceError, match="is a device"):
        open_input(link)
    r = _cellplan("simulate", "strategies_tiny", "--strategy", str(link), "-o", str(tmp_path / "o"))
    assert r.returncode == 2
    assert _one_line(r) == f"error: {link}: is a device, not a regular file; give a file"
    assert not (tmp_path / "o").exists()


def test_a_fifo_as_input_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "s.yaml"
    os.mkfifo(fifo)
    r = _cellplan_process("validate", str(fifo))
    assert r.returncode == 2 and "pipe (FIFO), not a scenario file" in _one_line(r)
    r = _cellplan_process(
        "plot", "strategies_tiny", "--strategy", str(fifo), "-o", str(tmp_path / "p.png")
    )
    assert r.returncode == 2 and "pipe (FIFO)" in _one_line(r)


# --- outputs never land on inputs ---------------------------------------------------------------


def test_check_distinct_sees_links_hard_links_and_patterns(tmp_path: Path) -> None:
    real = tmp_path / "real.npz"
    real.write_bytes(b"x")
    (tmp_path / "sym.npz").symlink_to(real)
    os.link(real, tmp_path / "hard.npz")
    for alias in ("sym.npz", "hard.npz", "sub/../real.npz"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        with pytest.raises(ArgumentError, match="--strategy"):
            check_distinct([("--output", tmp_path / alias)], {"--strategy": real})
    with pytest.raises(ArgumentError):
        check_distinct([("--output", tmp_path / "re*.npz")], {"--strategy": real})
    check_distinct([("--output", tmp_path / "other.npz")], {"--strategy": real})


@pytest.fixture
def scenario_as(tmp_path: Path) -> Iterator[Any]:
    def make(name: str) -> Path:
        path = tmp_path / name
        shutil.copy(scenario_path("strategies_tiny"), path)
        return path

    yield make


@pytest.mark.parametrize(
    ("command", "name"),
    [
        (["solve"], "s.npz"),
        (["show"], "s.png"),
        (["cspace"], "s.png"),
    ],
)
def test_a_command_refuses_to_write_over_its_scenario(
    command: list[str], name: str, scenario_as: Any
) -> None:
    scenario = scenario_as(name)
    before = scenario.read_bytes()
    r = _cellplan(*command, str(scenario), "-o", str(scenario))
    assert r.returncode == 2
    assert _one_line(r) == (
        f"error: --output: {scenario} is the input given as SCENARIO; writing it would destroy it"
    )
    assert scenario.read_bytes() == before


def test_plot_and_simulate_refuse_to_write_over_the_strategy(tmp_path: Path) -> None:
    strat = tmp_path / "frames.png"  # a strategy file under a name simulate writes
    assert _cellplan("solve", "strategies_tiny", "-o", str(tmp_path / "q.npz")).returncode == 0
    (tmp_path / "q.npz").rename(strat)
    before = strat.read_bytes()
    r = _cellplan("plot", "strategies_tiny", "--strategy", str(strat), "-o", str(strat))
    assert r.returncode == 2 and "given as --strategy" in _one_line(r)
    r = _cellplan("simulate", "strategies_tiny", "--strategy", str(strat), "-o", str(tmp_path))
    assert r.returncode == 2 and "given as --strategy" in _one_line(r)
    frame = tmp_path / "frame_007.png"
    strat.rename(frame)
    r = _cellplan("simulate", "strategies_tiny", "--strategy", str(frame), "-o", str(tmp_path))
    assert r.returncode == 2 and "given as --strategy" in _one_line(r)
    assert frame.read_bytes() == before


def test_assemble_refuses_to_write_over_its_scenario(tmp_path: Path) -> None:
    scenario = tmp_path / "metrics.json"
    shutil.copy(scenario_path("discs_swap"), scenario)
    before = scenario.read_bytes()
    r = _cellplan("assemble", str(scenario), "-o", str(tmp_path))
    assert r.returncode == 2 and "given as FILE" in _one_line(r)
    assert scenario.read_bytes() == before


# --- a failure half-way leaves the folder as it was ---------------------------------------------


def test_a_staged_folder_moves_nothing_when_its_writer_fails(tmp_path: Path) -> None:
    target = tmp_path / "out"
    with pytest.raises(OSError), staged_folder(target) as stage:
        (stage / "a.csv").write_text("1", encoding="utf-8")
        raise OSError(28, "No space left on device")
    assert list(tmp_path.iterdir()) == []
    target.mkdir()
    (target / "a.csv").write_text("old", encoding="utf-8")
    with staged_folder(target) as stage:
        (stage / "a.csv").write_text("new", encoding="utf-8")
        (stage / "b.csv").write_text("b", encoding="utf-8")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert (target / "a.csv").read_text(encoding="utf-8") == "new"
    assert (target / "b.csv").read_text(encoding="utf-8") == "b"


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[Path]:
    """A 256 KiB file system: a simulation's pictures do not fit."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)], capture_output=True
    )
    if made.returncode != 0:
        pytest.skip("mounting a small tmpfs needs root (CI runs as root)")
    try:
        yield mount
    finally:
        with contextlib.suppress(Exception):
            subprocess.run(["umount", str(mount)], check=True)


def test_a_full_disk_leaves_no_half_written_output(full_disk: Path, tmp_path: Path) -> None:
    strat = tmp_path / "q.npz"
    assert _cellplan("solve", "strategies_tiny", "-o", str(strat)).returncode == 0
    out = full_disk / "sim"
    r = _cellplan(
        "simulate", "strategies_tiny", "--strategy", str(strat), "--stages", "400", "-o", str(out)
    )
    assert r.returncode == 2
    assert "No space left on device" in _one_line(r)
    assert list(full_disk.iterdir()) == []  # no folder, no staging left behind
    r = _cellplan("assemble", "discs_seven", "--frames", "8", "-o", str(out))  # 380 KiB
    assert r.returncode == 2 and "No space left on device" in _one_line(r)
    assert list(full_disk.iterdir()) == []


def test_a_sweep_on_a_full_disk_leaves_no_folder_behind(full_disk: Path) -> None:
    with open(full_disk / "filler", "wb") as fh:  # what is left of 256 KiB, filled
        with contextlib.suppress(OSError):
            fh.write(b"\0" * (1 << 20))
    out = full_disk / "report"
    tests = Path(__file__).parent
    r = subprocess.run(
        [sys.executable, str(tests / "sweep_cli_driver.py"), "reproduce", "assembly",
         "--runs", "3", "--serial", "-o", str(out)],
        capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(tests)},
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1] == "error: output: No space left on device"
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]

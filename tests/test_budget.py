"""Resource guards: the memory model of the C-space bitmap against measured allocations,
and refusals that come before any allocation (library and command line)."""

from __future__ import annotations

import gc
import subprocess
import sys
import tracemalloc

import pytest

from cellplan import budget
from cellplan.api import load
from cellplan.cspace import Grid, estimate_memory, free_bitmap
from cellplan.errors import ArgumentError


def test_sizes_parse_and_print():
    assert budget.parse_bytes("2GB") == 2 * 10**9
    assert budget.parse_bytes("512 MiB") == 512 * 2**20
    assert budget.parse_bytes("1000") == 1000
    with pytest.raises(ValueError):
        budget.parse_bytes("lots")
    assert budget.format_bytes(190e9) == "190 GB"
    assert budget.format_bytes(2.44e6) == "2.4 MB"
    assert budget.format_bytes(512) == "512 B"


def test_the_limit_variable_lowers_what_is_available(monkeypatch):
    monkeypatch.setenv(budget.LIMIT_VARIABLE, "3MB")
    assert budget.available_memory() <= 3 * 10**6
    with pytest.raises(ArgumentError, match=r"^x: needs about 4\.0 MB for y; this machine has"):
        budget.require(4e6, "x", "for y")
    monkeypatch.setenv(budget.LIMIT_VARIABLE, "plenty")
    with pytest.raises(ArgumentError, match=budget.LIMIT_VARIABLE):
        budget.available_memory()


def test_available_memory_is_positive_without_the_variable(monkeypatch):
    monkeypatch.delenv(budget.LIMIT_VARIABLE, raising=False)
    assert budget.available_memory() > 0


def test_an_address_space_limit_lowers_what_is_available():
    # ulimit -v: an allocation past it is a MemoryError, so the budget must see it.
    code = (
        "import resource; from cellplan import budget; "
        "resource.setrlimit(resource.RLIMIT_AS, (6 * 2**30, resource.RLIM_INFINITY)); "
        "print(budget.available_memory())"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert 0 < int(out.stdout) < 6 * 2**30


@pytest.mark.parametrize(
    ("scenario", "cells"),
    [
        ("strategies_tiny", (96, 80)),  # translating robot: FFT method
        ("rotating_bar", (48, 48, 12)),  # rotating robot: FFT per heading slice
        ("strategies_p6", (14, 14, 14)),  # arm: exact method
    ],
)
def test_bitmap_memory_estimate_matches_measured_allocations(scenario, cells):
    """The estimate counts the arrays free_bitmap allocates; tracemalloc sees numpy's."""
    cell = load(scenario).workcell
    grid = Grid.for_robot(cell.robot, cells)
    free_bitmap(cell, grid)  # warm caches (compiled kernels, robot shapes)
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        free_bitmap(cell, grid)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    ratio = peak / estimate_memory(cell, grid)
    assert 0.7 <= ratio <= 1.4, ratio


def test_the_library_refuses_a_bitmap_that_cannot_fit(monkeypatch):
    cell = load("strategies_tiny").workcell
    grid = Grid.for_robot(cell.robot, (2048, 2048))
    monkeypatch.setenv(budget.LIMIT_VARIABLE, "10MB")
    with pytest.raises(ArgumentError, match=r"cells 2048,2048: needs about .* for the C-space"):
        free_bitmap(cell, grid)


def test_cspace_command_refuses_4096_cubed_in_one_line(cellplan, tmp_path):
    out = tmp_path / "c.png"
    r = cellplan("cspace", "rotating_bar", "--cells", "4096,4096,4096", "-o", str(out))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "--cells 4096,4096,4096: needs about" in lines[0]
    assert "for the C-space bitmap; this machine has" in lines[0]
    assert not out.exists()

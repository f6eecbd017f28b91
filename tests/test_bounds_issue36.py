"""Issue 36 bounds: the memory limit counts the process, time is estimated, GIFs stream."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cellplan import budget, plots
from cellplan.errors import ArgumentError


def test_the_memory_limit_counts_what_the_process_already_holds(monkeypatch):
    held = budget.resident_memory()
    assert held > 10**7  # the interpreter with numpy: tens of MB at least
    monkeypatch.setenv(budget.LIMIT_VARIABLE, str(held + 50 * 10**6))
    assert budget.available_memory() <= 50 * 10**6 + 10**6


def test_time_limit_refuses_in_one_line_and_can_be_lifted(monkeypatch):
    monkeypatch.delenv(budget.TIME_LIMIT_VARIABLE, raising=False)
    assert budget.time_limit() == budget.DEFAULT_TIME_LIMIT_S
    with pytest.raises(ArgumentError, match=r"^x: would take about 2\.8 h for y; the time"):
        budget.require_time(10_000, "x", "for y")
    monkeypatch.setenv(budget.TIME_LIMIT_VARIABLE, "none")
    budget.require_time(1e300, "x")
    monkeypatch.setenv(budget.TIME_LIMIT_VARIABLE, "2min")
    assert budget.time_limit() == 120
    monkeypatch.setenv(budget.TIME_LIMIT_VARIABLE, "soon")
    with pytest.raises(ArgumentError, match=budget.TIME_LIMIT_VARIABLE):
        budget.time_limit()


def test_a_million_tasks_are_refused_by_their_time(tmp_path):
    from cellplan.adaptive.runner import task_count
    from cellplan.api import load
    from cellplan.errors import CellplanError

    setup = load("adaptive_fig4")
    with pytest.raises(CellplanError, match=r"^tasks: would take about 27\.8 h"):
        task_count(setup.scenario, 1_000_000)


def test_a_gif_frame_that_cannot_fit_is_refused_without_drawing(monkeypatch):
    monkeypatch.setenv(budget.LIMIT_VARIABLE, str(budget.resident_memory() + 60 * 10**6))
    assert plots.check_gif_size(640) == 640  # 9.8 MB
    with pytest.raises(ArgumentError, match=r"^--gif-size 2400: needs about 138 MB to draw"):
        plots.check_gif_size(2400)


def test_gif_frames_stream_and_decode_to_what_was_drawn(tmp_path: Path):
    colours = [(255, 255, 255), (200, 30, 30), (30, 30, 200)]
    drawn: list[np.ndarray] = []

    def frames() -> Iterator[np.ndarray]:
        for i in range(6):
            f = np.full((40, 50, 3), 255, np.uint8)
            f[5 * i : 5 * i + 8, 10:30] = colours[1 + i % 2]
            if i == 3:
                f = drawn[-1].copy()  # unchanged: lengthens the frame before
            drawn.append(f)
            yield f

    path = plots.save_gif(frames(), tmp_path / "a.gif", fps=10.0, hold_last=4)
    with Image.open(path) as im:
        assert im.size == (50, 40) and im.info.get("loop") == 0
        shown, durations = [], []
        for k in range(im.n_frames):
            im.seek(k)
            shown.append(np.asarray(im.convert("RGB")))
            durations.append(im.info["duration"])
    expected = [drawn[i] for i in (0, 1, 2, 4, 5)]
    assert all(np.array_equal(a, b) for a, b in zip(shown, expected, strict=True))
    assert durations == [100, 100, 200, 100, 500]


def _the_one_note_of_validate(cellplan, monkeypatch, scenario: str) -> str:
    """``validate scenario`` with every estimate announced: it succeeds and prints exactly
    one line on stderr, which is returned."""
    monkeypatch.setattr(budget, "NOTICE_SECONDS", 0.0)
    r = cellplan("validate", scenario)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_long_accepted_work_is_announced_in_one_note_line(cellplan, monkeypatch):
    """Work estimated past budget.NOTICE_SECONDS says so on stderr, even off a terminal."""
    line = _the_one_note_of_validate(cellplan, monkeypatch, "strategies_tiny")
    assert line.startswith("note: strategy.cells ")
    assert "of work to build the model of 5 modes" in line
    monkeypatch.setattr(budget, "NOTICE_SECONDS", budget.DEFAULT_TIME_LIMIT_S)
    assert cellplan("validate", "strategies_tiny").stderr == ""


def test_a_long_adaptive_run_is_announced_once_by_validate(cellplan, monkeypatch):
    # validate checks the task count's time once (preflight) and prints the count from the
    # section; it used to check it twice and print the note twice (a scenario fuzzer's
    # case: 15,011 random tasks in adaptive_fig3).
    line = _the_one_note_of_validate(cellplan, monkeypatch, "adaptive_fig3")
    assert line.startswith("note: adaptive.tasks.count: about ")


def test_the_second_gif_check_names_the_flag():
    """The pictures check a frame's memory again after planning; on the command line the
    refusal names --gif-size, as the first check does, not the library's ``size``."""
    from cellplan.cliutil import as_flags

    with pytest.raises(ArgumentError) as exc, as_flags({"size": "--gif-size"}):
        plots.check_gif_size(10**9, "size")
    assert [p.field for p in exc.value.problems] == ["--gif-size"]

"""Shared test settings and fixtures: hypothesis profiles sized for a 2-core CI machine,
and the ``cellplan`` fixture that runs the command line in-process."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from cellplan.cli import main

settings.register_profile(
    "default", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile("thorough", max_examples=500, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@dataclass
class Result:
    """Exit status and captured output of one command."""

    returncode: int
    stdout: str
    stderr: str


@pytest.fixture
def cellplan(capsys, monkeypatch) -> Callable[..., Result]:
    """Run the CLI entry point in-process, as the console script would."""

    def run(*args: str, cwd: Path | None = None) -> Result:
        if cwd is not None:
            monkeypatch.chdir(cwd)
        monkeypatch.setattr(sys, "argv", ["cellplan", *args])
        code = 0
        try:
            main()
        except SystemExit as exc:
            code = int(exc.code or 0)
        out = capsys.readouterr()
        return Result(code, out.out, out.err)

    return run


@pytest.fixture
def frame_counters(monkeypatch) -> list[str]:
    """The frame-counter texts of every animation frame rendered during the test."""
    import cellplan.plots

    counters: list[str] = []
    render = cellplan.plots.figure_to_rgb

    def spy(fig, width):
        counters.extend(
            t.get_text() for ax in fig.axes for t in ax.texts if t.get_gid() == "frame-counter"
        )
        return render(fig, width)

    monkeypatch.setattr(cellplan.plots, "figure_to_rgb", spy)
    return counters

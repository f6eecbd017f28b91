"""The small typed core shared by every planner: result status and statistics.

Modelled on OMPL's planner status: every planner returns a result that says
whether it solved the problem, ran out of time or budget, or proved it
infeasible, together with plain-number statistics (collision checks, sweeps,
wall time) that benchmarks and reports read without knowing the planner.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any


class Status(enum.StrEnum):
    """Outcome of a planning call."""

    SOLVED = "solved"
    APPROXIMATE = "approximate"
    TIMEOUT = "timeout"
    BUDGET_EXHAUSTED = "budget_exhausted"
    STUCK = "stuck"
    INFEASIBLE = "infeasible"
    NOT_CONVERGED = "not_converged"

    @property
    def ok(self) -> bool:
        return self is Status.SOLVED


@dataclass(frozen=True)
class PlanResult:
    """What every planner returns: a status, statistics, and a planner-specific payload."""

    status: Status
    stats: Mapping[str, float] = field(default_factory=dict)
    payload: Any = None


@dataclass(frozen=True)
class PlannerEntry:
    """A registered planner.

    Parameters
    ----------
    name
        Registry key, ``<paper>.<planner>`` (``assembly.gradient``).
    paper
        ``strategies``, ``adaptive`` or ``assembly``.
    summary
        One line for ``cellplan planners``.
    smoke
        Runs the planner on a tiny bundled problem with the given seed and returns
        its :class:`PlanResult`; the conformance test calls it twice per seed and
        checks status, statistics and determinism.
    """

    name: str
    paper: str
    summary: str
    smoke: Callable[[int], PlanResult]


def check_stats(stats: Mapping[str, float]) -> list[str]:
    """Problems with a statistics mapping (used by the conformance test)."""
    bad = []
    for key, value in stats.items():
        if not isinstance(key, str):
            bad.append(f"key {key!r} is not a string")
        if not isinstance(value, int | float) or value != value:
            bad.append(f"{key}={value!r} is not a finite number")
    return bad


# --- experiments -----------------------------------------------------------------------------
#
# Each paper package lists its experiments in ``<package>/experiments.py`` as
# ``EXPERIMENTS: list[Experiment]``. The runner (:mod:`cellplan.experiments`)
# expands them into runs, executes each run as a pure function of its spec (on
# Dask, cached on disk), and hands the rows back to the experiment's ``report``,
# which draws figures and states its claims; :mod:`cellplan.report` renders them.

Scalar = str | int | float | bool


@dataclass(frozen=True)
class RunSpec:
    """One run: a pure function of (experiment, scenario, parameters, seed)."""

    experiment: str
    params: Mapping[str, Scalar]
    seed: int


@dataclass(frozen=True)
class Claim:
    """One checkable claim, ours beside the paper's, with a plain verdict."""

    claim: str
    paper: str
    ours: str
    reproduced: bool
    detail: str = ""


@dataclass
class ReportPiece:
    """What an experiment contributes to the report."""

    title: str
    text: str = ""
    figures: list[Any] = field(default_factory=list)  # paths of PNG or GIF files
    tables: list[tuple[str, list[dict[str, Scalar]]]] = field(default_factory=list)
    claims: list[Claim] = field(default_factory=list)
    command: str = ""


@dataclass(frozen=True)
class Experiment:
    """A named experiment of one paper.

    Parameters
    ----------
    name
        ``<paper>.<experiment>``, e.g. ``assembly.ratio_vs_k``.
    paper
        ``strategies``, ``adaptive`` or ``assembly``.
    title
        Heading in the report.
    make_runs
        ``make_runs(runs, quick)`` lists the runs: ``runs`` repetitions (seeds) per
        parameter point; ``quick`` selects the small version used by ``cellplan demo``.
    run
        ``run(spec)`` executes one run and returns one flat row of scalars; it must
        depend only on ``spec`` (no global state), so serial and parallel sweeps agree.
    report
        ``report(rows, outdir)`` turns the rows of every run into a
        :class:`ReportPiece` (figures written under ``outdir``).
    """

    name: str
    paper: str
    title: str
    make_runs: Callable[[int, bool], list[RunSpec]]
    run: Callable[[RunSpec], dict[str, Scalar]]
    report: Callable[[list[dict[str, Scalar]], Any], ReportPiece]

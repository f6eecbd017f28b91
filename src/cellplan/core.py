"""The small typed core every planner shares: status, result, planner and package declarations.

Modelled on OMPL's planner status and scipy's ``OptimizeResult``: every planner, whatever
its paper, returns one :class:`Result` that says whether it solved the problem
(:class:`Status`), why not in one line (``message``), plain-number statistics
(``stats``), the planner's own object (``solution``: a strategy to query, an assembly
sequence, an experience graph) and the motion itself (``trajectory``, a
:class:`~cellplan.trajectory.Trajectory`).

Planners are declared, not hard-wired, in the spirit of Gymnasium's registry: a
:class:`PlannerSpec` names a planner, its options (a pydantic model whose fields are the
single source of each option's default, range and description) and the function that
runs it; a :class:`Package` declares one paper package (its scenario section, planners,
experiments, CLI commands and report metadata). :mod:`cellplan.registry` collects the
packages; nothing in the core names a paper.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict

if TYPE_CHECKING:
    from cellplan.setup import Setup
    from cellplan.trajectory import Trajectory


class Status(enum.StrEnum):
    """Outcome of a planning call (OMPL's ``PlannerStatus`` in spirit)."""

    SOLVED = "solved"
    APPROXIMATE = "approximate"
    TIMEOUT = "timeout"
    BUDGET_EXHAUSTED = "budget_exhausted"
    STUCK = "stuck"
    INFEASIBLE = "infeasible"
    NOT_CONVERGED = "not_converged"
    FAILED = "failed"

    @property
    def ok(self) -> bool:
        """True only for :attr:`SOLVED`."""
        return self is Status.SOLVED


Scalar = str | int | float | bool

Stat = int | float | bool
"""A value of :attr:`Result.stats`: a count (``int``), a flag (``bool``) or a measure
(``float``); each keeps its type in JSON."""


@dataclass(frozen=True, eq=False)
class Result:
    """What every planner returns.

    Attributes
    ----------
    status
        :class:`Status`; ``status.ok`` (also :attr:`success`) is true only when solved.
    message
        One line a person can read: what was achieved, or why not.
    planner
        Registry name of the planner that produced it.
    stats
        Plain finite numbers (counts, ratios, seconds); benchmarks and reports read them
        without knowing the planner. A count is an ``int`` and a flag a ``bool``: they keep
        that type in :meth:`summary` and in every ``--json`` output.
    solution
        The planner's own object: a strategy to query, an assembly run, an experience
        graph ... (see the planner's documentation).
    trajectory
        The motion, as a :class:`~cellplan.trajectory.Trajectory`; ``None`` only where the
        planner found none to give, so a type checker needs the narrowing
        ``assert result.trajectory is not None`` (or an ``if``) before using it.
    options
        The validated options the planner ran with (defaults filled in).
    """

    status: Status
    message: str
    planner: str = ""
    stats: Mapping[str, Stat] = field(default_factory=dict)
    solution: Any = None
    trajectory: Trajectory | None = None
    options: Mapping[str, Any] = field(default_factory=dict)

    @property
    def success(self) -> bool:
        """True when the planner solved the problem (``status is Status.SOLVED``)."""
        return self.status.ok

    def summary(self) -> dict[str, Any]:
        """A JSON-ready dict: planner, status, message, statistics and options."""
        return {
            "planner": self.planner,
            "status": str(self.status),
            "success": self.success,
            "message": self.message,
            "stats": {k: _json_number(v) for k, v in self.stats.items()},
            "options": {k: _json_value(v) for k, v in self.options.items()},
        }

    def __repr__(self) -> str:
        traj = "none" if self.trajectory is None else f"{len(self.trajectory)} samples"
        return (
            f"Result(planner={self.planner!r}, status={self.status.value!r}, "
            f"message={self.message!r}, stats={len(self.stats)} numbers, trajectory={traj})"
        )


def _json_number(value: Stat) -> Stat | None:
    """A statistic as JSON: a flag stays a ``bool`` and a count an ``int`` (numpy's
    included), a measure a ``float``; a non-finite measure is ``None`` (strict JSON)."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    number = float(value)
    return number if math.isfinite(number) else None


def _json_value(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, tuple | list):
        return [_json_value(v) for v in value]
    return value


def check_stats(stats: Mapping[str, Stat]) -> list[str]:
    """Problems with a statistics mapping (used by the conformance test).

    Each value must be a Python ``bool`` (a flag), ``int`` (a count) or finite ``float``
    (a measure); numpy integers and booleans are refused, since ``json`` cannot write them.
    """
    bad = []
    for key, value in stats.items():
        if not isinstance(key, str):
            bad.append(f"key {key!r} is not a string")
        if isinstance(value, bool):
            continue
        if not isinstance(value, int | float) or not math.isfinite(value):
            bad.append(f"{key}={value!r} is not a finite number, a count or a flag")
    return bad


class Options(BaseModel):
    """Base of every planner's options: unknown names are errors, values are frozen.

    Each field's default, range (pydantic constraints) and description are the one
    source the library, the CLI and the docs read. A default of ``None`` means "the
    scenario's value" (its section's default when the file does not set it).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


Progress = Callable[[float, float | None, str], None]
"""``progress(done, total, text)``: how a planner reports progress (``total`` None when unknown)."""


@dataclass(frozen=True)
class PlannerSpec:
    """A registered planner (an entry of :func:`cellplan.planners`).

    Parameters
    ----------
    name
        Registry key: the package name, or ``<package>.<variant>``.
    package
        Name of the package that registered it.
    summary
        One line for ``cellplan planners``.
    options
        The :class:`Options` model of the planner.
    run
        ``run(setup, options, progress) -> Result``; pure apart from the files the
        options name (an experience database), never prints or plots.
    section
        The scenario section the planner needs (``None``: none).
    smoke
        ``(scenario, options)``: a small bundled problem the planner must solve; the
        conformance test runs it and checks the result contract.
    deterministic
        Whether the same setup and options give the same trajectory and statistics
        (timings aside). ``False`` only for planners whose search depends on thread
        timing (OMPL's PRM grows its roadmap in one thread while another looks for a
        path); the conformance test then checks the contract but not repeatability.
    """

    name: str
    package: str
    summary: str
    options: type[Options]
    run: Callable[[Setup, Any, Progress | None], Result]
    section: str | None = None
    smoke: tuple[str, Mapping[str, Any]] = ("", {})
    deterministic: bool = True

    def option_table(self) -> list[tuple[str, str, str]]:
        """``(name, default, description)`` for each option, in declaration order.

        A default of ``None`` is shown as ``None``; the description says what it means
        (usually the scenario's value).
        """
        return [
            (key, repr(info.default), info.description or "")
            for key, info in self.options.model_fields.items()
        ]


@dataclass(frozen=True)
class Fact:
    """One fact of ``cellplan validate``: the same thing for a person and for a program.

    Attributes
    ----------
    key
        Machine key of ``validate --json`` (lower case, ``_`` between words).
    label
        What the text output prints before the colon.
    value
        The typed value ``--json`` prints: a count is an ``int``, a fraction a ``float``,
        names a list, regions a mapping; JSON-ready (str, int, float, bool, None, lists
        and mappings of these).
    text
        What the text output prints after the colon.
    """

    key: str
    label: str
    value: Any
    text: str


@dataclass(frozen=True)
class ShowcaseItem:
    """One picture set of the demo's showcase, made through the library API.

    ``code`` is the few lines of Python (or a ``cellplan`` command) that make it; the
    report shows them as a code block under the figures, with ``caption``.
    """

    title: str
    figures: Sequence[Any]  # paths of PNG or GIF files
    caption: str
    code: str = ""


@dataclass(frozen=True)
class Package:
    """One package of planners (one paper), declared once in its ``plugin.py``.

    The core (scenario loading, registry, CLI, experiment runner, report) iterates over
    the registered packages; adding a planner family means writing a package and adding
    it to :data:`cellplan.registry.BUILTIN_PACKAGES` (or declaring a ``cellplan.packages``
    entry point), touching nothing else in the core.

    Parameters
    ----------
    name
        Short name, used in reports, ``cellplan reproduce`` and planner names.
    title, citation, summary
        How the report introduces the package's paper.
    section, section_model
        The scenario key the package reads (``strategy``) and the pydantic model of that
        section; the model may define ``check(scenario) -> list[Problem]`` for checks that
        span sections. ``None`` when the package has no section.
    planners
        The planners it registers.
    experiments
        Module path of its experiment list (``EXPERIMENTS``), imported only when needed.
    commands
        Module path with ``register(app)`` adding its CLI commands, imported by the CLI.
    paper_runs
        Repetitions per parameter point in the paper (``cellplan reproduce`` default).
    describe
        ``describe(setup) -> [Fact]``: the facts ``cellplan validate`` prints for the
        package's section (each with a machine key, a label, a typed value and the text
        a person reads; see :class:`Fact`). The legacy form ``{label: text}`` is still
        accepted: its keys are the labels slugged and its values the texts. It may also
        run the checks every command of the package runs and raise
        :class:`~cellplan.errors.ScenarioError`.
    showcase
        ``showcase(folder) -> [ShowcaseItem]``: one run of the package's planners on
        bundled scenarios through the API, with pictures, for the demo report.
    draw
        ``draw(setup, ax) -> [legend handles]``: draws the package's section onto the
        workcell picture of ``cellplan show`` (discs' starts and goals, goals and changes).
    workcells
        The kinds of workcell (``"2d"``, ``"3d"``) its section and planners work in; a
        scenario of another kind with the package's section is refused with one line.
    """

    name: str
    title: str
    citation: str
    summary: str
    section: str | None = None
    section_model: type[BaseModel] | None = None
    planners: Sequence[PlannerSpec] = ()
    experiments: str | None = None
    commands: str | None = None
    paper_runs: int = 1
    describe: Callable[[Setup], Sequence[Fact] | Mapping[str, str]] | None = None
    showcase: Callable[[Any], Sequence[ShowcaseItem]] | None = None
    draw: Callable[[Setup, Any], Sequence[Any]] | None = None
    workcells: tuple[str, ...] = ("2d",)


# --- experiments -----------------------------------------------------------------------------
#
# Each paper package lists its experiments in ``<package>/experiments.py`` as
# ``EXPERIMENTS: list[Experiment]``. The runner (:mod:`cellplan.experiments`)
# expands them into runs, executes each run as a pure function of its spec (on
# Dask, cached on disk), and hands the rows back to the experiment's ``report``,
# which draws figures and states its claims; :mod:`cellplan.report` renders them.


@dataclass(frozen=True)
class RunSpec:
    """One run: a pure function of (experiment, scenario, parameters, seed)."""

    experiment: str
    params: Mapping[str, Scalar]
    seed: int


@dataclass(frozen=True)
class Claim:
    """One checkable claim, ours beside the paper's, with a verdict and what it rests on.

    Attributes
    ----------
    reproduced
        True (reproduced), False (differs) or None (not enough runs to decide: the
        interval from the runs contains both outcomes, or there are too few runs).
    n
        Number of runs the verdict rests on (0 when it is not a statistical claim).
    rule
        The decision rule, e.g. "95% interval of the mean reduction above 0".
    explanation
        Where a "differs" verdict is explained (a docs/ path and anchor).
    """

    claim: str
    paper: str
    ours: str
    reproduced: bool | None
    detail: str = ""
    n: int = 0
    rule: str = ""
    explanation: str = ""


MIN_RUNS = 5
"""Fewest runs behind a statistical verdict (:func:`decide_interval`'s default): below it,
a claim is "not enough runs to decide" however its interval lies. The demo runs at least
this many seeds of every experiment with a statistical claim
(:attr:`Experiment.demo_runs`)."""


def decide_interval(
    low: float,
    high: float,
    n: int,
    *,
    above: float | None = None,
    below: float | None = None,
    min_runs: int = MIN_RUNS,
) -> bool | None:
    """The verdict of "the quantity is above ``above`` (and/or below ``below``)".

    ``[low, high]`` is an interval from ``n`` runs (a 95% confidence interval, say).
    Reproduced when the whole interval satisfies the claim, differs when the whole
    interval contradicts it, and undecided (None) when it straddles a bound or when
    fewer than ``min_runs`` runs stand behind it.
    """
    if n < min_runs or not (math.isfinite(low) and math.isfinite(high)):
        return None
    inside = (above is None or low > above) and (below is None or high < below)
    outside = (above is not None and high <= above) or (below is not None and low >= below)
    if inside:
        return True
    if outside:
        return False
    return None


def mean_interval(values: Sequence[float] | np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Mean and Student-t half-width of ``values`` (the one interval every report uses).

    Non-finite values are dropped first (a run that measured nothing). With fewer than two
    values left the half-width is NaN, so :func:`decide_interval` leaves the claim
    undecided.

    Parameters
    ----------
    values : array_like of float
        One measurement per independent run (seed).
    level : float, optional
        Two-sided confidence level, by default 0.95.

    Returns
    -------
    mean, half : float
        The sample mean and the half-width ``t_{(1+level)/2, n-1} s / sqrt(n)``.
    """
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    n = len(v)
    if n == 0:
        return float("nan"), float("nan")
    if n < 2:
        return float(v[0]), float("nan")
    # scipy.stats costs about a second to import: only reports need it, not the CLI's start.
    from scipy.stats import t as student_t

    half = float(student_t.ppf((1.0 + level) / 2.0, n - 1)) * float(v.std(ddof=1)) / math.sqrt(n)
    return float(v.mean()), half


@dataclass
class ReportPiece:
    """What an experiment contributes to the report.

    ``captions`` maps a figure's file name to what it shows, written from the parameters
    actually run (the report prints the file name where a figure has none).
    """

    title: str
    text: str = ""
    figures: list[Any] = field(default_factory=list)  # paths of PNG or GIF files
    captions: dict[str, str] = field(default_factory=dict)
    tables: list[tuple[str, list[dict[str, Scalar]]]] = field(default_factory=list)
    claims: list[Claim] = field(default_factory=list)
    command: str = ""


@dataclass(frozen=True)
class Experiment:
    """A named experiment of one paper.

    Parameters
    ----------
    name
        ``<package>.<experiment>``.
    paper
        Name of the package it belongs to.
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
    demo_runs
        How ``cellplan demo`` runs it: its quick version with this many seeds per
        parameter point, chosen so that every claim it states is decided (reproduced or
        differs) under the same rules as the full reproduction. ``None`` (the default):
        not in the demo, because its claims cannot be decided at a demo's size; the
        demo's report lists it under "run ``cellplan reproduce`` to decide" with the
        command that decides it.
    """

    name: str
    paper: str
    title: str
    make_runs: Callable[[int, bool], list[RunSpec]]
    run: Callable[[RunSpec], dict[str, Scalar]]
    report: Callable[[list[dict[str, Scalar]], Any], ReportPiece]
    demo_runs: int | None = None

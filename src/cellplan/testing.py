"""The planner conformance check, for any planner package (``check_planner``).

A package that registers planners (its own distribution, through the
``cellplan.packages`` entry point) can check that each obeys the contract every planner
of cellplan obeys, the way Gymnasium's ``check_env`` checks an environment and
scikit-learn's ``check_estimator`` an estimator::

    from cellplan.testing import check_planner

    def test_my_planner():
        check_planner("mypkg.fast", "my_scenario.yaml", {"budget": 100})

The contract (docs/architecture.md, "Adding a planner package"):

* the registry entry is well formed: its name is the package's or ``<package>.<variant>``,
  it has a summary, its options class derives from :class:`~cellplan.core.Options` and
  documents every option, and an unknown option is refused in one problem naming it;
* a run returns a :class:`~cellplan.core.Result` with a :class:`~cellplan.core.Status`,
  the planner's name, a one-line message, valid statistics
  (:func:`~cellplan.core.check_stats`), a solution and a :class:`~cellplan.trajectory.
  Trajectory` of at least two samples that round-trips through CSV, JSON and NPZ;
* the problem it is given (its smoke problem by default) is *solved*, twice;
* the result pickles (it crosses to worker processes);
* a planner declared deterministic gives the same statistics (timings aside) and the
  same trajectory twice.

Every rule broken is reported at once, in one :class:`ConformanceError`.
"""

from __future__ import annotations

import math
import pickle
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cellplan.api import Planner
from cellplan.core import Options, PlannerSpec, Result, Status, check_stats
from cellplan.errors import ArgumentError
from cellplan.registry import parse_options, planner
from cellplan.setup import Setup, as_setup
from cellplan.trajectory import Trajectory

#: Statistics whose key contains one of these are timings, left out of the determinism test.
TIMING_KEYS = ("time", "seconds", "wall")
#: An option name no planner has (the unknown-option rule).
UNKNOWN_OPTION = "no_such_option"


class ConformanceError(AssertionError):
    """A planner breaks its contract: one line per rule broken (``failures``)."""

    def __init__(self, name: str, failures: list[str]) -> None:
        self.name = name
        self.failures = list(failures)
        lines = "\n".join(f"- {f}" for f in self.failures)
        super().__init__(f"planner {name} breaks {len(self.failures)} rule(s):\n{lines}")


def check_planner(
    spec_or_name: PlannerSpec | str,
    setup: Setup | str | Path | None = None,
    options: Mapping[str, Any] | None = None,
) -> tuple[Result, Result]:
    """Check that a planner obeys the planner contract (module docstring).

    Parameters
    ----------
    spec_or_name
        The planner: its :class:`~cellplan.core.PlannerSpec` (registered or not) or its
        registry name.
    setup
        The problem it must solve: a :class:`~cellplan.setup.Setup`, a bundled scenario's
        name or a scenario file; default the planner's smoke problem (``spec.smoke``).
    options
        The planner's options for the runs; default the smoke problem's options when
        ``setup`` is None, else none (the documented defaults).

    Returns
    -------
    first, second : Result
        The two runs, for further checks of the caller's own.

    Raises
    ------
    ConformanceError
        Listing every rule the planner breaks (an ``AssertionError``, so test runners
        report it as a failed test).
    """
    spec = planner(spec_or_name) if isinstance(spec_or_name, str) else spec_or_name
    if setup is None:
        scenario, smoke_options = spec.smoke
        setup = scenario
        options = smoke_options if options is None else options
    problem = as_setup(setup)
    given = dict(options or {})
    failures = _entry_failures(spec, given)
    if failures:  # the runs need valid options
        raise ConformanceError(spec.name, failures)
    runs = tuple(_run(spec, problem, given) for _ in range(2))
    for i, result in enumerate(runs):
        failures += [f"run {i + 1}: {f}" for f in _result_failures(spec, result)]
    if failures:
        raise ConformanceError(spec.name, failures)
    first, second = runs
    failures += _pickle_failures(first)
    if spec.deterministic:
        failures += _determinism_failures(first, second)
    if failures:
        raise ConformanceError(spec.name, failures)
    return first, second


def _run(spec: PlannerSpec, setup: Setup, options: Mapping[str, Any]) -> Any:
    """One run through the public path (:meth:`cellplan.api.Planner.solve`, as
    ``cellplan.plan`` runs it), for a registered planner or not."""
    return Planner(spec, setup, parse_options(spec, dict(options))).solve()


def _entry_failures(spec: PlannerSpec, options: Mapping[str, Any]) -> list[str]:
    """The registry entry's rules: name, summary, options class, option docs, refusals."""
    out = []
    if not (spec.name == spec.package or spec.name.startswith(spec.package + ".")):
        out.append(f"its name is not '{spec.package}' or '{spec.package}.<variant>'")
    if not spec.summary:
        out.append("it has no summary")
    if not (isinstance(spec.options, type) and issubclass(spec.options, Options)):
        out.append("its options class does not derive from cellplan.core.Options")
        return out
    for key, _default, description in spec.option_table():
        if not description:
            out.append(f"option {key} has no description")
    try:
        parse_options(spec, dict(options))
    except ArgumentError as exc:
        out.append(f"the options {dict(options)} are refused: {exc}")
    try:
        parse_options(spec, {**options, UNKNOWN_OPTION: 1})
        out.append(f"an unknown option ({UNKNOWN_OPTION}) is accepted")
    except ArgumentError as exc:
        fields = [p.field for p in exc.problems]
        if fields != [UNKNOWN_OPTION]:
            out.append(f"an unknown option is refused as {fields}, not one problem naming it")
    return out


def _result_failures(spec: PlannerSpec, result: Any) -> list[str]:
    """The rules of one run's result."""
    if not isinstance(result, Result):
        return [f"returned {type(result).__name__}, not a cellplan.core.Result"]
    out = []
    if not isinstance(result.status, Status):
        out.append(f"status {result.status!r} is not a cellplan.core.Status")
    if result.planner != spec.name:
        out.append(f"the result names planner {result.planner!r}")
    if not result.message or "\n" in result.message:
        out.append(f"the message is not one line: {result.message!r}")
    out += [f"stats: {p}" for p in check_stats(result.stats)]
    if result.solution is None:
        out.append("the result has no solution")
    if not isinstance(result.trajectory, Trajectory) or len(result.trajectory) < 2:
        out.append("the trajectory is not a Trajectory of at least two samples")
    else:
        out += _round_trip_failures(result.trajectory)
    if result.status is not Status.SOLVED:
        out.append(f"it did not solve the problem ({result.status}): {result.message}")
    return out


def _round_trip_failures(traj: Trajectory) -> list[str]:
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".csv", ".json", ".npz"):
            path = traj.save(Path(tmp) / f"trajectory{suffix}")
            if Trajectory.load(path) != traj:
                out.append(f"the trajectory does not round-trip through {suffix}")
    return out


def _pickle_failures(result: Result) -> list[str]:
    """A result crosses to a worker process: it pickles, and comes back the same."""
    try:
        copy = pickle.loads(pickle.dumps(result))
    except Exception as exc:  # any pickling failure breaks the rule
        return [f"the result does not pickle: {type(exc).__name__}: {exc}"]
    same = (
        copy.status is result.status
        and copy.message == result.message
        and _same_stats(dict(copy.stats), dict(result.stats))
        and copy.trajectory == result.trajectory
        and type(copy.solution) is type(result.solution)
    )
    return [] if same else ["the result changes when pickled and unpickled"]


def _determinism_failures(first: Result, second: Result) -> list[str]:
    """A deterministic planner's two runs agree (timing statistics aside)."""
    out = []
    a, b = _untimed(first.stats), _untimed(second.stats)
    if not _same_stats(a, b):
        keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        out.append(f"declared deterministic, but two runs differ in stats {keys}")
    assert first.trajectory is not None and second.trajectory is not None  # checked before
    if not np.array_equal(first.trajectory.q, second.trajectory.q):
        out.append("declared deterministic, but two runs give different trajectories")
    return out


def _untimed(stats: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in stats.items() if not any(t in k for t in TIMING_KEYS)}


def _same_stats(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Equal statistics (NaN equal to NaN, which check_stats refuses anyway)."""
    if set(a) != set(b):
        return False
    for k, v in a.items():
        w = b[k]
        both_nan = isinstance(v, float) and isinstance(w, float) and math.isnan(v) and math.isnan(w)
        if v != w and not both_nan:
            return False
    return True

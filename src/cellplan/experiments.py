"""The experiment runner: expand experiments into runs, execute them (serially or on Dask), cache.

Each registered package names the module that lists its experiments
(:attr:`cellplan.core.Package.experiments`), which holds ``EXPERIMENTS:
list[Experiment]`` (the contract is in :mod:`cellplan.core`).
:func:`run_sweep` turns them into runs with ``make_runs``, executes every run as
a pure function of its :class:`~cellplan.core.RunSpec`, and writes one tidy CSV
per experiment (one row per run) beside a JSON file of metadata (versions,
machine, command line, scheduler).

Runs execute on :mod:`dask.distributed`: by default on a ``LocalCluster`` of one
single-threaded worker process per core, or on an existing cluster given by its
scheduler address (used as it is: never scaled, never shut down). ``serial=True``
runs everything in this process. Both produce identical rows, because a row
depends only on its spec and every row passes through the same JSON round trip.

Finished runs are cached on disk, one JSON file per run, keyed by a hash of
(experiment name, parameters, seed, cellplan version). Each entry carries a
SHA-256 checksum of its content; an entry that does not parse, whose checksum
does not match, or that describes another run is reported and recomputed, never
trusted. Entries are plain JSON (never pickles) and are written atomically.
Failed runs are not cached, so they are retried by the next sweep.

Dask is imported only when a parallel sweep starts, so ``import cellplan`` stays light.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import hashlib
import importlib
import io
import json
import math
import os
import platform
import re
import shlex
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import CancelledError
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rich.markup import escape

from cellplan.core import Experiment, RunSpec, Scalar
from cellplan.errors import ArgumentError, Problem
from cellplan.fileio import write_json, write_text
from cellplan.scheduler import check_scheduler_address, connect_client, run_with_deadline

CACHE_FORMAT = 1
"""Version of the cache-entry layout; part of every entry, checked on read."""

MAX_ENTRY_BYTES = 1_000_000
"""Largest cache entry read (a row of scalars is a few kB); a bigger file is damaged."""

# Columns the runner adds to every row. The prefix keeps them apart from the
# experiments' own columns (a planner row often has its own ``status``).
RUN_COLUMNS: tuple[str, ...] = ("run_status", "run_error", "run_wall_s")
OK, FAILED, SKIPPED = "ok", "failed", "skipped"

_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*\.[A-Za-z0-9_.-]+$")


# --- discovery --------------------------------------------------------------------------------


@dataclass
class PaperExperiments:
    """The experiments one paper package offers, or why it offers none.

    ``note`` is empty when the package's experiments module imported; otherwise
    it says why there is nothing to run ("no experiments yet", or the import error).
    """

    paper: str
    experiments: list[Experiment] = field(default_factory=list)
    note: str = ""


def experiment_modules() -> dict[str, str]:
    """Package name -> module path of its experiments, for every registered package, in order."""
    from cellplan.registry import packages

    return {p.name: p.experiments for p in packages().values() if p.experiments}


def discover(papers: Mapping[str, str] | Sequence[str] | None = None) -> list[PaperExperiments]:
    """Import each package's experiments module and collect its ``EXPERIMENTS``.

    ``papers`` maps package names to module paths (default: :func:`experiment_modules`);
    a sequence of names selects registered packages.

    A package without that module has "no experiments yet". A module that fails
    to import, or whose ``EXPERIMENTS`` is malformed, is reported in ``note`` rather
    than raised, so one broken package does not hide the others' results.
    """
    modules = experiment_modules()
    if papers is None:
        papers = modules
    elif not isinstance(papers, Mapping):
        papers = {name: modules.get(name, "") for name in papers}
    found = []
    for paper, module_name in papers.items():
        if not module_name:
            found.append(PaperExperiments(paper, note="no experiments yet"))
            continue
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            # Missing is fine (the package has not written its experiments yet); a missing
            # import *inside* the module is a bug and is reported as such.
            if exc.name is not None and module_name.startswith(exc.name):
                found.append(PaperExperiments(paper, note="no experiments yet"))
                continue
            found.append(
                PaperExperiments(paper, note=f"{module_name} failed to import: {_describe(exc)}")
            )
            continue
        except Exception as exc:  # a bug in another package must not stop the report
            found.append(
                PaperExperiments(paper, note=f"{module_name} failed to import: {_describe(exc)}")
            )
            continue
        experiments = getattr(module, "EXPERIMENTS", None)
        if experiments is None:
            found.append(
                PaperExperiments(paper, note=f"{module_name} defines no EXPERIMENTS list yet")
            )
            continue
        bad = [e for e in experiments if not isinstance(e, Experiment)]
        if bad:
            found.append(
                PaperExperiments(
                    paper,
                    note=f"{module_name}.EXPERIMENTS holds non-Experiment items: {bad!r:.200}",
                )
            )
            continue
        if not experiments:
            found.append(PaperExperiments(paper, list(experiments), note="no experiments yet"))
            continue
        found.append(PaperExperiments(paper, list(experiments)))
    return found


def check_experiments(experiments: Sequence[Experiment]) -> None:
    """Refuse experiment lists the runner cannot store: bad or duplicate names, unknown papers."""
    problems = []
    seen: set[str] = set()
    for exp in experiments:
        if not _NAME_RE.match(exp.name):
            problems.append(
                Problem(
                    exp.name,
                    "experiment name must look like <paper>.<name> (letters, digits, _ . -)",
                )
            )
        if exp.name in seen:
            problems.append(Problem(exp.name, "experiment listed twice"))
        seen.add(exp.name)
    if problems:
        raise ArgumentError(problems)


# --- the sweep --------------------------------------------------------------------------------


@dataclass
class ExperimentRun:
    """The outcome of sweeping one experiment.

    Attributes
    ----------
    experiment
        The experiment.
    rows
        One row per run, in ``make_runs`` order: the spec's parameters, ``seed``,
        the runner's columns (:data:`RUN_COLUMNS`) and the experiment's own columns.
    csv_path, meta_path
        The tidy CSV and its JSON metadata.
    n_cached
        Runs answered from the cache.
    n_recomputed_corrupt
        Cache entries found corrupted (recomputed).
    error
        Set when ``make_runs`` itself failed (then there are no rows).
    param_names
        The parameter names of the runs, in order of first appearance.
    """

    experiment: Experiment
    rows: list[dict[str, Scalar]]
    csv_path: Path
    meta_path: Path
    n_cached: int = 0
    n_recomputed_corrupt: int = 0
    error: str = ""
    param_names: list[str] = field(default_factory=list)

    @property
    def n_failed(self) -> int:
        return sum(1 for row in self.rows if row["run_status"] != OK)

    @property
    def compute_s(self) -> float:
        """Sum of the runs' own wall times (cached runs count their original time)."""
        return float(sum(float(row["run_wall_s"]) for row in self.rows))

    @property
    def ok_rows(self) -> list[dict[str, Scalar]]:
        """Rows of the runs that succeeded (what the experiment's ``report`` receives)."""
        return [row for row in self.rows if row["run_status"] == OK]


@dataclass
class SweepResult:
    """Everything one sweep produced."""

    runs: list[ExperimentRun]
    outdir: Path
    scheduler: str
    command: str
    wall_s: float
    metadata: dict[str, Any]
    lost: str = ""
    """Why the sweep gave up on the runs still out (the Dask scheduler was lost, or no
    worker was left); empty when every run finished, failed or was skipped by itself."""

    @property
    def n_runs(self) -> int:
        return sum(len(r.rows) for r in self.runs)

    @property
    def n_failed(self) -> int:
        """Runs that did not finish (failed, skipped, or lost with their worker)."""
        return sum(r.n_failed for r in self.runs)

    @property
    def n_broken(self) -> int:
        """Experiments whose ``make_runs`` failed (they have no rows)."""
        return sum(1 for r in self.runs if r.error)


@dataclass
class _Pending:
    exp_index: int
    run_index: int
    spec: RunSpec
    key: str


@contextlib.contextmanager
def _workers_ignore_ctrl_c() -> Iterator[None]:
    """Start worker processes with Ctrl-C ignored (they inherit the ignore disposition).

    Ctrl-C then reaches only this process, which stops the sweep and reports one line;
    the workers are shut down with the cluster instead of each printing a traceback.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def run_sweep(
    experiments: Sequence[Experiment],
    runs: int | Mapping[str, int],
    quick: bool,
    outdir: Path,
    scheduler: str | None = None,
    serial: bool = False,
    progress: bool = True,
    console: Any = None,
    cache_dir: Path | None = None,
    use_cache: bool = True,
    workers: int | None = None,
    command: str | None = None,
    time_budget_s: float | None = None,
) -> SweepResult:
    """Run every run of every experiment, write CSV and JSON per experiment, return the rows.

    Parameters
    ----------
    experiments
        The experiments to sweep (names unique, ``<paper>.<name>``).
    runs
        Repetitions (seeds) per parameter point, passed to ``make_runs``; a mapping
        gives one count per experiment name or per paper (an experiment's own entry
        first, as the demo gives each experiment its ``demo_runs``).
    quick
        Ask each experiment for its small version (``cellplan demo``).
    outdir
        Output folder: ``data/<experiment>.csv`` and ``data/<experiment>.json`` go here.
    scheduler
        Address of an existing Dask scheduler (``tcp://HOST:8786``); used unchanged.
        ``None`` starts a ``LocalCluster`` sized to the machine.
    serial
        Run everything in this process, in order (no Dask).
    progress
        Show a progress bar (runs done, failures, elapsed time) on ``console``.
    console
        A :class:`rich.console.Console`; defaults to one on stderr.
    cache_dir
        Where finished runs are cached (default ``outdir / "cache"``).
    use_cache
        ``False`` ignores existing entries (they are still rewritten).
    workers
        Worker processes of the local cluster (default: the usable cores).
    command
        The command line recorded in the metadata (default: this process's argv).
    time_budget_s
        Stop starting runs after this many seconds: runs not finished by then are
        recorded as ``run_status=skipped`` (not cached), so a demo with a time limit
        still writes its report. ``None`` runs everything.

    Returns
    -------
    SweepResult
        Per experiment, its rows in ``make_runs`` order and the files written.

    Notes
    -----
    A run that raises an :class:`Exception` is recorded as ``run_status=failed``
    with its error and the sweep goes on. ``KeyboardInterrupt`` and ``SystemExit``
    stop the sweep; the runs that finished before are already cached, so the next
    sweep recomputes only the rest.
    """
    problems = []
    if isinstance(runs, Mapping):
        bad_runs = {k: v for k, v in runs.items() if not _is_count(v)}
    else:
        bad_runs = {} if _is_count(runs) else {"": runs}
    if bad_runs:
        problems.append(
            Problem("--runs", f"must be a positive integer, got {next(iter(bad_runs.values()))!r}")
        )
    if workers is not None and not _is_count(workers):
        problems.append(Problem("workers", f"must be a positive integer, got {workers!r}"))
    if problems:
        raise ArgumentError(problems)
    if scheduler is not None:
        check_scheduler_address(scheduler)
    check_experiments(experiments)

    from rich.console import Console

    console = console if console is not None else Console(stderr=True)
    outdir = Path(outdir)
    cache = RunCache(cache_dir if cache_dir is not None else outdir / "cache")
    command = (
        command if command is not None else shlex.join([Path(sys.argv[0]).name, *sys.argv[1:]])
    )
    started = time.perf_counter()
    started_at = datetime.now(UTC).isoformat(timespec="seconds")

    # Expand every experiment first, so a broken make_runs is reported before any work.
    results: list[ExperimentRun] = []
    pending: list[_Pending] = []
    for exp_index, exp in enumerate(experiments):
        data = outdir / "data"
        result = ExperimentRun(exp, [], data / f"{exp.name}.csv", data / f"{exp.name}.json")
        results.append(result)
        n = _runs_of(exp, runs)
        try:
            specs = _expand(exp, n, quick)
        except Exception as exc:
            result.error = f"make_runs failed: {_describe(exc)}"
            continue
        result.rows = [{} for _ in specs]
        result.param_names = list(dict.fromkeys(k for spec in specs for k in spec.params))
        for run_index, spec in enumerate(specs):
            key = cache_key(spec)
            row = cache.get(key, spec) if use_cache else None
            if row is not None:
                result.rows[run_index] = row
                result.n_cached += 1
                continue
            if cache.last_corrupt:
                result.n_recomputed_corrupt += 1
                console.print(
                    f"[yellow]warning[/]: {escape(cache.last_corrupt)}; recomputing",
                    highlight=False,
                )
            pending.append(_Pending(exp_index, run_index, spec, key))

    n_cached = sum(r.n_cached for r in results)
    with contextlib.ExitStack() as stack:
        client = None
        if pending and not serial:
            # Dask's loggers print tracebacks on stderr when the scheduler goes away, until
            # its client is closed; the loss is reported once, as ``lost``, instead. Imported
            # first, so that every logger it creates exists to be silenced.
            importlib.import_module("distributed")
            stack.enter_context(_quiet_loggers(*DASK_LOGGERS))
        if scheduler is not None and pending and not serial:
            # Probed, connected and asked once under deadlines, before the progress bar:
            # a wrong address is one --scheduler line, never a hang or a huge allocation.
            client = stack.enter_context(connect_client(scheduler))
        with _progress_bar(console, progress, len(pending), n_cached) as tick:

            def finish(item: _Pending, row: dict[str, Scalar]) -> None:
                results[item.exp_index].rows[item.run_index] = row
                if row["run_status"] == OK:
                    cache.put(item.key, item.spec, row)
                tick(row["run_status"] != OK)

            deadline = None if time_budget_s is None else started + time_budget_s
            lost = ""
            if serial or not pending:
                scheduler_desc = "serial (in process)"
                for item in pending:
                    if deadline is not None and time.perf_counter() > deadline:
                        finish(item, _skipped(item.spec, time_budget_s))
                    else:
                        finish(item, execute_run(experiments[item.exp_index].run, item.spec))
            else:
                scheduler_desc, lost = _run_on_dask(
                    experiments,
                    pending,
                    finish,
                    scheduler,
                    client,
                    workers,
                    deadline,
                    time_budget_s,
                )

    wall = time.perf_counter() - started
    metadata = run_metadata(command=command, scheduler=scheduler_desc, quick=quick, runs=runs)
    metadata.update(started=started_at, wall_s=round(wall, 3))
    for result in results:
        _write_outputs(result, metadata)
    return SweepResult(results, outdir, scheduler_desc, command, wall, metadata, lost)


def _runs_of(exp: Experiment, runs: int | Mapping[str, int]) -> int:
    """The seeds per point of ``exp``: its own entry of ``runs``, else its paper's."""
    if not isinstance(runs, Mapping):
        return runs
    return runs[exp.name] if exp.name in runs else runs[exp.paper]


def _expand(exp: Experiment, runs: int, quick: bool) -> list[RunSpec]:
    specs = list(exp.make_runs(runs, quick))
    for i, spec in enumerate(specs):
        if not isinstance(spec, RunSpec):
            raise TypeError(f"make_runs item {i} is a {type(spec).__name__}, not a RunSpec")
        if spec.experiment != exp.name:
            raise ValueError(
                f"make_runs item {i} names experiment {spec.experiment!r}, not {exp.name!r}"
            )
        if not isinstance(spec.seed, int) or isinstance(spec.seed, bool):
            raise TypeError(f"make_runs item {i} has seed {spec.seed!r}, not an int")
        for key, value in spec.params.items():
            if key in ("seed", *RUN_COLUMNS) or not isinstance(value, str | int | float | bool):
                raise ValueError(
                    f"make_runs item {i}: parameter {key}={value!r} is reserved or not a scalar"
                )
    return specs


def execute_run(run: Callable[[RunSpec], Mapping[str, Any]], spec: RunSpec) -> dict[str, Scalar]:
    """Execute one run and return its full row; an :class:`Exception` becomes a failed row.

    The row is the spec's parameters, ``seed``, the runner's columns and the
    experiment's own columns, passed through a JSON round trip so that a row from
    this process, from a worker, or from the cache compare equal.
    """
    t0 = time.perf_counter()
    try:
        values = _check_values(run(spec), spec)
    except Exception as exc:
        return _row(spec, FAILED, _describe_with_place(exc), time.perf_counter() - t0, {})
    return _row(spec, OK, "", time.perf_counter() - t0, values)


def _row(
    spec: RunSpec, status: str, error: str, wall: float, values: Mapping[str, Scalar]
) -> dict[str, Scalar]:
    row: dict[str, Scalar] = {**spec.params, "seed": spec.seed}
    row.update(run_status=status, run_error=error, run_wall_s=round(wall, 6))
    row.update(values)
    return json.loads(json.dumps(row))


def _check_values(values: Any, spec: RunSpec) -> dict[str, Scalar]:
    if not isinstance(values, Mapping):
        raise TypeError(f"run returned a {type(values).__name__}, not a mapping of scalars")
    out: dict[str, Scalar] = {}
    for key, value in values.items():
        if not isinstance(key, str):
            raise TypeError(f"run returned a non-string key {key!r}")
        if hasattr(value, "item") and not isinstance(value, str):
            value = value.item()  # numpy scalar -> Python scalar
        if not isinstance(value, str | int | float | bool):
            raise TypeError(f"run returned {key}={value!r:.80}, not a scalar")
        if key in RUN_COLUMNS:
            raise ValueError(f"run returned the reserved column {key!r}")
        if key == "seed" and value != spec.seed:
            raise ValueError(f"run returned seed={value!r} for a run with seed {spec.seed}")
        if key in spec.params and value != spec.params[key]:
            raise ValueError(
                f"run returned {key}={value!r} for a run with parameter {key}={spec.params[key]!r}"
            )
        out[key] = value
    return out


NO_WORKER_TIMEOUT_S = 60.0
"""Seconds a Dask sweep waits with no worker alive before it gives up on its runs.

Long enough for a nanny to restart a killed worker or a cluster to scale up again; the
runs left are then recorded as failed (not cached), so the same command resumes."""

POLL_S = 1.0
"""Seconds between two looks at the cluster while no run finishes."""

WORKER_CHECK_TIMEOUT_S = 10.0
"""Seconds the scheduler has to say how many workers it has (else: none)."""

SCHEDULER_LOST = "the Dask scheduler was lost"

DASK_LOGGERS = ("distributed", "tornado", "asyncio")
"""Loggers silenced while a sweep holds a Dask client."""


def _run_on_dask(
    experiments: Sequence[Experiment],
    pending: list[_Pending],
    finish: Callable[[_Pending, dict[str, Scalar]], None],
    scheduler: str | None,
    client: Any,
    workers: int | None,
    deadline: float | None,
    budget: float | None,
) -> tuple[str, str]:
    """Run ``pending`` on Dask; call ``finish`` as each run completes.

    ``client``: connected to ``scheduler`` (:func:`~cellplan.scheduler.connect_client`),
    or ``None`` for a ``LocalCluster`` started here.

    Returns
    -------
    tuple of str
        A description of where the runs went, and why runs were abandoned (empty when
        none was): the scheduler was lost, or no worker was alive for
        :data:`NO_WORKER_TIMEOUT_S`. Abandoned runs are finished as failed rows.
    """
    import logging

    from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        if client is None:
            n = workers or usable_cores()
            with _workers_ignore_ctrl_c():
                cluster = stack.enter_context(
                    LocalCluster(
                        n_workers=n,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=None,
                        silence_logs=logging.ERROR,
                        # one worker per core: keep numba's own thread pool from oversubscribing
                        env={"NUMBA_NUM_THREADS": "1"},
                    )
                )
            client = stack.enter_context(Client(cluster))
            desc = f"dask LocalCluster, {n} worker processes x 1 thread"
        else:
            n_workers = len(client.scheduler_info().get("workers", {}))
            desc = f"dask scheduler {scheduler} ({n_workers} workers)"
        slots = sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())
        size = batch_size(len(pending), slots)
        futures: dict[Any, list[_Pending]] = {}
        for start in range(0, len(pending), size):
            batch = pending[start : start + size]
            tasks = [(experiments[item.exp_index].run, item.spec) for item in batch]
            first = batch[0]
            key = f"cellplan-runs-{first.key[:16]}-{first.exp_index}-{first.run_index}-{len(batch)}"
            futures[client.submit(execute_batch, tasks, key=key, pure=False)] = batch
        try:
            lost = _collect(client, futures, finish, deadline, budget)
        finally:
            # Leave an existing cluster as we found it: cancel only our own leftover work.
            if client.status == "running":
                client.cancel([f for f in futures if not f.done()])
    return desc, lost


def _collect(
    client: Any,
    futures: dict[Any, list[_Pending]],
    finish: Callable[[_Pending, dict[str, Scalar]], None],
    deadline: float | None,
    budget: float | None,
) -> str:
    """Finish every batch of ``futures`` as it completes; return why runs were abandoned.

    Waits at most :data:`POLL_S` at a time. When nothing finished, it asks the
    scheduler for its workers: with none alive for :data:`NO_WORKER_TIMEOUT_S` (or no
    answer), the batches still out are finished as failed rows, so the sweep ends in a
    bounded time and the next one recomputes them. Past ``deadline`` (the time budget)
    they are skipped instead.
    """
    from distributed import wait

    remaining = dict(futures)
    lost = ""
    alone_since: float | None = None
    while remaining:
        now = time.perf_counter()
        if deadline is not None and now >= deadline:
            for batch in remaining.values():
                for item in batch:
                    finish(item, _skipped(item.spec, budget))
            return lost
        step = POLL_S if deadline is None else min(POLL_S, deadline - now)
        # A timeout, or cancelled futures (a lost scheduler): either way, each future's
        # own state is read below.
        with contextlib.suppress(TimeoutError, CancelledError):
            wait(list(remaining), timeout=step, return_when="FIRST_COMPLETED")
        finished = [f for f in remaining if f.done()]
        for future in finished:
            batch = remaining.pop(future)
            rows = _batch_rows(future, batch)
            if future.status == "cancelled" and client.status != "running":
                lost = SCHEDULER_LOST
            for item, row in zip(batch, rows, strict=True):
                finish(item, row)
        if finished or not remaining:
            continue
        if client.status != "running":
            why = SCHEDULER_LOST
        elif _live_workers(client) > 0:
            alone_since = None
            continue
        else:
            alone_since = now if alone_since is None else alone_since
            if time.perf_counter() - alone_since < NO_WORKER_TIMEOUT_S:
                continue
            why = f"no Dask worker was alive for {NO_WORKER_TIMEOUT_S:g} s"
        for batch in remaining.values():
            for item in batch:
                finish(item, _row(item.spec, FAILED, f"dask: not run: {why}", 0.0, {}))
        return why
    return lost


def _live_workers(client: Any) -> int:
    """Workers the scheduler knows now; 0 if it does not answer in time."""
    try:
        info = run_with_deadline(client.scheduler_info, WORKER_CHECK_TIMEOUT_S)
    except Exception:  # no answer, or the connection broke: no worker can be reached
        return 0
    return len(info.get("workers", {}))


@contextlib.contextmanager
def _quiet_loggers(*names: str) -> Iterator[None]:
    """Silence the named loggers (and their children) for the block, then restore them."""
    import logging

    saved = [(logging.getLogger(n), logging.getLogger(n).disabled) for n in names]
    children = [
        logging.getLogger(n)
        for n in list(logging.root.manager.loggerDict)
        if any(n.startswith(f"{p}.") for p in names)
    ]
    saved += [(lg, lg.disabled) for lg in children]
    for lg, _ in saved:
        lg.disabled = True
    try:
        yield
    finally:
        for lg, was in saved:
            lg.disabled = was


MAX_BATCH = 8
"""Most runs sent to a worker as one Dask task."""


def batch_size(n_runs: int, slots: int) -> int:
    """Runs per Dask task: about 16 tasks per worker thread, at most :data:`MAX_BATCH`.

    Each task costs the scheduler a few milliseconds; many cheap runs are sent in
    small batches to amortise that, while expensive experiments (few runs) still get
    one run per task so the work stays balanced to the end.
    """
    return max(1, min(MAX_BATCH, n_runs // (16 * max(1, slots))))


def execute_batch(
    tasks: Sequence[tuple[Callable[[RunSpec], Mapping[str, Any]], RunSpec]],
) -> list[dict[str, Scalar]]:
    """Execute several runs in order on one worker (see :func:`execute_run`)."""
    return [execute_run(run, spec) for run, spec in tasks]


def _batch_rows(future: Any, batch: list[_Pending]) -> list[dict[str, Scalar]]:
    try:
        rows: list[dict[str, Scalar]] = future.result()
    except Exception as exc:  # the worker died or the task could not be sent
        rows = [_row(item.spec, FAILED, f"dask: {_describe(exc)}", 0.0, {}) for item in batch]
    return rows


def _skipped(spec: RunSpec, budget: float | None) -> dict[str, Scalar]:
    return _row(spec, SKIPPED, f"not run: the time budget of {budget:g} s was spent", 0.0, {})


def usable_cores() -> int:
    """Cores this process may use (CPU affinity where the platform has it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def _progress_bar(
    console: Any, enabled: bool, total: int, cached: int
) -> Iterator[Callable[[bool], None]]:
    """A rich progress bar over the runs to compute; yields ``tick(failed)``."""
    if not enabled:
        yield lambda failed: None
        return
    if total == 0:
        console.print(f"all {cached} runs answered from the cache", highlight=False)
        yield lambda failed: None
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    # No time-left estimate: runs differ in cost by orders of magnitude (a 50-disc flow
    # against a 5-disc one), so a rate from the runs done so far misleads by 10x.
    columns = (
        TextColumn("[bold]runs[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[failed]} failed, {task.fields[cached]} cached"),
        TimeElapsedColumn(),
        TextColumn("elapsed"),
    )
    with Progress(*columns, console=console, transient=False) as bar:
        task = bar.add_task("runs", total=total, failed=0, cached=cached)
        failures = 0

        def tick(failed: bool) -> None:
            nonlocal failures
            failures += failed
            bar.update(task, advance=1, failed=failures)

        yield tick


# --- the cache --------------------------------------------------------------------------------


def cache_key(spec: RunSpec) -> str:
    """SHA-256 (hex) of the run's inputs: experiment, parameters, seed, and the code and
    bundled scenarios that compute it (:func:`code_digest`)."""
    from cellplan import __version__

    text = _canonical(
        {
            "experiment": spec.experiment,
            "params": dict(spec.params),
            "seed": spec.seed,
            "cellplan": __version__,
            "code": code_digest(),
        }
    )
    return hashlib.sha256(text.encode()).hexdigest()


@functools.cache
def code_digest() -> str:
    """Digest of cellplan's source files and bundled scenarios.

    Part of every cache key, so that changing an algorithm or a scenario never
    serves a result computed by the old one.
    """
    root = Path(__file__).resolve().parent
    files = sorted(root.rglob("*.py")) + sorted((root / "bundled_scenarios").glob("*.yaml"))
    digest = hashlib.sha256()
    for path in files:
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _canonical(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)


class RunCache:
    """Finished runs on disk: ``<root>/<experiment>/<key[:2]>/<key>.json``.

    An entry is ``{"format", "key", "spec", "row", "checksum"}``, where the checksum
    is the SHA-256 of the canonical JSON of the other fields. :meth:`get` returns
    ``None`` for a missing entry and also for any entry it cannot trust (then
    :attr:`last_corrupt` says why), so the run is simply recomputed.
    """

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.last_corrupt = ""

    def path(self, key: str, experiment: str) -> Path:
        return self.root / experiment / key[:2] / f"{key}.json"

    def get(self, key: str, spec: RunSpec) -> dict[str, Scalar] | None:
        """The cached row of ``spec``, or ``None`` when absent or untrustworthy."""
        self.last_corrupt = ""
        path = self.path(key, spec.experiment)
        if not path.is_file():
            return None
        try:
            with path.open("rb") as f:
                data = f.read(MAX_ENTRY_BYTES + 1)
            if len(data) > MAX_ENTRY_BYTES:
                raise ValueError("larger than any entry the runner writes")
            entry = json.loads(data.decode("utf-8"))
            body = {k: entry[k] for k in ("format", "key", "spec", "row")}
            ok = (
                entry["checksum"] == _checksum(body)
                and body["format"] == CACHE_FORMAT
                and body["key"] == key
                and body["spec"] == _spec_json(spec)
                and isinstance(body["row"], dict)
                and body["row"].get("run_status") == OK
            )
        # RecursionError: nesting deeper than the parser's stack (200,000 ``[``); ValueError
        # also covers an integer of more than 4,300 digits and bytes that are not UTF-8.
        except (OSError, ValueError, KeyError, TypeError, RecursionError):
            ok = False
        if not ok:
            self.last_corrupt = f"cache entry {path} is corrupted or belongs to another run"
            return None
        return body["row"]

    def put(self, key: str, spec: RunSpec, row: Mapping[str, Scalar]) -> Path:
        """Store a finished row atomically."""
        body = {"format": CACHE_FORMAT, "key": key, "spec": _spec_json(spec), "row": dict(row)}
        entry = {**body, "checksum": _checksum(body)}
        # Durable: a finished run lost to a power cut would have to be computed again.
        return write_text(
            self.path(key, spec.experiment), json.dumps(entry, sort_keys=True) + "\n", durable=True
        )


def _spec_json(spec: RunSpec) -> dict[str, Any]:
    return json.loads(
        json.dumps({"experiment": spec.experiment, "params": dict(spec.params), "seed": spec.seed})
    )


def _checksum(body: Mapping[str, Any]) -> str:
    return hashlib.sha256(_canonical(body).encode()).hexdigest()


# --- outputs ----------------------------------------------------------------------------------


def columns_of(rows: Sequence[Mapping[str, Scalar]]) -> list[str]:
    """CSV columns: every key of every row, in order of first appearance."""
    seen: dict[str, None] = {}
    for row in rows:
        seen.update(dict.fromkeys(row))
    return list(seen)


def to_csv(rows: Sequence[Mapping[str, Scalar]]) -> str:
    """Rows as CSV text (missing values empty; floats as Python writes them, round-trippable)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns_of(rows), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def _write_outputs(result: ExperimentRun, metadata: Mapping[str, Any]) -> None:
    exp = result.experiment
    write_text(result.csv_path, to_csv(result.rows) if result.rows else "")
    meta = {
        "experiment": exp.name,
        "paper": exp.paper,
        "title": exp.title,
        "csv": result.csv_path.name,
        "runs_total": len(result.rows),
        "runs_failed": result.n_failed,
        "runs_cached": result.n_cached,
        "cache_entries_corrupted": result.n_recomputed_corrupt,
        "make_runs_error": result.error,
        "columns": columns_of(result.rows),
        **metadata,
    }
    write_json(result.meta_path, meta)


def run_metadata(
    command: str, scheduler: str, quick: bool, runs: int | Mapping[str, int]
) -> dict[str, Any]:
    """Versions, machine and command line, recorded beside every CSV."""
    import importlib.metadata as md

    versions = {"python": platform.python_version()}
    for dist in (
        "cellplan",
        "numpy",
        "scipy",
        "numba",
        "shapely",
        "matplotlib",
        "networkx",
        "ompl",
        "dask",
        "distributed",
    ):
        try:
            versions[dist] = md.version(dist)
        except md.PackageNotFoundError:
            versions[dist] = "not installed"
    return {
        "command": command,
        "quick": quick,
        "runs_per_point": dict(runs) if isinstance(runs, Mapping) else runs,
        "scheduler": scheduler,
        "versions": versions,
        "machine": {
            "platform": platform.platform(),
            "machine": platform.machine(),
            "processor": platform.processor(),
            "cores": usable_cores(),
            "hostname": platform.node(),
        },
        "finished": datetime.now(UTC).isoformat(timespec="seconds"),
    }


# --- small helpers ----------------------------------------------------------------------------


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def _describe(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def _describe_with_place(exc: BaseException) -> str:
    """The error and the innermost frame that raised it (file:line), on one line."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(frames[-1].filename).name}:{frames[-1].lineno})" if frames else ""
    return _describe(exc) + where


def is_finite_number(value: Any) -> bool:
    """True for ints and finite floats (not bools): what a numeric table cell may hold."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)

"""The sweep runner: rows, CSV and metadata, failures, cache, resume, serial vs Dask."""

from __future__ import annotations

import csv
import json
import socket
import subprocess
import sys
import time
import types
from dataclasses import replace
from pathlib import Path

import cloudpickle
import pytest
from hypothesis import given
from hypothesis import strategies as st

import fake_sweep_experiments as fake
from cellplan import experiments as ex
from cellplan.core import Experiment, RunSpec
from cellplan.errors import ArgumentError

FULL = 6 * 2  # runs of fake.grid with runs=2 and quick=False: 3 sizes x 2 shapes x 2 seeds


def sweep(exps, outdir, runs=2, **kw):
    kw.setdefault("serial", True)
    return ex.run_sweep(exps, runs, False, outdir, progress=False, **kw)


def counting(exp: Experiment, calls: list[RunSpec], stop_after: int | None = None, error=None):
    """``exp`` with a run that records its calls and raises ``error`` after ``stop_after`` runs."""

    def run(spec):
        if stop_after is not None and len(calls) == stop_after:
            raise error
        calls.append(spec)
        return fake.grid_run(spec)

    return replace(exp, run=run)


def without_wall(rows):
    return [{k: v for k, v in row.items() if k != "run_wall_s"} for row in rows]


def test_serial_sweep_writes_one_tidy_row_per_run(tmp_path):
    result = sweep([fake.grid()], tmp_path)
    (run,) = result.runs
    assert len(run.rows) == FULL
    assert run.param_names == ["n", "shape"]
    assert [(r["n"], r["shape"], r["seed"]) for r in run.rows] == [
        (s.params["n"], s.params["shape"], s.seed) for s in fake.grid_runs("fake.grid", 2, False)
    ]
    ok = run.ok_rows[0]
    assert ok["run_status"] == "ok" and ok["run_error"] == ""
    assert ok["area"] == pytest.approx(3.141592653589793)
    assert isinstance(ok["np_value"], float) and isinstance(ok["big"], bool)

    with run.csv_path.open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == FULL
    assert list(table[0])[:5] == ["n", "shape", "seed", "run_status", "run_error"]
    # floats survive the CSV exactly
    assert [float(r["noise"]) for r in table if r["noise"]] == [r["noise"] for r in run.ok_rows]

    meta = json.loads(run.meta_path.read_text())
    assert meta["experiment"] == "fake.grid" and meta["runs_total"] == FULL
    assert meta["runs_failed"] == 2 and meta["scheduler"].startswith("serial")
    assert {"cellplan", "numpy", "dask", "python"} <= set(meta["versions"])
    assert meta["machine"]["cores"] >= 1 and meta["command"]


def test_failing_run_is_recorded_and_retried_next_time(tmp_path):
    result = sweep([fake.grid()], tmp_path)
    failed = [r for r in result.runs[0].rows if r["run_status"] == "failed"]
    assert [(r["n"], r["seed"]) for r in failed] == [(3, 1), (3, 1)]
    assert all("ValueError: n=3 seed=1 is the broken case" in r["run_error"] for r in failed)
    assert all("area" not in r for r in failed)
    assert result.runs[0].n_failed == 2

    calls: list[RunSpec] = []
    again = sweep([counting(fake.grid(), calls)], tmp_path)
    # failures are not cached: only the two failed runs are tried again
    assert [(c.params["n"], c.seed) for c in calls] == [(3, 1), (3, 1)]
    assert again.runs[0].n_cached == FULL - 2
    assert without_wall(again.runs[0].rows) == without_wall(result.runs[0].rows)


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt(), SystemExit(1)])
def test_interrupted_sweep_resumes_with_only_the_missing_runs(tmp_path, interrupt):
    first: list[RunSpec] = []
    with pytest.raises(type(interrupt)):
        sweep([counting(fake.grid(), first, stop_after=5, error=interrupt)], tmp_path)
    assert len(first) == 5

    second: list[RunSpec] = []
    resumed = sweep([counting(fake.grid(), second)], tmp_path)
    all_specs = fake.grid_runs("fake.grid", 2, False)
    assert second == all_specs[5:]  # the five finished runs came from the cache
    assert resumed.runs[0].n_cached == 5

    reference = sweep([fake.grid()], tmp_path / "fresh")
    assert without_wall(resumed.runs[0].rows) == without_wall(reference.runs[0].rows)


def test_corrupted_cache_entries_are_detected_and_recomputed(tmp_path):
    from rich.console import Console

    original = sweep([fake.grid()], tmp_path)
    entries = sorted((tmp_path / "cache" / "fake.grid").rglob("*.json"))
    assert len(entries) == FULL - 2  # failures are not cached

    # 1: a value changed but the checksum kept; 2: truncated; 3: another run's entry copied in
    tampered = json.loads(entries[0].read_text())
    tampered["row"]["area"] = 99.0
    entries[0].write_text(json.dumps(tampered))
    entries[1].write_text(entries[1].read_text()[:40])
    entries[2].write_text(entries[3].read_text())

    calls: list[RunSpec] = []
    console = Console(file=(log := __import__("io").StringIO()), width=200)
    again = sweep([counting(fake.grid(), calls)], tmp_path, console=console)
    assert len(calls) == 3 + 2  # the three bad entries and the two failures
    assert again.runs[0].n_recomputed_corrupt == 3
    assert log.getvalue().count("recomputing") == 3
    assert without_wall(again.runs[0].rows) == without_wall(original.runs[0].rows)
    # the entries were rewritten and are trusted again
    calls.clear()
    sweep([counting(fake.grid(), calls)], tmp_path)
    assert len(calls) == 2


def test_fresh_sweep_ignores_the_cache(tmp_path):
    sweep([fake.grid()], tmp_path)
    calls: list[RunSpec] = []
    sweep([counting(fake.grid(), calls)], tmp_path, use_cache=False)
    assert len(calls) == FULL


def test_serial_and_parallel_sweeps_give_identical_rows(tmp_path):
    # Worker processes cannot import this test folder: send the fake functions by value.
    cloudpickle.register_pickle_by_value(fake)
    try:
        exps = [fake.grid("fake.one"), fake.grid("fake.two", paper="strategies")]
        serial = sweep(exps, tmp_path / "serial", runs=6)
        parallel = sweep(exps, tmp_path / "parallel", runs=6, serial=False, workers=2)
    finally:
        cloudpickle.unregister_pickle_by_value(fake)
    assert "LocalCluster, 2 worker" in parallel.scheduler
    for s, p in zip(serial.runs, parallel.runs, strict=True):
        assert len(s.rows) == 36  # 72 runs on 2 workers: sent two per task
        assert without_wall(s.rows) == without_wall(p.rows)
        assert s.n_failed == p.n_failed == 2
        assert s.csv_path.read_text().count("\n") == p.csv_path.read_text().count("\n")


def test_an_existing_cluster_is_used_and_left_running(tmp_path):
    from distributed import Client, LocalCluster

    with LocalCluster(
        n_workers=1,
        threads_per_worker=2,
        processes=False,
        protocol="tcp://",
        dashboard_address=None,
    ) as cluster:
        address = cluster.scheduler_address
        result = sweep([fake.grid()], tmp_path, serial=False, scheduler=address)
        assert result.scheduler == f"dask scheduler {address} (1 workers)"
        assert without_wall(result.runs[0].rows) == without_wall(
            sweep([fake.grid()], tmp_path / "serial").runs[0].rows
        )
        with Client(address) as client:  # still there, same size, nothing left on it
            assert len(client.scheduler_info()["workers"]) == 1
            # our futures are released asynchronously once our client has closed
            deadline = time.monotonic() + 10
            while client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)):
                assert time.monotonic() < deadline, "tasks left on the scheduler"
                time.sleep(0.05)


def test_time_budget_skips_the_rest_serially(tmp_path):
    result = sweep([fake.sleepy(sleep=0.03)], tmp_path, runs=20, time_budget_s=0.12)
    statuses = [r["run_status"] for r in result.runs[0].rows]
    done = statuses.count("ok")
    assert 1 <= done < 20 and statuses == ["ok"] * done + ["skipped"] * (20 - done)
    assert "time budget of 0.12 s" in str(result.runs[0].rows[-1]["run_error"])
    again = sweep([fake.sleepy(sleep=0.03)], tmp_path, runs=20)  # skipped runs are not cached
    assert again.runs[0].n_cached == done
    assert [r["run_status"] for r in again.runs[0].rows] == ["ok"] * 20


def test_time_budget_on_a_cluster(tmp_path):
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=False,
        protocol="tcp://",
        dashboard_address=None,
    ) as cluster:
        result = sweep(
            [fake.sleepy(sleep=0.2)],
            tmp_path,
            runs=12,
            serial=False,
            scheduler=cluster.scheduler_address,
            time_budget_s=0.7,
        )
    statuses = [r["run_status"] for r in result.runs[0].rows]
    assert 1 <= statuses.count("ok") <= 5 and statuses.count("skipped") >= 7
    assert set(statuses) == {"ok", "skipped"}


def test_batch_size_amortises_cheap_runs_and_balances_expensive_ones():
    assert ex.batch_size(10, 2) == 1
    assert ex.batch_size(72, 2) == 2
    assert ex.batch_size(100_000, 2) == ex.MAX_BATCH
    assert ex.batch_size(100_000, 10_000) == 1
    assert ex.batch_size(5, 0) == 1


def test_bad_arguments_are_refused_before_any_work(tmp_path):
    exp = fake.grid()
    for runs in (0, -1, True, 2.0):
        with pytest.raises(ArgumentError) as info:
            sweep([exp], tmp_path, runs=runs)
        assert info.value.problems[0].field == "--runs"
    with pytest.raises(ArgumentError, match="twice"):
        sweep([exp, exp], tmp_path)
    with pytest.raises(ArgumentError, match=r"<paper>\.<name>"):
        sweep([fake.grid("no dots here")], tmp_path)
    for address in (
        "localhost:8786",
        "tcp://host",
        "http://h:1",
        "tcp://h:0",
        "tcp://h:70000",
        "tls://h:8786",
        "ucx://h:8786",
    ):
        with pytest.raises(ArgumentError) as info:
            sweep([exp], tmp_path, scheduler=address)
        assert info.value.problems[0].field == "--scheduler"
    assert not (tmp_path / "data").exists()


def test_unreachable_scheduler_is_an_argument_error(tmp_path, monkeypatch):
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ArgumentError) as info:
        sweep([fake.grid()], tmp_path, serial=False, scheduler=f"tcp://127.0.0.1:{port}")
    assert info.value.problems[0].field == "--scheduler"


@pytest.mark.parametrize(
    ("output", "message"),
    [
        ({"x": [1, 2]}, "not a scalar"),
        ([1, 2], "not a mapping"),
        ({"run_status": "mine"}, "reserved"),
        ({"n": 7}, "with parameter n="),
        ({"seed": 99}, "seed=99"),
    ],
)
def test_malformed_run_outputs_become_failed_rows(tmp_path, output, message):
    exp = replace(fake.grid(), run=lambda spec: output)
    rows = sweep([exp], tmp_path, runs=1).runs[0].rows
    assert all(r["run_status"] == "failed" and message in r["run_error"] for r in rows)


def test_a_broken_make_runs_does_not_stop_the_others(tmp_path):
    def broken(runs, quick):
        raise RuntimeError("no runs today")

    bad = replace(fake.grid("fake.bad"), make_runs=broken)
    wrong = replace(fake.grid("fake.wrong"), make_runs=lambda r, q: fake.grid_runs("fake.x", r, q))
    result = sweep([bad, wrong, fake.grid()], tmp_path)
    assert "RuntimeError: no runs today" in result.runs[0].error
    assert "names experiment 'fake.x'" in result.runs[1].error
    assert result.runs[0].rows == [] and len(result.runs[2].rows) == FULL
    assert json.loads(result.runs[0].meta_path.read_text())["make_runs_error"]


@given(
    params=st.dictionaries(st.text("abcxyz", min_size=1, max_size=4), st.integers(), max_size=4),
    seed=st.integers(0, 2**31),
)
def test_cache_key_depends_on_content_not_parameter_order(params, seed):
    spec = RunSpec("p.e", params, seed)
    shuffled = RunSpec("p.e", dict(reversed(list(params.items()))), seed)
    assert ex.cache_key(spec) == ex.cache_key(shuffled)
    assert ex.cache_key(spec) != ex.cache_key(RunSpec("p.e", params, seed + 1))
    assert ex.cache_key(spec) != ex.cache_key(RunSpec("p.f", params, seed))
    assert ex.cache_key(spec) != ex.cache_key(RunSpec("p.e", {**params, "new": 1}, seed))


def test_cache_key_includes_the_cellplan_version(monkeypatch):
    import cellplan

    spec = RunSpec("p.e", {"a": 1}, 0)
    before = ex.cache_key(spec)
    monkeypatch.setattr(cellplan, "__version__", "9.9.9")
    assert ex.cache_key(spec) != before


def _fake_package(monkeypatch, tmp_path, name: str, source: str | None) -> str:
    """Register ``cellplan.<name>`` as a package living in ``tmp_path/<name>``."""
    folder = tmp_path / name
    folder.mkdir()
    if source is not None:
        (folder / "experiments.py").write_text(source)
    package = types.ModuleType(f"cellplan.{name}")
    package.__path__ = [str(folder)]
    monkeypatch.setitem(sys.modules, f"cellplan.{name}", package)
    monkeypatch.delitem(sys.modules, f"cellplan.{name}.experiments", raising=False)
    return name


def test_discover_reports_missing_broken_and_present_modules(tmp_path, monkeypatch):
    missing = _fake_package(monkeypatch, tmp_path, "fk_missing", None)
    broken = _fake_package(monkeypatch, tmp_path, "fk_broken", "raise RuntimeError('oops')\n")
    bad_import = _fake_package(monkeypatch, tmp_path, "fk_badimport", "import no_such_mod_xyz\n")
    empty = _fake_package(monkeypatch, tmp_path, "fk_empty", "EXPERIMENTS = []\n")
    fine = _fake_package(
        monkeypatch,
        tmp_path,
        "fk_fine",
        "import fake_sweep_experiments as f\nEXPERIMENTS = [f.grid('fk_fine.grid')]\n",
    )
    try:
        names = [missing, broken, bad_import, empty, fine]
        modules = {name: f"cellplan.{name}.experiments" for name in names}
        found = {f.paper: f for f in ex.discover(modules)}
    finally:
        for name in (broken, bad_import, empty, fine):
            sys.modules.pop(f"cellplan.{name}.experiments", None)
    assert found[missing].note == "no experiments yet" and not found[missing].experiments
    assert "RuntimeError: oops" in found[broken].note
    assert "no_such_mod_xyz" in found[bad_import].note
    assert found[empty].note == "no experiments yet"
    assert found[fine].note == "" and [e.name for e in found[fine].experiments] == ["fk_fine.grid"]


def test_csv_of_rows_with_different_columns(tmp_path):
    text = ex.to_csv([{"a": 1, "b": 0.1}, {"a": 2, "c": "x,y"}])
    rows = list(csv.DictReader(text.splitlines()))
    assert rows == [{"a": "1", "b": "0.1", "c": ""}, {"a": "2", "b": "", "c": "x,y"}]
    assert Path(ex.__file__).name == "experiments.py"


def test_importing_the_runner_does_not_import_dask():
    code = "import sys, cellplan.experiments, cellplan.report, cellplan.demo;"
    code += "import cellplan.reproduce_cli;"
    code += "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"

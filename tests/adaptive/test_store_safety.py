"""The experience database under concurrency, kills and damage (issue 16).

One writer at a time (a second process gets "in use by process N", exit 2; a lock
never outlives its process), creation that a kill cannot leave half-made, and
damaged or tampered files refused with one line before anything is written.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st
from hypothesis.control import currently_in_test_context

from cellplan.adaptive.runner import run_adaptive
from cellplan.adaptive.store import ExperienceStore
from cellplan.errors import CellplanError, PersistenceError
from cellplan.scenario import Scenario, loads_scenario

HERE = Path(__file__).parent
EXAMPLES = settings(
    max_examples=int(os.environ.get("CELLPLAN_DB_EXAMPLES", "15")),
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def _cellplan(*args: str, **kw: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cellplan.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
        **kw,
    )


def _comparable(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]


@pytest.fixture(scope="module")
def sc() -> Scenario:
    return loads_scenario(POINT_SCENARIO)


@pytest.fixture(scope="module")
def reference(sc: Scenario) -> list[dict[str, Any]]:
    """The task rows of an uninterrupted run without a database."""
    return _comparable(run_adaptive(sc).rows)


@pytest.fixture
def scenario_file(tmp_path: Path) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(POINT_SCENARIO, encoding="utf-8")
    return path


@pytest.fixture
def holder(tmp_path: Path, scenario_file: Path) -> Iterator[tuple[subprocess.Popen[str], Path]]:
    """A process that holds a new database open until the test kills it."""
    db = tmp_path / "exp.sqlite"
    proc = subprocess.Popen(
        [sys.executable, str(HERE / "db_child.py"), "hold", str(db), str(scenario_file)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        yield proc, db
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


# --- one writer ----------------------------------------------------------------------------


def test_a_second_process_gets_the_in_use_line_and_the_lock_dies_with_its_holder(
    holder: tuple[subprocess.Popen[str], Path], scenario_file: Path, tmp_path: Path
) -> None:
    proc, db = holder
    out = tmp_path / "out"
    second = _cellplan("adapt", str(scenario_file), "--db", str(db), "-o", str(out))
    assert second.returncode == 2, second.stderr
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 1 and f"in use by process {proc.pid}" in lines[0], second.stderr
    assert not out.exists()  # refused before any work
    sc = loads_scenario(POINT_SCENARIO)
    with pytest.raises(PersistenceError, match=f"in use by process {proc.pid}"):
        ExperienceStore(db, sc)
    proc.send_signal(signal.SIGKILL)  # the kernel drops the lock with the process
    proc.wait()
    third = _cellplan("adapt", str(scenario_file), "--db", str(db), "-o", str(out))
    assert third.returncode == 0, third.stderr
    assert not Path(f"{db}.lock").exists()  # removed on close


def test_two_runs_started_at_once_never_interleave(
    scenario_file: Path, tmp_path: Path, sc: Scenario, reference: list[dict[str, Any]]
) -> None:
    db = tmp_path / "exp.sqlite"
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "cellplan.cli",
                "adapt",
                str(scenario_file),
                "--db",
                str(db),
                "-o",
                str(tmp_path / f"out{i}"),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]  # type: ignore[union-attr]
    codes = sorted(code for code, _ in results)
    # Either one ran while the other was refused, or they did not overlap at all (the
    # second then found every task done). Never two writers.
    assert codes in ([0, 2], [0, 0]), results
    for code, err in results:
        if code == 2:
            assert len(err.strip().splitlines()) == 1 and "in use by process" in err, err
    with ExperienceStore(db, sc) as store:
        assert _comparable(store.task_rows()) == reference


# --- creation ------------------------------------------------------------------------------


@pytest.mark.parametrize("step", ["begun", "written", "synced", "renamed"])
def test_a_kill_during_creation_leaves_no_half_made_database(
    step: str, scenario_file: Path, tmp_path: Path, sc: Scenario, reference: list[dict[str, Any]]
) -> None:
    db = tmp_path / "exp.sqlite"
    proc = subprocess.run(
        [
            sys.executable,
            str(HERE / "db_child.py"),
            "kill-create",
            str(db),
            str(scenario_file),
            step,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert db.exists() == (step == "renamed")  # before the rename, nothing at the path
    with ExperienceStore(db, sc) as store:
        assert _comparable(run_adaptive(sc, store=store).rows) == reference
    assert not any(p.name.endswith(".creating") for p in tmp_path.iterdir())


def test_an_empty_or_header_only_file_is_created_afresh(sc: Scenario, tmp_path: Path) -> None:
    # What an older cellplan killed during creation left: an SQLite header, no schema.
    half = tmp_path / "half.sqlite"
    conn = sqlite3.connect(half)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.close()
    empty = tmp_path / "empty.sqlite"
    empty.touch()
    for db in (half, empty):
        with ExperienceStore(db, sc) as store:
            run_adaptive(sc, tasks=2, store=store)
        with ExperienceStore(db, sc) as store:
            assert store.state()["tasks_done"] == 2  # type: ignore[index]


def test_stale_journal_files_of_a_deleted_database_are_not_replayed(
    sc: Scenario, tmp_path: Path
) -> None:
    db = tmp_path / "exp.sqlite"
    with ExperienceStore(db, sc) as store:
        run_adaptive(sc, tasks=2, store=store)
    wal = Path(f"{db}-wal")
    wal.write_bytes(b"\x37\x7f\x06\x82" + b"\x00" * 60)  # a stale log left beside the path
    db.unlink()
    with ExperienceStore(db, sc) as store:
        assert store.state() is None and not store.task_rows()


# --- types of a continued run --------------------------------------------------------------


def test_a_continued_run_has_the_types_of_a_fresh_one(sc: Scenario, tmp_path: Path) -> None:
    fresh = run_adaptive(sc).rows
    db = tmp_path / "exp.sqlite"
    with ExperienceStore(db, sc) as store:
        run_adaptive(sc, tasks=3, store=store)
    with ExperienceStore(db, sc) as store:
        continued = run_adaptive(sc, store=store).rows
    assert [{k: type(v) for k, v in r.items()} for r in continued] == [
        {k: type(v) for k, v in r.items()} for r in fresh
    ]
    assert _comparable(continued) == _comparable(fresh)


# slow: 21 s; test_adaptive_cli.py continues a CLI run from its store (the same code)
@pytest.mark.slow
def test_a_continued_cli_run_writes_the_same_tasks_csv(scenario_file: Path, tmp_path: Path) -> None:
    db = tmp_path / "exp.sqlite"
    first = _cellplan(
        "adapt", str(scenario_file), "--tasks", "3", "--db", str(db), "-o", str(tmp_path / "a")
    )
    rest = _cellplan("adapt", str(scenario_file), "--db", str(db), "-o", str(tmp_path / "b"))
    fresh = _cellplan("adapt", str(scenario_file), "-o", str(tmp_path / "c"))
    assert first.returncode == rest.returncode == fresh.returncode == 0, rest.stderr

    def table(folder: str) -> list[list[str]]:
        lines = (tmp_path / folder / "tasks.csv").read_text(encoding="utf-8").splitlines()
        header = lines[0].split(",")
        drop = header.index("seconds")
        return [[c for i, c in enumerate(line.split(",")) if i != drop] for line in lines]

    assert table("b") == table("c")
    assert "1.0" not in (tmp_path / "b" / "tasks.csv").read_text(encoding="utf-8")


# --- damage and tampering ------------------------------------------------------------------


class Blob(bytes):
    """Bytes with a short repr (hypothesis prints the arguments of a failing case)."""

    def __repr__(self) -> str:
        return f"<{len(self)} bytes>"


@pytest.fixture(scope="module")
def good_db(sc: Scenario, tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The bytes of a database after three tasks (closed: the log is in the file)."""
    db = tmp_path_factory.mktemp("good") / "exp.sqlite"
    with ExperienceStore(db, sc) as store:
        run_adaptive(sc, tasks=3, store=store, baseline=False)
    assert not Path(f"{db}-wal").exists()
    return Blob(db.read_bytes())


def _open_and_continue(db: Path, sc: Scenario) -> str:
    """Open and run one more task: "ran", or "refused" with exactly one one-line problem."""
    try:
        with ExperienceStore(db, sc) as store:
            run_adaptive(sc, tasks=4, store=store, baseline=False)
    except CellplanError as exc:
        assert len(exc.problems) == 1 and "\n" not in str(exc), str(exc)
        _count("refused")
        return "refused"
    _count("ran")
    return "ran"


def _count(outcome: str) -> None:
    """Count the outcome in hypothesis' statistics (``--hypothesis-show-statistics``)."""
    if currently_in_test_context():
        event(outcome)


def _fresh_copy(tmp_path: Path, data: bytes) -> Path:
    folder = tmp_path / "case"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    db = folder / "exp.sqlite"
    db.write_bytes(data)
    return db


@EXAMPLES
@given(
    flips=st.lists(st.tuples(st.integers(0, 2**31), st.integers(1, 255)), min_size=1, max_size=4)
)
def test_flipped_bytes_are_refused_in_one_line_or_harmless(
    flips: list[tuple[int, int]], good_db: bytes, sc: Scenario, tmp_path: Path
) -> None:
    data = bytearray(good_db)
    for pos, mask in flips:
        data[pos % len(data)] ^= mask
    _open_and_continue(_fresh_copy(tmp_path, bytes(data)), sc)


@EXAMPLES
@given(size=st.integers(1, 2**31))
def test_truncated_files_are_refused_and_left_alone(
    size: int, good_db: bytes, sc: Scenario, tmp_path: Path
) -> None:
    data = good_db[: size % len(good_db)] or good_db[:1]
    db = _fresh_copy(tmp_path, data)
    assert _open_and_continue(db, sc) == "refused"
    assert db.read_bytes() == data  # never written into


_VALUES = st.one_of(
    st.none(),
    st.integers(-(2**63), 2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.binary(max_size=8),
    st.sampled_from(["[]", "[1e999]", "{}", "[1, 2]", "free", "blocked", "-1", "1e30", "null"]),
)
_COLUMNS = {
    "meta": ["value"],
    "vertices": ["id", "object", "rx", "ry", "rphi", "branch", "q"],
    "edges": ["a", "b", "status", "gen"],
    "goal_links": ["vertex", "goal", "ok", "gen"],
    "tasks": ["task", "goal", "success", "adapt", "seconds", "note"],
}
_STRUCTURE = [
    "DROP TABLE edges",
    "DROP TABLE meta",
    "ALTER TABLE vertices DROP COLUMN q",
    "ALTER TABLE vertices ADD COLUMN extra REAL",
    "ALTER TABLE tasks RENAME COLUMN note TO notes",
    "CREATE TRIGGER t AFTER INSERT ON tasks BEGIN SELECT RAISE(ABORT, 'no'); END",
    "CREATE VIEW v AS SELECT 1",
    "DELETE FROM vertices",
    "DELETE FROM tasks WHERE task = 2",
    "DELETE FROM meta WHERE key = 'state'",
    "DELETE FROM meta WHERE key = 'format'",
    "DELETE FROM meta WHERE key = 'robot_signature'",
    "UPDATE meta SET value = '2' WHERE key = 'schema_version'",
    "UPDATE meta SET value = 'x' WHERE key = 'format'",
    "INSERT INTO edges VALUES (999, 1000, 'free', 0)",
    "INSERT INTO tasks (task, goal) VALUES (9, 'g1')",
    "INSERT INTO meta VALUES ('planner', '{}')",
    # well-formed edits: only the content digest sees them
    "UPDATE vertices SET rx = rx + 0.1 WHERE id = (SELECT min(id) FROM vertices)",
    "UPDATE tasks SET seconds = seconds + 1 WHERE task = 1",
    "UPDATE edges SET status = 'blocked' WHERE rowid = (SELECT min(rowid) FROM edges)",
]


@EXAMPLES
@given(
    table=st.sampled_from(sorted(_COLUMNS)),
    data=st.data(),
    value=_VALUES,
    all_rows=st.booleans(),
)
def test_tampered_values_are_refused_in_one_line_or_harmless(
    table: str,
    data: st.DataObject,
    value: Any,
    all_rows: bool,
    good_db: bytes,
    sc: Scenario,
    tmp_path: Path,
) -> None:
    db = _fresh_copy(tmp_path, good_db)
    column = data.draw(st.sampled_from(_COLUMNS[table]))
    where = "" if all_rows else f" WHERE rowid = (SELECT min(rowid) FROM {table})"
    conn = sqlite3.connect(db)
    try:
        conn.execute(f"UPDATE {table} SET {column} = ?{where}", (value,))
        conn.commit()
    except sqlite3.IntegrityError:
        assume(False)  # SQLite itself refused the change
    finally:
        conn.close()
    _open_and_continue(db, sc)


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=3)
    ),
    max_leaves=6,
)


@EXAMPLES
@given(data=st.data(), value=_JSON, delete=st.booleans())
def test_tampered_run_state_is_refused_in_one_line_or_harmless(
    data: st.DataObject, value: Any, delete: bool, good_db: bytes, sc: Scenario, tmp_path: Path
) -> None:
    db = _fresh_copy(tmp_path, good_db)
    conn = sqlite3.connect(db)
    state = json.loads(conn.execute("SELECT value FROM meta WHERE key = 'state'").fetchone()[0])
    key = data.draw(st.sampled_from(sorted(state)))
    if delete:
        del state[key]
    else:
        state[key] = value
    conn.execute("UPDATE meta SET value = ? WHERE key = 'state'", (json.dumps(state),))
    conn.commit()
    conn.close()
    _open_and_continue(db, sc)


@pytest.mark.parametrize("statement", _STRUCTURE)
def test_structural_tampering_is_refused_in_one_line(
    statement: str, good_db: bytes, sc: Scenario, tmp_path: Path
) -> None:
    db = _fresh_copy(tmp_path, good_db)
    conn = sqlite3.connect(db)
    conn.execute(statement)
    conn.commit()
    conn.close()
    assert _open_and_continue(db, sc) == "refused"


def test_a_truncated_file_on_the_command_line_is_one_line_exit_2(
    good_db: bytes, scenario_file: Path, tmp_path: Path
) -> None:
    db = tmp_path / "exp.sqlite"
    db.write_bytes(good_db[: len(good_db) // 2])
    res = _cellplan("adapt", str(scenario_file), "--db", str(db), "-o", str(tmp_path / "o"))
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "Traceback" not in res.stderr and str(db) in res.stderr
    assert db.read_bytes() == good_db[: len(good_db) // 2]


@pytest.fixture(scope="module")
def planner_db(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """A database an ExperiencePlanner session wrote: two queries and an added object."""
    from cellplan.adaptive import ExperiencePlanner

    db = tmp_path_factory.mktemp("planner") / "exp.sqlite"
    with ExperiencePlanner(loads_scenario(POINT_SCENARIO), db=db) as ep:
        assert ep.plan(None, "g1").success
        ep.add("lid", {"type": "box", "min": [3.0, 7.05], "max": [7.0, 9.0]})
        assert ep.plan(None, "home").success
    return Blob(db.read_bytes())


@EXAMPLES
@given(data=st.data(), value=_JSON, delete=st.booleans())
def test_tampered_planner_state_is_refused_in_one_line_or_harmless(
    data: st.DataObject, value: Any, delete: bool, planner_db: bytes, tmp_path: Path
) -> None:
    from cellplan.adaptive import ExperiencePlanner

    db = _fresh_copy(tmp_path, planner_db)
    conn = sqlite3.connect(db)
    state = json.loads(conn.execute("SELECT value FROM meta WHERE key = 'planner'").fetchone()[0])
    path = [data.draw(st.sampled_from(sorted(state)))]
    inner = state[path[0]]
    if isinstance(inner, dict) and inner and data.draw(st.booleans()):
        path.append(data.draw(st.sampled_from(sorted(inner))))  # e.g. objects.lid, goals.g1
    target = state
    for key in path[:-1]:
        target = target[key]
    if delete:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    conn.execute("UPDATE meta SET value = ? WHERE key = 'planner'", (json.dumps(state),))
    conn.commit()
    conn.close()
    try:
        with ExperiencePlanner(loads_scenario(POINT_SCENARIO), db=db) as ep:
            ep.plan(None, "g1")
    except CellplanError as exc:
        assert len(exc.problems) == 1 and "\n" not in str(exc), str(exc)


@pytest.mark.slow
def test_random_kills_of_the_command_never_lose_or_change_work(
    scenario_file: Path, tmp_path: Path
) -> None:
    """``kill -9`` of ``cellplan adapt`` at random moments while it holds the database
    (creation included), until a run finishes: its tasks.csv equals an uninterrupted
    run's. ``CELLPLAN_KILL_TRIALS`` databases (default 4), delays up to
    ``CELLPLAN_KILL_MAX_S`` seconds (default 2) after the lock appears, at most 12 kills
    each. The fast tests above cover the same code (kill in task 4, kills at each
    creation step)."""
    import random
    import time

    rng = random.Random(16)
    trials = int(os.environ.get("CELLPLAN_KILL_TRIALS", "4"))
    max_s = float(os.environ.get("CELLPLAN_KILL_MAX_S", "2"))

    def table(folder: Path) -> list[list[str]]:
        lines = (folder / "tasks.csv").read_text(encoding="utf-8").splitlines()
        drop = lines[0].split(",").index("seconds")
        return [[c for i, c in enumerate(line.split(",")) if i != drop] for line in lines]

    base = [sys.executable, "-m", "cellplan.cli", "adapt", str(scenario_file)]
    assert subprocess.run([*base, "-o", str(tmp_path / "ref")], timeout=300).returncode == 0
    kills = 0
    for t in range(trials):
        db, out = tmp_path / f"t{t}.sqlite", tmp_path / f"o{t}"
        lock = Path(f"{db}.lock")
        for attempt in range(13):
            proc = subprocess.Popen(
                [*base, "--db", str(db), "-o", str(out)], stderr=subprocess.PIPE
            )
            while proc.poll() is None and not lock.exists():
                time.sleep(0.002)
            if attempt < 12 and proc.poll() is None:
                time.sleep(rng.uniform(0, max_s))
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate()
                    kills += 1
                    continue
            _, err = proc.communicate(timeout=300)
            assert proc.returncode == 0, err
            break
        assert table(out) == table(tmp_path / "ref")
    print(f"{trials} databases, {kills} kills while holding the database")


def test_a_header_sqlite_would_open_read_only_is_refused(
    good_db: bytes, sc: Scenario, tmp_path: Path
) -> None:
    data = bytearray(good_db)
    data[18] = 3  # write version 3: SQLite opens the file read-only
    db = _fresh_copy(tmp_path, bytes(data))
    with pytest.raises(PersistenceError, match="file-format versions"):
        ExperienceStore(db, sc)


def test_a_write_the_file_system_refuses_is_one_line(sc: Scenario, tmp_path: Path) -> None:
    db = tmp_path / "exp.sqlite"
    with ExperienceStore(db, sc) as store:
        run_adaptive(sc, tasks=1, store=store, baseline=False)
        store._conn().execute("PRAGMA query_only = ON")  # as if the disk refused writes
        with pytest.raises(PersistenceError, match="cannot write the database"):
            run_adaptive(sc, tasks=2, store=store, baseline=False)
    with ExperienceStore(db, sc) as store:
        assert store.state()["tasks_done"] == 1  # type: ignore[index]


def test_text_that_is_not_utf8_is_refused(good_db: bytes, sc: Scenario, tmp_path: Path) -> None:
    data = bytearray(good_db)
    data[good_db.index(b"CREATE TABLE vertices") + 3] ^= 0x80  # inside SQLite's schema text
    assert _open_and_continue(_fresh_copy(tmp_path, bytes(data)), sc) == "refused"
    db = _fresh_copy(tmp_path, good_db)
    conn = sqlite3.connect(db)
    conn.execute("UPDATE meta SET value = CAST(x'c5ff' AS TEXT) WHERE key = 'state'")
    conn.commit()
    conn.close()
    assert _open_and_continue(db, sc) == "refused"

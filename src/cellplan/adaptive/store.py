"""The experience database: G and the run state in SQLite (standard library, WAL journal).

Tables
------
``meta(key, value)``
    ``format`` (``cellplan-adaptive``), ``schema_version``, ``robot_signature``,
    ``scenario_signature``, the environment ``generation``, ``tasks_done`` and
    the rest of the run state (robot position, pointers, seed, repair strategy).
``vertices(id, object, rx, ry, rphi, branch, q)``
    Subgoals: attached object (NULL for the world), tool pose relative to it,
    IK branch, and the configuration (JSON list).
``edges(a, b, status, gen)``
    ``status`` in unknown / free / blocked and the generation last checked in.
``tasks(task, goal, success, ...)``
    One row of costs per task (for the CSV and continued runs).

What a database is keyed on
---------------------------
A database belongs to one problem: ``robot_signature`` (the robot's spec) and
``scenario_signature`` (workcell, robot, and the ``adaptive:`` section without the
task list and the repair strategy). An :class:`~.experience.ExperiencePlanner` built
on a bare :class:`~cellplan.workcell.Workcell` keys it on the workcell's own numbers
instead (:func:`workcell_signatures`). Two kinds of state live in ``meta``:

* ``state``: a scenario run (``cellplan adapt``, the ``adaptive`` planner): tasks done,
  robot position, pointers, seed and repair strategy. A continued run replays the
  scenario's scheduled changes up to ``tasks_done``.
* ``planner``: an :class:`~.experience.ExperiencePlanner` session: the same pointers,
  plus the objects of the changed world (shapes and poses) and the named goals, because
  its changes (``add``, ``remove``, ``move``) are not in any file. A planner can open a
  run's database (it continues from the graph and world after the last task); a run
  refuses a database a planner has written to.

Every task is committed in one transaction (:meth:`ExperienceStore.commit_task`),
so a process killed mid-task leaves the database exactly as after the previous
task. Each commit also stores ``meta.digest``, a SHA-256 of every stored row
(:func:`content_digest`).

Opening (see :class:`ExperienceStore`) takes the one-writer lock
(:class:`DatabaseLock`), creates a new database whole (:func:`create_database`),
and checks an existing one before writing anything (:func:`check_database`:
integrity, schema, format, digest, every value); it refuses a file made for another
robot or scenario, a damaged one, or one that is not an experience database, with a
:class:`~cellplan.errors.PersistenceError` of one line.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import functools
import hashlib
import json
import math
import os
import sqlite3
import stat
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cellplan.adaptive.graph import EDGE_STATUSES, ExperienceGraph
from cellplan.errors import PersistenceError, Problem
from cellplan.fileio import atomic_path, fsync_path, kind_of, name_max
from cellplan.geometry import ShapeSet
from cellplan.scenario import Scenario
from cellplan.workcell import Workcell

FORMAT = "cellplan-adaptive"
SCHEMA_VERSION = 1
TASK_COLUMNS = (
    "goal",
    "success",
    "solve_calls",
    "reach",
    "trace",
    "solve",
    "abstract",
    "cut",
    "repair",
    "adapt",
    "baseline",
    "seconds",
    "vertices",
    "edges",
    "path_ok",
    "generation",
    "s_fallbacks",
    "note",
)
_TEXT_COLUMNS = {"goal", "note"}
#: Task columns a run writes as whole numbers (counts, flags); stored as REAL.
_INTEGER_TASK_COLUMNS = frozenset({"task", *TASK_COLUMNS} - _TEXT_COLUMNS - {"seconds"})
#: Task columns added after schema version 1 first shipped; an older file gains them
#: (empty) when it is opened, so its rows read like new ones.
_ADDED_COLUMNS = {"s_fallbacks": "REAL DEFAULT 0", "note": "TEXT DEFAULT ''"}

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS vertices (
    id INTEGER PRIMARY KEY, object TEXT, rx REAL NOT NULL, ry REAL NOT NULL, rphi REAL NOT NULL,
    branch INTEGER, q TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS edges (
    a INTEGER NOT NULL, b INTEGER NOT NULL,
    status TEXT NOT NULL CHECK (status IN ({", ".join(repr(s) for s in EDGE_STATUSES)})),
    gen INTEGER NOT NULL, PRIMARY KEY (a, b));
CREATE TABLE IF NOT EXISTS goal_links (
    vertex INTEGER NOT NULL, goal TEXT NOT NULL, ok INTEGER NOT NULL, gen INTEGER NOT NULL,
    PRIMARY KEY (vertex, goal));
CREATE TABLE IF NOT EXISTS tasks (task INTEGER PRIMARY KEY, {
    ", ".join(f"{c} {'TEXT' if c in _TEXT_COLUMNS else 'REAL'}" for c in TASK_COLUMNS)
});
"""


def signatures(scenario: Scenario) -> dict[str, str]:
    """Robot and scenario signatures (SHA-256 of canonical JSON).

    The scenario signature covers the workcell, the robot and everything of the
    adaptive section that the saved graph depends on (goals, changes, resolution,
    planners), but not the task list or the repair strategy.
    """
    data = scenario.model_dump(mode="json")
    adaptive = dict(data.get("adaptive") or {})
    adaptive.pop("tasks", None)
    adaptive.pop("repair", None)

    return {
        "robot_signature": _digest(data["robot"]),
        "scenario_signature": _digest(
            {"workcell": data["workcell"], "robot": data["robot"], "adaptive": adaptive}
        ),
    }


def _digest(obj: Any) -> str:
    return hashlib.sha256(
        json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()
    ).hexdigest()


def workcell_signatures(cell: Workcell) -> dict[str, str]:
    """Robot and workcell signatures of a bare workcell model (from its numbers)."""
    robot = cell.robot
    robot_data = {
        "kind": robot.kind,
        "axes": list(robot.axis_names),
        "lower": robot.lower.tolist(),
        "upper": robot.upper.tolist(),
        "start": robot.start.tolist(),
        "bodies": [shape_to_json(b) for b in robot.bodies.bodies],
    }
    return {
        "robot_signature": _digest(robot_data),
        "scenario_signature": _digest(
            {
                "bounds": list(cell.bounds),
                "robot": robot_data,
                "obstacles": {n: shape_to_json(s) for n, s in sorted(cell.obstacles.items())},
            }
        ),
    }


def shape_to_json(shape: ShapeSet) -> dict[str, Any]:
    """A shape set as plain lists (exact: floats survive JSON)."""
    return {
        "verts": shape.verts.tolist(),
        "counts": shape.counts.tolist(),
        "centres": shape.centres.tolist(),
        "radii": shape.radii.tolist(),
    }


def shape_from_json(data: Mapping[str, Any]) -> ShapeSet:
    """The inverse of :func:`shape_to_json`."""
    verts = np.asarray(data["verts"], dtype=float)
    if verts.size == 0:
        verts = np.zeros((0, 3, 2))
    return ShapeSet(
        verts,
        np.asarray(data["counts"], dtype=np.int64),
        np.asarray(data["centres"], dtype=float).reshape(-1, 2),
        np.asarray(data["radii"], dtype=float),
    )


# --- the writer lock ---------------------------------------------------------------------------


class DatabaseLock:
    """The one-writer lock of a database: ``flock`` on a sidecar file and on the database.

    An OS file lock, not a lock row or SQLite's own locking, because the kernel drops it
    when its process dies however it dies (``kill -9`` included): no stale lock is ever
    left to clear by hand, and a second process learns who holds it, from the PID the
    holder writes into the sidecar. SQLite's locks are released between transactions
    (each task commits), so they cannot keep a second run from interleaving its tasks.

    The lock belongs to the file, not to the name it was reached by:

    * the database path is resolved first (symbolic links followed), and the sidecar
      is ``<resolved path>.lock``: two names linked to one database share one sidecar.
      It serialises the creation of a database that does not exist yet;
    * once the database exists, its own inode is locked too (:meth:`lock_database`), so
      a hard link, which no path resolution can see, meets the same lock.

    Neither file is opened through a final symbolic link (``O_NOFOLLOW``), and neither
    is written unless it is a regular file: a sidecar planted as a link to another file
    is refused, never truncated. ``flock`` locks are independent of the POSIX record
    locks SQLite takes on the database, so the two do not interfere.

    The locks are taken without waiting; a second opener gets a
    :class:`~cellplan.errors.PersistenceError` naming the holder. :meth:`release`
    removes the sidecar while still holding the lock; an opener that locked a sidecar
    removed meanwhile sees its inode gone from the path and tries again.
    """

    def __init__(self, db: Path) -> None:
        self.given = db
        self.db = Path(os.path.realpath(db))
        self.path = self.db.with_name(self.db.name + ".lock")
        self.db_fd: int | None = None
        _require_regular_or_absent(self.db, db)
        longest = len(os.fsencode(f".{self.db.name}.creating-journal"))
        if longest > name_max(self.db.parent):
            raise PersistenceError(
                [
                    Problem(
                        str(db),
                        f"the file name is too long: the database needs files named up to "
                        f"{longest} bytes beside it, more than this file system takes",
                    )
                ]
            )
        while True:
            fd = _open_regular(self.path, os.O_RDWR | os.O_CREAT, db)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _lock_holder(fd)
                os.close(fd)
                raise self._busy(f"process {holder}" if holder else "another process") from None
            except BaseException:
                os.close(fd)
                raise
            if _same_file(fd, self.path):
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd: int | None = fd
        try:
            if self.db.exists():
                self.lock_database()
        except BaseException:
            self.release()
            raise

    def _busy(self, who: str) -> PersistenceError:
        return PersistenceError(
            [
                Problem(
                    str(self.given),
                    f"in use by {who} (one run at a time per database); "
                    "wait for it to finish or use another --db file",
                )
            ]
        )

    def lock_database(self) -> None:
        """Lock the database file's inode (again, after :func:`create_database` renamed a
        new file into place). Refuses a database that another process holds through any
        name, a hard link included."""
        fd = _open_regular(self.db, os.O_RDONLY, self.given)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise self._busy("another process, through another name (a hard link)") from None
        except BaseException:
            os.close(fd)
            raise
        if self.db_fd is not None:
            os.close(self.db_fd)
        self.db_fd = fd

    def release(self) -> None:
        """Remove the sidecar and unlock both files (idempotent)."""
        if self.db_fd is not None:
            os.close(self.db_fd)
            self.db_fd = None
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            if _same_file(self.fd, self.path):
                self.path.unlink()
        os.close(self.fd)
        self.fd = None


def _require_regular_or_absent(path: Path, given: Path) -> None:
    """Refuse a database path that exists and is not a regular file (a device, a FIFO,
    a socket, a folder): creating the database would rename a new file onto it."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISREG(mode):
        raise PersistenceError(
            [
                Problem(
                    str(given),
                    f"is {kind_of(mode)}, not a database file; cellplan replaces only "
                    "regular files",
                )
            ]
        )


def _open_regular(path: Path, flags: int, given: Path) -> int:
    """Open ``path`` without following a final link and without blocking on a FIFO, and
    refuse it unless it is a regular file; the descriptor, switched to blocking."""
    with contextlib.suppress(FileNotFoundError):
        # Looked at before opening too: opening a device can have effects of its own.
        mode = os.lstat(path).st_mode
        if not stat.S_ISREG(mode):
            raise PersistenceError(
                [Problem(str(given), f"{path} is {kind_of(mode)}, not a regular file")]
            )
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise PersistenceError(
                [Problem(str(given), f"{path} is a symbolic link; cellplan does not follow it")]
            ) from None
        raise
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise PersistenceError(
            [Problem(str(given), f"{path} is {kind_of(mode)}, not a regular file")]
        )
    os.set_blocking(fd, True)
    return fd


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _lock_holder(fd: int) -> int | None:
    """The PID in a held lock file (the holder writes it just after locking)."""
    for _ in range(20):
        os.lseek(fd, 0, os.SEEK_SET)
        text = os.read(fd, 32).decode("ascii", "replace").strip()
        if text.isdigit():
            return int(text)
        time.sleep(0.01)
    return None


# --- creation and checks -----------------------------------------------------------------------


def create_database(path: Path, sig: Mapping[str, str]) -> None:
    """Create the database at ``path`` whole, or not at all.

    The schema and the meta rows are written into ``.<name>.creating`` beside it, which
    is flushed to disk (``fsync``) and renamed onto ``path``, then the folder is flushed:
    a process killed at any point leaves either no database (and a leftover temporary
    file the next creation removes) or a complete one, never a header without a schema.
    The caller holds the :class:`DatabaseLock`, so the temporary name is its own, and
    journal files at ``path`` are stale leftovers of a deleted database (SQLite would
    otherwise replay an old write-ahead log into the new file): they are removed.
    """
    tmp = path.with_name(f".{path.name}.creating")
    for leftover in _sidecars(tmp):
        leftover.unlink(missing_ok=True)
    conn = sqlite3.connect(tmp, isolation_level=None)
    try:
        conn.execute("PRAGMA journal_mode=WAL")  # recorded in the file's header
        conn.execute("PRAGMA synchronous=FULL")
        conn.execute("BEGIN IMMEDIATE")
        for stmt in _SCHEMA.strip().split(";"):
            if stmt.strip():
                conn.execute(stmt)
        rows = {
            "format": FORMAT,
            "schema_version": str(SCHEMA_VERSION),
            "tasks_done": "0",
            **sig,
        }
        conn.executemany("INSERT INTO meta VALUES (?, ?)", rows.items())
        write_digest(conn)
        _creation_step("begun")
        conn.execute("COMMIT")
    finally:
        conn.close()  # checkpoints the write-ahead log into the file and removes it
    _creation_step("written")
    fsync_path(tmp)
    for stale in _sidecars(path)[1:]:
        stale.unlink(missing_ok=True)
    _creation_step("synced")
    os.replace(tmp, path)
    _creation_step("renamed")
    fsync_path(path.parent)


def _check_writable_format(path: Path) -> None:
    """Refuse a file whose header SQLite would open read-only (its write version, byte
    18, above 2: a damaged header), before a commit fails half-way through a run."""
    with path.open("rb") as fh:
        header = fh.read(20)
    if len(header) == 20 and not (header[18] in (1, 2) and header[19] in (1, 2)):
        raise PersistenceError(
            [Problem(str(path), "is damaged: its SQLite header has unknown file-format versions")]
        )


def _sidecars(path: Path) -> list[Path]:
    return [path, *(path.with_name(path.name + s) for s in ("-wal", "-shm", "-journal"))]


def _creation_step(step: str) -> None:
    """Between the steps of :func:`create_database` (``begun``, ``written``, ``synced``,
    ``renamed``):
    a seam for the tests that kill the process there; does nothing."""


@functools.cache
def _expected_columns() -> dict[str, list[tuple[str, str, int, int]]]:
    """(name, type, not null, primary-key position) of every column, from :data:`_SCHEMA`."""
    conn = sqlite3.connect(":memory:")
    try:
        conn.executescript(_SCHEMA)
        return {t: _columns(conn, t) for t in _TABLES}
    finally:
        conn.close()


_TABLES = ("meta", "vertices", "edges", "goal_links", "tasks")


def _columns(conn: sqlite3.Connection, table: str) -> list[tuple[str, str, int, int]]:
    return [
        (str(r[1]), str(r[2]).upper(), int(r[3]), int(r[5]))
        for r in conn.execute(f"PRAGMA table_info({table})")
    ]


def check_database(conn: sqlite3.Connection, where: str) -> None:
    """Refuse a file that is damaged or not an experience database of this version.

    Reads only. Checks, in order: ``PRAGMA integrity_check`` (SQLite's own structure),
    the tables, their columns and declared types (a file of an older cellplan may lack
    the columns of :data:`_ADDED_COLUMNS`, which opening adds), that there are no
    triggers or views (cellplan creates none, and one could change what a write does),
    the format and the schema version, and then every stored value
    (:func:`check_contents`). Raises :class:`~cellplan.errors.PersistenceError`.
    """

    def fail(message: str) -> PersistenceError:
        return PersistenceError([Problem(where, message)])

    report = [str(r[0]) for r in conn.execute("PRAGMA integrity_check(5)")]
    if report != ["ok"]:
        found = " ".join(" ".join(report).replace("*** in database main ***", "").split())
        raise fail(f"is damaged (SQLite integrity check: {found[:200]})")
    objects = conn.execute("SELECT type, name FROM sqlite_master").fetchall()
    tables = {str(n) for t, n in objects if t == "table"}
    if "meta" not in tables:
        raise fail("is an SQLite file but not a cellplan experience database (no meta table)")
    if _columns(conn, "meta") != _expected_columns()["meta"]:
        raise fail("is not a cellplan experience database (its meta table differs)")
    meta = dict(conn.execute("SELECT key, value FROM meta").fetchall())
    if meta.get("format") != FORMAT:
        raise fail("is not a cellplan experience database")
    if meta.get("schema_version") != str(SCHEMA_VERSION):
        raise fail(
            f"has schema version {str(meta.get('schema_version'))[:20]!r}; "
            f"this cellplan reads {SCHEMA_VERSION}"
        )
    missing = [t for t in _TABLES if t not in tables]
    if missing:
        raise fail(f"is damaged: missing tables {missing}")
    others = sorted(f"{t} {n}" for t, n in objects if t in ("trigger", "view"))
    if others:
        raise fail(f"is damaged: has {', '.join(others)[:120]}, which cellplan never creates")
    for table, want in _expected_columns().items():
        have = _columns(conn, table)
        if table == "tasks" and len(have) < len(want):
            # An older file: the added columns come last, and opening adds them.
            want = want[: len(want) - len(_ADDED_COLUMNS)]
            if have == want[: len(have)] and len(have) >= len(want):
                continue
        if have != want:
            raise fail(f"is damaged: the columns of table {table} are not cellplan's")
    stored = conn.execute("SELECT value FROM meta WHERE key = 'digest'").fetchone()
    if stored is None:
        # Every database cellplan writes has one; without it any edit would pass.
        raise fail(
            "has no content checksum (meta 'digest'): every database cellplan writes has "
            "one, so this file was changed outside cellplan; start a new database"
        )
    if stored[0] != content_digest(conn):
        raise fail(
            "is damaged: its contents do not match their checksum "
            "(changed outside cellplan, or corrupted on disk)"
        )
    check_contents(conn, where)


#: Primary-key order of each table, for the content digest.
_ORDER = {
    "meta": "key",
    "vertices": "id",
    "edges": "a, b",
    "goal_links": "vertex, goal",
    "tasks": "task",
}


def content_digest(conn: sqlite3.Connection) -> str:
    """SHA-256 of every stored row (all tables, in key order), the meta ``digest`` aside.

    Rows are hashed as SQLite returns them (``repr`` of each tuple: exact for floats,
    and it tells text from blobs and integers from reals), so any change to a stored
    value, a row or a column changes the digest.
    """
    h = hashlib.sha256()
    for table in _TABLES:
        h.update(f"\x00{table}\x00".encode())
        for row in conn.execute(f"SELECT * FROM {table} ORDER BY {_ORDER[table]}"):
            if table == "meta" and row[0] == "digest":
                continue
            h.update(repr(tuple(row)).encode())
            h.update(b"\n")
    return h.hexdigest()


def write_digest(conn: sqlite3.Connection) -> None:
    """Store :func:`content_digest` in meta (inside the caller's transaction)."""
    conn.execute("INSERT OR REPLACE INTO meta VALUES ('digest', ?)", (content_digest(conn),))


def check_contents(conn: sqlite3.Connection, where: str) -> None:
    """Check every stored value's type and range, so that nothing read later can crash.

    SQLite stores any type in any column, so a file edited by hand (or damaged where
    the integrity check cannot see, inside a value) is read row by row: meta counters
    are whole numbers, the run states are JSON objects of the right shape, vertex
    coordinates are finite numbers, edges join stored vertices, task rows are numbered
    from 1 and hold numbers where numbers belong.
    """
    problems: list[str] = []
    meta = dict(conn.execute("SELECT key, value FROM meta").fetchall())
    for key in ("robot_signature", "scenario_signature", "tasks_done"):
        if not isinstance(meta.get(key), str):
            problems.append(f"meta {key} is missing")
    for key in ("tasks_done", "next_id"):
        if key in meta and _whole(meta[key]) is None:
            problems.append(f"meta {key} is not a whole number >= 0")
    for key, check in (("state", _check_run_state), ("planner", _check_planner_state)):
        if key in meta:
            try:
                value = json.loads(meta[key]) if isinstance(meta[key], str) else None
            except (ValueError, RecursionError):
                value = None
            problem = "is not a JSON object" if not isinstance(value, dict) else check(value)
            if problem:
                problems.append(f"meta {key} {problem}")
    ids: set[int] = set()
    dims: set[int] = set()
    for vid, obj, rx, ry, rphi, branch, q in conn.execute(
        "SELECT id, object, rx, ry, rphi, branch, q FROM vertices"
    ):
        coords = _numbers(q)
        if (
            not isinstance(vid, int)
            or vid < 0
            or not (obj is None or isinstance(obj, str))
            or not all(_finite(x) for x in (rx, ry, rphi))
            or not (branch is None or (isinstance(branch, int) and branch in (-1, 0, 1)))
            or not coords
        ):
            problems.append(f"vertex {str(vid)[:20]} holds values of the wrong type")
            break
        ids.add(vid)
        dims.add(len(coords))
    if len(dims) > 1:
        problems.append("vertices have configurations of different lengths")
    for a, b, status, gen in conn.execute("SELECT a, b, status, gen FROM edges"):
        if a not in ids or b not in ids or status not in EDGE_STATUSES or _whole(gen) is None:
            problems.append(f"edge ({str(a)[:20]}, {str(b)[:20]}) is not a valid edge of G")
            break
    for vertex, goal, ok, gen in conn.execute("SELECT vertex, goal, ok, gen FROM goal_links"):
        if (
            vertex not in ids
            or not isinstance(goal, str)
            or ok not in (0, 1)
            or _whole(gen) is None
        ):
            problems.append(f"goal link ({str(vertex)[:20]}, {str(goal)[:20]}) is not valid")
            break
    cols = [
        c
        for c in ("task", *TASK_COLUMNS)
        if c in {r[1] for r in conn.execute("PRAGMA table_info(tasks)")}
    ]
    rows = conn.execute(f"SELECT {', '.join(cols)} FROM tasks ORDER BY task").fetchall()
    for i, values in enumerate(rows, start=1):
        row = dict(zip(cols, values, strict=True))
        bad = [
            c
            for c, v in row.items()
            if not (
                isinstance(v, str)
                if c in _TEXT_COLUMNS
                else (_whole(v) is not None if c in _INTEGER_TASK_COLUMNS else _finite(v))
            )
        ]
        if row["task"] != i:
            bad.insert(0, "task")
        if bad:
            problems.append(f"task row {i} has bad values in {', '.join(bad[:4])}")
            break
    if "state" not in meta and (rows or ("planner" not in meta and ids)):
        problems.append("it holds tasks or G but no run state")
    if "state" in meta and not problems:
        done = json.loads(meta["state"])["tasks_done"]
        if done != len(rows):
            problems.append(f"the run state has {done} tasks done but the tasks table {len(rows)}")
    if problems:
        raise PersistenceError([Problem(where, f"is damaged: {problems[0]}")])


_RUN_STATE = {
    "tasks_done": "whole",
    "generation": "whole",
    "u": "numbers",
    "u_hat": "whole",
    "link_gen": "whole",
    "repaired_gen": "whole",
    "current_goal": "name",
    "solve_calls": "whole",
    "u_base": "numbers",
    "repair": "text",
    "seed": "int",
}
_PLANNER_STATE = {
    **{k: v for k, v in _RUN_STATE.items() if k not in ("u_base", "repair", "seed")},
    "resolution": "positive",
    "counts": "counts",
    "objects": "objects",
    "goals": "goals",
}


def _check_run_state(state: dict[str, Any]) -> str:
    return _check_fields(state, _RUN_STATE)


def _check_planner_state(state: dict[str, Any]) -> str:
    return _check_fields(state, _PLANNER_STATE)


def _check_fields(state: dict[str, Any], kinds: Mapping[str, str]) -> str:
    for key, kind in kinds.items():
        if key not in state:
            return f"lacks {key}"
        if not _KINDS[kind](state[key]):
            return f"has a bad {key}"
    return ""


def _is_objects(value: Any) -> bool:
    if not isinstance(value, dict):
        return False
    for obj in value.values():
        if not (isinstance(obj, dict) and _numbers(obj.get("pose")) and len(obj["pose"]) == 3):
            return False
        if "solid" in obj:  # a 3-D cell's object (``World3D.objects_json``)
            if not _is_solid(obj["solid"]) or not _is_turn(obj.get("turn")):
                return False
            continue
        shape = obj.get("shape")
        if not isinstance(shape, dict) or not all(
            isinstance(shape.get(k), list) for k in ("verts", "counts", "centres", "radii")
        ):
            return False
        try:
            s = shape_from_json(shape)
        except (ValueError, TypeError, OverflowError):
            return False
        if not (
            s.verts.ndim == 3
            and s.verts.shape[0] == len(s.counts)
            and s.verts.shape[2] == 2
            and np.isfinite(s.verts).all()
            and np.isfinite(s.centres).all()
            and np.isfinite(s.radii).all()
            and len(s.centres) == len(s.radii)
            and (s.radii >= 0).all()
            and ((s.counts >= 1) & (s.counts <= s.verts.shape[1])).all()
        ):
            return False
    return True


def _is_solid(value: Any) -> bool:
    """A primitive solid as ``World3D.objects_json`` writes it: kind, 4x4 pose, size."""
    if not isinstance(value, dict) or value.get("kind") not in _SOLID_SIZES:
        return False
    pose, size = value.get("pose"), _numbers(value.get("size"))
    if not (isinstance(pose, list) and len(pose) == 4):
        return False
    rows = [_numbers(r) for r in pose]
    if not all(r is not None and len(r) == 4 for r in rows):
        return False
    matrix = np.array(rows, float)
    rigid = np.allclose(matrix[:3, :3] @ matrix[:3, :3].T, np.eye(3), atol=1e-6) and np.allclose(
        matrix[3], [0.0, 0.0, 0.0, 1.0]
    )
    return bool(
        rigid
        and size is not None
        and len(size) == _SOLID_SIZES[value["kind"]]
        and all(math.isfinite(v) and v > 0 for v in size)
    )


_SOLID_SIZES = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1}


def _is_turn(value: Any) -> bool:
    """A 3-D object's turn (``World3D.objects_json``): absent (stores written before
    objects could turn), or a row-major 3x3 rotation."""
    if value is None:
        return True
    numbers = _numbers(value)
    if numbers is None or len(numbers) != 9 or not all(math.isfinite(v) for v in numbers):
        return False
    m = np.array(numbers, float).reshape(3, 3)
    return bool(np.allclose(m @ m.T, np.eye(3), atol=1e-6) and np.linalg.det(m) > 0)


def _is_goals(value: Any) -> bool:
    # A 3-D goal has a fourth entry: the tool's orientation (9 numbers) or None.
    return isinstance(value, dict) and all(
        isinstance(g, list)
        and len(g) in (3, 4)
        and (g[0] is None or isinstance(g[0], str))
        and _numbers(g[1])
        and len(g[1]) == 3
        and (g[2] is None or g[2] in (-1, 0, 1))
        and (len(g) == 3 or g[3] is None or (_numbers(g[3]) and len(g[3]) == 9))
        for g in value.values()
    )


_KINDS: dict[str, Callable[[Any], bool]] = {
    "whole": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "numbers": lambda v: bool(_numbers(v)),
    "name": lambda v: v is None or isinstance(v, str),
    "text": lambda v: isinstance(v, str),
    "positive": lambda v: _finite(v) and v > 0,
    "counts": lambda v: (
        isinstance(v, dict)
        and all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in v.values())
    ),
    "objects": _is_objects,
    "goals": _is_goals,
}


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _whole(value: Any) -> int | None:
    """``value`` as a whole number >= 0 (an int, a float like 3.0, or its text), else None."""
    if isinstance(value, str):
        value = value.strip()
        if not value.isdigit() or len(value) > 18:
            return None
        return int(value)
    if _finite(value) and float(value).is_integer() and 0 <= value < 2**53:
        return int(value)
    return None


def _numbers(value: Any) -> list[float] | None:
    """A non-empty list of finite numbers (or its JSON text), else None."""
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except (ValueError, RecursionError):
            return None
    if not isinstance(value, list) or not value or len(value) > 64:
        return None
    if not all(_finite(x) for x in value):
        return None
    return [float(x) for x in value]


class ExperienceStore:
    """An open experience database, locked for this process until :meth:`close`.

    ``problem`` is the scenario the database belongs to, or the signatures to key it on
    (:func:`signatures`, :func:`workcell_signatures`).

    Opening takes the writer lock (:class:`DatabaseLock`), creates a missing database
    whole (:func:`create_database`), and checks an existing one before anything is
    written to it: ``PRAGMA integrity_check``, the tables and columns, the format and
    schema version, the signatures and every stored value (:func:`check_contents`).
    Any failure raises :class:`~cellplan.errors.PersistenceError` with one line.
    """

    def __init__(self, path: str | Path, problem: Scenario | Mapping[str, str]) -> None:
        self.path = Path(path)
        self.conn: sqlite3.Connection | None = None
        self._lock: DatabaseLock | None = None
        self._sig = dict(problem) if isinstance(problem, Mapping) else signatures(problem)
        where = str(self.path)
        try:
            if self.path.is_dir():
                raise PersistenceError([Problem(where, "is a folder, not a database file")])
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._lock = DatabaseLock(self.path)
            # From here on the database is reached by its resolved path, the one locked.
            real = self._lock.db
            if not self._holds_schema(real):
                create_database(real, self._sig)
                self._lock.lock_database()
            self.conn = sqlite3.connect(real, isolation_level=None)
            check_database(self.conn, where)
            _check_writable_format(real)
            self._check_signature()
            # Only now, with the file known to be ours and whole, is anything written.
            self.conn.execute("PRAGMA journal_mode=WAL")
            self.conn.execute("PRAGMA synchronous=FULL")
            self._add_columns()
        except sqlite3.DatabaseError as exc:
            self.close()
            raise PersistenceError(
                [Problem(where, f"not a readable experience database ({exc})")]
            ) from None
        except UnicodeDecodeError:  # damaged text, in a value or in SQLite's own messages
            self.close()
            raise PersistenceError(
                [Problem(where, "not a readable experience database (text that is not UTF-8)")]
            ) from None
        except OSError as exc:
            self.close()
            raise PersistenceError(
                [Problem(where, f"cannot open the database ({exc.strerror or exc})")]
            ) from None
        except BaseException:
            self.close()
            raise

    # --- opening ---------------------------------------------------------------------------

    def _holds_schema(self, path: Path) -> bool:
        """Whether the file exists and has a schema: a missing or empty file, or a whole
        SQLite page 1 with no tables at all (what an older cellplan killed during creation
        left), holds nothing and is created afresh. Anything else is checked (and a file
        cut short, or not SQLite, refused) by :func:`check_database`."""
        if not path.exists() or path.stat().st_size == 0:
            return False
        with path.open("rb") as fh:
            header = fh.read(100)
        page = int.from_bytes(header[16:18], "big") if len(header) == 100 else 0
        page = 65536 if page == 1 else page
        if not header.startswith(b"SQLite format 3\0") or path.stat().st_size < max(page, 512):
            return True  # not an SQLite file, or cut short in its first page: refused later
        conn = sqlite3.connect(path, isolation_level=None)
        try:
            return conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0] > 0
        finally:
            conn.close()

    def _add_columns(self) -> None:
        conn = self._conn()
        have = {r[1] for r in conn.execute("PRAGMA table_info(tasks)")}
        missing = [c for c in _ADDED_COLUMNS if c not in have]
        if missing:
            with self.transaction():
                for c in missing:
                    conn.execute(f"ALTER TABLE tasks ADD COLUMN {c} {_ADDED_COLUMNS[c]}")

    def _check_signature(self) -> None:
        meta = self.meta()
        if meta.get("robot_signature") != self._sig["robot_signature"]:
            raise PersistenceError(
                [
                    Problem(
                        str(self.path),
                        "was made for another robot; use a new --db file for this scenario",
                    )
                ]
            )
        if meta.get("scenario_signature") != self._sig["scenario_signature"]:
            raise PersistenceError(
                [
                    Problem(
                        str(self.path),
                        "was made for another workcell or adaptive section; use a new --db file",
                    )
                ]
            )

    def _conn(self) -> sqlite3.Connection:
        if self.conn is None:
            raise PersistenceError([Problem(str(self.path), "the database is closed")])
        return self.conn

    def close(self) -> None:
        """Close the connection and release the lock (idempotent)."""
        conn = getattr(self, "conn", None)
        if conn is not None:
            conn.close()
            self.conn = None
        lock = getattr(self, "_lock", None)
        if lock is not None:
            lock.release()
            self._lock = None

    def __enter__(self) -> ExperienceStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- transactions ----------------------------------------------------------------------

    class _Tx:
        def __init__(self, conn: sqlite3.Connection) -> None:
            self.conn = conn

        def __enter__(self) -> sqlite3.Connection:
            self.conn.execute("BEGIN IMMEDIATE")
            return self.conn

        def __exit__(self, exc_type: object, *rest: object) -> None:
            if exc_type is None:
                try:
                    self.conn.execute("COMMIT")
                    return
                except sqlite3.Error:
                    self._rollback()
                    raise
            self._rollback()

        def _rollback(self) -> None:
            if self.conn.in_transaction:
                self.conn.execute("ROLLBACK")

    def transaction(self) -> ExperienceStore._Tx:
        """``with store.transaction():`` - all or nothing."""
        return ExperienceStore._Tx(self._conn())

    # --- reading ---------------------------------------------------------------------------

    def meta(self) -> dict[str, str]:
        """The meta table as raw strings."""
        return dict(self._conn().execute("SELECT key, value FROM meta").fetchall())

    def state(self) -> dict[str, Any] | None:
        """The saved run state (JSON values), or ``None`` for a database with no task yet."""
        raw = self.meta()
        if "state" not in raw:
            return None
        return dict(json.loads(raw["state"]))

    def planner_state(self) -> dict[str, Any] | None:
        """The saved :class:`~.experience.ExperiencePlanner` state, or ``None``."""
        raw = self.meta().get("planner")
        return None if raw is None else dict(json.loads(raw))

    def load_graph(self) -> ExperienceGraph:
        """The saved experience graph."""
        g = ExperienceGraph()
        for vid, obj, rx, ry, rphi, branch, q in self._conn().execute(
            "SELECT id, object, rx, ry, rphi, branch, q FROM vertices ORDER BY id"
        ):
            g.add_vertex(np.array(json.loads(q), float), obj, (rx, ry, rphi), branch, vid=vid)
        for a, b, status, gen in self._conn().execute(
            "SELECT a, b, status, gen FROM edges ORDER BY a, b"
        ):
            g.set_edge(a, b, status, gen)
        next_id = self.meta().get("next_id")
        if next_id is not None:
            g.next_id = max(g.next_id, int(next_id))
        return g

    def check_state(self, graph: ExperienceGraph, state: Mapping[str, Any], dim: int) -> None:
        """Refuse a saved state that does not fit the robot (``dim`` joints) or G."""
        sizes = {len(v.q) for v in graph.vertices.values()} | {len(state["u"])}
        if "u_base" in state:
            sizes.add(len(state["u_base"]))
        if sizes != {dim}:
            raise PersistenceError(
                [Problem(str(self.path), f"is damaged: configurations are not {dim} numbers long")]
            )
        if state["u_hat"] not in graph.vertices:
            raise PersistenceError([Problem(str(self.path), "is damaged: û is not a vertex")])

    def load_links(self) -> tuple[dict[tuple[int, str], bool], int | None]:
        """Remembered Reach(vertex, goal) answers and their generation."""
        rows = self._conn().execute("SELECT vertex, goal, ok, gen FROM goal_links").fetchall()
        gens = {r[3] for r in rows}
        return {(int(v), str(g)): bool(ok) for v, g, ok, _ in rows}, (
            gens.pop() if len(gens) == 1 else None
        )

    def task_rows(self) -> list[dict[str, Any]]:
        """Every saved task row, in order."""
        cols = ("task", *TASK_COLUMNS)
        rows = self._conn().execute(f"SELECT {', '.join(cols)} FROM tasks ORDER BY task")
        # REAL columns hand back 1.0 for the 1 a run wrote: give every value the type a
        # fresh run's row has, so a continued run's CSV reads like an uninterrupted one's.
        return [
            {c: int(v) if c in _INTEGER_TASK_COLUMNS else v for c, v in zip(cols, r, strict=True)}
            for r in rows
        ]

    # --- writing ---------------------------------------------------------------------------

    def commit_task(
        self,
        graph: ExperienceGraph,
        state: Mapping[str, Any],
        row: Mapping[str, Any] | None,
        links: Mapping[tuple[int, str], bool] | None = None,
        key: str = "state",
    ) -> None:
        """Write G, the run state (meta ``key``) and one task row in a single transaction.

        A write the file system refuses (disk full, a read-only file) raises
        :class:`~cellplan.errors.PersistenceError`; the transaction is rolled back, so
        the database keeps the previous task.
        """
        try:
            self._commit_task(graph, state, row, links, key)
        except sqlite3.OperationalError as exc:
            raise PersistenceError(
                [Problem(str(self.path), f"cannot write the database ({exc})")]
            ) from None

    def _commit_task(
        self,
        graph: ExperienceGraph,
        state: Mapping[str, Any],
        row: Mapping[str, Any] | None,
        links: Mapping[tuple[int, str], bool] | None,
        key: str,
    ) -> None:
        with self.transaction() as c:
            c.execute("DELETE FROM vertices")
            c.execute("DELETE FROM edges")
            c.execute("DELETE FROM goal_links")
            gen = int(state.get("generation", 0))
            c.executemany(
                "INSERT INTO goal_links VALUES (?, ?, ?, ?)",
                [
                    (v, g, int(ok), gen)
                    for (v, g), ok in (links or {}).items()
                    if v in graph.vertices
                ],
            )
            c.executemany(
                "INSERT INTO vertices VALUES (?, ?, ?, ?, ?, ?, ?)",
                [
                    (
                        v.id,
                        v.obj,
                        v.rel[0],
                        v.rel[1],
                        v.rel[2],
                        v.branch,
                        json.dumps([float(x) for x in v.q]),
                    )
                    for v in graph.vertices.values()
                ],
            )
            c.executemany(
                "INSERT INTO edges VALUES (?, ?, ?, ?)",
                [(a, b, e.status, e.gen) for (a, b), e in graph.edges.items()],
            )
            c.executemany(
                "INSERT OR REPLACE INTO meta VALUES (?, ?)",
                [
                    (key, json.dumps(dict(state))),
                    ("next_id", str(graph.next_id)),
                    ("tasks_done", str(int(state["tasks_done"]))),
                ],
            )
            if row is not None:
                cols = ("task", *TASK_COLUMNS)
                c.execute(
                    f"INSERT OR REPLACE INTO tasks ({', '.join(cols)}) "
                    f"VALUES ({', '.join('?' * len(cols))})",
                    [row.get(k) for k in cols],
                )
            write_digest(c)


def export_graphml(graph: ExperienceGraph, path: str | Path) -> Path:
    """Write G as GraphML (atomically) for inspection in Gephi, yEd or networkx."""
    import networkx as nx

    nxg = nx.Graph()
    for v in graph.vertices.values():
        nxg.add_node(
            v.id,
            object=v.obj or "",
            rx=float(v.rel[0]),
            ry=float(v.rel[1]),
            rphi=float(v.rel[2]),
            branch=int(v.branch or 0),
            q=" ".join(f"{x:.6g}" for x in v.q),
        )
    for (a, b), e in graph.edges.items():
        nxg.add_edge(a, b, status=e.status, gen=int(e.gen))
    with atomic_path(path) as tmp:
        nx.write_graphml(nxg, tmp)
    return Path(path)

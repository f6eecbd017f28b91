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
task. Opening checks the format and the signatures and refuses a file made for
another robot or scenario, or one that is not an experience database, with a
:class:`~cellplan.errors.PersistenceError`.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cellplan.adaptive.graph import EDGE_STATUSES, ExperienceGraph
from cellplan.errors import PersistenceError, Problem
from cellplan.fileio import atomic_path
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


class ExperienceStore:
    """An open experience database.

    ``problem`` is the scenario the database belongs to, or the signatures to key it on
    (:func:`signatures`, :func:`workcell_signatures`).
    """

    def __init__(self, path: str | Path, problem: Scenario | Mapping[str, str]) -> None:
        self.path = Path(path)
        self._sig = dict(problem) if isinstance(problem, Mapping) else signatures(problem)
        fresh = not self.path.exists() or self.path.stat().st_size == 0
        if self.path.is_dir():
            raise PersistenceError([Problem(str(self.path), "is a folder, not a database file")])
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self.conn = sqlite3.connect(self.path, isolation_level=None)
            if not fresh:
                self._check_foreign()
            self.conn.execute("PRAGMA journal_mode=WAL")
            self.conn.execute("PRAGMA synchronous=FULL")
            if fresh:
                self._create()
            else:
                self._check_signature()
                self._add_columns()
        except sqlite3.DatabaseError as exc:
            self.close()
            raise PersistenceError(
                [Problem(str(self.path), f"not a readable experience database ({exc})")]
            ) from None

    # --- opening ---------------------------------------------------------------------------

    def _create(self) -> None:
        with self.transaction():
            for stmt in _SCHEMA.strip().split(";"):
                if stmt.strip():
                    self.conn.execute(stmt)
            rows = {
                "format": FORMAT,
                "schema_version": str(SCHEMA_VERSION),
                "tasks_done": "0",
                **self._sig,
            }
            self.conn.executemany("INSERT INTO meta VALUES (?, ?)", rows.items())

    def _add_columns(self) -> None:
        have = {r[1] for r in self.conn.execute("PRAGMA table_info(tasks)")}
        missing = [c for c in _ADDED_COLUMNS if c not in have]
        if missing:
            with self.transaction():
                for c in missing:
                    self.conn.execute(f"ALTER TABLE tasks ADD COLUMN {c} {_ADDED_COLUMNS[c]}")

    def _check_foreign(self) -> None:
        tables = {
            r[0] for r in self.conn.execute("SELECT name FROM sqlite_master WHERE type='table'")
        }
        if "meta" not in tables:
            raise PersistenceError(
                [
                    Problem(
                        str(self.path),
                        "is an SQLite file but not a cellplan experience database (no meta table)",
                    )
                ]
            )
        meta = self.meta()
        if meta.get("format") != FORMAT:
            raise PersistenceError(
                [Problem(str(self.path), "is not a cellplan experience database")]
            )
        if meta.get("schema_version") != str(SCHEMA_VERSION):
            raise PersistenceError(
                [
                    Problem(
                        str(self.path),
                        f"has schema version {meta.get('schema_version')}; "
                        f"this cellplan reads {SCHEMA_VERSION}",
                    )
                ]
            )
        missing = {"vertices", "edges", "goal_links", "tasks"} - tables
        if missing:
            raise PersistenceError(
                [Problem(str(self.path), f"is damaged: missing tables {sorted(missing)}")]
            )

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

    def close(self) -> None:
        """Close the connection (idempotent)."""
        conn = getattr(self, "conn", None)
        if conn is not None:
            conn.close()
            self.conn = None  # type: ignore[assignment]

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
            self.conn.execute("ROLLBACK" if exc_type is not None else "COMMIT")

    def transaction(self) -> ExperienceStore._Tx:
        """``with store.transaction():`` - all or nothing."""
        return ExperienceStore._Tx(self.conn)

    # --- reading ---------------------------------------------------------------------------

    def meta(self) -> dict[str, str]:
        """The meta table as raw strings."""
        return dict(self.conn.execute("SELECT key, value FROM meta").fetchall())

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
        for vid, obj, rx, ry, rphi, branch, q in self.conn.execute(
            "SELECT id, object, rx, ry, rphi, branch, q FROM vertices ORDER BY id"
        ):
            g.add_vertex(np.array(json.loads(q), float), obj, (rx, ry, rphi), branch, vid=vid)
        for a, b, status, gen in self.conn.execute(
            "SELECT a, b, status, gen FROM edges ORDER BY a, b"
        ):
            g.set_edge(a, b, status, gen)
        next_id = self.meta().get("next_id")
        if next_id is not None:
            g.next_id = max(g.next_id, int(next_id))
        return g

    def load_links(self) -> tuple[dict[tuple[int, str], bool], int | None]:
        """Remembered Reach(vertex, goal) answers and their generation."""
        rows = self.conn.execute("SELECT vertex, goal, ok, gen FROM goal_links").fetchall()
        gens = {r[3] for r in rows}
        return {(int(v), str(g)): bool(ok) for v, g, ok, _ in rows}, (
            gens.pop() if len(gens) == 1 else None
        )

    def task_rows(self) -> list[dict[str, Any]]:
        """Every saved task row, in order."""
        cols = ("task", *TASK_COLUMNS)
        rows = self.conn.execute(f"SELECT {', '.join(cols)} FROM tasks ORDER BY task").fetchall()
        return [dict(zip(cols, r, strict=True)) for r in rows]

    # --- writing ---------------------------------------------------------------------------

    def commit_task(
        self,
        graph: ExperienceGraph,
        state: Mapping[str, Any],
        row: Mapping[str, Any] | None,
        links: Mapping[tuple[int, str], bool] | None = None,
        key: str = "state",
    ) -> None:
        """Write G, the run state (meta ``key``) and one task row in a single transaction."""
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

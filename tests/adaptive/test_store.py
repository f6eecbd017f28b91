from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]

from cellplan.adaptive.graph import BLOCKED, FREE
from cellplan.adaptive.runner import run_adaptive
from cellplan.adaptive.store import ExperienceStore, export_graphml
from cellplan.errors import PersistenceError
from cellplan.scenario import loads_scenario

HERE = Path(__file__).parent


def _graph_rows(g):  # type: ignore[no-untyped-def]
    return (
        sorted((v.id, v.obj, tuple(np.round(v.q, 12))) for v in g.vertices.values()),
        sorted((k, e.status, e.gen) for k, e in g.edges.items()),
    )


def test_round_trip_and_continue_equals_one_run(tmp_path: Path) -> None:
    sc = loads_scenario(POINT_SCENARIO)
    full = run_adaptive(sc)
    db = tmp_path / "exp.sqlite"
    with ExperienceStore(db, sc) as store:
        run_adaptive(sc, tasks=3, store=store)
    with ExperienceStore(db, sc) as store:
        assert store.state()["tasks_done"] == 3  # type: ignore[index]
        part = run_adaptive(sc, store=store)
        saved = store.load_graph()
    assert [r["task"] for r in part.rows] == list(range(1, 8))
    assert _graph_rows(saved) == _graph_rows(full.adapter.graph)  # type: ignore[union-attr]
    assert [r["adapt"] for r in part.rows] == [r["adapt"] for r in full.rows]
    out = export_graphml(saved, tmp_path / "g.graphml")
    import networkx as nx

    assert nx.read_graphml(out).number_of_nodes() == len(saved)


def test_edge_status_and_generation_are_stored(tmp_path: Path) -> None:
    sc = loads_scenario(POINT_SCENARIO)
    db = tmp_path / "exp.sqlite"
    with ExperienceStore(db, sc) as store:
        run_adaptive(sc, store=store)
    conn = sqlite3.connect(db)
    statuses = {r[0] for r in conn.execute("SELECT status FROM edges")}
    gens = {r[0] for r in conn.execute("SELECT gen FROM edges")}
    mode = conn.execute("PRAGMA journal_mode").fetchone()[0]
    conn.close()
    assert statuses <= {FREE, BLOCKED, "unknown"} and FREE in statuses
    assert 1 in gens  # edges verified after the change carry generation 1
    assert mode == "wal"


def test_foreign_and_corrupt_databases_are_refused(tmp_path: Path) -> None:
    sc = loads_scenario(POINT_SCENARIO)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database at all" * 100)
    with pytest.raises(PersistenceError, match="not a readable experience database"):
        ExperienceStore(junk, sc)
    foreign = tmp_path / "foreign.sqlite"
    conn = sqlite3.connect(foreign)
    conn.execute("CREATE TABLE t (x)")
    conn.commit()
    conn.close()
    with pytest.raises(PersistenceError, match="not a cellplan experience database"):
        ExperienceStore(foreign, sc)
    assert sqlite3.connect(foreign).execute("SELECT count(*) FROM t").fetchone() == (
        0,
    )  # untouched
    db = tmp_path / "exp.sqlite"
    with ExperienceStore(db, sc) as store:
        run_adaptive(sc, tasks=2, store=store)
    other_robot = loads_scenario(POINT_SCENARIO.replace("start: [1.0, 1.0]", "start: [1.0, 1.5]"))
    with pytest.raises(PersistenceError, match="another robot"):
        ExperienceStore(db, other_robot)
    other_cell = loads_scenario(POINT_SCENARIO.replace("max: [6.0, 7.0]", "max: [6.0, 7.5]"))
    with pytest.raises(PersistenceError, match="another workcell"):
        ExperienceStore(db, other_cell)
    with ExperienceStore(db, sc) as store:  # nothing lost
        assert store.state()["tasks_done"] == 2  # type: ignore[index]


def test_killed_mid_task_leaves_the_previous_task(tmp_path: Path) -> None:
    scenario_file = tmp_path / "s.yaml"
    scenario_file.write_text(POINT_SCENARIO, encoding="utf-8")
    db, snap = tmp_path / "exp.sqlite", tmp_path / "snap.json"
    kill_task = 4
    proc = subprocess.run(
        [
            sys.executable,
            str(HERE / "kill_run.py"),
            str(scenario_file),
            str(db),
            str(kill_task),
            str(snap),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == -9, proc.stderr  # SIGKILL inside task 4, after G was changed
    sys.path.insert(0, str(HERE))
    try:
        from kill_run import dump  # type: ignore[import-not-found]
    finally:
        sys.path.pop(0)
    before = json.loads(snap.read_text(encoding="utf-8"))
    assert dump(str(db)) == before
    sc = loads_scenario(POINT_SCENARIO)
    with ExperienceStore(db, sc) as store:
        assert store.state()["tasks_done"] == kill_task - 1  # type: ignore[index]
        rest = run_adaptive(sc, store=store)
    assert len(rest.rows) == 7 and all(r["success"] for r in rest.rows)

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]

from cellplan.trajectory import Trajectory


def _cellplan(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cellplan.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_adapt_command_writes_csv_pictures_and_continues(tmp_path: Path) -> None:
    scenario = tmp_path / "s.yaml"
    scenario.write_text(POINT_SCENARIO, encoding="utf-8")
    out, db = tmp_path / "out", tmp_path / "exp.sqlite"
    first = _cellplan(
        "adapt",
        str(scenario),
        "--repair",
        "A3",
        "--tasks",
        "3",
        "--seed",
        "0",
        "--db",
        str(db),
        "-o",
        str(out),
    )
    assert first.returncode == 0, first.stderr
    assert first.stdout.startswith("3 of 3 tasks solved") and first.stdout.count("\n") == 1
    for name in (
        "paths.csv",
        "paths.png",
        "tasks.csv",
        "ratio.png",
        "costs.png",
        "graph.png",
        "snapshots.png",
        "graph.graphml",
        "summary.json",
    ):
        assert (out / name).stat().st_size > 0, name
    rows = list(csv.DictReader((out / "tasks.csv").open(encoding="utf-8")))
    assert len(rows) == 3 and {"reach", "trace", "solve", "abstract", "baseline"} <= set(rows[0])
    paths = Trajectory.load(out / "paths.csv")
    assert [e.detail for e in paths.events_of("arrive")] == ["g1", "home", "g1"]
    second = _cellplan(
        "adapt",
        str(scenario),
        "--tasks",
        "7",
        "--seed",
        "0",
        "--db",
        str(db),
        "-o",
        str(out),
        "--json",
    )
    assert second.returncode == 0, second.stderr
    payload = json.loads(second.stdout)
    assert payload["status"] == "solved" and payload["stats"]["tasks"] == 7
    assert payload["options"]["db"] == str(db)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["tasks"] == 7 and summary["paths_ok_at_4x"] == 7
    # the continued run's paths are the tasks it ran: 4 to 7, the change before task 5
    paths = Trajectory.load(out / "paths.csv")
    assert [e.detail for e in paths.events_of("task")] == ["g2", "home", "g1", "home"]
    assert [e.detail for e in paths.events_of("change")] == ["add_object C"]


def test_adapt_command_reports_user_errors(tmp_path: Path) -> None:
    scenario = tmp_path / "s.yaml"
    scenario.write_text(POINT_SCENARIO, encoding="utf-8")
    bad = _cellplan("adapt", str(scenario), "--repair", "A7", "-o", str(tmp_path / "o"))
    assert bad.returncode == 2 and "--repair" in bad.stderr and "Traceback" not in bad.stderr
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"\x00garbage" * 200)
    corrupt = _cellplan("adapt", str(scenario), "--db", str(junk), "-o", str(tmp_path / "o"))
    assert corrupt.returncode == 2 and "not a readable experience database" in corrupt.stderr
    assert junk.read_bytes() == b"\x00garbage" * 200  # nothing written to a foreign file
    wrong = tmp_path / "w.yaml"
    wrong.write_text(POINT_SCENARIO.replace("object: C\n", "object: A\n"), encoding="utf-8")
    res = _cellplan("adapt", str(wrong), "-o", str(tmp_path / "o"))
    assert res.returncode == 2 and "adaptive.changes[0].object" in res.stderr

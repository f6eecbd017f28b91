"""Subprocess helper for the kill test: run, snapshot the database after task K-1, die in task K."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import sys

from cellplan.adaptive.runner import run_adaptive
from cellplan.adaptive.store import ExperienceStore
from cellplan.scenario import loads_scenario


def dump(db: str) -> dict[str, list[list[object]]]:
    conn = sqlite3.connect(db)
    try:
        return {
            t: [list(r) for r in conn.execute(f"SELECT * FROM {t} ORDER BY 1, 2")]
            for t in ("meta", "vertices", "edges", "tasks")
        }
    finally:
        conn.close()


def main() -> None:
    scenario_file, db, kill_task, snap = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    with open(scenario_file, encoding="utf-8") as fh:
        sc = loads_scenario(fh.read())
    store = ExperienceStore(db, sc)
    done = {"n": 0}

    def on_task(n: int, total: int, row: dict[str, object]) -> None:
        done["n"] = n
        if n == kill_task - 1:
            with open(snap, "w", encoding="utf-8") as fh:
                json.dump(dump(db), fh)

    def hook(phase: str) -> None:
        if done["n"] == kill_task - 1 and phase == "executed":
            os.kill(os.getpid(), signal.SIGKILL)

    run_adaptive(sc, store=store, on_task=on_task, hook=hook)


if __name__ == "__main__":
    main()

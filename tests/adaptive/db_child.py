"""Subprocess helper for the database tests.

``hold DB SCENARIO``: open the experience database, print ``locked`` and sleep (the
test kills it). ``kill-create DB SCENARIO STEP``: create the database and SIGKILL this
process at a step of the creation (``begun``, ``written``, ``synced``, ``renamed``).
"""

from __future__ import annotations

import os
import signal
import sys
import time

from cellplan.adaptive import store
from cellplan.scenario import loads_scenario


def main() -> None:
    mode, db, scenario_file = sys.argv[1:4]
    with open(scenario_file, encoding="utf-8") as fh:
        sc = loads_scenario(fh.read())
    if mode == "hold":
        store.ExperienceStore(db, sc)
        print("locked", flush=True)
        time.sleep(600)
    elif mode == "kill-create":
        at = sys.argv[4]

        def step(name: str) -> None:
            if name == at:
                os.kill(os.getpid(), signal.SIGKILL)

        store._creation_step = step
        store.ExperienceStore(db, sc)
        raise SystemExit("the kill step was never reached")


if __name__ == "__main__":
    main()

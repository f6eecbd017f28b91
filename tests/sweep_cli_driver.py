"""``cellplan`` as a subprocess whose packages offer only fake, cheap experiments.

Usage: ``python tests/sweep_cli_driver.py reproduce assembly --scheduler ... -o DIR``.
Every paper then offers one :func:`fake_sweep_experiments.sleepy` experiment of
``FAKE_SLEEP`` seconds per run (default 0.05); ``FAKE_NO_WORKER_S`` shortens the sweep's
wait for a worker (:data:`cellplan.experiments.NO_WORKER_TIMEOUT_S`) so that a test of
lost workers stays quick. Workers import ``fake_sweep_experiments`` from this folder
(give them ``PYTHONPATH``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import replace

import fake_sweep_experiments as fake
from cellplan import experiments as ex
from cellplan.cli import main


def discover(
    papers: Mapping[str, str] | Sequence[str] | None = None,
) -> list[ex.PaperExperiments]:
    """One sleepy experiment per paper, named ``<paper>.sleepy``."""
    names = list(ex.experiment_modules()) if papers is None else list(papers)
    sleep = float(os.environ.get("FAKE_SLEEP", "0.05"))
    found = []
    for paper in names:
        exp = replace(fake.sleepy(f"{paper}.sleepy", sleep=sleep), paper=paper)
        found.append(ex.PaperExperiments(paper, [exp]))
    return found


if __name__ == "__main__":
    ex.discover = discover
    # The cache key holds a digest of cellplan's sources; pinned, so that an edit of the
    # working tree between a test's two commands does not pass for a failed resume.
    ex.code_digest = lambda: "fake-code"  # type: ignore[assignment]
    if "FAKE_NO_WORKER_S" in os.environ:
        ex.NO_WORKER_TIMEOUT_S = float(os.environ["FAKE_NO_WORKER_S"])
    main()

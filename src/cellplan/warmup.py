"""Compiled kernels: warm the cache after an install, and say so when a compile happens.

cellplan's kernels are numba functions compiled with ``cache=True``: the first call of
each on a machine compiles it (seconds each, up to a minute for a planner's first run),
and later runs load the machine code from the cache. The cache lives beside each source
file, in its ``__pycache__`` folder (``*.nbi`` index and ``*.nbc`` code files), or under
``NUMBA_CACHE_DIR`` when that is set (an installation whose sources are read-only).
``make clean-kernels`` deletes it; it is rebuilt on the next run.

:func:`warm_up` (``python -m cellplan.warmup``, run by ``make install``) runs the
commands a newcomer runs first, on small bundled problems, in one process per core, so
that their kernels are compiled once at install time instead of during a first
``cellplan solve``. They also reach every kernel the demo runs (policy iteration, the
strategy's point queries, the reactive baseline, the place rule), so the demo's sweep
workers load them all instead of each compiling them again. The groups are balanced (about
the same compile each) and compile no (kernel, signature) twice:
``benchmarks/bench_warmup_compiles.py`` prints both. A compile that still happens in a
command (a kernel this warm-up does not reach, or one specialised at run time) is
announced by the CLI in one ``note:`` line (:func:`cellplan.cliutil.announce_compiles`).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import io
import multiprocessing
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from cellplan.cli import app

#: Groups of CLI commands, each run in one process; ``{tmp}`` is a scratch folder. Every
#: command reads a bundled scenario, so the warm-up needs no file of the user's.
WARMUP_GROUPS: tuple[tuple[tuple[str, ...], ...], ...] = (
    (
        ("solve", "strategies_tiny", "-o", "{tmp}/tiny.npz"),
        (
            "simulate",
            "strategies_tiny",
            "--strategy",
            "{tmp}/tiny.npz",
            "--stages",
            "200",
            "--no-gif",
            "-o",
            "{tmp}/sim",
        ),
        ("validate", "strategies_p1"),
        ("validate", "strategies_p6"),
    ),
    (
        # without --pictures: drawing compiles no kernel, and cost about 5 CPU s a command
        ("assemble", "discs_seven", "-o", "{tmp}/gradient"),
        ("assemble", "discs_seven", "--algorithm", "sequential", "-o", "{tmp}/sequential"),
        # the place rule's segment clearances (segments_gap_kernel)
        (
            "assemble",
            "discs_seven",
            "--algorithm",
            "sequential",
            "--rule",
            "place",
            "-o",
            "{tmp}/place",
        ),
        ("adapt", "adaptive_fig3", "--tasks", "3", "-o", "{tmp}/adapt"),
        ("validate", "ur5_cell"),
        # Last, once the first group has compiled the model's kernels (it starts with
        # them): policy iteration, the solver of every model with failures or noise, whose
        # kernels no structured solve reaches. It also compiles the certificate's Bellman
        # sweep and the point queries of the sample run before the first group gets
        # there, which then loads them: the two groups share the strategies' compiling.
        ("solve", "strategies_tiny", "--method", "policy", "-o", "{tmp}/policy.npz"),
        # strategy.action (the query kernels), as `plot` and the demo's pictures use it
        ("plot", "strategies_tiny", "--strategy", "{tmp}/policy.npz", "-o", "{tmp}/plot.png"),
        # the reactive baseline's layer sweeps
        (
            "simulate",
            "strategies_tiny",
            "--strategy",
            "{tmp}/policy.npz",
            "--stages",
            "50",
            "--policy",
            "reactive",
            "--no-gif",
            "-o",
            "{tmp}/reactive",
        ),
    ),
)


def _run_group(commands: Sequence[Sequence[str]], tmp: str) -> float:
    """Run CLI commands in this process (output discarded); return the seconds taken.

    A command that exits with a status other than 0 or 1 is a failed warm-up.
    """
    Path(tmp).mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    for command in commands:
        args = [part.format(tmp=tmp) for part in command]
        sink = io.StringIO()
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            try:
                code = app(args, standalone_mode=False)
            except SystemExit as exc:
                code = exc.code
        if code not in (None, 0, 1):
            raise RuntimeError(f"warm-up command `cellplan {' '.join(args)}` exited {code}")
    return time.perf_counter() - t0


def warm_up(workers: int | None = None) -> float:
    """Compile the kernels of the first commands a user runs; return the seconds taken.

    Each group of :data:`WARMUP_GROUPS` runs in a fresh process (spawned, so no numba
    state is inherited), at most ``workers`` at a time (default: the CPU count).
    """
    workers = max(1, min(len(WARMUP_GROUPS), workers or os.cpu_count() or 1))
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="cellplan-warmup-") as tmp:
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(workers, mp_context=context) as pool:
            jobs = [
                pool.submit(_run_group, group, str(Path(tmp) / f"group{i}"))
                for i, group in enumerate(WARMUP_GROUPS)
            ]
            for job in jobs:
                job.result()
    return time.perf_counter() - t0


def main() -> None:
    """``python -m cellplan.warmup``: compile the kernels and print one line."""
    seconds = warm_up()
    print(f"cellplan: kernels compiled and cached in {seconds:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()

"""How many threads the strategies solver uses, and the pool that runs its parallel steps.

The kernels are serial and release the GIL (``nogil=True``); the solver runs independent
work items (C layers, W layers, ranges of states of a Jacobi sweep) on a small pool of
Python threads. Why not numba's ``prange``: its OpenMP and TBB layers keep their workers
spinning between parallel regions, which on a shared 2-core machine steals the core the
solver's serial steps need (problem 1: 0.34 s with two threads against 0.26 s with one;
the 12 x 12 problem 0.15-0.4 s instead of 0.002 s). Threads of a pool wait on a lock
instead, and take work items as they free up, so a thread slowed by another process's job
takes fewer items rather than holding the others at a barrier.

Below :data:`SERIAL_BELOW` states per parallel step the pool is not used at all (its
start-up and hand-over, tens of microseconds per item, would cost more than the work).
The thread count is ``NUMBA_NUM_THREADS`` (numba's own setting, default: the CPUs this
process may run on), or the ``threads`` argument of
:func:`cellplan.strategies.solve.solver.solve`. docs/strategies.md ("Threads") has the
measurements.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

from numba.core import config as numba_config

T = TypeVar("T")
R = TypeVar("R")

# Problems with fewer live states than this run in the calling thread.
SERIAL_BELOW = 20_000


def default_threads() -> int:
    """The thread count by default: numba's ``NUMBA_NUM_THREADS``, at most the CPUs usable."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    # numba's setting (its environment variable, or the CPU count) read at import.
    configured = int(getattr(numba_config, "NUMBA_NUM_THREADS", usable or 1))
    return max(1, min(configured, usable or 1))


class Workers:
    """A pool of ``threads`` threads for independent kernel calls (serial when 1).

    Use as a context manager; :meth:`map` runs ``fn`` over ``items`` and returns the
    results in order.
    """

    def __init__(self, threads: int) -> None:
        self.threads = max(1, int(threads))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
        if self._pool is None:
            return [fn(item) for item in items]
        return list(self._pool.map(fn, items))

    def map_chains(
        self, fn: Callable[[T], R], roots: Iterable[T], after: Callable[[T], list[T]]
    ) -> dict[T, R]:
        """Run ``fn`` on every root and, as soon as an item is done, on the items
        ``after(item)`` names (each item named once, by one predecessor).

        Items that wait for a predecessor take a thread only once it is done, so no
        thread idles at a barrier between stages (the solver's W layer of a request
        starts as soon as its C layer is solved). Serially an item's followers run right
        after it. Returns ``{item: fn(item)}``.
        """
        results: dict[T, R] = {}
        if self._pool is None:
            todo = list(roots)[::-1]
            while todo:
                item = todo.pop()
                results[item] = fn(item)
                todo.extend(after(item)[::-1])
            return results
        pool = self._pool
        futures: list[Future[None]] = []

        def run(item: T) -> None:
            results[item] = fn(item)
            # Submitted before this future completes, so the loop below waits for them.
            futures.extend(pool.submit(run, nxt) for nxt in after(item))

        futures.extend(pool.submit(run, item) for item in roots)
        done = 0
        while done < len(futures):
            futures[done].result()  # re-raises a worker's exception here
            done += 1
        return results

    def ranges(self, n: int, per_thread: int = 4) -> list[tuple[int, int]]:
        """``[start, stop)`` chunks of ``range(n)``: ``per_thread`` per thread (one if serial)."""
        k = 1 if self._pool is None else self.threads * per_thread
        cuts = [n * i // k for i in range(k + 1)]
        return [(a, b) for a, b in itertools.pairwise(cuts) if b > a]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def workers_for(states: int, threads: int | None = None) -> Workers:
    """The pool for a problem of ``states`` live states (serial below :data:`SERIAL_BELOW`)."""
    n = default_threads() if threads is None else int(threads)
    if states < SERIAL_BELOW:
        n = 1
    return Workers(n)

"""The solver's thread pool: the same answer with any thread count; small problems serial."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from strategies_helpers import tiny

from cellplan.strategies import threads
from cellplan.strategies.model import build_model
from cellplan.strategies.solver import solve


@given(st.integers(0, 5000), st.integers(1, 8), st.integers(1, 6))
def test_ranges_cover_every_index_once_in_order(n, nthreads, per_thread):
    with threads.Workers(nthreads) as pool:
        chunks = pool.ranges(n, per_thread)
    covered = [i for a, b in chunks for i in range(a, b)]
    assert covered == list(range(n))
    assert all(b > a for a, b in chunks)


def test_small_problems_run_without_a_pool():
    assert threads.workers_for(threads.SERIAL_BELOW - 1, threads=4).threads == 1
    assert threads.workers_for(threads.SERIAL_BELOW, threads=4).threads == 4


def test_threaded_solve_gives_the_serial_answer(monkeypatch):
    mdp = build_model(*tiny(cells=16))
    serial = solve(mdp, threads=1)
    # Force the pool on this small problem: layers and Jacobi ranges on two threads.
    monkeypatch.setattr(threads, "SERIAL_BELOW", 0)
    pooled = solve(mdp, threads=2)
    assert pooled.converged and serial.converged
    assert pooled.gain == serial.gain
    assert (pooled.gain_lower, pooled.gain_upper) == (serial.gain_lower, serial.gain_upper)
    np.testing.assert_array_equal(pooled.values, serial.values)
    np.testing.assert_array_equal(pooled.policy, serial.policy)

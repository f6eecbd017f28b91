"""The solver's thread pool: the same answer with any thread count; small problems serial."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from strategies_helpers import TINY, tiny

from cellplan.scenario import loads_scenario
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.solve import threads
from cellplan.strategies.solve.layers import Layers
from cellplan.strategies.solve.solver import solve
from cellplan.workcell import Workcell


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


@given(
    st.lists(st.integers(-1, 30), min_size=1, max_size=30),
    st.integers(1, 4),
)
def test_map_chains_runs_every_item_once_after_its_predecessor(parents, nthreads):
    # Item i follows parents[i] when that is an earlier item, else it is a root: a forest.
    parent = [p if 0 <= p < i else -1 for i, p in enumerate(parents)]
    children: dict[int, list[int]] = {i: [] for i in range(len(parent))}
    for i, p in enumerate(parent):
        if p >= 0:
            children[p].append(i)
    roots = [i for i, p in enumerate(parent) if p < 0]
    lock = threading.Lock()
    done: list[int] = []

    def fn(item: int) -> int:
        with lock:
            # A follower runs only once its predecessor has finished.
            assert parent[item] < 0 or parent[item] in done
            done.append(item)
        return 10 * item

    with threads.Workers(nthreads) as pool:
        results = pool.map_chains(fn, roots, children.__getitem__)
    assert sorted(done) == list(range(len(parent)))
    assert results == {i: 10 * i for i in range(len(parent))}


@pytest.mark.parametrize("nthreads", [1, 2])
def test_map_chains_raises_a_workers_error(nthreads):
    def fn(item: int) -> int:
        if item == 3:
            raise ValueError("item 3")
        return item

    with threads.Workers(nthreads) as pool, pytest.raises(ValueError, match="item 3"):
        pool.map_chains(fn, [0, 1], {0: [2], 1: [3], 2: [], 3: []}.__getitem__)


def test_threaded_solve_with_shared_layers_gives_the_serial_answer(monkeypatch):
    # D2 is D1 again: the requests to D2 have the same C and W layers as those to D1,
    # solved once and copied; each W layer must read its C layer only once it is copied.
    d1_line = "  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}\n"
    text = TINY.replace("CELLS", "16").replace(d1_line, d1_line + d1_line.replace("D1", "D2"))
    sc = loads_scenario(text)
    mdp = build_model(sc, Workcell.from_scenario(sc))
    run = Layers(mdp, 100, threads.Workers(1))
    assert len(run.c_reps) == len(run.c_layers) // 2
    assert len(run.w_reps) == len(run.w_layers) // 2
    serial = solve(mdp, threads=1)
    monkeypatch.setattr(threads, "SERIAL_BELOW", 0)
    pooled = solve(mdp, threads=2)
    assert pooled.converged and serial.converged
    assert pooled.gain == serial.gain
    np.testing.assert_array_equal(pooled.values, serial.values)
    np.testing.assert_array_equal(pooled.policy, serial.policy)
    # The requests to D1 and to D2 have the same values.
    for r1, r2 in ((0, 1), (2, 3)):
        for layer in (mdp.c_layer, mdp.w_layer):
            np.testing.assert_array_equal(pooled.values[layer(r1)], pooled.values[layer(r2)])

"""The named steps of the structured solver's outer loop (solver.solve_structured)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from strategies_helpers import tiny

from cellplan.core import Status
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.solve import solver
from cellplan.strategies.solve.layers import Layers
from cellplan.strategies.solve.solver import (
    _certificate_due,
    _Drift,
    _inner_accuracy,
    _moved_along_newton,
    _normalise_nr,
)
from cellplan.strategies.solve.threads import Workers

TOL = 1e-6
finite = st.floats(-1e3, 1e3, allow_nan=False)
small = st.floats(0.0, 1e3, allow_nan=False)


def _drift(drift: float = 0.0, deriv: float = -1.0, shape: float = 0.0) -> _Drift:
    return _Drift(drift=drift, deriv=deriv, shape=shape, shift=0.0, d_shift=0.0)


@given(st.integers(0, 2**32 - 1), st.booleans())
@settings(max_examples=40, deadline=None)
def test_normalise_nr_measures_the_pass_and_zeroes_the_reference(seed, first):
    rng = np.random.default_rng(seed)
    M, N = 3, 12
    lnr = rng.random(N) < 0.7
    lnr[rng.integers(N)] = True
    ref = int(rng.choice(np.flatnonzero(lnr)))
    h = rng.normal(size=(M, N))
    D = rng.normal(size=(M, N))
    old, old_d = rng.normal(size=N), rng.normal(size=N)
    h0, D0 = h.copy(), D.copy()
    p = _normalise_nr(h, D, old, old_d, lnr, ref, first)
    assert p.drift == h0[0, ref] - old[ref]
    assert p.deriv == D0[0, ref] - old_d[ref]
    change = (h0[0] - old)[lnr]
    assert p.shape == (np.inf if first else change.max() - change.min())
    assert (p.shift, p.d_shift) == (h0[0, ref], D0[0, ref])
    assert h[0, ref] == 0.0 and D[0, ref] == 0.0
    np.testing.assert_array_equal(h[0][lnr], h0[0][lnr] - h0[0, ref])
    # Outside NR's live states, and in the other layers, nothing moves.
    np.testing.assert_array_equal(h[0][~lnr], h0[0][~lnr])
    np.testing.assert_array_equal(h[1:], h0[1:])
    np.testing.assert_array_equal(D[1:], D0[1:])


@given(finite, st.floats(-1e3, -1e-3), finite)
def test_newton_step_zeroes_a_linear_drift(a, b, g0):
    # drift(g) = a + b (g - g0) with b < 0 (the expected cycle length is positive).
    step = _drift(drift=a, deriv=b).newton()
    assert abs(a + b * step) <= 1e-9 * max(1.0, abs(a))


@given(finite, st.floats(0.0, 1e3))
def test_no_newton_step_without_descent(a, b):
    assert _drift(drift=a, deriv=b).newton() == 0.0


@given(small, small, st.booleans())
def test_inner_accuracy_follows_the_outer_progress(drift, shape, coupled):
    inner = TOL * solver.INNER_FACTOR
    p = _drift(drift=drift, shape=shape)
    assert _inner_accuracy(p, True, coupled, inner, TOL) == solver.FIRST_ACCURACY
    acc = _inner_accuracy(p, False, coupled, inner, TOL)
    assert inner <= acc <= solver.FIRST_ACCURACY
    if shape <= solver.EARLY_SHAPE * TOL and not coupled:
        expected = inner
    else:
        rule = solver.ACCURACY_FACTOR * min(drift, shape)
        expected = min(solver.FIRST_ACCURACY, max(inner, rule))
    assert acc == expected


@given(st.floats(0.0, 1e-2), st.floats(0.0, 1e-5), st.floats(1e-10, 1e-2), st.floats(0.0, 1.0))
def test_certificate_is_due_only_after_a_full_settled_pass(drift, shape, accuracy, less):
    p = _drift(drift=drift, shape=shape)
    due = _certificate_due(p, False, False, accuracy, TOL)
    # Never on a capped or the first pass.
    assert not _certificate_due(p, True, False, accuracy, TOL)
    assert not _certificate_due(p, False, True, accuracy, TOL)
    # Monotone: a smaller drift and shape change, or more accurate layers, keep it due.
    closer = _drift(drift=drift * less, shape=shape * less)
    assert not due or _certificate_due(closer, False, False, accuracy * less, TOL)
    assert due == (
        shape < solver.ATTEMPT_SHAPE * TOL
        and (
            drift < TOL
            or (drift < solver.NEWTON_DRIFT * TOL and accuracy <= solver.NEWTON_ACCURACY * TOL)
        )
    )


@pytest.fixture(scope="module")
def tiny_run():
    sc, cell = tiny(cells=12)
    mdp = build_model(sc, cell)
    with Workers(1) as workers:
        yield Layers(mdp, 100, workers)


@given(st.integers(0, 2**32 - 1), st.floats(-0.1, 0.1))
@settings(max_examples=20, deadline=None)
def test_trial_moves_every_layer_along_newton(tiny_run, seed, step):
    run = tiny_run
    rng = np.random.default_rng(seed)
    live = run.live
    run.h[:] = np.where(live, rng.normal(size=live.shape), np.nan)
    run.D[:] = np.where(live, -rng.random(live.shape) * 50, np.nan)
    p = _Drift(drift=0.0, deriv=-1.0, shape=0.0, shift=rng.normal(), d_shift=rng.normal())
    h0 = run.h.copy()
    trial = _moved_along_newton(run, p, step)
    np.testing.assert_array_equal(run.h, h0)  # the solver's values are not touched
    np.testing.assert_array_equal(trial[0][live[0]], (run.h[0] + step * run.D[0])[live[0]])
    for m in run.order:
        lm = live[m]
        moved = run.h[m] + step * (run.D[m] - p.d_shift) - p.shift
        np.testing.assert_allclose(trial[m][lm], moved[lm], rtol=0, atol=1e-12)
    assert np.all(np.isnan(trial[~live]))


@pytest.fixture(scope="module")
def tiny_solved():
    sc, cell = tiny(cells=12)
    mdp = build_model(sc, cell)
    return mdp, solver.solve_structured(mdp, TOL)


def _brackets_overlap(a, b) -> bool:
    return max(a.gain_lower, b.gain_lower) <= min(a.gain_upper, b.gain_upper)


@given(st.floats(0.0, 1.0), st.floats(0.0, 100.0), st.integers(0, 2**32 - 1))
@settings(max_examples=15, deadline=None)
def test_a_start_changes_the_path_not_the_answer(tiny_solved, g_frac, scale, seed):
    mdp, cold = tiny_solved
    nr = np.random.default_rng(seed).normal(size=mdp.live.shape[1]) * scale
    res = solver.solve_structured(mdp, TOL, start=(g_frac * mdp.stage_time, nr))
    assert res.status is Status.SOLVED
    assert res.span < TOL
    assert _brackets_overlap(res, cold)  # both certified: the gain lies in each


def test_started_from_its_own_answer_the_outer_loop_has_nothing_to_find(tiny_solved):
    # One exact pass from the answer's g and NR (C and W layers cold), one that confirms
    # it: the floor that benchmarks/bench_strategies.py --oracle measures.
    mdp, cold = tiny_solved
    assert cold.outer_iterations > 2
    res = solver.solve_structured(mdp, TOL, start=(cold.gain, cold.values[0]))
    assert res.status is Status.SOLVED
    assert res.outer_iterations == 2
    assert _brackets_overlap(res, cold)


@pytest.mark.parametrize(
    ("gain", "values", "field"),
    [
        (np.nan, None, "gain nan"),
        (-0.1, None, "gain -0.1"),
        (None, "short", "shape"),
        (None, "nan on live", "not finite"),
    ],
)
def test_a_bad_start_is_refused_naming_the_field(tiny_solved, gain, values, field):
    mdp, cold = tiny_solved
    nr = cold.values[0].copy()
    if values == "short":
        nr = nr[:-1]
    elif values == "nan on live":
        nr[np.flatnonzero(mdp.live[0])[3]] = np.nan
    with pytest.raises(ValueError, match=f"^start: .*{field}"):
        solver.solve_structured(mdp, TOL, start=(cold.gain if gain is None else gain, nr))

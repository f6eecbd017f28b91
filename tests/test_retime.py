"""Time-optimal retiming (TOPP-RA): limits hold, the path is unchanged, stops stay stops."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan import timing
from cellplan.errors import ArgumentError
from cellplan.trajectory import Event, Trajectory

#: Relative tolerance on the limits at the samples (TOPP-RA's LP solver is exact to ~1e-9).
LIMIT_TOL = 1e-6


def _traj(q, events=(), **extra):
    q = np.asarray(q, dtype=float)
    n = len(q)
    dim = q.shape[1]
    return Trajectory(
        np.arange(n, dtype=float),
        q,
        np.zeros(n, dtype=np.int64),
        ("m",),
        tuple(f"q{j + 1}" for j in range(dim)),
        ("rad",) * dim,
        events=tuple(events),
        **extra,
    )


def _check(original, retimed, vlim, alim):
    """Limits at every sample, samples on the original path, every input sample kept."""
    assert np.all(np.abs(retimed.qd) <= np.asarray(vlim) * (1 + LIMIT_TOL))
    assert np.all(np.abs(retimed.qdd) <= np.asarray(alim) * (1 + LIMIT_TOL))
    # the geometric path: each new sample lies on the original polyline at its t
    assert np.allclose(original.sample(retimed.t), retimed.q, atol=1e-9)
    # every input sample is an output sample, at rest where it is a stop
    assert np.all(np.diff(retimed.seconds) >= 0)
    assert retimed.qd[0].tolist() == [0.0] * original.dim
    assert retimed.qd[-1].tolist() == [0.0] * original.dim


def test_a_straight_line_takes_the_trapezoid_time():
    # independent oracle: on a line, the fastest motion accelerates at the largest
    # acceleration the line allows, cruises at its top speed, and brakes
    q = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5], [3.0, 6.0, 1.5]])
    vlim = np.array([1.0, 1.5, 2.0])
    alim = np.array([2.0, 1.0, 3.0])
    traj = _traj(q)
    out = traj.retime(vlim, alim)
    _check(traj, out, vlim, alim)
    d = q[-1] - q[0]
    length = np.linalg.norm(d)
    u = d / length
    v = np.min(vlim / np.abs(u))
    a = np.min(alim / np.abs(u))
    best = length / v + v / a if length > v * v / a else 2 * np.sqrt(length / a)
    assert out.duration_s == pytest.approx(best, rel=0.02)
    assert out.duration_s >= best * (1 - 1e-9)
    assert np.array_equal(out.q[0], q[0]) and np.array_equal(out.q[-1], q[-1])


@st.composite
def polylines(draw):
    """Grid-like polylines (steps along a few directions, some repeated, some zero)."""
    dim = draw(st.integers(1, 3))
    n = draw(st.integers(2, 9))
    steps = draw(
        st.lists(
            st.lists(st.sampled_from([-0.5, 0.0, 0.25, 0.5]), min_size=dim, max_size=dim),
            min_size=n - 1,
            max_size=n - 1,
        )
    )
    q = np.concatenate([np.zeros((1, dim)), np.cumsum(np.asarray(steps), axis=0)])
    vlim = np.asarray(draw(st.lists(st.floats(0.2, 5.0), min_size=dim, max_size=dim)))
    alim = np.asarray(draw(st.lists(st.floats(0.2, 5.0), min_size=dim, max_size=dim)))
    stops = draw(st.lists(st.integers(0, n - 1), max_size=2))
    events = tuple(sorted((Event(i, "pick", "P1 at S1") for i in stops), key=lambda e: e.index))
    return q, vlim, alim, events


@settings(max_examples=25, deadline=None)
@given(polylines())
def test_limits_hold_the_path_is_unchanged_and_stops_stay(case):
    q, vlim, alim, events = case
    traj = _traj(q, events, stage_duration=1.0)
    out = traj.retime(vlim, alim)
    _check(traj, out, vlim, alim)
    # the timing law at top speed is a lower bound on any timing within the limits
    assert out.duration_s >= timing.path_seconds(q, vlim)[-1] - 1e-9
    # events move with their samples; a pick is a stop
    for before, after in zip(traj.events, out.events, strict=True):
        assert np.array_equal(out.q[after.index], traj.q[before.index])
        assert np.all(out.qd[after.index] == 0.0)
        assert after.kind == before.kind and after.part == before.part
    # standing still keeps its duration (a dwell), here a stage of 1 s
    still = int(np.sum(np.all(np.diff(q, axis=0) == 0, axis=1)))
    assert out.duration_s >= still * 1.0 - 1e-9


def test_a_dwell_keeps_its_seconds_and_the_robot_rests():
    q = [[0.0], [1.0], [1.0], [1.0], [0.0]]
    traj = _traj(q, stage_duration=2.0)
    out = traj.retime([1.0], [1.0])
    resting = out.seconds[(out.q[:, 0] == 1.0)]
    assert resting.max() - resting.min() == pytest.approx(4.0)  # two stages of 2 s
    assert np.all(out.qd[out.q[:, 0] == 1.0] == 0.0)


@pytest.mark.parametrize(
    ("vlim", "alim", "field"),
    [
        ([0.0, 1.0], [1.0, 1.0], "velocity_limits"),
        ([-1.0, 1.0], [1.0, 1.0], "velocity_limits"),
        ([float("nan"), 1.0], [1.0, 1.0], "velocity_limits"),
        ([1.0, 1.0, 1.0], [1.0, 1.0], "velocity_limits"),
        ([1.0, 1.0], [1.0, float("inf")], "acceleration_limits"),
        ([1.0, 1.0], [], "acceleration_limits"),
    ],
)
def test_bad_limits_are_refused_in_one_line(vlim, alim, field):
    traj = _traj([[0.0, 0.0], [1.0, 1.0]])
    with pytest.raises(ArgumentError) as err:
        traj.retime(vlim, alim)
    assert len(err.value.problems) == 1
    assert err.value.problems[0].field == field


def test_a_path_leaving_the_joint_limits_is_refused():
    traj = _traj([[0.0, 0.0], [2.0, 0.5]])
    with pytest.raises(ArgumentError) as err:
        traj.retime(position_limits=([-1.0, -1.0], [1.0, 1.0]))
    (problem,) = err.value.problems
    assert "cannot be retimed: it leaves the joint limits (q1 = 2 at sample 1" in problem.message


def test_a_strategy_run_retimes_with_its_fine_motions_as_stops():
    import cellplan

    res = cellplan.plan(cellplan.load("strategies_tiny"), "strategies", sample_stages=80)
    traj = res.trajectory
    assert traj is not None and traj.events_of("pick")
    out = traj.retime()
    vlim = np.asarray(traj.velocity_limits)
    alim = np.asarray(traj.acceleration_limits)
    _check(traj, out, vlim, alim)
    for e in out.events:
        if e.kind in ("pick", "place"):
            assert np.all(out.qd[e.index] == 0.0)
    # no timing within the speed limits beats the timing law at top speed
    assert out.duration_s >= timing.path_seconds(traj.q, vlim)[-1] - 1e-9
    assert out.meta["retimed"] is True

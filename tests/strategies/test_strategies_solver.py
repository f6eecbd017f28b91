"""The solvers against a plain sparse-matrix relative value iteration, and against geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
from strategies_helpers import empty, tiny

from cellplan.core import Status
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.sim.options import SimulationOptions
from cellplan.strategies.solve.layers import Layers
from cellplan.strategies.solve.nr import other_branches
from cellplan.strategies.solve.solver import solve_general, solve_structured
from cellplan.strategies.solve.threads import Workers
from cellplan.workcell import load_workcell


def _stencil(q, mdp):
    """Multilinear stencil written independently of the kernels (plain numpy)."""
    d = len(q)
    base, frac, nxt = [], [], []
    for j in range(d):
        f = (q[j] - mdp.lower[j]) / mdp.spacing[j] - 0.5
        i0 = math.floor(f + 1e-9)
        t = f - i0
        if t < 1e-9:
            t = 0.0
        n = int(mdp.shape[j])
        if mdp.periodic[j]:
            base.append(i0 % n)
            nxt.append((i0 + 1) % n)
            frac.append(t)
            continue
        if i0 < 0:
            i0, t = 0, 0.0
        elif i0 >= n - 1:
            i0, t = n - 1, 0.0
        base.append(i0)
        nxt.append(min(i0 + 1, n - 1))
        frac.append(t)
    out = {}
    for k in range(1 << d):
        idx, w = [], 1.0
        for j in range(d):
            bit = (k >> (d - 1 - j)) & 1
            idx.append(nxt[j] if bit else base[j])
            w *= frac[j] if bit else 1.0 - frac[j]
        flat = int(np.ravel_multi_index(tuple(idx), tuple(mdp.shape)))
        out[flat] = out.get(flat, 0.0) + w
    return out


def _landing(centre, step, mdp):
    """Where a move from a cell centre lands (robot-frame moves turned, angles wrapped)."""
    step = step.copy()
    if mdp.heading_axis >= 0:  # robot-frame move of the rotating robot
        th = centre[mdp.heading_axis]
        dx, dy = step[0], step[1]
        step[0], step[1] = (dx * np.cos(th) - dy * np.sin(th), dx * np.sin(th) + dy * np.cos(th))
    q = centre + step
    for j in range(len(q)):
        if mdp.periodic[j]:
            span = mdp.upper[j] - mdp.lower[j]
            q[j] = mdp.lower[j] + (q[j] - mdp.lower[j]) % span
    return q


def sparse_rvi(mdp, tol=1e-10, max_iter=200000, damping=1.0):
    """Relative value iteration from the definition, one scipy.sparse matrix per action.

    FMP option j of mode m (one per mode but with simultaneous requests) costs t_f(j, x)
    and then, with probability p_o, adds c_o and moves to mode L_o at the same cell
    (Section V: one outcome; failure modes: several), every outcome a live state; stay
    keeps the cell in every branch; a move lands at each of its landings with
    probability p_j (one, exact, in Section V; noisy motion: row ``A + a J + j`` of
    ``disp``), on the stencil's live corners renormalised per branch. ``damping`` < 1
    averages each iterate with the last (aperiodic whatever the chain). Returns the gain
    and the relative values (NaN off the live states).
    """
    live = mdp.live
    out = mdp.fmp_outcomes()
    states = np.argwhere(live)
    index = -np.ones(live.shape, np.int64)
    index[live] = np.arange(len(states))
    S = len(states)
    A = int(mdp.nact.max())
    J = len(mdp.noise_prob)
    options = mdp.options  # FMP options per mode (several with simultaneous requests)
    fmp = [-2 - j for j in range(int(np.diff(options).max(initial=0)))]  # keys, not codes
    rows = {a: ([], [], []) for a in [*fmp, *range(-1, A)]}
    cost = {a: np.full(S, np.inf) for a in rows}
    for s, (m, c) in enumerate(states):
        centre = mdp.lower + (np.array(np.unravel_index(c, tuple(mdp.shape))) + 0.5) * mdp.spacing
        for j, opt in enumerate(range(options[m], options[m + 1])):
            outs = [
                (int(out.layer[o]), float(out.prob[o]), float(out.cost[o]))
                for o in range(out.ptr[opt], out.ptr[opt + 1])
                if out.prob[o] > 0
            ]
            if np.isfinite(mdp.tf[opt, c]) and outs and all(live[L, c] for L, _, _ in outs):
                for L, p, _ in outs:
                    rows[-2 - j][0].append(s)
                    rows[-2 - j][1].append(index[L, c])
                    rows[-2 - j][2].append(p)
                cost[-2 - j][s] = mdp.tf[opt, c] + sum(p * co for _, p, co in outs)
        k = mdp.vcls[m]
        na = int(mdp.nact[k])
        for a in range(-1, na):
            if a >= 0 and not (int(mdp.valid[k, c]) >> a) & 1:
                continue
            if a < 0:
                landings = [({c: 1.0}, 1.0)]
            elif J == 1:
                landings = [(_stencil(_landing(centre, mdp.disp[k, a], mdp), mdp), 1.0)]
            else:
                landings = [
                    (_stencil(_landing(centre, mdp.disp[k, na + a * J + j], mdp), mdp), pj)
                    for j, pj in enumerate(mdp.noise_prob.tolist())
                    if pj > 0
                ]
            entries = []
            ok = True
            for st, pj in landings:
                for b in range(mdp.branch_ptr[m], mdp.branch_ptr[m + 1]):
                    L = mdp.branch_layer[b]
                    wl = {i: w for i, w in st.items() if w > 1e-12 and live[L, i]}
                    tot = sum(wl.values())
                    if tot <= 1e-12:
                        ok = False
                        break
                    entries += [
                        (index[L, i], pj * mdp.branch_prob[b] * w / tot) for i, w in wl.items()
                    ]
            if not ok:
                continue
            for j, p in entries:
                rows[a][0].append(s)
                rows[a][1].append(j)
                rows[a][2].append(p)
            cost[a][s] = mdp.cost[m]
    mats = {a: sp.csr_matrix((r[2], (r[0], r[1])), shape=(S, S)) for a, r in rows.items()}
    h = np.zeros(S)
    ref = 0
    for _ in range(max_iter):
        th = np.min(np.stack([cost[a] + mats[a] @ h for a in mats]), axis=0)
        diff = th - h
        if diff.max() - diff.min() < tol:
            break
        h = (1.0 - damping) * h + damping * th
        h -= h[ref]
    values = np.full(live.shape, np.nan)
    values[live] = h
    return 0.5 * (diff.max() + diff.min()), values


@pytest.fixture(scope="module")
def tiny_model():
    sc, cell = tiny(cells=12)
    return build_model(sc, cell)


def _same_ref(a, b, live):
    ref = np.flatnonzero(live[0])[0]
    return a - a[0, ref], b - b[0, ref]


def test_structured_matches_plain_sparse_rvi(tiny_model):
    mdp = tiny_model
    res = solve_structured(mdp, tol=1e-9)
    assert res.status is Status.SOLVED
    g_ref, h_ref = sparse_rvi(mdp)
    assert abs(res.gain - g_ref) < 1e-6
    a, b = _same_ref(res.values, h_ref, mdp.live)
    assert np.nanmax(np.abs(a - b)) < 1e-6


def test_general_matches_structured(tiny_model):
    mdp = tiny_model
    s = solve_structured(mdp, tol=1e-9)
    g = solve_general(mdp, tol=1e-9)
    assert g.status is Status.SOLVED
    assert abs(g.gain - s.gain) < 1e-6
    assert g.gain_lower <= s.gain + 1e-9 and s.gain <= g.gain_upper + 1e-9


def test_gain_bounds_bracket_and_span(tiny_model):
    res = solve_structured(tiny_model, tol=1e-7)
    assert res.gain_lower <= res.gain <= res.gain_upper
    assert res.span < 1e-7
    assert 0.0 < res.gain < tiny_model.stage_time


def test_general_reports_non_convergence(tiny_model):
    res = solve_general(tiny_model, tol=1e-12, max_sweeps=3)
    assert res.status is Status.NOT_CONVERGED
    assert res.span >= 1e-12


def test_carrying_values_approximate_distance_over_speed_plus_tf():
    sc, cell = empty()
    mdp = build_model(sc, cell)
    res = solve_structured(mdp, tol=1e-8)
    c = mdp.c_layer(0)
    # h_C(x) - h_NR(drop point) = (stage - g) * stages + t_f - g along the path; with
    # g known, recover the number of stages and compare with distance / step.
    values = res.values[c].reshape(tuple(mdp.shape))
    xs = mdp.lower[0] + (np.arange(mdp.shape[0]) + 0.5) * mdp.spacing[0]
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    drop = (mdp.tf[c] < np.inf).reshape(tuple(mdp.shape))
    h_nr = res.values[0].reshape(tuple(mdp.shape))
    step = sc.strategy.speed * sc.strategy.stage_time
    g = res.gain
    checked = 0
    for i, j in [(5, 5), (10, 30), (20, 20), (3, 25)]:
        # Distance to the nearest drop cell centre (the destination is convex and open).
        dist = np.min(np.hypot(X[drop] - X[i, j], Y[drop] - Y[i, j]))
        target = h_nr[drop][np.argmin(np.hypot(X[drop] - X[i, j], Y[drop] - Y[i, j]))]
        stages = (values[i, j] - target - (3.0 - g)) / (1.0 - g)
        # Semi-Lagrangian interpolation error: within a couple of steps.
        assert abs(stages - dist / step) < 2.0 + 0.05 * dist / step
        checked += 1
    assert checked == 4


def test_symmetric_problem_gives_symmetric_idle_position():
    sc, cell = tiny(cells=16)
    mdp = build_model(sc, cell)
    res = solve_structured(mdp, tol=1e-8)
    h = res.values[0].reshape(tuple(mdp.shape))
    # The workcell and the request distribution are symmetric about x = 15.
    assert np.allclose(h, h[::-1, :], atol=1e-6, equal_nan=True)
    best = np.nanmin(h)
    idle = np.argwhere(np.abs(h - best) < 1e-9)
    xs = mdp.lower[0] + (idle[:, 0] + 0.5) * mdp.spacing[0]
    assert abs(xs.mean() - 15.0) < 1e-9


def test_structured_handles_destination_and_source_changes():
    from strategies_helpers import TINY

    from cellplan.scenario import loads_scenario
    from cellplan.workcell import Workcell

    text = TINY.replace("CELLS", "12").replace(
        "destinations:\n  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}",
        "destinations:\n  D1: {components: [{type: box, min: [2, 25], max: [6, 28]}]}\n"
        "  D2: {components: [{type: box, min: [24, 25], max: [28, 28]}]}",
    )
    text += "  destination_change: {probability: 0.05}\n  source_change: {probability: 0.03}\n"
    sc = loads_scenario(text)
    mdp = build_model(sc, Workcell.from_scenario(sc))
    assert mdp.has_changes()
    s = solve_structured(mdp, tol=1e-9)
    g_ref, h_ref = sparse_rvi(mdp)
    assert s.status is Status.SOLVED
    assert abs(s.gain - g_ref) < 1e-6
    a, b = _same_ref(s.values, h_ref, mdp.live)
    assert np.nanmax(np.abs(a - b)) < 1e-6


ROTATING = """
cellplan: 1
name: tiny-rotating
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 30, ymax: 30}
  obstacles:
    middle: {type: box, min: [12, 13], max: [18, 16]}
robot:
  type: rotating
  shape: {type: box, min: [-2, -1], max: [2, 1]}
  start: [15, 7, 90]
parts:
  P1: {shape: {type: box, min: [2, -1], max: [4, 1]}}
sources:
  S1: {components: [{type: box, min: [2, 2], max: [7, 6]}]}
destinations:
  D1: {components: [{type: box, min: [12, 24], max: [18, 28]}]}
strategy:
  speed: 2.5
  turn_speed: 45
  arrival: {probability: 0.1}
  fine_motion: {time: 1.0}
  cells: [10, 10, 8]
"""


def test_rotating_robot_matches_plain_sparse_rvi_and_serves_requests():
    from cellplan.scenario import loads_scenario
    from cellplan.strategies.policy.strategy import Strategy
    from cellplan.strategies.sim.simulate import simulate
    from cellplan.workcell import Workcell

    sc = loads_scenario(ROTATING)
    cell = Workcell.from_scenario(sc)
    mdp = build_model(sc, cell)
    assert mdp.heading_axis == 2
    s = solve_structured(mdp, tol=1e-9)
    g_ref, h_ref = sparse_rvi(mdp)
    assert abs(s.gain - g_ref) < 1e-6
    a, b = _same_ref(s.values, h_ref, mdp.live)
    assert np.nanmax(np.abs(a - b)) < 1e-6
    sim = simulate(
        Strategy.from_solution(mdp, s, sc),
        2000,
        0,
        SimulationOptions(start=cell.robot.start),
        cell=cell,
    )
    assert sim.metrics()["served"] > 10


def test_merged_request_branches_give_the_same_expectations():
    # NR's request branches into W layers with one live set are interpolated once, as
    # the probability-weighted mean of their values: the same E (and dE/dg) per action.
    # Problem 1 (coarse): its eight requests wait in W layers with one live set.
    sc, cell = load_workcell("strategies_p1")
    mdp = build_model(sc, cell, [34, 34])
    run = Layers(mdp, 100, Workers(1))
    assert run.merged is not None
    assert max(len(bs) for bs in run.nr_groups) > 1
    rng = np.random.default_rng(5)
    run.h[:] = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    run.D[:] = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    assert run._merged_values()
    n = mdp.live.shape[1]
    ref, ref_d = np.empty_like(run.E), np.empty_like(run.E)
    other_branches(0, run.h, run.D, ref, ref_d, 0, n, mdp.kernel_args())
    got, got_d = np.empty_like(run.E), np.empty_like(run.E)
    other_branches(0, run.hg, run.Dg, got, got_d, 0, n, run.merged)
    assert np.array_equal(np.isinf(ref), np.isinf(got))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(got[fin], ref[fin], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got_d[fin], ref_d[fin], rtol=1e-12, atol=1e-12)
    # An unreached W state keeps the branches apart.
    w = mdp.w_layer(0)
    run.h[w][np.flatnonzero(mdp.live[w])[0]] = np.inf
    assert not run._merged_values()

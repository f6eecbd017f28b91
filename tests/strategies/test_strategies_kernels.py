"""The numba kernels, imported directly, against plain numpy references on small random grids.

Each reference is written from the equations (multilinear interpolation of Section IV-B,
the right-hand side of equation (9), the linear system of a fixed policy), not from the
kernels: loops over states in Python, weights as products over axes, dense linear solves.
"""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from cellplan.strategies.model.actions import ActionSet
from cellplan.strategies.model.bundles import Grid
from cellplan.strategies.model.interpolation import interp
from cellplan.strategies.model.mdp import Geometry, LayeredMDP, assemble, grid_box
from cellplan.strategies.model.spec import Motions, Process
from cellplan.strategies.model.stencils import MAX_DIM, stencil
from cellplan.strategies.solve.bellman import bellman_all
from cellplan.strategies.solve.evaluation import evaluate, layer_system, live_cells
from cellplan.strategies.solve.nr import NRBranches, Slab, other_branches, sweep_self
from cellplan.strategies.solve.sweeps import Sweep, sweep_layer, sweep_policy, sweep_spec

# --- references ---------------------------------------------------------------------------


def ref_stencil(q, shape, lower, spacing, periodic):
    """``{flat cell: weight}`` of the multilinear stencil of ``q`` over cell centres."""
    axes = []
    for j in range(len(shape)):
        f = (q[j] - lower[j]) / spacing[j] - 0.5
        i0 = int(np.floor(f + 1e-9))
        t = f - i0
        t = 0.0 if t < 1e-9 else t
        n = int(shape[j])
        if periodic[j]:
            axes.append([(i0 % n, 1.0 - t), ((i0 + 1) % n, t)])
        elif i0 < 0:
            axes.append([(0, 1.0)])
        elif i0 >= n - 1:
            axes.append([(n - 1, 1.0)])
        else:
            axes.append([(i0, 1.0 - t), (i0 + 1, t)])
    out: dict[int, float] = {}
    for combo in itertools.product(*axes):
        idx = tuple(i for i, _ in combo)
        w = float(np.prod([wt for _, wt in combo]))
        flat = int(np.ravel_multi_index(idx, tuple(int(n) for n in shape)))
        out[flat] = out.get(flat, 0.0) + w
    return out


def ref_interp(values, live, weights):
    """Weighted mean of ``values`` over the live corners with weight (NaN if none)."""
    ws = {i: w for i, w in weights.items() if w > 1e-12 and live[i]}
    total = sum(ws.values())
    if total <= 1e-12:
        return np.nan
    return sum(w * values[i] for i, w in ws.items()) / total


def centre(mdp, c):
    idx = np.array(np.unravel_index(c, tuple(int(n) for n in mdp.shape)))
    return mdp.lower + (idx + 0.5) * mdp.spacing


def landing(mdp, m, c, a):
    """Stencil of action ``a`` (-1 stay) from the centre of cell ``c`` in layer ``m``."""
    q = centre(mdp, c)
    if a >= 0:
        q = q + mdp.disp[mdp.vcls[m], a]
        span = mdp.upper - mdp.lower
        q = np.where(mdp.periodic, mdp.lower + (q - mdp.lower) % span, q)
        return ref_stencil(q, mdp.shape, mdp.lower, mdp.spacing, mdp.periodic)
    return {c: 1.0}


def ref_transition(mdp, h, m, c, a):
    """``(cost, [(layer, cell, probability)])`` of an action, or None where unavailable."""
    if a == -2:
        nxt = int(mdp.fmp_next[m])
        if nxt < 0 or not np.isfinite(mdp.tf[m, c]) or not mdp.live[nxt, c]:
            return None
        return float(mdp.tf[m, c]), [(nxt, c, 1.0)]
    if a >= 0 and not (int(mdp.valid[mdp.vcls[m], c]) >> a) & 1:
        return None
    st_ = landing(mdp, m, c, a)
    out = []
    for b in range(mdp.branch_ptr[m], mdp.branch_ptr[m + 1]):
        L, p = int(mdp.branch_layer[b]), float(mdp.branch_prob[b])
        ws = {i: w for i, w in st_.items() if w > 1e-12 and mdp.live[L, i]}
        total = sum(ws.values())
        if total <= 1e-12:
            return None
        out += [(L, i, p * w / total) for i, w in ws.items()]
    return float(mdp.cost[m]), out


def ref_bellman(mdp, h):
    """``T h`` of equation (9) (no g) at every live state, by plain loops."""
    out = np.full(h.shape, np.nan)
    for m, c in zip(*np.nonzero(mdp.live), strict=True):
        best = np.inf
        for a in range(-2, int(mdp.nact[mdp.vcls[m]])):
            tr = ref_transition(mdp, h, m, c, a)
            if tr is None:
                continue
            cost, succ = tr
            best = min(best, cost + sum(p * h[L, i] for L, i, p in succ))
        out[m, c] = best
    return out


# --- random models ------------------------------------------------------------------------


def random_actions(rng: np.random.Generator, nact: int) -> ActionSet:
    """Displacements of up to 1.5 cells (spacing 1): landing points between centres."""
    disp = rng.uniform(-1.5, 1.5, size=(nact, 2))
    return ActionSet(np.ascontiguousarray(disp), -1, tuple(f"a{i}" for i in range(nact)))


@st.composite
def models(draw) -> LayeredMDP:
    """A one-request layered MDP on a random 2-D grid with random bitmaps and actions."""
    nx, ny = draw(st.integers(3, 7)), draw(st.integers(3, 7))
    periodic = (False, draw(st.booleans()))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    n = nx * ny
    free = rng.random(n) < 0.85
    carry = free & (rng.random(n) < 0.9)
    pick = rng.random(n) < 0.3
    drop = rng.random(n) < 0.3
    geometry = Geometry(
        free_nr=free,
        free_w={"S": free},
        free_c={("P", "S"): carry},
        pick={("P", "S"): pick},
        drop={("P", "D"): drop},
        tf_pick={("P", "S"): 1.0 + rng.random(n)},
        tf_drop={("P", "D"): 1.0 + rng.random(n)},
    )
    acts = random_actions(rng, draw(st.integers(2, 5)))
    return assemble(
        grid_box((nx, ny), (0.0, 0.0), (float(nx), float(ny)), periodic),
        [("P", "S", "D", 1.0)],
        geometry,
        Motions(acts, {"P": acts}),
        Process(1.0, float(rng.uniform(0.05, 0.5))),
    )


# --- interpolation ------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.integers(2, 6), min_size=1, max_size=3),
    st.lists(st.booleans(), min_size=3, max_size=3),
    st.integers(0, 2**31 - 1),
)
def test_interpolation_is_the_renormalised_multilinear_mean(shape, periodic, seed):
    d = len(shape)
    rng = np.random.default_rng(seed)
    shape_a = np.array(shape, np.int64)
    lower = rng.uniform(-2.0, 2.0, d)
    spacing = rng.uniform(0.5, 2.0, d)
    per = np.array(periodic[:d])
    n = int(np.prod(shape_a))
    values = rng.normal(size=n)
    live = rng.random(n) < 0.7
    # Points inside the box and up to a cell beyond it (clamped or wrapped).
    q = lower + rng.uniform(-1.0, shape_a + 1.0) * spacing
    idx = np.empty(1 << d, np.int64)
    w = np.empty(1 << d)
    grid = Grid(shape_a, lower, lower + shape_a * spacing, spacing, per)
    k = stencil(q, grid, idx, w, np.empty(2 * MAX_DIM, np.int64), np.empty(MAX_DIM))
    ref = ref_stencil(q, shape_a, lower, spacing, per)
    got: dict[int, float] = {}
    for i, wt in zip(idx[:k], w[:k], strict=True):
        got[int(i)] = got.get(int(i), 0.0) + float(wt)
    assert set(got) >= {i for i, wt in ref.items() if wt > 1e-12}
    for i in set(got) | set(ref):
        assert abs(got.get(i, 0.0) - ref.get(i, 0.0)) < 1e-9
    np.testing.assert_allclose(
        interp(values, live, idx, w, k), ref_interp(values, live, ref), rtol=1e-9, atol=1e-12
    )


# --- one Bellman backup -------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(models(), st.integers(0, 2**31 - 1))
def test_one_jacobi_bellman_backup_matches_the_reference(mdp, seed):
    h = np.where(mdp.live, np.random.default_rng(seed).normal(size=mdp.live.shape), 0.0)
    out = np.full_like(h, np.nan)
    policy = np.full(h.shape, -3, np.int64)
    gap = np.full_like(h, np.nan)
    bellman_all(h, out, policy, gap, np.zeros((0, 0), np.bool_), mdp.kernel_args())
    ref = ref_bellman(mdp, h)
    live = mdp.live
    np.testing.assert_allclose(out[live], ref[live], rtol=1e-10, atol=1e-10)
    # The recorded action attains the minimum.
    for m, c in zip(*np.nonzero(live & np.isfinite(ref)), strict=True):
        cost, succ = ref_transition(mdp, h, m, c, int(policy[m, c]))
        assert abs(cost + sum(p * h[L, i] for L, i, p in succ) - ref[m, c]) < 1e-10


@settings(max_examples=40, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.floats(0.0, 0.9))
def test_gauss_seidel_sweeps_converge_to_the_layers_bellman_fixed_point(mdp, seed, g):
    # A C layer with the other layers fixed: sweeps from +inf (as the solver starts) reach
    # h_m = (T h)_m - g at every live cell of the layer, T by the reference.
    rng = np.random.default_rng(seed)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    m = mdp.c_layer(0)
    h[m][mdp.live[m]] = np.inf
    D = np.zeros_like(h)
    model = mdp.kernel_args()
    converged = False
    for s in range(100_000):
        if sweep_layer(m, s % 4, h, D, g, False, True, model) < 1e-12:
            converged = True
            break
    # Policies that leave a near-closed cycle only rarely converge too slowly to check.
    assume(converged)
    live = mdp.live[m]
    assert np.all(np.isfinite(h[m][live]))
    ref = ref_bellman(mdp, h)
    np.testing.assert_allclose(h[m][live], ref[m][live] - g, rtol=1e-9, atol=1e-9)


# --- one exact policy evaluation ----------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.floats(0.0, 0.9))
def test_exact_evaluation_solves_the_policys_linear_system(mdp, seed, g):
    rng = np.random.default_rng(seed)
    m = mdp.c_layer(0)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    D = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    cells = np.flatnonzero(mdp.live[m])
    assume(len(cells) > 0)
    # A random policy among the available actions of each live cell.
    pol = np.full(mdp.live.shape, -3, np.int16)
    trans = {}
    for c in cells:
        options = []
        for a in range(-2, int(mdp.nact[mdp.vcls[m]])):
            tr = ref_transition(mdp, h, m, c, a)
            if tr is not None and (a != -1 or mdp.fmp_next[m] < 0):
                options.append((a, tr))
        assume(options)
        a, tr = options[rng.integers(len(options))]
        pol[m, c] = a
        trans[c] = tr
    # Reference: h_m = c + W h_m, D_m = dc + W D_m over the live cells, dense.
    pos = {int(c): v for v, c in enumerate(cells)}
    n = len(cells)
    W = np.zeros((n, n))
    const = np.zeros(n)
    dconst = np.zeros(n)
    for c in cells:
        cost, succ = trans[c]
        v = pos[int(c)]
        const[v] = cost - g
        dconst[v] = -1.0
        for L, i, p in succ:
            if L == m:
                W[v, pos[int(i)]] += p
            else:
                const[v] += p * h[L, i]
                dconst[v] += p * D[L, i]
    A = np.eye(n) - W
    # The policy reaches FMP from every cell, not only after thousands of stages (a
    # component is solved by Gauss-Seidel, which needs a leak to converge).
    assume(np.linalg.cond(A) < 1e3)
    h_ref = np.linalg.solve(A, const)
    d_ref = np.linalg.solve(A, dconst)
    model = mdp.kernel_args()
    live_c, local = live_cells(mdp.live[m])
    ptr, succ_, wt, cst, dcst, fixed = layer_system(m, h, D, g, pol, live_c, local, model)
    assert not fixed.any()
    evaluate(h[m], D[m], live_c, (ptr, succ_, wt, cst, dcst, fixed))
    np.testing.assert_allclose(h[m][cells], h_ref, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(D[m][cells], d_ref, rtol=1e-8, atol=1e-8)


# --- live states --------------------------------------------------------------------------


def ref_live(mdp):
    """The live states from their definition (docs/strategies.md, "Live states").

    Plain loops, Jacobi order across layers: a W or C layer keeps the cells from which
    some chain of actions, each with a live corner in every branch, reaches a cell where
    its FMP is allowed and lands live; NR keeps the cells with some such action. Iterated
    from the free bitmaps down to the greatest fixed point, which does not depend on the
    order the layers are visited in.
    """
    M = mdp.n_modes
    fmp_ok = np.isfinite(mdp.tf)
    live = np.stack([mdp.free[mdp.vcls[m]] for m in range(M)])

    def action_ok(m, c, a, target, prev):
        if a >= 0 and not (int(mdp.valid[mdp.vcls[m], c]) >> a) & 1:
            return False
        st_ = landing(mdp, m, c, a)
        for b in range(mdp.branch_ptr[m], mdp.branch_ptr[m + 1]):
            L, p = int(mdp.branch_layer[b]), float(mdp.branch_prob[b])
            src = target if L == m else prev[L]
            if p > 0 and not any(w > 1e-12 and src[i] for i, w in st_.items()):
                return False
        return True

    while True:
        prev = live.copy()
        for m in range(M):
            nxt = int(mdp.fmp_next[m])
            acts = range(0 if nxt >= 0 else -1, int(mdp.nact[mdp.vcls[m]]))
            if nxt >= 0:
                target = prev[m] & fmp_ok[m] & prev[nxt]
            else:
                target = prev[m].copy()
            while True:
                before = target.copy()
                for c in np.flatnonzero(prev[m]):
                    good = any(action_ok(m, c, a, before, prev) for a in acts)
                    if nxt >= 0 and good:
                        target[c] = True
                    if nxt < 0 and not good:
                        target[c] = False
                if np.array_equal(before, target):
                    break
            live[m] = target
        if np.array_equal(prev, live):
            return live


@st.composite
def multi_request_models(draw) -> LayeredMDP:
    """Two sources, two destinations (the second sometimes a copy of the first), changes."""
    nx, ny = draw(st.integers(3, 6)), draw(st.integers(3, 6))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    n = nx * ny
    free = rng.random(n) < draw(st.sampled_from([0.6, 0.85, 1.0]))
    copies = draw(st.booleans())
    drop_d = rng.random(n) < 0.3
    drop_e = drop_d if copies else rng.random(n) < 0.3
    geometry = Geometry(
        free_nr=free,
        free_w={"S": free, "T": free & (rng.random(n) < 0.9)},
        free_c={("P", s): free & (rng.random(n) < 0.9) for s in "ST"},
        pick={("P", s): rng.random(n) < 0.3 for s in "ST"},
        drop={("P", "D"): drop_d, ("P", "E"): drop_e},
        tf_pick={("P", s): np.ones(n) for s in "ST"},
        tf_drop={("P", d): np.ones(n) for d in "DE"},
    )
    acts = random_actions(rng, draw(st.integers(2, 4)))
    return assemble(
        grid_box((nx, ny), (0.0, 0.0), (float(nx), float(ny)), (False, draw(st.booleans()))),
        [("P", s, d, 0.25) for s in "ST" for d in "DE"],
        geometry,
        Motions(acts, {"P": acts}),
        Process(1.0, 0.2, draw(st.sampled_from([0.0, 0.1])), draw(st.sampled_from([0.0, 0.1]))),
    )


@settings(max_examples=60, deadline=None)
@given(multi_request_models())
def test_live_states_match_their_definition(mdp):
    # assemble() ran compute_live, which skips layers whose inputs did not change and
    # copies the result of a layer with identical inputs (the copied destination).
    np.testing.assert_array_equal(mdp.live, ref_live(mdp))


# --- the single-branch fast paths ---------------------------------------------------------


def with_idle_branch(model, m):
    """The model with a second, zero-probability branch of layer ``m`` into itself.

    The layer's equation is unchanged, but it no longer has exactly one branch, so the
    kernels take their general loop over branches instead of the single-branch fast path.
    """
    lay = model.layers
    end = int(lay.branch_ptr[m + 1])
    ptr = lay.branch_ptr.copy()
    ptr[m + 1 :] += 1
    layers = lay._replace(
        branch_ptr=ptr,
        branch_layer=np.insert(lay.branch_layer, end, m),
        branch_prob=np.insert(lay.branch_prob, end, 0.0),
    )
    return model._replace(layers=layers)


@settings(max_examples=60, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.floats(0.0, 0.9), st.integers(0, 3))
def test_single_branch_fast_paths_equal_the_general_loops(mdp, seed, g, flips):
    # A C and a W layer (one branch each): one Gauss-Seidel sweep recording its policy, that
    # policy's linear system and one Jacobi backup give bit for bit what the general loops
    # give.
    rng = np.random.default_rng(seed)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    D = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    model = mdp.kernel_args()
    for m in (mdp.c_layer(0), mdp.w_layer(0)):
        general = with_idle_branch(model, m)
        runs = []
        for mod in (model, general):
            hh, DD = h.copy(), D.copy()
            pol = np.full(h.shape, -3, np.int16)
            nchg = np.zeros(1, np.int64)
            change = sweep_policy(m, hh, DD, g, sweep_spec(flips, pol, nchg, 1e-9), mod)
            runs.append((change, hh, DD, pol, nchg))
        (c1, h1, d1, p1, n1), (c2, h2, d2, p2, n2) = runs
        assert c1 == c2
        np.testing.assert_array_equal(h1, h2)
        np.testing.assert_array_equal(d1, d2)
        np.testing.assert_array_equal(p1, p2)
        np.testing.assert_array_equal(n1, n2)
        # The linear system of the recorded policy (an exact evaluation's input).
        cells, local = live_cells(mdp.live[m])
        systems = [layer_system(m, h1, d1, g, p1, cells, local, mod) for mod in (model, general)]
        for a, b in zip(*systems, strict=True):
            np.testing.assert_array_equal(a, b)
        outs = []
        for mod in (model, general):
            out = np.full_like(h, np.nan)
            policy = np.full(h.shape, -3, np.int64)
            gap = np.full_like(h, np.nan)
            bellman_all(h, out, policy, gap, np.zeros((0, 0), np.bool_), mod)
            outs.append((out, policy, gap))
        for a, b in zip(*outs, strict=True):
            np.testing.assert_array_equal(a[m], b[m])


# --- NR in slabs --------------------------------------------------------------------------


def _nr_inputs(mdp, seed):
    """Random values, NR's request branches summed, and its stay probability."""
    rng = np.random.default_rng(seed)
    h = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    D = np.where(mdp.live, rng.normal(size=mdp.live.shape), 0.0)
    model = mdp.kernel_args()
    n = mdp.live.shape[1]
    E = np.empty((n, int(mdp.nact[mdp.vcls[0]]) + 1))
    ED = np.empty_like(E)
    other_branches(0, h, D, E, ED, 0, n, model)
    b = range(int(mdp.branch_ptr[0]), int(mdp.branch_ptr[1]))
    pself = float(sum(mdp.branch_prob[k] for k in b if mdp.branch_layer[k] == 0))
    return h, D, E, ED, pself, model


def _slab_sweep(h, D, E, ED, pself, model, g, flips, slabs):
    """One NR sweep, its slabs in the given order, reading each other's old values (each
    slab works on its own copy of the layer from before the sweep)."""
    work = [(h[0].copy(), D[0].copy()) for _ in slabs]
    pol = np.full(h.shape, -3, np.int16)
    changed = np.zeros(1, np.int64)
    change = 0.0
    nr = NRBranches(E, ED, pself)
    sw = Sweep(int(flips), True, True, pol, 1, changed, 1e-9)
    for rows, (wh, wd) in zip(slabs, work, strict=True):
        slab = Slab((int(rows[0]), int(rows[1])), wh, wd)
        change = max(change, sweep_self(0, h, D, g, nr, sw, model, slab))
    return change, pol, int(changed[0])


@settings(max_examples=60, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.floats(0.0, 0.9), st.integers(0, 3), st.data())
def test_nr_slabs_give_the_same_sweep_in_any_order(mdp, seed, g, flips, data):
    # Two slabs of rows read each other's values from before the sweep: run in either
    # order (as two threads may) they give bit for bit the same values, D and policy.
    rows = int(mdp.shape[0])
    cut = data.draw(st.integers(1, rows - 1))
    slabs = [(0, cut), (cut, rows)]
    h, D, E, ED, pself, model = _nr_inputs(mdp, seed)
    runs = []
    for order in (slabs, slabs[::-1]):
        hh, DD = h.copy(), D.copy()
        change, pol, changed = _slab_sweep(hh, DD, E, ED, pself, model, g, flips, order)
        runs.append((change, hh, DD, pol, changed))
    (c1, h1, d1, p1, n1), (c2, h2, d2, p2, n2) = runs
    assert (c1, n1) == (c2, n2)
    np.testing.assert_array_equal(h1, h2)
    np.testing.assert_array_equal(d1, d2)
    np.testing.assert_array_equal(p1, p2)
    # Only NR moves.
    np.testing.assert_array_equal(h1[1:], h[1:])


@settings(max_examples=40, deadline=None)
@given(models(), st.integers(0, 2**31 - 1), st.floats(0.0, 0.9), st.data())
def test_nr_sweeps_in_slabs_reach_nr_bellman_fixed_point(mdp, seed, g, data):
    # With the W layers fixed, repeated sweeps in two slabs (Gauss-Seidel inside, Jacobi
    # across) reach h_NR = (T h)_NR - g at every live NR state, T by the reference.
    rows = int(mdp.shape[0])
    cut = data.draw(st.integers(1, rows - 1))
    h, D, E, ED, pself, model = _nr_inputs(mdp, seed)
    for s in range(20_000):
        change, _, _ = _slab_sweep(h, D, E, ED, pself, model, g, s % 4, [(0, cut), (cut, rows)])
        if change < 1e-13:
            break
    assert change < 1e-13  # the NR update contracts by the stay probability, below 1
    ref = ref_bellman(mdp, h)[0] - g
    live = mdp.live[0] & np.isfinite(ref)
    np.testing.assert_allclose(h[0][live], ref[live], rtol=1e-9, atol=1e-9)

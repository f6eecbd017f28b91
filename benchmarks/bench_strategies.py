"""Benchmark of the strategies solver (Section IV of the strategies paper).

1. Problem 1 at 100 x 100 and 200 x 200 cells (16 headings): the structured solver against
   generic solvers on the identical MDP (:func:`explicit_mdp` exports every state and
   action of the model the structured solver solves):

   * ``--peer storm``: Storm's long-run-average value iteration (stormpy, the ``bench``
     extra): a sparse MDP with one row group per state, the state-action reward model
     "cost", ``R{"cost"}min=? [ LRA ]``, absolute precision equal to the solver's tolerance;
     the model-checking call is timed (export and model building are not);
   * a generic relative value iteration the way general MDP toolboxes do it (one
     ``scipy.sparse`` matrix per action, ``h <- min_a (c_a + P_a h)``, span stopping rule),
     at 100 x 100 only (``--skip-generic`` skips it);

   prints the times, the gains (the structured one with its certified bracket) and the
   ratios, with the machine load.
2. One online action query (equation (9) at a real-valued state).
3. Absolute times of ``solve`` on the bundled problems and the peak memory.
4. ``--kernels P[=cells]``: one sweep and one exact evaluation of a C and a W layer
   (thread CPU time), to compare the hot loops of two trees.
5. ``--oracle P[=cells]``: the solver's floor. The problem is solved as shipped, then
   again started from that answer's own gain and NR values with every layer solved exactly
   from the first pass (``solve_structured(..., start=...)``): one exact pass of the C and
   W layers from cold against the right terminal values, one pass that confirms it, the
   certificate. A better start or outer iteration could save the confirming pass at
   most; only cheaper layer solves can go lower. Prints both times, the passes and the
   ratio (the solver's DEBUG log splits each pass into C/W layers and NR).

Run: ``.venv/bin/python benchmarks/bench_strategies.py --peer storm --problems ""`` for
the comparison alone; other grids with ``--skip-p1 --problems p3,p6 --cells
p3=128,128,64``. Every solve line also gives the CPU time (for the P1 rows, of a
one-thread solve), which other jobs on the machine disturb less than the wall time.
Without stormpy the Storm rows are skipped with one line. numba compilation is cached
and excluded (a warm-up solve on a small grid runs first). The structured P1 solves are
timed best of 3 (the machine is shared); the others once.
"""

from __future__ import annotations

import argparse
import functools
import os
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numba import njit

from cellplan.errors import CellplanError
from cellplan.strategies.model.mdp import LayeredMDP, build_model
from cellplan.strategies.model.stencils import decode, table_stencil
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.section import SolverSpec
from cellplan.strategies.solve import sweeps
from cellplan.strategies.solve.evaluation import evaluate, layer_system, live_cells
from cellplan.strategies.solve.solver import SolveResult, solve, solve_structured
from cellplan.strategies.solve.sweeps import sweep_policy
from cellplan.strategies.solve.threads import default_threads
from cellplan.workcell import load_workcell


@njit(cache=True)
def _choices(model, index):  # pragma: no cover - numba
    """Every (state, action) row of the MDP with its cost and transition entries.

    States in the order of ``index`` (layer by layer), rows per state in the order FMP,
    stay, moves; an action is a row only where all its branches have a live corner (the
    MDP's transition law: multilinear weights renormalised over live corners). Returns
    ``(row_state, row_action, row_cost, entry_row, entry_col, entry_val)``.
    """
    moves = model.moves
    grid = model.grid
    lay = model.layers
    live = lay.live
    M, N = live.shape
    d = grid.shape.shape[0]
    S = 0
    for m in range(M):
        for c in range(N):
            if live[m, c]:
                S += 1
    A = moves.disp.shape[1]
    row_cap = S * (A + 2)
    ent_cap = 0
    for m in range(M):
        nb = lay.branch_ptr[m + 1] - lay.branch_ptr[m]
        for c in range(N):
            if live[m, c]:
                ent_cap += 1 + nb * (1 + (A << d))
    row_state = np.empty(row_cap, np.int64)
    row_action = np.empty(row_cap, np.int64)
    row_cost = np.empty(row_cap)
    entry_row = np.empty(ent_cap, np.int64)
    entry_col = np.empty(ent_cap, np.int64)
    entry_val = np.empty(ent_cap)
    mi = np.empty(d, np.int64)
    idx = np.empty(1 << d, np.int64)
    w = np.empty(1 << d)
    nrow = 0
    nent = 0
    for m in range(M):
        k = lay.vcls[m]
        nx = lay.fmp_next[m]
        for c in range(N):
            if not live[m, c]:
                continue
            s = index[m, c]
            decode(c, grid.shape, mi)
            for a in range(-2, moves.nact[k]):
                if a == -2:
                    if nx < 0 or lay.tf[m, c] == np.inf or not live[nx, c]:
                        continue
                    entry_row[nent] = nrow
                    entry_col[nent] = index[nx, c]
                    entry_val[nent] = 1.0
                    nent += 1
                    row_state[nrow] = s
                    row_action[nrow] = a
                    row_cost[nrow] = lay.tf[m, c]
                    nrow += 1
                    continue
                if a >= 0:
                    if ((moves.valid[k, c] >> a) & 1) == 0:
                        continue
                    ncorner = table_stencil(moves, grid, k, a, mi, idx, w)
                else:
                    ncorner = 1
                    idx[0] = c
                    w[0] = 1.0
                start = nent
                ok = True
                for b in range(lay.branch_ptr[m], lay.branch_ptr[m + 1]):
                    L = lay.branch_layer[b]
                    if lay.branch_prob[b] == 0.0:
                        continue
                    tot = 0.0
                    for j in range(ncorner):
                        if w[j] > 1e-12 and live[L, idx[j]]:
                            tot += w[j]
                    if tot <= 1e-12:
                        ok = False
                        break
                    for j in range(ncorner):
                        if w[j] > 1e-12 and live[L, idx[j]]:
                            entry_row[nent] = nrow
                            entry_col[nent] = index[L, idx[j]]
                            entry_val[nent] = lay.branch_prob[b] * w[j] / tot
                            nent += 1
                if not ok:
                    nent = start
                    continue
                row_state[nrow] = s
                row_action[nrow] = a
                row_cost[nrow] = lay.cost[m]
                nrow += 1
    return (
        row_state[:nrow],
        row_action[:nrow],
        row_cost[:nrow],
        entry_row[:nent],
        entry_col[:nent],
        entry_val[:nent],
    )


@dataclass
class ExplicitMDP:
    """The MDP as a generic solver sees it: rows of (state, action), row groups per state.

    Entries are sorted by row and column, duplicates summed; ``group_start[s]`` is the
    first row of state ``s`` (``len(group_start) == states + 1``).
    """

    states: int
    row_state: np.ndarray
    row_action: np.ndarray
    row_cost: np.ndarray
    entry_row: np.ndarray
    entry_col: np.ndarray
    entry_val: np.ndarray
    group_start: np.ndarray
    index: np.ndarray  # (M, N) state number of each live (mode, cell), -1 elsewhere


def explicit_mdp(mdp: LayeredMDP) -> ExplicitMDP:
    """Export the identical MDP the structured solver solves (every state and action)."""
    index = -np.ones(mdp.live.shape, np.int64)
    S = int(mdp.live.sum())
    index[mdp.live] = np.arange(S)
    rs, ra, rc, er, ec, ev = _choices(mdp.kernel_args(), index)
    order = np.lexsort((ec, er))
    er, ec, ev = er[order], ec[order], ev[order]
    first = np.ones(len(er), bool)
    first[1:] = (er[1:] != er[:-1]) | (ec[1:] != ec[:-1])
    starts = np.flatnonzero(first)
    ev = np.add.reduceat(ev, starts)
    er, ec = er[starts], ec[starts]
    group_start = np.searchsorted(rs, np.arange(S + 1))
    return ExplicitMDP(S, rs, ra, rc, er, ec, ev, group_start, index)


def sparse_mdp(mdp: LayeredMDP) -> tuple[list[sp.csr_matrix], list[np.ndarray], np.ndarray]:
    """One sparse matrix and one cost vector per action: the generic-toolbox form of the MDP."""
    ex = explicit_mdp(mdp)
    S = ex.states
    mats, costs = [], []
    entry_action = ex.row_action[ex.entry_row]
    for a in range(-2, int(mdp.nact.max())):
        rows = np.flatnonzero(ex.row_action == a)
        take = entry_action == a
        local = ex.row_state[ex.entry_row[take]]
        mats.append(sp.csr_matrix((ex.entry_val[take], (local, ex.entry_col[take])), shape=(S, S)))
        cst = np.full(S, np.inf)
        cst[ex.row_state[rows]] = ex.row_cost[rows]
        costs.append(cst)
    return mats, costs, ex.index


def generic_rvi(
    mats: list[sp.csr_matrix], costs: list[np.ndarray], tol: float = 1e-6, max_sweeps: int = 100000
) -> tuple[float, int, np.ndarray]:
    """Relative value iteration with sparse matrix-vector products (span stopping rule)."""
    h = np.zeros(mats[0].shape[0])
    for k in range(1, max_sweeps + 1):
        th = np.min(np.stack([c + P @ h for P, c in zip(mats, costs, strict=True)]), axis=0)
        diff = th - h
        lo, hi = diff.min(), diff.max()
        if hi - lo < tol:
            return 0.5 * (lo + hi), k, th
        h = th - th[0]
    return 0.5 * (lo + hi), max_sweeps, th


def storm_model(ex: ExplicitMDP, chunk: int = 2_000_000) -> Any:
    """The MDP as a stormpy sparse MDP: one row group per state, state-action reward "cost"."""
    from stormpy import models
    from stormpy.datastructures import SparseMatrixBuilder

    nrow = len(ex.row_state)
    builder = SparseMatrixBuilder[float](
        rows=nrow,
        columns=ex.states,
        entries=len(ex.entry_val),
        force_dimensions=True,
        has_custom_row_grouping=True,
        row_groups=ex.states,
    )
    # In pieces of whole rows, each with the row groups that start in it (the lists the
    # binding converts cost about 100 bytes an entry).
    cuts = np.searchsorted(ex.entry_row, np.arange(0, nrow + chunk, chunk))
    for i in range(len(cuts) - 1):
        lo, hi = cuts[i], cuts[i + 1]
        r0 = i * chunk
        groups = ex.group_start[(ex.group_start >= r0) & (ex.group_start < r0 + chunk)]
        groups = groups[groups < nrow]
        builder.add_next_values(
            ex.entry_row[lo:hi].tolist(),
            ex.entry_col[lo:hi].tolist(),
            ex.entry_val[lo:hi].tolist(),
            np.unique(groups).tolist(),
        )
    matrix = builder.build()
    labels = models.StateLabeling(ex.states)
    labels.add_label("init")
    labels.add_label_to_state("init", 0)
    reward = models.SparseRewardModel[float](
        optional_state_action_reward_vector=ex.row_cost.tolist()
    )
    components = models.SparseModelComponents[float](
        transition_matrix=matrix, state_labeling=labels, reward_models={"cost": reward}
    )
    return models.SparseMdp[float](components)


@functools.cache
def _storm_settings(tol: float) -> None:
    """Storm's LRA solver: value iteration, absolute precision ``tol`` (settable once)."""
    import stormpy.developer

    stormpy.developer.set_from_exploded_string(
        ["--lra:nondetmethod", "vi", "--lra:precision", repr(tol), "--lra:absolute"]
    )


def storm_lra(model: Any, tol: float) -> tuple[float, float]:
    """``R{"cost"}min=? [ LRA ]`` by Storm's value iteration, absolute precision ``tol``.

    Returns (seconds, gain at the initial state): the model-checking call alone.
    """
    import stormpy

    _storm_settings(tol)
    env = stormpy.Environment()
    prop = stormpy.parse_properties('R{"cost"}min=? [ LRA ]')[0]
    t = time.perf_counter()
    result = stormpy.model_checking(model, prop, environment=env, only_initial_states=True)
    return time.perf_counter() - t, float(result.get_value(0))


def have_stormpy() -> bool:
    try:
        import stormpy  # noqa: F401
    except ImportError:
        return False
    return True


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load {one:.2f} {five:.2f} {fifteen:.2f}"


def warm_up() -> None:
    sc, cell = load_workcell("strategies_p1")
    mdp = build_model(sc, cell, [64, 64])
    solve(mdp, "structured")
    solve(mdp, "general", max_sweeps=3)
    sparse_mdp(mdp)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--skip-generic", action="store_true", help="skip the scipy.sparse baseline")
    ap.add_argument(
        "--peer",
        action="append",
        default=[],
        choices=["storm"],
        help="compare with a generic solver on the identical MDP (stormpy, the bench extra)",
    )
    ap.add_argument(
        "--p1-grids",
        default="100,200",
        help="P1 grids (cells per axis) compared with the peers, e.g. 100,200",
    )
    ap.add_argument("--problems", default="p1,p2,p3,p4,p5,p6")
    ap.add_argument(
        "--cells",
        action="append",
        default=[],
        metavar="P=N,N[,N]",
        help="solve problem P on another grid, e.g. --cells p3=64,64,64 (repeatable)",
    )
    ap.add_argument("--skip-p1", action="store_true", help="skip the P1 comparison and query")
    ap.add_argument(
        "--kernels",
        default="",
        metavar="P[=N,N[,N]]",
        help="time one sweep and one exact evaluation of a C and a W layer of problem P "
        "(thread CPU time, best of 7), e.g. --kernels p1=200,200 or --kernels p6",
    )
    ap.add_argument(
        "--oracle",
        default="",
        metavar="P[=N,N[,N]]",
        help="solve problem P as shipped and again from that answer's gain and NR values "
        "(the solver's floor), e.g. --oracle p6 or --oracle p1=200,200",
    )
    args = ap.parse_args()
    grids = {k: [int(v) for v in g.split(",")] for k, g in (c.split("=") for c in args.cells)}
    print(f"start: {load()}; threads {default_threads()}", flush=True)
    warm_up()
    if not args.skip_p1:
        storm = "storm" in args.peer
        if storm and not have_stormpy():
            print("Storm rows skipped: stormpy is not installed (pip install -e '.[bench]')")
            storm = False
        for n in (int(v) for v in args.p1_grids.split(",")):
            compare_p1(n, generic=not args.skip_generic and n <= 100, storm=storm)
        query_time()
    for p in [p for p in args.problems.split(",") if p]:
        solve_problem(p, grids.get(p))
    if args.kernels:
        name, _, cells = args.kernels.partition("=")
        kernel_times(name, [int(v) for v in cells.split(",")] if cells else None)
    if args.oracle:
        name, _, cells = args.oracle.partition("=")
        oracle_floor(name, [int(v) for v in cells.split(",")] if cells else None)
    print(f"end: {load()}")


def _tolerance(sc: Any) -> float:
    """The solver tolerance of scenario ``sc`` (the solver section's default without one)."""
    return (sc.strategy.solver if sc.strategy is not None else SolverSpec()).tolerance


def _timed(fn: Callable[[], SolveResult], repeat: int) -> tuple[list[float], SolveResult]:
    """Wall times of ``repeat`` calls of ``fn`` and the last call's result."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        res = fn()
        times.append(time.perf_counter() - t)
    return times, res


def compare_p1(n: int, generic: bool, storm: bool) -> None:
    """Problem 1 on an ``n x n`` grid: structured solve against the peers, one run."""
    sc, cell = load_workcell("strategies_p1")
    tol = _tolerance(sc)
    t = time.perf_counter()
    mdp = build_model(sc, cell, [n, n])
    t_build = time.perf_counter() - t
    # Best of 3: the machine is shared, and the minimum is the least disturbed run.
    times, res = _timed(lambda: solve(mdp, "structured", tol=tol), 3)
    t_struct = min(times)
    # CPU time of a one-thread solve: less sensitive to other jobs on the machine than the
    # wall time (it still includes their effect on the caches).
    cpu = []
    for _ in range(3):
        t = time.process_time()
        solve(mdp, "structured", tol=tol, threads=1)
        cpu.append(time.process_time() - t)
    states = int(mdp.live.sum())
    print(
        f"P1 {n}x{n} ({states:,} states, 16 headings): model build {t_build:.2f} s; "
        f"structured {t_struct:.3f} s (best of {', '.join(f'{v:.3f}' for v in times)}; "
        f"1 thread: CPU {min(cpu):.3f} s, best of 3), "
        f"gain {res.gain:.9f} in [{res.gain_lower:.9f}, {res.gain_upper:.9f}], "
        f"{res.outer_iterations} passes, {res.sweeps} full sweeps + {res.eval_sweeps} "
        f"evaluations, {res.status}; {load()}",
        flush=True,
    )
    if generic:
        mats, costs, _ = sparse_mdp(mdp)
        t = time.perf_counter()
        g_gen, sweeps, _ = generic_rvi(mats, costs, tol)
        t_gen = time.perf_counter() - t
        print(
            f"  scipy.sparse RVI: {t_gen:.2f} s, {sweeps} sweeps, gain {g_gen:.9f}; "
            f"ratio {t_gen / t_struct:.1f}x; |gain difference| {abs(g_gen - res.gain):.1e}",
            flush=True,
        )
        del mats, costs
    if storm:
        t = time.perf_counter()
        ex = explicit_mdp(mdp)
        model = storm_model(ex)
        t_export = time.perf_counter() - t
        t_storm, g_storm = storm_lra(model, tol)
        inside = res.gain_lower - tol <= g_storm <= res.gain_upper + tol
        print(
            f"  Storm LRA value iteration (absolute precision {tol:g}): {t_storm:.2f} s "
            f"(export {t_export:.1f} s, {len(ex.row_state):,} choices, "
            f"{len(ex.entry_val):,} transitions), gain {g_storm:.9f}; "
            f"ratio Storm / structured = {t_storm / t_struct:.1f}x; |gain difference| "
            f"{abs(g_storm - res.gain):.1e} ({'within' if inside else 'OUTSIDE'} the bracket "
            f"widened by the precision); {load()}",
            flush=True,
        )
        del model, ex


def query_time() -> None:
    """One online action query (equation (9) at a real-valued state), P1 bundled grid."""
    sc, cell = load_workcell("strategies_p1")
    mdp = build_model(sc, cell)
    res = solve(mdp, "structured")
    strategy = Strategy.from_solution(mdp, res, sc)
    q = np.array([37.3, 61.9])
    modes = [m for m in range(mdp.n_modes) if mdp.live[m, strategy.cell_of(q)]]
    strategy.action(q, 0)
    n = 20000
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        for i in range(n):
            strategy.action(q, modes[i % len(modes)])
        best = min(best, (time.perf_counter() - t) / n * 1e6)
    print(f"online action query (P1): {best:.1f} microseconds (best of 3 x {n})")


def _best_ms(fn: Any) -> float:
    """Thread CPU time of ``fn()`` in milliseconds, best of 7."""
    times = []
    for _ in range(7):
        t = time.thread_time()
        fn()
        times.append(time.thread_time() - t)
    return min(times) * 1e3


def _layer_kernels(mdp: LayeredMDP, m: int, h: np.ndarray, pol: np.ndarray, g: float) -> str:
    model = mdp.kernel_args()
    if hasattr(sweeps, "with_dense"):  # as the solver sweeps it (trees from 2026-11-24 on)
        model = sweeps.with_dense(model)
    D = np.zeros_like(h)
    nchg = np.zeros(1, np.int64)
    spec = sweeps.sweep_spec(1, pol, nchg, 1e-9)
    t_sweep = _best_ms(lambda: sweep_policy(m, h, D, g, spec, model))
    cells, local = live_cells(mdp.live[m])

    def one_evaluation() -> None:
        system = layer_system(m, h, D, g, pol, cells, local, model)
        evaluate(h[m], D[m], cells, system)

    t_eval = _best_ms(one_evaluation)
    return f"layer {m} ({cells.size:,} live): sweep {t_sweep:.2f} ms, evaluation {t_eval:.2f} ms"


def kernel_times(p: str, cells: list[int] | None) -> None:
    """One Gauss-Seidel sweep (every action, policy and dh/dg recorded) and one exact
    evaluation of the recorded policy, on the first C and W layers of a solved problem.

    Thread CPU time, best of 7: the hot loops alone, for comparing trees (run the same
    command with ``PYTHONPATH`` on the other tree's ``src``).
    """
    sc, cell = load_workcell(f"strategies_{p}")
    mdp = build_model(sc, cell, cells)
    res = solve(mdp, "structured", threads=1)
    h = np.where(mdp.live, res.values, 0.0)
    pol = res.policy.astype(np.int16)
    out = [
        f"{kind} {_layer_kernels(mdp, m, h.copy(), pol.copy(), res.gain)}"
        for kind, m in (("C", mdp.c_layer(0)), ("W", mdp.w_layer(0)))
    ]
    print(f"kernels {p} {tuple(int(v) for v in mdp.shape)}: {'; '.join(out)}; {load()}")


def oracle_floor(p: str, cells: list[int] | None) -> None:
    """The shipped solve against a solve started from its own answer's gain and NR values
    (every pass exact, the C and W layers cold): the second is what the solve costs when
    its outer iteration has nothing left to find. Each timed twice, best of 2, in this
    process."""
    sc, cell = load_workcell(f"strategies_{p}")
    mdp = build_model(sc, cell, cells)
    tol = _tolerance(sc)
    shipped, res = _timed(lambda: solve_structured(mdp, tol), 2)
    start = (res.gain, res.values[0])
    floor, again = _timed(lambda: solve_structured(mdp, tol, start=start), 2)
    print(
        f"oracle {p} {tuple(int(v) for v in mdp.shape)}: shipped {min(shipped):.3f} s "
        f"({res.outer_iterations} passes, gain {res.gain:.9f}); from its own gain and NR "
        f"{min(floor):.3f} s ({again.outer_iterations} passes, gain {again.gain:.9f} in "
        f"[{again.gain_lower:.9f}, {again.gain_upper:.9f}], {again.status}); "
        f"ratio {min(shipped) / min(floor):.2f}x; {load()}",
        flush=True,
    )


def solve_problem(p: str, cells: list[int] | None) -> None:
    name = f"strategies_{p}"
    sc, cell = load_workcell(name)
    t = time.perf_counter()
    try:
        mdp = build_model(sc, cell, cells)
    except CellplanError as exc:
        print(f"{p}: model refused ({len(exc.problems)} problems), e.g. {exc.problems[-1]}")
        return
    t_build = time.perf_counter() - t
    t = time.perf_counter()
    cpu = time.process_time()
    sec = sc.strategy
    assert sec is not None
    res = solve(mdp, sec.solver.method, sec.solver.tolerance, sec.solver.max_sweeps)
    print(
        f"{p}: cells {tuple(int(v) for v in mdp.shape)}, {mdp.n_modes} modes, "
        f"build {t_build:.2f} s, "
        f"solve ({res.method}) {time.perf_counter() - t:.2f} s "
        f"(CPU {time.process_time() - cpu:.2f} s, all threads), gain {res.gain:.9f}, "
        f"gain in [{res.gain_lower:.9f}, {res.gain_upper:.9f}], "
        f"{res.outer_iterations} passes, {res.status}; peak RSS {peak_mb():.0f} MB; {load()}",
        flush=True,
    )


if __name__ == "__main__":
    main()

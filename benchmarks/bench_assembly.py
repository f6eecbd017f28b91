"""Benchmark of the assembly package: log-space vs plain linear-space phi, time vs n.

Run: ``.venv/bin/python benchmarks/bench_assembly.py`` (add ``--quick`` for a short run;
``--only-eigh`` for section 4 alone, ``--only-kernels`` for section 5 alone). No
environment variable is needed: the flows limit the BLAS to one thread themselves
(section 4).

1. Where each formulation fails. For n discs (random legal starts; a hexagonal goal
   cluster up to 15 discs, random legal goals beyond), the same RK4 gradient-flow
   integrator runs twice in the same process: with the log-space direction
   (:func:`navigation.evaluate`) and with ``-grad phi`` evaluated by equation (8) in
   plain floating point (:func:`navigation.grad_linear`; only the speed is borrowed,
   so the path is the linear arithmetic's own). It prints whether ``beta`` and
   ``gamma^k`` are representable at the start, each run's status and time, and their
   ratio; then the default integrator (the linearly implicit arc-length step) on the
   log-space function.
2. Evaluation cost: microseconds per call of the log-space and linear-space gradient.
3. Fifteen discs: time per run over several seeds and k (the paper: about 5 minutes),
   the default implicit step against the RK4 integrator (baseline) in the same run.
   The implicit runs use the planner's escape (a run stuck at a spurious minimum
   continues at k/2, k/4, ...; Section 3.2); they report how many runs the flow at k
   solved alone and how many with k lowered, and the time of the whole run. The RK4
   baseline is the flow at k alone, as before.
4. The implicit step's eigen-decomposition: LAPACK ``eigh`` on one BLAS thread
   (``threadpoolctl``, :func:`eigen.one_blas_thread`; what the library uses since issue
   13) against the hand-written BLAS-free solver it replaced
   (``benchmarks/baseline_eigen.py``) and against ``eigh`` on OpenBLAS's default threads.
   Per call, at 14, 30 and 100 rows (7, 15 and 50 discs): the full decomposition and the
   whole step; the experiment ``assembly.ratio_vs_k`` at 7 discs, k=96 (25 seeds;
   ``--quick`` 5) with both steps (same paths to rounding); a 50-disc flow with both
   steps, same process, same problem (full run; ``--quick``: the first 300 steps of
   each). Ratios printed are baseline / LAPACK (above 1: LAPACK faster).
5. The numba kernels (issue 13) against the numpy functions they replaced, kept as
   references, same process, same inputs (hexagonal clusters, gap 0.01, at their
   start): ms per call of the Hessian of L, the implicit step's exact segment test, the
   place rule's segment clearances (a parking search's 48 x 48 exit-spot segments) and
   one RK4 step (three stages in one numba call against the generic stages), at 7, 15
   and 50 discs; then whole RK4 flows (random goals, the planner's k rule) with both
   stage paths, checking the paths are equal. Ratios printed are numpy / numba.
   Prints the machine's load.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable
from typing import Literal
from unittest import mock

import numpy as np

from baseline_eigen import implicit_step_kernel as baseline_step_kernel
from baseline_eigen import sym_eigh as baseline_eigh
from cellplan.assembly import eigen, experiments, flows
from cellplan.assembly.flows import FlowSettings, gradient_flow, implicit_step
from cellplan.assembly.navigation import (
    NavEval,
    evaluate,
    grad_linear,
    hessian_log_w,
    log_beta_parts,
)
from cellplan.assembly.options import GradientOptions
from cellplan.assembly.problems import DiscProblem, default_workspace, generate_problem
from cellplan.assembly.section import GeneratorSpec
from cellplan.core import RunSpec

#: the planner's default number of k-halvings (its options model is the one source)
ESCAPES: int = GradientOptions.model_fields["escapes"].default
LOG_MAX = math.log(np.finfo(float).max)
LOG_TINY = math.log(np.finfo(float).tiny)


K_BY_N = {3: 32.0, 5: 64.0, 7: 64.0, 10: 128.0, 15: 256.0, 20: 256.0, 30: 512.0, 50: 2000.0}


def k_for(n: int) -> float:
    """The k used per size: the repulsion weight is gamma/k and gamma(b0) grows with n
    (about 100 for 7 discs, 10^4 for 50 in their workspaces), so k grows with it."""
    return K_BY_N[n]


def problem_for(n: int, seed: int) -> DiscProblem:
    """Hexagonal goal cluster (gap 0.1) up to 15 discs; random legal goals beyond."""
    pattern: Literal["hex", "random"] = "hex" if n <= 15 else "random"
    return generate_problem(
        GeneratorSpec(n=n, seed=seed, gap=0.1, pattern=pattern), default_workspace(n)
    )


def representable(log_value: float) -> str:
    if log_value > LOG_MAX:
        return "overflow"
    if log_value < LOG_TINY:
        return "underflow"
    return "ok"


def compare(n: int, seed: int, max_steps: int) -> None:
    p = problem_for(n, seed)
    k = k_for(n)
    pairs, bnd = log_beta_parts(p.start, p.radii, p.workspace)
    ev = evaluate(p.start, p, k)
    rk4 = FlowSettings(max_steps=max_steps, method="rk4")
    t0 = time.perf_counter()
    log_res = gradient_flow(p, k, settings=rk4)
    t_log = time.perf_counter() - t0
    t0 = time.perf_counter()
    lin_res = gradient_flow(p, k, settings=rk4, direction=lambda b: -grad_linear(b, p, k))
    t_lin = time.perf_counter() - t0
    t0 = time.perf_counter()
    imp_res = gradient_flow(p, k, settings=FlowSettings(max_steps=max_steps))
    t_imp = time.perf_counter() - t0
    straight = float(np.linalg.norm(p.start - p.goal))
    print(
        f"{n:>3} {k:>5g} {representable(pairs + bnd):>9} {representable(k * ev.log_gamma):>9}"
        f" {log_res.status.value:>16} {log_res.length() / straight:6.3f} {t_log:7.2f}"
        f" {lin_res.status.value:>16} {lin_res.reason[:18]:>18} {t_lin:7.2f}"
        f" {t_lin / t_log:6.2f} | {imp_res.status.value:>8} {imp_res.length() / straight:6.3f}"
        f" {t_imp:6.2f}"
    )


def eval_cost(n: int, reps: int) -> None:
    p = problem_for(n, 0)
    k = k_for(n)
    t0 = time.perf_counter()
    for _ in range(reps):
        evaluate(p.start, p, k)
    t_log = (time.perf_counter() - t0) / reps * 1e6
    t0 = time.perf_counter()
    for _ in range(reps):
        grad_linear(p.start, p, k)
    t_lin = (time.perf_counter() - t0) / reps * 1e6
    print(f"{n:>3} {t_log:9.1f} {t_lin:9.1f} {t_log / t_lin:6.2f}")


def fifteen(seeds: int, ks: tuple[float, ...], baseline_k: float) -> None:
    """Time per 15-disc run; the RK4 integrator (20,000-step budget) as the baseline."""

    def sweep(
        k: float, settings: FlowSettings, escapes: int
    ) -> tuple[np.ndarray, list[float], int, list[float]]:
        times, ratios, ok, at_k = [], [], 0, []
        for seed in range(seeds):
            p = problem_for(15, seed)
            t0 = time.perf_counter()
            res = gradient_flow(p, k, settings=settings, escapes=escapes)
            times.append(time.perf_counter() - t0)
            if res.status.ok:
                ok += 1
                ratios.append(res.length() / float(np.linalg.norm(p.start - p.goal)))
                if res.escapes == 0:
                    at_k.append(ratios[-1])
        return np.array(times), ratios, ok, at_k

    results = {}
    for k in ks:
        t, r, ok, at_k = sweep(k, FlowSettings(max_steps=20000), ESCAPES)
        results[k] = t
        print(
            f"15 discs, k={k:g}, implicit: {len(at_k)}/{seeds} solved at k, {ok}/{seeds} "
            f"with k lowered when stuck; s/run mean {t.mean():.3f}, median "
            f"{np.median(t):.3f}, max {t.max():.3f}; ratio (all solved) "
            f"{np.mean(r) if r else float('nan'):.3f}, (solved at k) "
            f"{np.mean(at_k) if at_k else float('nan'):.3f}"
        )
    t, r, ok, _ = sweep(baseline_k, FlowSettings(max_steps=20000, method="rk4"), 0)
    print(
        f"15 discs, k={baseline_k:g}, RK4 baseline: {ok}/{seeds} solved, s/run mean "
        f"{t.mean():.3f}, median {np.median(t):.3f}, max {t.max():.3f}; ratio (solved) "
        f"{np.mean(r) if r else float('nan'):.3f}"
    )
    if baseline_k in results:
        print(
            f"   mean time RK4 / implicit at k={baseline_k:g}: "
            f"{t.mean() / results[baseline_k].mean():.1f}x; paper ~300 s per run "
            f"(SPARCstation-1, not comparable)"
        )


def per_call_ms(fn: Callable[[], object], reps: int) -> float:
    """Median over 7 batches of the mean time per call (the machine is shared)."""
    fn()
    batches = []
    for _ in range(7):
        t0 = time.perf_counter()
        for _ in range(reps):
            fn()
        batches.append((time.perf_counter() - t0) / reps * 1e3)
    return statistics.median(batches)


def baseline_step(g: np.ndarray, hess: np.ndarray, length: float) -> np.ndarray:
    """The previous implicit step: the BLAS-free kernel (benchmarks/baseline_eigen.py)."""
    return baseline_step_kernel(
        np.ascontiguousarray(g, dtype=np.float64),
        np.ascontiguousarray(hess, dtype=np.float64),
        float(length),
    )


def eigh_cost(m: int, reps: int) -> None:
    """One decomposition and one step on a real Hessian of ``m / 2`` discs."""
    p = problem_for(m // 2, 0)
    k = k_for(m // 2)
    b = p.start
    ev = evaluate(b, p, k)
    g = ev.v.reshape(-1) / math.exp(ev.log_gamma)
    hess = np.ascontiguousarray(hessian_log_w(b, p, k))
    old = per_call_ms(lambda: baseline_eigh(hess), reps)
    threads = per_call_ms(lambda: np.linalg.eigh(hess), reps)
    step_old = per_call_ms(lambda: baseline_step(g, hess, 0.05), reps)
    with eigen.one_blas_thread():
        one = per_call_ms(lambda: np.linalg.eigh(hess), reps)
        step_new = per_call_ms(lambda: implicit_step(g, hess, 0.05), reps)
    print(
        f"{m:>4} {old:9.4f} {one:9.4f} {threads:9.4f} {old / one:7.2f} |"
        f" {step_old:9.4f} {step_new:9.4f} {step_old / step_new:7.2f}"
    )


def flow_new_vs_old(n: int, max_steps: int) -> None:
    """The same flow with the LAPACK step and with the previous BLAS-free step."""
    p = problem_for(n, 0)
    k = k_for(n)
    settings = FlowSettings(max_steps=max_steps)
    gradient_flow(problem_for(3, 0), k_for(3))  # compile outside the timing
    t0 = time.perf_counter()
    new = gradient_flow(p, k, settings=settings)
    t_new = time.perf_counter() - t0
    with mock.patch.object(flows, "implicit_step", baseline_step):
        t0 = time.perf_counter()
        old = gradient_flow(p, k, settings=settings)
        t_old = time.perf_counter() - t0
    straight = float(np.linalg.norm(p.start - p.goal))
    gap = (
        float(np.max(np.abs(new.path[-1] - old.path[-1])))
        if len(new.path) == len(old.path)
        else float("nan")
    )
    print(
        f"{n} discs, k={k:g}: LAPACK step {new.status.value} in {new.steps} steps, "
        f"{t_new:.2f} s ({t_new / max(new.steps, 1) * 1e3:.2f} ms/step), ratio "
        f"{new.length() / straight:.4f}; BLAS-free step {old.status.value} in {old.steps} "
        f"steps, {t_old:.2f} s ({t_old / max(old.steps, 1) * 1e3:.2f} ms/step), ratio "
        f"{old.length() / straight:.4f}; old/new time {t_old / t_new:.2f}x; "
        f"end points differ by {gap:.1e}"
    )


def paths_new_vs_old(n: int, k: float, seeds: int) -> None:
    """The experiment ``assembly.ratio_vs_k`` (planner runs, escapes included) with both
    steps: the paths must agree to rounding."""
    specs = [
        RunSpec("assembly.ratio_vs_k", {"algorithm": "gradient", "n": n, "k": k}, s)
        for s in range(seeds)
    ]
    experiments.run(specs[0])  # compile outside the timing
    t0 = time.perf_counter()
    new = np.array([float(experiments.run(spec)["ratio"]) for spec in specs])
    t_new = time.perf_counter() - t0
    with mock.patch.object(flows, "implicit_step", baseline_step):
        t0 = time.perf_counter()
        old = np.array([float(experiments.run(spec)["ratio"]) for spec in specs])
        t_old = time.perf_counter() - t0
    print(
        f"{n} discs, k={k:g}, seeds 0..{seeds - 1}: mean ratio LAPACK {new.mean():.6f}, "
        f"BLAS-free {old.mean():.6f}; largest per-run difference "
        f"{np.max(np.abs(new - old)):.1e}; time {t_new:.2f} s / {t_old:.2f} s "
        f"(old/new {t_old / t_new:.2f}x)"
    )


def eigh_section(quick: bool) -> None:
    print(
        "\n4. eigen-decomposition: LAPACK eigh on one BLAS thread against the BLAS-free"
        " baseline (ms per call, median of 7 batches)"
    )
    print("rows  baseline  eigh-1thr  eigh-default  base/eigh | step-base  step-eigh  base/eigh")
    for m in (14, 30, 100):
        eigh_cost(m, 200 if m < 100 else 40)
    paths_new_vs_old(7, 96.0, 5 if quick else 25)
    flow_new_vs_old(50, 300 if quick else 60000)


def kernel_costs(n: int) -> None:
    """One row of section 5: ms per call, numpy reference / numba kernel, at n discs."""
    from cellplan.assembly.layout import clearances, rule_k
    from cellplan.assembly.navigation import hessian_log_w_numpy
    from cellplan.assembly.routes import segments_clearance, segments_clearance_numpy

    p = generate_problem(GeneratorSpec(n=n, seed=0, gap=0.01), default_workspace(n))
    k, b = rule_k(p.radii, p.workspace), p.start
    rng = np.random.default_rng(0)
    reps = 200 if n < 50 else 50
    h_np = per_call_ms(lambda: hessian_log_w_numpy(b, p, k), reps)
    h_nb = per_call_ms(lambda: hessian_log_w(b, p, k), reps)
    gaps, bgap = clearances(b, p.radii, p.workspace)
    delta = 0.01 * rng.normal(size=b.shape)
    args = (b, delta, p.radii, gaps, bgap, clearances(b + delta, p.radii, p.workspace)[1], 0.5)
    s_np = per_call_ms(lambda: flows.segment_is_safe_numpy(*args), reps)
    s_nb = per_call_ms(lambda: flows.segment_is_safe(*args), reps)
    # a parking search's exit -> spot segments: 48 x 48
    P = np.repeat(b[0] + rng.normal(size=(48, 2)), 48, axis=0)
    Q = np.tile(b[0] + 5.0 * rng.normal(size=(48, 2)), (48, 1))
    r_np = per_call_ms(lambda: segments_clearance_numpy(p, b, 0, P, Q), max(reps // 10, 5))
    r_nb = per_call_ms(lambda: segments_clearance(p, b, 0, P, Q), max(reps // 10, 5))
    ev = evaluate(b, p, k)
    w, mask = -ev.v, np.ones((n, 1))
    dt = 0.3 * flows.max_dt(w, ev, mask[:, 0], gaps, bgap)

    def fld(x: np.ndarray) -> tuple[np.ndarray, NavEval]:
        e = evaluate(x, p, k)
        return -(e.v * mask) * 1.0, e

    g_np = per_call_ms(lambda: flows._rk4(fld, b, w, dt, gaps, bgap), reps)
    g_nb = per_call_ms(lambda: flows._rk4_fast(fld, p, k, mask, b, w, dt, gaps, bgap), reps)
    print(
        f"{n:4d}  {h_np:6.3f} {h_nb:6.3f} {h_np / h_nb:5.1f}x | {s_np:6.3f} {s_nb:6.3f} "
        f"{s_np / s_nb:5.1f}x | {r_np:6.3f} {r_nb:6.3f} {r_np / r_nb:5.1f}x | "
        f"{g_np:6.3f} {g_nb:6.3f} {g_np / g_nb:5.1f}x"
    )


def kernels_section(quick: bool) -> None:
    """Section 5: each numba kernel against the numpy reference it replaced."""
    import os

    from cellplan.assembly.layout import rule_k

    print(
        f"\n5. numba kernels against their numpy references (ms per call, median of 7 "
        f"batches; load {os.getloadavg()[0]:.2f})"
    )
    print(
        "   n  hessian np/nb  ratio | segment np/nb  ratio | routes np/nb  ratio | "
        "rk4 step np/nb ratio"
    )
    for n in (7, 15, 50):
        kernel_costs(n)
    print("   whole RK4 flows, random goals (seconds; generic / numba stages; same path?)")
    for n in (20,) if quick else (20, 30, 50):
        p = generate_problem(
            GeneratorSpec(n=n, seed=0, pattern="random", min_start_gap=0.1), default_workspace(n)
        )
        k = rule_k(p.radii, p.workspace)
        rk4 = FlowSettings(method="rk4")
        t0 = time.perf_counter()
        fast = gradient_flow(p, k, settings=rk4)
        t1 = time.perf_counter()
        generic = mock.patch.object(
            flows, "_rk4_fast", lambda fld, prob, kk, m, *a: (flows._rk4(fld, *a), 0)
        )
        with generic:
            slow = gradient_flow(p, k, settings=rk4)
        t2 = time.perf_counter()
        same = bool(np.array_equal(fast.path, slow.path))
        print(
            f"{n:4d}  {fast.steps} steps  generic {t2 - t1:6.2f}  numba {t1 - t0:6.2f}  "
            f"{(t2 - t1) / (t1 - t0):4.1f}x  same path: {same}  load {os.getloadavg()[0]:.2f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only-eigh", action="store_true", help="section 4 alone")
    ap.add_argument("--only-kernels", action="store_true", help="section 5 alone")
    args = ap.parse_args()
    if args.only_eigh:
        eigh_section(args.quick)
        return
    if args.only_kernels:
        kernels_section(args.quick)
        return
    sizes = (3, 7, 15) if args.quick else (3, 5, 7, 10, 15, 20, 30, 50)
    max_steps = 4000 if args.quick else 60000
    print("1. log-space vs linear-space phi along the same integrator (seed 0)")
    print(
        "  n     k  beta(b0)  gamma^k   log-space RK4  ratio  time_s   linear-space RK4"
        "             reason  time_s lin/log | implicit  ratio time_s"
    )
    for n in sizes:
        compare(n, 0, max_steps)
    print("\n2. one gradient evaluation, microseconds (log / linear)")
    for n in sizes:
        eval_cost(n, 200)
    print("\n3. fifteen discs")
    if args.quick:
        fifteen(3, (256.0,), 256.0)
    else:
        fifteen(20, (128.0, 256.0, 512.0, 1024.0), 256.0)
    eigh_section(args.quick)
    kernels_section(args.quick)


if __name__ == "__main__":
    main()

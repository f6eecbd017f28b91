"""Seeded problem sets of the disc-assembly planners (issue 13): reporting sets and a fitting grid.

Run: ``.venv/bin/python benchmarks/assembly_sets.py [--set report|fit] [--n 7 12 ...]
[--opt k=128 ...] [--planner assembly.gradient] [--csv out.csv]`` plans every problem of
the set with ``cellplan.plan(setup, planner, **opts)`` (no options: the defaults of
``cellplan assemble``) and prints one line per run and a summary per n (solved, mean and
max seconds per run, mean path-length ratio of the solved runs), with the machine's
load (1-minute average) before and after each n.

``--compare OTHER_SRC`` (before / after): every problem runs in two worker processes,
one importing cellplan from ``OTHER_SRC`` (e.g. a worktree of the previous commit,
``.../src``) and one from this tree's ``src``, one right after the other (alternating
which goes first), so both see the same machine load; printed per n: solved and mean
seconds of each, and the ratio of the mean times (other / this).

``--spheres-fit-k``: the fitting grid of the spheres' default-k constant (3-D; see
:func:`fit_sphere_k`).

Every problem is a scenario with a ``discs: generate:`` section
(:func:`cellplan.assembly.problems.generated_setup`, discs cover 5% of a circular
workspace, unit discs), so it is planned exactly like ``cellplan assemble --random``.
The eight kinds are the issue's grid:

* goals ``hex`` (a hexagonal cluster, gap between neighbours 0.01 or 0.1 radius) or
  ``random`` (random legal goals, no two closer than the gap 0.01 or 0.1 radius);
* starts ``random`` (random legal positions) or ``permutation`` (a random permutation of
  the goals, Section 5.2.2).

**Reporting sets** (:func:`reporting_set`): n = 7, 12, 15, 25 with seeds 0-19, and
n = 50 with seeds 0-9; seed ``s`` has kind ``KINDS[s % 8]``, so each kind appears 2-3
times per n (at n = 50 once or twice). The targets of the issue are measured here only.

**Fitting grid** (:func:`fitting_set`): other sizes (n = 5, 10, 20, 30) and other seeds
(1000-1015, each kind twice per n). Rules (the default k, the escape, the integrator
choice) are fitted on this grid and never on the reporting sets.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: (goal pattern, gap in radii, starts): the issue's 2 x 2 x 2 grid of problem kinds
KINDS: tuple[tuple[str, float, str], ...] = tuple(
    (pattern, gap, starts)
    for pattern in ("hex", "random")
    for gap in (0.01, 0.1)
    for starts in ("random", "permutation")
)

REPORT_SIZES: dict[int, range] = {
    7: range(20),
    12: range(20),
    15: range(20),
    25: range(20),
    50: range(10),
}
FIT_SIZES: dict[int, range] = {
    5: range(1000, 1016),
    10: range(1000, 1016),
    20: range(1000, 1016),
    30: range(1000, 1008),
}


@dataclass(frozen=True)
class Case:
    """One generated problem: its size, seed and kind, and the generator fields."""

    n: int
    seed: int
    pattern: str
    gap: float
    starts: str

    @property
    def label(self) -> str:
        return f"n{self.n}-s{self.seed}-{self.pattern}{self.gap:g}-{self.starts[:4]}"

    def generate(self) -> dict[str, Any]:
        """The ``discs.generate`` fields of this problem."""
        fields: dict[str, Any] = {
            "n": self.n,
            "seed": self.seed,
            "pattern": self.pattern,
            "starts": self.starts,
        }
        if self.pattern == "hex":
            fields["gap"] = self.gap
        else:
            # random goals: the gap is the smallest goal (and start) gap of the sampler
            fields["min_start_gap"] = self.gap
        return fields

    def setup(self) -> Any:
        from cellplan.assembly.problems import generated_setup

        return generated_setup(self.generate(), name=self.label)


def _cases(sizes: dict[int, range]) -> list[Case]:
    return [Case(n, s, *KINDS[s % len(KINDS)]) for n, seeds in sizes.items() for s in seeds]


def reporting_set(sizes: list[int] | None = None) -> list[Case]:
    """The reporting problems (targets are measured here; never fit on them)."""
    return _cases({n: r for n, r in REPORT_SIZES.items() if sizes is None or n in sizes})


def fitting_set(sizes: list[int] | None = None) -> list[Case]:
    """The fitting grid: other sizes and seeds than :func:`reporting_set`."""
    return _cases({n: r for n, r in FIT_SIZES.items() if sizes is None or n in sizes})


def _value(text: str) -> Any:
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"none": None, "true": True, "false": False}.get(text.lower(), text)


def _load() -> str:
    return f"load {os.getloadavg()[0]:.2f}"


def _worker() -> int:
    """Plan the cases named on stdin (one JSON object per line), answer one JSON line each."""
    import cellplan

    for line in sys.stdin:
        job = json.loads(line)
        case = Case(job["n"], job["seed"], *KINDS[job["seed"] % len(KINDS)])
        setup = case.setup()
        t0 = time.perf_counter()
        res = cellplan.plan(setup, job["planner"], **job["opts"])
        wall = time.perf_counter() - t0
        answer = {
            "status": res.status.value,
            "wall_s": wall,
            "ratio": res.stats.get("ratio", float("nan")),
            "switches_per_disc": res.stats.get("switches_per_disc", float("nan")),
            "message": res.message,
        }
        print(json.dumps(answer), flush=True)
    return 0


class _Worker:
    """A worker process planning with the cellplan found under ``src``."""

    def __init__(self, src: Path) -> None:
        env = dict(os.environ, PYTHONPATH=str(src))
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )

    def plan(self, case: Case, planner: str, opts: dict[str, Any]) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        job = {"n": case.n, "seed": case.seed, "planner": planner, "opts": opts}
        self.proc.stdin.write(json.dumps(job) + "\n")
        self.proc.stdin.flush()
        answer: dict[str, Any] = json.loads(self.proc.stdout.readline())
        return answer

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait()


def compare(cases: list[Case], other: Path, planner: str, opts: dict[str, Any]) -> int:
    """Before / after: each case on ``other``'s cellplan and on this tree's, back to back."""
    this = Path(__file__).resolve().parent.parent / "src"
    workers = {"other": _Worker(other), "this": _Worker(this)}
    warm = Case(7, 0, *KINDS[0])  # numba compiles (or loads its cache) outside the timing
    for w in workers.values():
        w.plan(warm, planner, opts)
    print(f"other = {other}, this = {this}; planner={planner} options={opts or 'defaults'}")
    rows: list[tuple[Case, dict[str, Any], dict[str, Any]]] = []
    for n in sorted({c.n for c in cases}):
        print(f"n={n}: {_load()}", flush=True)
        for idx, case in enumerate(c for c in cases if c.n == n):
            order = ("other", "this") if idx % 2 == 0 else ("this", "other")
            got = {name: workers[name].plan(case, planner, opts) for name in order}
            rows.append((case, got["other"], got["this"]))
            print(
                f"{case.label:32s} other {got['other']['status']:8s} "
                f"{got['other']['wall_s']:7.2f} s ratio {got['other']['ratio']:7.3f} "
                f"sw/disc {got['other']['switches_per_disc']:5.2f} | "
                f"this {got['this']['status']:8s} {got['this']['wall_s']:7.2f} s "
                f"ratio {got['this']['ratio']:7.3f} "
                f"sw/disc {got['this']['switches_per_disc']:5.2f}",
                flush=True,
            )
        print(f"n={n}: {_load()}", flush=True)
    for w in workers.values():
        w.close()
    print("\n| n | other: solved | other: mean s | this: solved | this: mean s | other / this |")
    print("|---|---|---|---|---|---|")
    for n in sorted({c.n for c, _, _ in rows}):
        mine = [(a, b) for c, a, b in rows if c.n == n]
        t_other = statistics.fmean(a["wall_s"] for a, _ in mine)
        t_this = statistics.fmean(b["wall_s"] for _, b in mine)
        ok_other = sum(a["status"] == "solved" for a, _ in mine)
        ok_this = sum(b["status"] == "solved" for _, b in mine)
        print(
            f"| {n} | {ok_other}/{len(mine)} | {t_other:.2f} | {ok_this}/{len(mine)} | "
            f"{t_this:.2f} | {t_other / t_this:.2f}x |"
        )
    return 0


# --- spheres (3-D): the fitting grid of the default-k constant ------------------------------

#: Sizes and seeds of the spheres' fitting grid (never the reporting seeds 0-99 of
#: ``cellplan reproduce assembly``'s ``assembly.spheres``).
SPHERE_FIT_SIZES: dict[int, range] = {5: range(1000, 1008), 10: range(1000, 1008)}
#: Candidate constants of ``k = C n (n / fill)^(2/3)`` (``layout.rule_k`` for spheres).
SPHERE_FIT_C = (0.05, 0.2, 0.8, 3.2)


def sphere_generate(n: int, seed: int) -> dict[str, Any]:
    """The generator fields of a sphere case: close-packed goals (gap 0.1 or 0.01 by
    ``seed // 2``), random or permuted starts (by ``seed``'s parity)."""
    return {
        "n": n,
        "seed": seed,
        "gap": (0.1, 0.01)[(seed // 2) % 2],
        "starts": ("random", "permutation")[seed % 2],
    }


def fit_sphere_k() -> int:
    """``--spheres-fit-k``: the gradient planner on the spheres' fitting grid at each
    candidate constant; prints solved, solved at k, mean ratio and the smallest clearance."""
    import cellplan
    from cellplan.assembly.layout import K_RULE_MIN, ball_volume
    from cellplan.assembly.problems import generated_setup

    print(f"spheres fitting grid {SPHERE_FIT_SIZES}: {_load()}", flush=True)
    out: dict[float, list[tuple[bool, float, bool, float]]] = {c: [] for c in SPHERE_FIT_C}
    for n, seeds in SPHERE_FIT_SIZES.items():
        for seed in seeds:
            setup = generated_setup(sphere_generate(n, seed), dim=3)
            radius = setup.scenario.discs.boundary.radius
            fill = n * float(ball_volume(1.0, 3)) / float(ball_volume(radius, 3))
            for c in SPHERE_FIT_C:
                k = max(K_RULE_MIN, c * n * (n / fill) ** (2.0 / 3.0))
                res = cellplan.plan(setup, "assembly.gradient", k=k)
                out[c].append(
                    (
                        res.status.ok,
                        res.stats["ratio"],
                        res.stats["solved_at_k"] > 0,
                        res.stats["min_clearance"],
                    )
                )
    print(f"after: {_load()}")
    print("\n| C | solved | solved at k | mean ratio (solved) | min clearance |")
    print("|---|---|---|---|---|")
    for c, runs in out.items():
        ratio = statistics.fmean(r for ok, r, _, _ in runs if ok)
        print(
            f"| {c:g} | {sum(ok for ok, *_ in runs)}/{len(runs)} | "
            f"{sum(at for _, _, at, _ in runs)}/{len(runs)} | {ratio:.3f} | "
            f"{min(cl for *_, cl in runs):.3g} |"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    if (argv if argv is not None else sys.argv[1:]) == ["--worker"]:
        return _worker()
    if (argv if argv is not None else sys.argv[1:]) == ["--spheres-fit-k"]:
        return fit_sphere_k()
    import cellplan

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("report", "fit"), default="report")
    ap.add_argument("--n", type=int, nargs="*", help="sizes (default: all of the set)")
    ap.add_argument("--seeds", type=int, nargs="*", help="only these seeds")
    ap.add_argument("--planner", default="assembly.gradient")
    ap.add_argument("--opt", nargs="*", default=[], help="planner options, name=value")
    ap.add_argument("--csv", help="write one row per run here")
    ap.add_argument(
        "--compare", type=Path, help="before / after: another tree's src folder (see above)"
    )
    args = ap.parse_args(argv)
    opts = {k: _value(v) for k, v in (o.split("=", 1) for o in args.opt)}
    cases = (reporting_set if args.set == "report" else fitting_set)(args.n)
    if args.seeds:
        cases = [c for c in cases if c.seed in args.seeds]
    if args.compare is not None:
        return compare(cases, args.compare.resolve(), args.planner, opts)
    print(f"set={args.set} planner={args.planner} options={opts or 'defaults'}", flush=True)
    rows: list[dict[str, Any]] = []
    current_n = None
    for case in cases:
        if case.n != current_n:
            if current_n is not None:
                print(f"n={current_n}: {_load()}", flush=True)
            current_n = case.n
            print(f"n={current_n}: {_load()}", flush=True)
        t0 = time.perf_counter()
        res = cellplan.plan(case.setup(), args.planner, **opts)
        wall = time.perf_counter() - t0
        row = {
            "label": case.label,
            "n": case.n,
            "seed": case.seed,
            "pattern": case.pattern,
            "gap": case.gap,
            "starts": case.starts,
            "status": res.status.value,
            "wall_s": wall,
            "ratio": res.stats.get("ratio", float("nan")),
            "k": res.stats.get("k", float("nan")),
            "solved_at_k": res.stats.get("solved_at_k", float("nan")),
            "switches_per_disc": res.stats.get("switches_per_disc", float("nan")),
            "message": res.message,
        }
        rows.append(row)
        print(f"{case.label:32s} {row['status']:16s} {wall:7.2f} s  {res.message}", flush=True)
    if current_n is not None:
        print(f"n={current_n}: {_load()}", flush=True)
    print("\n| n | solved | mean s/run | max s | mean ratio (solved) |")
    print("|---|---|---|---|---|")
    for n in sorted({r["n"] for r in rows}):
        mine = [r for r in rows if r["n"] == n]
        ok = [r for r in mine if r["status"] == "solved"]
        walls = [r["wall_s"] for r in mine]
        ratio = statistics.fmean(r["ratio"] for r in ok) if ok else float("nan")
        print(
            f"| {n} | {len(ok)}/{len(mine)} | {statistics.fmean(walls):.2f} | "
            f"{max(walls):.2f} | {ratio:.3f} |"
        )
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

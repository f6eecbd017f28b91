"""Small fake experiments for the runner, report and demo tests (pure, deterministic, fast).

``grid`` sweeps ``n`` in 1..3 (1..2 when quick) and two shapes over ``runs`` seeds;
its run for ``n == 3, seed == 1`` raises, so every full sweep has exactly one
failure per shape. Its report draws a PNG and a two-frame GIF with Pillow and
states one claim that holds and one that does not.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np

from cellplan.core import Claim, Experiment, ReportPiece, RunSpec, Scalar

SHAPES = ("disc", "square")


def grid_runs(name: str, runs: int, quick: bool) -> list[RunSpec]:
    ns = (1, 2) if quick else (1, 2, 3)
    return [
        RunSpec(name, {"n": n, "shape": s}, seed)
        for n in ns
        for s in SHAPES
        for seed in range(runs)
    ]


def grid_run(spec: RunSpec) -> dict[str, Scalar]:
    n, shape = int(spec.params["n"]), str(spec.params["shape"])
    if n == 3 and spec.seed == 1:
        raise ValueError(f"n={n} seed=1 is the broken case")
    rng = np.random.default_rng([spec.seed, n])
    area = math.pi * n**2 if shape == "disc" else 4.0 * n**2
    return {
        "area": area,
        "noise": float(rng.normal()),
        "hits": int(rng.integers(0, 100)),
        "big": bool(area > 10),
        "label": f"{shape}-{n}",
        "np_value": np.float64(n) / 3,  # numpy scalars are accepted and converted
    }


def grid_report(rows: list[dict[str, Scalar]], outdir: Path) -> ReportPiece:
    from PIL import Image

    outdir = Path(outdir)
    png = outdir / "bars.png"
    Image.new("RGB", (64, 48), (40, 90, 200)).save(png)
    gif = outdir / "anim.gif"
    frames = [Image.new("P", (32, 32), color) for color in (1, 2)]
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=200, loop=0)
    table = []
    for n in sorted({int(r["n"]) for r in rows}):
        for shape in SHAPES:
            sel = [float(r["area"]) for r in rows if r["n"] == n and r["shape"] == shape]
            table.append(
                {"n": n, "shape": shape, "runs": len(sel), "mean area": float(np.mean(sel))}
            )
    discs = [float(t["mean area"]) for t in table if t["shape"] == "disc"]
    grows = all(a < b for a, b in itertools.pairwise(discs))
    return ReportPiece(
        title="Area against size",
        text="Area of a disc and a square of size n.\n\nOne claim holds, one does not.",
        figures=[png, gif],
        tables=[("Mean area per point", table)],
        claims=[
            Claim("area grows with n", "grows", "grows" if grows else "does not grow", grows),
            Claim("area of the unit disc", "3.0", f"{discs[0]:.3f}", False, "pi, not 3"),
        ],
    )


def grid(name: str = "fake.grid", paper: str = "assembly") -> Experiment:
    """The grid experiment under ``name`` (the functions are module-level, so picklable)."""
    return Experiment(
        name=name,
        paper=paper,
        title=f"Fake grid {name}",
        make_runs=lambda runs, quick: grid_runs(name, runs, quick),
        run=grid_run,
        report=grid_report,
    )


def sleepy_run(spec: RunSpec) -> dict[str, Scalar]:
    """A run that takes ``params["sleep"]`` seconds (for time-budget tests)."""
    import time

    time.sleep(float(spec.params["sleep"]))
    return {"slept": float(spec.params["sleep"])}


def sleepy(name: str = "fake.sleepy", sleep: float = 0.1) -> Experiment:
    return Experiment(
        name=name,
        paper="adaptive",
        title="Fake sleeper",
        make_runs=lambda runs, quick: [RunSpec(name, {"sleep": sleep}, s) for s in range(runs)],
        run=sleepy_run,
        report=lambda rows, outdir: ReportPiece("Sleeper"),
    )

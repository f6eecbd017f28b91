"""Real arms (issue 30): the UR5 cell's sphere checks against Pinocchio's mesh checks.

Run: ``nice .venv/bin/python benchmarks/bench_arms.py`` (about 1.5 to 2 minutes on the
shared 2-core machine; ``--quick`` for a smoke run of a few seconds after the imports).

Every figure is measured on ``ur5_cell`` (seeded configurations uniform within the joint
limits) in one process, on one thread: numba is held to one thread
(``numba.set_num_threads(1)``) and BLAS/OpenMP pools to one (``threadpoolctl``); coal and
Pinocchio's ``computeCollisions`` are serial. Rates are given per CPU-second of this
process ("per core") and per wall-second; the two differ only when other jobs share the
cores (the load is printed before each section).

1. **Batched collision checks.** ``Workcell3D.collides(Q)`` (the 49-sphere cover against
   the obstacles, the avoided sources and the walls, plus the SRDF's self pairs)
   against the baseline, the per-configuration loop of :func:`cellplan.arm.exact_collides`
   (Pinocchio's ``computeCollisions`` on the URDF's collision meshes and the same solids
   as coal shapes, the collision model built once). Agreement is checked on the
   configurations the meshes test, with the walls added to the mesh side exactly (every
   vertex of each moving link's collision mesh inside the bounds; coal is not asked:
   six ``coal.Halfspace`` walls, or large boxes, make the mesh loop about 80 times
   slower: 500 configurations took 0.03 s of CPU without walls, 2.4 s with them).
2. **Certified segment checks.** ``motion_collides(q0, q1, step=0.01)`` on pairs of free
   configurations 0.1 and 0.5 rad apart (Euclidean norm in joint space), batched and one
   call per segment; baseline: the same sample points checked by the meshes (dense
   sampling, which certifies nothing between the samples), one ``exact_collides`` call
   over all of them, and one call per segment beside the certified check's one call per
   segment.
3. **The C-space bitmap of three UR5 joints** (pan, lift, elbow; the wrist locked at
   -90, -90, 0 degrees) at 64^3: ``free_bitmap`` time, memory (tracemalloc's peak, and
   the resident set's growth in a fresh process) beside ``estimate_memory``, the free
   fraction, and its per-cell rate against rate 1 and against the plain check of the
   same cell centres; what the box margin costs in free cells.
"""

from __future__ import annotations

import argparse
import gc
import importlib.resources
import json
import os
import resource
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, TypeVar, cast

import numba
import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.spatial import ConvexHull
from threadpoolctl import threadpool_limits

import cellplan.api as api
from cellplan import arm as arms
from cellplan import solids
from cellplan.cspace import Grid, estimate_memory, free_bitmap
from cellplan.workcell3d import Workcell3D

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
T = TypeVar("T")

GOAL_RATE = 100_000.0
"""Issue 30's goal: sphere-cover checks per second per core."""

STEP = 0.01
"""Certified step of the segment checks (metres a cover point may move between samples)."""

NORMS = (0.1, 0.5)
"""Joint-space lengths (radians, Euclidean norm) of the segments of section 2."""

LOCKED_WRIST = {"wrist_1_joint": -90.0, "wrist_2_joint": -90.0, "wrist_3_joint": 0.0}
#: The working range of the three active joints (degrees), narrower than the URDF's +-360:
#: a cell of a grid over +-360 degrees lets the shoulder's cover move farther than the 5 mm
#: it keeps from the table, so no cell would be certainly free.
WORKING_RANGE = {
    "shoulder_pan_joint": [-180.0, 180.0],
    "shoulder_lift_joint": [-180.0, 0.0],
    "elbow_joint": [-160.0, 160.0],
}
"""Wrist of the 3-joint variant (degrees, as in the scenario file)."""


@dataclass(frozen=True)
class Sizes:
    """How much work each section does.

    Parameters
    ----------
    configs
        Random configurations of the sphere check (section 1).
    mesh_configs
        The first ``mesh_configs`` of them are checked by the meshes too.
    repeats
        Repeats of the sphere check; the best is reported.
    segments
        Segments per norm (section 2).
    per_call
        Segments per norm checked one call each.
    cells
        Bitmap cells per joint (section 3).
    fresh_rss
        Measure the bitmap's resident memory in a fresh interpreter (section 3).
    """

    configs: int
    mesh_configs: int
    repeats: int
    segments: int
    per_call: int
    cells: int
    fresh_rss: bool


FULL = Sizes(
    configs=100_000,
    mesh_configs=20_000,
    repeats=3,
    segments=2000,
    per_call=300,
    cells=64,
    fresh_rss=True,
)
QUICK = Sizes(
    configs=3000,
    mesh_configs=300,
    repeats=1,
    segments=40,
    per_call=10,
    cells=12,
    fresh_rss=False,
)


@dataclass(frozen=True)
class Timing:
    """Wall and CPU seconds of one call."""

    wall: float
    cpu: float


def timed(fn: Callable[[], T], repeat: int = 1) -> tuple[Timing, T]:
    """Run ``fn`` ``repeat`` times; the fastest run (by CPU time) and its result.

    Parameters
    ----------
    fn
        The work.
    repeat
        How many runs.

    Returns
    -------
    tuple
        ``(Timing, result of the last run)``.
    """
    best = Timing(np.inf, np.inf)
    result: Any = None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        result = fn()
        t = Timing(time.perf_counter() - w0, time.process_time() - c0)
        if t.cpu < best.cpu:
            best = t
    return best, result


def say(key: str, text: str) -> None:
    """Print one result line: a fixed key (what the smoke test looks for), then the text."""
    print(f"{key:<30} {text}", flush=True)


def load_line() -> str:
    """The machine's 1, 5 and 15 minute load averages (``os.getloadavg``)."""
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f} {five:.2f} {fifteen:.2f} (1/5/15 min; {os.cpu_count()} cores)"


def rates(n: float, t: Timing) -> str:
    """``n`` items in ``t`` as per-CPU-second and per-wall-second rates."""
    return f"{n / t.cpu:12,.0f} /s per core (CPU)  {n / t.wall:12,.0f} /s wall"


def maxrss_bytes() -> int:
    """The process's resident-set high-water mark (``ru_maxrss``: KiB on Linux)."""
    scale = 1 if sys.platform == "darwin" else 1024
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * scale


# --- the mesh side ---------------------------------------------------------------------------


def coal_obstacles(cell: Workcell3D) -> list[tuple[Any, FloatArray]]:
    """The solids ``collides`` tests by default (obstacles and every source) as coal shapes.

    Parameters
    ----------
    cell
        The workcell.

    Returns
    -------
    list
        ``(coal geometry, (4, 4) world pose)`` pairs for :func:`cellplan.arm.exact_collides`.
    """
    return [(s.to_coal(), s.pose) for s in cell.obstacle_set("all").solids]


def hull_points(cell: Workcell3D) -> list[tuple[int, FloatArray]]:
    """Per moving collision mesh of the arm: its frame and its convex hull's vertices there.

    A mesh lies inside the (convex) bounds exactly when its hull's vertices do.

    Parameters
    ----------
    cell
        The workcell.

    Returns
    -------
    list
        ``(frame index of arms.forward, (K, 3) points in that frame)``.
    """
    out = []
    for mesh in arms.link_meshes(cell.robot.arm):
        if mesh.frame < 0:
            continue  # fixed links are checked once, when the cell is built
        pts = mesh.vertices @ mesh.placement[:3, :3].T + mesh.placement[:3, 3]
        out.append((mesh.frame, pts[ConvexHull(pts).vertices]))
    return out


def mesh_outside_bounds(
    cell: Workcell3D, hulls: Sequence[tuple[int, FloatArray]], q: FloatArray, chunk: int = 1024
) -> BoolArray:
    """Whether a moving collision mesh leaves the cell's bounds, per configuration (exact).

    Parameters
    ----------
    cell
        The workcell.
    hulls
        :func:`hull_points` of the cell.
    q
        ``(N, dim)`` configurations.
    chunk
        Configurations per batch.

    Returns
    -------
    BoolArray
        ``(N,)``.
    """
    out = np.zeros(len(q), bool)
    for start in range(0, len(q), chunk):
        poses = arms.forward(cell.robot.arm, q[start : start + chunk])
        hit = np.zeros(len(poses), bool)
        for frame, pts in hulls:
            rot = poses[:, frame, :3, :3]
            world = np.einsum("nij,kj->nki", rot, pts) + poses[:, frame, None, :3, 3]
            hit |= ((world < cell.lo) | (world > cell.hi)).any(axis=(1, 2))
        out[start : start + chunk] = hit
    return out


# --- section 1 -------------------------------------------------------------------------------


def bench_collides(cell: Workcell3D, q: FloatArray, sizes: Sizes) -> dict[str, float]:
    """Section 1: batched sphere checks against the mesh loop, and their agreement.

    Parameters
    ----------
    cell
        ``ur5_cell``.
    q
        Random configurations within the joint limits.
    sizes
        The benchmark's sizes.

    Returns
    -------
    dict
        ``rate`` (sphere checks per CPU-second), ``mesh_rate``, ``unsafe`` (free for the
        spheres, colliding for the meshes) and ``sphere_hit`` (the sphere verdicts).
    """
    arm = cell.robot.arm
    print(f"\n[1] batched collision checks, ur5_cell, load {load_line()}")
    cell.collides(q[:64])  # numba's cache loaded, obstacle set prepared
    t_sph, hit = timed(lambda: cell.collides(q), sizes.repeats)
    rate = len(q) / t_sph.cpu
    say(
        "sphere check (collides):",
        f"{len(q):,} configs (best of {sizes.repeats}) {t_sph.cpu:.3f} s CPU, "
        f"{t_sph.wall:.3f} s wall; {rates(len(q), t_sph)}; colliding {hit.mean():.3f}",
    )

    # Where the time goes, on the chunks collides uses (8192 configurations).
    obstacles = cell.obstacle_set("all")
    radii = arm.spheres.radii
    parts = {"FK + 49 centres": 0.0, "obstacles (4 solids)": 0.0, "walls": 0.0, "self": 0.0}
    for start in range(0, len(q), 8192):
        part = q[start : start + 8192]
        t, centres = timed(partial(arms.sphere_centers, arm, part))
        parts["FK + 49 centres"] += t.cpu
        t, _ = timed(partial(solids.sphere_gaps, obstacles, centres, radii))
        parts["obstacles (4 solids)"] += t.cpu
        t, _ = timed(partial(solids.bounds_gaps, cell.lo, cell.hi, centres, radii))
        parts["walls"] += t.cpu
        t, _ = timed(partial(arms.self_collides, arm, part))
        parts["self"] += t.cpu
    pairs = len(arm.self_pairs) + len(arm.fixed_pairs)
    say(
        "sphere check, per config:",
        ", ".join(f"{k} {v / len(q) * 1e6:.2f} us" for k, v in parts.items())
        + f" (self: FK again + {pairs} sphere pairs); whole call "
        f"{t_sph.cpu / len(q) * 1e6:.2f} us",
    )

    m = min(sizes.mesh_configs, len(q))
    qm = q[:m]
    shapes = coal_obstacles(cell)
    arms.exact_collides(arm, qm[:4], shapes)
    t_mesh, mesh_hit = timed(lambda: arms.exact_collides(arm, qm, shapes))
    mesh_rate = m / t_mesh.cpu
    free_q = qm[~hit[:m]]
    t_free, _ = timed(lambda: arms.exact_collides(arm, free_q, shapes))
    t_sph_free, _ = timed(lambda: cell.collides(free_q), sizes.repeats)
    say(
        "mesh loop (exact_collides):",
        f"{m:,} configs {t_mesh.cpu:.3f} s CPU; {rates(m, t_mesh)}; colliding "
        f"{mesh_hit.mean():.3f} (it stops at the first colliding pair)",
    )
    say(
        "mesh loop, free configs only:",
        f"{len(free_q):,} configs {rates(len(free_q), t_free)}; spheres on them "
        f"{len(free_q) / t_sph_free.cpu:,.0f} /s per core",
    )
    say(
        "ratio sphere / mesh:",
        f"{rate / mesh_rate:.1f}x (all configs, CPU), "
        f"{t_free.cpu / t_sph_free.cpu:.1f}x (free configs)",
    )
    met = "met" if rate >= GOAL_RATE else "NOT met"
    say("goal >= 100,000 /s per core:", f"{met} ({rate:,.0f} /s per core)")

    hulls = hull_points(cell)
    walls = mesh_outside_bounds(cell, hulls, qm)
    exact = mesh_hit | walls
    sph = hit[:m]
    conservative = sph & ~exact
    unsafe = int((~sph & exact).sum())
    say(
        "agreement on mesh configs:",
        f"spheres colliding {sph.sum():,}, meshes colliding {exact.sum():,} "
        f"({walls.sum():,} leave the bounds, {(walls & ~mesh_hit).sum():,} only that)",
    )
    # Which sphere test fires on the configurations only the spheres call colliding.
    qc = qm[conservative]
    if len(qc):
        centres = arms.sphere_centers(arm, qc)
        by_self = arms.self_collides(arm, qc)
        by_obst = solids.sphere_gaps(obstacles, centres, radii) <= 0
        by_wall = solids.bounds_gaps(cell.lo, cell.hi, centres, radii) <= 0
        why = (
            f"self {by_self.mean():.2f}, obstacles {by_obst.mean():.2f}, "
            f"walls {by_wall.mean():.2f} of them"
        )
    else:
        why = "none"
    say(
        "conservatism:",
        f"{conservative.sum() / max(1, sph.sum()):.4f} of sphere-colliding configs are "
        f"mesh-free ({conservative.sum():,}; {why})",
    )
    say("unsafe (sphere-free, mesh-hit):", f"{unsafe} (must be 0)")
    best = float(cell.clearance(q).max())
    table = cell.obstacles["table"]
    mesh_best = float(
        arms.exact_min_distance(arm, cell.robot.start, [(table.to_coal(), table.pose)])[0]
    )
    say(
        "largest clearance:",
        f"cover {best * 1e3:.1f} mm over the {len(q):,} configs (the shoulder's spheres over "
        f"the table, which no joint moves closer or farther); meshes "
        f"{mesh_best * 1e3:.1f} mm (shoulder to table at the start)",
    )
    return {"rate": rate, "mesh_rate": mesh_rate, "unsafe": float(unsafe), "clearance": best}


# --- section 2 -------------------------------------------------------------------------------


def free_pairs(
    cell: Workcell3D, pool: FloatArray, norm: float, n: int, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    """``n`` pairs of sphere-free configurations ``norm`` radians apart.

    Parameters
    ----------
    cell
        The workcell.
    pool
        Free configurations to start from.
    norm
        Euclidean joint-space distance between the two ends.
    n
        Pairs wanted.
    rng
        Random generator.

    Returns
    -------
    tuple
        ``(q0, q1)``, each ``(n, dim)``.
    """
    got0: list[FloatArray] = []
    got1: list[FloatArray] = []
    have = 0
    while have < n:
        q0 = pool[rng.integers(len(pool), size=4 * n)]
        d = rng.normal(size=q0.shape)
        q1 = q0 + norm * d / np.linalg.norm(d, axis=1, keepdims=True)
        inside = cell.robot.within_limits(q1)
        q0, q1 = q0[inside], q1[inside]
        ok = ~cell.collides(q1)
        got0.append(q0[ok])
        got1.append(q1[ok])
        have += int(ok.sum())
    return np.concatenate(got0)[:n], np.concatenate(got1)[:n]


def segment_samples(cell: Workcell3D, q0: FloatArray, q1: FloatArray) -> tuple[FloatArray, Any]:
    """The sample points ``motion_collides`` checks (its lever bound at :data:`STEP`).

    Parameters
    ----------
    cell
        The workcell.
    q0, q1
        ``(N, dim)`` segment ends.

    Returns
    -------
    tuple
        ``(samples (total, dim), counts (N,))``.
    """
    d = cell.robot.difference(q0, q1)
    # The samples motion_collides takes: the farthest-moving sphere sets the count.
    travel = (np.abs(d) @ arms.sphere_levers(cell.robot.arm).T).max(axis=1)
    counts = (np.maximum(1.0, np.ceil(travel / STEP)) + 1.0).astype(np.int64)
    seg = np.repeat(np.arange(len(q0)), counts)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(counts.sum()) - np.repeat(offsets, counts)) / np.repeat(counts - 1, counts)
    return cell.robot.wrap(q0[seg] + t[:, None] * d[seg]), counts


def certified_each(cell: Workcell3D, q0: FloatArray, q1: FloatArray) -> list[bool]:
    """``motion_collides`` one segment per call, as a planner testing one local step.

    Parameters
    ----------
    cell
        The workcell.
    q0, q1
        ``(N, dim)`` segment ends.

    Returns
    -------
    list
        Whether each segment collides.
    """
    return [bool(cell.motion_collides(a, b, STEP)[0]) for a, b in zip(q0, q1, strict=True)]


def mesh_each(
    arm: arms.Arm, pieces: Sequence[FloatArray], shapes: Sequence[tuple[Any, FloatArray]]
) -> list[bool]:
    """``exact_collides`` on one segment's samples per call (the baseline of
    :func:`certified_each`).

    Parameters
    ----------
    arm
        The arm.
    pieces
        Each segment's sample configurations.
    shapes
        :func:`coal_obstacles`.

    Returns
    -------
    list
        Whether a sample of each segment collides.
    """
    return [bool(arms.exact_collides(arm, piece, shapes).any()) for piece in pieces]


def bench_segments(
    cell: Workcell3D, pool: FloatArray, sizes: Sizes, rng: np.random.Generator, clearance: float
) -> dict[str, float]:
    """Section 2: certified segment checks against dense mesh sampling.

    Parameters
    ----------
    cell
        ``ur5_cell``.
    pool
        Sphere-free configurations.
    sizes
        The benchmark's sizes.
    rng
        Random generator.
    clearance
        Section 1's largest cover clearance (a certified step above twice it finds every
        segment colliding).

    Returns
    -------
    dict
        Per norm: ``seg_rate_<norm>`` (segments per CPU-second, batched) and
        ``unsafe_<norm>`` (certified free, a mesh sample colliding).
    """
    arm = cell.robot.arm
    shapes = coal_obstacles(cell)
    hulls = hull_points(cell)
    print(f"\n[2] certified segment checks, step {STEP} m, load {load_line()}")
    cell.motion_collides(pool[:2], pool[1:3], STEP)
    out: dict[str, float] = {}
    for norm in NORMS:
        q0, q1 = free_pairs(cell, pool, norm, sizes.segments, rng)
        samples, counts = segment_samples(cell, q0, q1)
        t_cert, hit = timed(partial(cell.motion_collides, q0, q1, STEP))
        k = min(sizes.per_call, len(q0))
        t_one, _ = timed(partial(certified_each, cell, q0[:k], q1[:k]))
        t_mesh, mesh = timed(partial(arms.exact_collides, arm, samples, shapes))
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        pieces = np.split(samples, offsets[1:])[:k]
        t_mesh_one, _ = timed(partial(mesh_each, arm, pieces, shapes))
        mesh |= mesh_outside_bounds(cell, hulls, samples)
        mesh_seg = np.logical_or.reduceat(mesh, offsets)
        n = len(q0)
        seg_rate = n / t_cert.cpu
        base_rate = n / t_mesh.cpu
        unsafe = int((~hit & mesh_seg).sum())
        say(
            f"segments |dq| = {norm} rad:",
            f"{n:,} free pairs, samples per segment mean {counts.mean():.1f} "
            f"(min {counts.min()}, max {counts.max()})",
        )
        say(
            "  certified, batched:",
            f"{rates(n, t_cert)} segments; {counts.sum() / t_cert.cpu:,.0f} samples/s per "
            f"core; colliding {hit.mean():.3f}",
        )
        say("  certified, one call each:", f"{rates(k, t_one)} segments ({k} calls)")
        say(
            "  mesh, same samples:",
            f"{rates(n, t_mesh)} segments ({counts.sum():,} samples, one call); "
            f"colliding {mesh_seg.mean():.3f}",
        )
        say("  mesh, one call each:", f"{rates(k, t_mesh_one)} segments ({k} calls)")
        say(
            "  ratio certified / mesh:",
            f"{seg_rate / base_rate:.1f}x batched, {t_mesh_one.cpu / t_one.cpu:.1f}x one call each",
        )
        say("  unsafe (cert-free, mesh-hit):", f"{unsafe} (must be 0)")
        out[f"seg_rate_{norm}"] = seg_rate
        out[f"unsafe_{norm}"] = float(unsafe)
    return out


# --- section 3 -------------------------------------------------------------------------------


def grid_for(cell: Workcell3D, shape: tuple[int, ...]) -> Grid:
    """``Grid.for_robot`` of the cell's arm (annotated for planar robots; it reads only the
    limits and ``periodic``, which a ``UrdfRobot`` has).

    Parameters
    ----------
    cell
        The workcell.
    shape
        Cells per joint.

    Returns
    -------
    Grid
        The grid over the arm's joint limits.
    """
    return Grid.for_robot(cast(Any, cell.robot), shape)


def three_joint_cell(cells: int) -> Workcell3D:
    """``ur5_cell`` with pan, lift and elbow active over their working range
    (:data:`WORKING_RANGE`), the wrist locked and a ``cells^3`` grid.

    Parameters
    ----------
    cells
        Bitmap cells per joint.

    Returns
    -------
    Workcell3D
        The variant, loaded from edited YAML text with :func:`cellplan.api.loads`.
    """
    path = importlib.resources.files("cellplan") / "bundled_scenarios" / "ur5_cell.yaml"
    doc = yaml.safe_load(path.read_text())
    doc["name"] = "ur5_cell_3joint"
    doc["robot"]["joints"] = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
    doc["robot"]["locked"] = dict(LOCKED_WRIST)
    doc["robot"]["limits"] = {k: list(v) for k, v in WORKING_RANGE.items()}
    doc["robot"]["start"] = doc["robot"]["start"][:3]
    doc["cspace"] = {"cells": [cells] * 3}
    cell = api.loads(yaml.safe_dump(doc, sort_keys=False)).workcell
    assert isinstance(cell, Workcell3D)
    return cell


def rss_child(cells: int) -> None:
    """In a fresh process: print the resident set before and its peak during one
    ``free_bitmap`` of the 3-joint cell, as JSON (read by :func:`bitmap_rss`).

    On Linux the peak is reset first (``5`` written to ``/proc/self/clear_refs``), so
    loading the cell does not hide the bitmap's peak; elsewhere ``ru_maxrss`` is used and
    the growth may read 0.

    Parameters
    ----------
    cells
        Bitmap cells per joint.
    """
    cell = three_joint_cell(cells)
    free_bitmap(cell, grid_for(cell, (4, 4, 4)))
    gc.collect()
    reset = reset_peak_rss()
    before = proc_status_bytes("VmRSS") if reset else maxrss_bytes()
    free_bitmap(cell, grid_for(cell, (cells,) * 3))
    after = proc_status_bytes("VmHWM") if reset else maxrss_bytes()
    print(json.dumps({"before": before, "peak": after, "reset": reset}))


def reset_peak_rss() -> bool:
    """Reset this process's peak resident set to its present size (Linux 4.0+).

    Returns
    -------
    bool
        Whether it worked.
    """
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return proc_status_bytes("VmHWM") > 0
    except (OSError, ValueError):
        return False


def proc_status_bytes(field: str) -> int:
    """A ``kB`` field of ``/proc/self/status`` (``VmRSS``, ``VmHWM``) in bytes.

    Parameters
    ----------
    field
        The field's name.

    Returns
    -------
    int
        Bytes; 0 where the file or field is missing.
    """
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return 0
    for line in text.splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    return 0


def bitmap_rss(cells: int) -> dict[str, int]:
    """Run :func:`rss_child` in a fresh interpreter (this process's peak was set by
    earlier work) and return its figures.

    Parameters
    ----------
    cells
        Bitmap cells per joint.

    Returns
    -------
    dict
        ``before`` (resident set before the bitmap), ``peak`` (its peak during it), bytes,
        and ``reset`` (whether the peak was reset first).
    """
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    done = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--rss-child", str(cells)],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    )
    figures: dict[str, int] = json.loads(done.stdout.strip().splitlines()[-1])
    return figures


def bench_bitmap(sizes: Sizes, rate1: float) -> dict[str, float]:
    """Section 3: the free bitmap of three joints, its time and memory.

    Parameters
    ----------
    sizes
        The benchmark's sizes.
    rate1
        Section 1's sphere checks per CPU-second (the comparison).

    Returns
    -------
    dict
        ``bitmap_s`` (CPU seconds), ``peak_bytes`` (tracemalloc), ``estimate_bytes``,
        ``free``.
    """
    cell = three_joint_cell(sizes.cells)
    arm = cell.robot.arm
    n = sizes.cells
    grid = grid_for(cell, (n, n, n))
    print(f"\n[3] C-space bitmap, UR5 pan/lift/elbow, {n}^3 cells, load {load_line()}")
    free_bitmap(cell, grid_for(cell, (4, 4, 4)))  # compile / warm caches
    t_map, free = timed(lambda: free_bitmap(cell, grid), 2)
    tracemalloc.start()
    tracemalloc.reset_peak()
    free_bitmap(cell, grid)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = bitmap_rss(n) if sizes.fresh_rss else None
    estimate = estimate_memory(cell, grid)
    half = grid.spacing / 2
    margins = arms.sphere_levers(arm) @ half
    points = grid.points()
    t_ctr, clearance = timed(lambda: cell.clearance(points))
    centre_free = clearance > 0
    cell_rate = grid.size / t_map.cpu
    say(
        "bitmap (free_bitmap):",
        f"{grid.size:,} cells, best of 2 {t_map.cpu:.3f} s CPU, {t_map.wall:.3f} s wall; "
        f"free {free.mean():.4f}",
    )
    if rss is None:
        fresh = "fresh process: not run (--quick)"
    else:
        how = "peak reset first" if rss["reset"] else "ru_maxrss, not reset"
        fresh = (
            f"fresh process: RSS growth {(rss['peak'] - rss['before']) / 1e6:.1f} MB "
            f"(from {rss['before'] / 1e6:.0f} MB; {how})"
        )
    say(
        "bitmap memory:",
        f"tracemalloc peak {peak / 1e6:.1f} MB; {fresh}; estimate_memory "
        f"{estimate / 1e6:.1f} MB ({estimate / max(1, peak):.1f}x the traced peak)",
    )
    say(
        "bitmap per cell:",
        f"{rates(grid.size, t_map)}; {cell_rate / rate1:.2f}x rate 1 (6 joints, no margin)",
    )
    say(
        "centres, no margin (clearance):",
        f"{rates(grid.size, t_ctr)}; free {centre_free.mean():.4f}, largest clearance "
        f"{clearance.max() * 1e3:.1f} mm",
    )
    lost = (centre_free.mean() - free.mean()) / max(1e-12, centre_free.mean())
    say(
        "what the box margin costs:",
        f"each sphere keeps its own margin, {margins.min() * 1e3:.1f}-{margins.max() * 1e3:.0f}"
        f" mm (its levers x half-widths {np.round(half, 4).tolist()} rad); they block "
        f"{lost:.3f} of the free centres",
    )
    return {
        "bitmap_s": t_map.cpu,
        "peak_bytes": float(peak),
        "estimate_bytes": float(estimate),
        "free": float(free.mean()),
    }


# --- driver ----------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> dict[str, float]:
    """Run the three sections and print their figures.

    Parameters
    ----------
    argv
        Command-line arguments (``--quick``, ``--seed``); ``None`` reads ``sys.argv``.

    Returns
    -------
    dict
        The headline figures of every section (see each section's function).
    """
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--rss-child", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.rss_child:
        rss_child(args.rss_child)
        return {}
    sizes = QUICK if args.quick else FULL
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        with threadpool_limits(limits=1):
            w0 = time.perf_counter()
            say("load at start:", load_line())
            cell = api.load("ur5_cell").workcell
            assert isinstance(cell, Workcell3D)
            rng = np.random.default_rng(args.seed)
            q = cell.sample(sizes.configs, rng)
            say(
                "threads:",
                f"numba {numba.get_num_threads()}, BLAS/OpenMP 1 (threadpoolctl); "
                f"{sizes.configs:,} configs, seed {args.seed}",
            )
            results = bench_collides(cell, q, sizes)
            pool = q[~cell.collides(q)]
            results |= bench_segments(cell, pool, sizes, rng, results["clearance"])
            results |= bench_bitmap(sizes, results["rate"])
            say("load at end:", f"{load_line()}; total {time.perf_counter() - w0:.1f} s wall")
    finally:
        numba.set_num_threads(threads)  # as the caller had it (a test session goes on)
    unsafe = [k for k, v in results.items() if k.startswith("unsafe") and v]
    if unsafe:
        print(f"GUARANTEE VIOLATED: {unsafe}", file=sys.stderr)
    return results


if __name__ == "__main__":
    sys.exit(1 if any(k.startswith("unsafe") and v for k, v in main().items()) else 0)

"""Seconds for a motion: the robot's speeds, the one timing law, and time-optimal retiming.

Two ways to put seconds on a path of configurations ``q`` (``(T, dim)``, code units:
workcell units for positions, radians for angles):

* **The timing law** (:func:`segment_seconds`, :func:`path_seconds`). A straight segment
  ``dq`` takes ``max_j |dq_j| / v_j`` seconds: every axis moves at constant speed, the
  slowest-to-arrive axis at its top speed ``v_j``. This is the time a planner's own
  samples carry (``Trajectory.seconds``); a stage of a strategy lasts
  :func:`stage_duration`, the time of its longest step under this law.
* **Time-optimal retiming** (:func:`retime_polyline`), with TOPP-RA (``toppra``): the
  same geometric path, the fastest timing that keeps every joint's velocity and
  acceleration within its limits. A polyline has a kink at every corner, where any
  finite acceleration needs the robot to stop; so the path is cut at corners, at stops
  (pick, place, fine motion, task ends: the caller names them) and at places where the
  robot stands still (a dwell keeps its duration), and each straight piece is retimed
  from rest to rest. Every sample of the input stays a sample of the output.

Speeds and accelerations come from the scenario (a robot's ``speed`` and
``acceleration``, per axis, in workcell units/s and degrees/s in files); URDF arms
default to the URDF's velocity limits, other robots to :data:`DEFAULT_LINEAR_SPEED` and
:data:`DEFAULT_ANGULAR_SPEED_DEG`; the default acceleration reaches the top speed in
:data:`ACCELERATION_TIME` seconds. See docs/guide.md, "Motions for a controller".
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellplan import units
from cellplan.errors import ArgumentError, Problem

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Default top speed of a position axis, workcell units per second.
DEFAULT_LINEAR_SPEED = 10.0
#: Default top speed of an angle axis, degrees per second (radians in code).
DEFAULT_ANGULAR_SPEED_DEG = 90.0
#: The default acceleration reaches the top speed in this many seconds (``a = v / T``).
#: A URDF's ``effort`` limit is a torque, not an acceleration, so URDF arms use it too.
ACCELERATION_TIME = 0.5
#: Default largest gap between two samples of a retimed trajectory, seconds.
RETIME_STEP = 0.05
#: Grid points of the TOPP-RA problem along each straight piece.
GRIDPOINTS = 51
#: Two unit directions closer than this are one straight line (no corner between them).
CORNER_TOLERANCE = 1e-9
#: Most samples a retimed trajectory may have (about 2 GB of arrays at 12 axes).
MAX_SAMPLES = 10_000_000


# --- limits ------------------------------------------------------------------------------------


def default_limits(axis_units: Sequence[str]) -> tuple[FloatArray, FloatArray]:
    """Default ``(speed, acceleration)`` per axis in code units (per s, per s^2)."""
    speed = np.array(
        [
            units.radians(DEFAULT_ANGULAR_SPEED_DEG) if u == units.ANGLE else DEFAULT_LINEAR_SPEED
            for u in axis_units
        ],
        dtype=float,
    )
    return speed, speed / ACCELERATION_TIME


def robot_limits(
    spec: Any, robot: Any, axis_names: Sequence[str], axis_units: Sequence[str]
) -> tuple[FloatArray, FloatArray]:
    """``(speed, acceleration)`` per axis in code units for a robot.

    ``spec`` is the scenario's robot section (or None): its ``speed`` and ``acceleration``
    lists (file units: degrees for angles) win. Otherwise a URDF arm (``robot.arm``) uses
    its URDF velocity limits, and other robots the defaults (:func:`default_limits`). A
    missing acceleration reaches the speed in :data:`ACCELERATION_TIME` seconds.
    """
    angular = [u == units.ANGLE for u in axis_units]
    speed, _ = default_limits(axis_units)
    arm = getattr(robot, "arm", None)
    urdf = getattr(arm, "velocity_limit", None)
    if urdf is not None and len(urdf) == len(speed):
        given = np.asarray(urdf, dtype=float)
        # a URDF joint without a velocity limit (0 or inf) keeps the default
        ok = np.isfinite(given) & (given > 0)
        speed = np.where(ok, given, speed)
    if getattr(spec, "speed", None) is not None:
        speed = units.config_from_file(axis_names, spec.speed, angular)
    if getattr(spec, "acceleration", None) is not None:
        accel = units.config_from_file(axis_names, spec.acceleration, angular)
    else:
        accel = speed / ACCELERATION_TIME
    return np.asarray(speed, dtype=float), np.asarray(accel, dtype=float)


def robot_motion(
    spec: Any, robot: Any, axis_names: Sequence[str], axis_units: Sequence[str]
) -> tuple[tuple[bool, ...], tuple[float, ...], tuple[float, ...]]:
    """``(periodic, velocity_limits, acceleration_limits)`` of a trajectory's columns.

    ``robot`` (a robot model, or None) gives the periodic axes and a URDF arm's velocity
    limits, ``spec`` (the scenario's robot section, or None) the scenario's speeds
    (:func:`robot_limits`). Without a robot no axis is periodic.
    """
    dim = len(axis_names)
    flags = getattr(robot, "periodic", None)
    periodic = tuple(bool(p) for p in flags) if flags is not None and len(flags) == dim else ()
    speed, accel = robot_limits(spec, robot, axis_names, axis_units)
    return periodic, tuple(speed.tolist()), tuple(accel.tolist())


def check_limits(values: ArrayLike | None, dim: int, name: str) -> FloatArray:
    """``values`` as ``(dim,)`` positive finite limits, or an :class:`ArgumentError`.

    A single number applies to every axis.
    """
    try:
        arr = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArgumentError([Problem(name, f"expected {dim} numbers, got {values!r}")]) from None
    if arr.size == 1 and dim != 1:
        arr = np.full(dim, float(arr[0]))
    if arr.size != dim:
        raise ArgumentError(
            [Problem(name, f"expected {dim} values (one per axis), got {arr.size}")]
        )
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ArgumentError(
            [Problem(name, f"every limit must be a positive finite number, got {arr.tolist()}")]
        )
    return arr


# --- the timing law ----------------------------------------------------------------------------


def segment_seconds(dq: ArrayLike, speed: ArrayLike) -> FloatArray:
    """Seconds of straight segments ``dq`` (``(N, dim)``): ``max_j |dq_j| / v_j``."""
    d = np.abs(np.asarray(dq, dtype=float))
    if d.ndim == 1:
        d = d[None, :]
    if d.shape[0] == 0:
        return np.zeros(0)
    return np.asarray(np.max(d / np.asarray(speed, dtype=float), axis=1), dtype=float)


def path_seconds(q: ArrayLike, speed: ArrayLike) -> FloatArray:
    """Cumulative seconds along the polyline through ``q`` (0 at the first sample)."""
    arr = np.asarray(q, dtype=float)
    if len(arr) < 2:
        return np.zeros(len(arr))
    return np.concatenate([[0.0], np.cumsum(segment_seconds(np.diff(arr, axis=0), speed))])


def stage_duration(steps: ArrayLike, speed: ArrayLike) -> float:
    """Seconds of one stage: the longest of the straight ``steps`` (``(N, dim)``) a stage
    may make, under the timing law; so every stage's motion fits in it."""
    s = segment_seconds(steps, speed)
    return float(s.max()) if s.size else 0.0


def finite_velocities(seconds: ArrayLike, q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Velocities and accelerations at the samples by finite differences over ``seconds``.

    Used for trajectories that were not retimed (their exact velocity jumps at every
    sample). Samples at the same time (standing still) get the neighbours' values.
    """
    s = np.asarray(seconds, dtype=float)
    x = np.asarray(q, dtype=float)
    if len(s) < 2:
        return np.zeros_like(x), np.zeros_like(x)
    keep = np.concatenate([[True], np.diff(s) > 0])
    ss, xs = s[keep], x[keep]
    if len(ss) < 2:
        return np.zeros_like(x), np.zeros_like(x)
    v = np.gradient(xs, ss, axis=0)
    a = np.gradient(v, ss, axis=0)
    where = np.cumsum(keep) - 1
    return v[where], a[where]


# --- retiming ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Retimed:
    """A retimed polyline: samples ``(seconds, q, qd, qdd)``; ``origin[k]`` is the input
    sample at or before output sample ``k`` and ``fraction[k]`` how far it is towards the
    next; ``index[i]`` the output sample of input sample ``i``."""

    seconds: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    origin: IntArray
    fraction: FloatArray
    index: IntArray


def _corners(q: FloatArray) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """``(moving, breaks)``: which segments move, which samples end a straight piece."""
    seg = np.diff(q, axis=0)
    length = np.linalg.norm(seg, axis=1)
    scale = 1.0 + float(np.max(np.abs(q))) if q.size else 1.0
    moving = length > 1e-12 * scale
    breaks = np.zeros(len(q), dtype=bool)
    breaks[0] = breaks[-1] = True
    breaks[:-1] |= ~moving
    breaks[1:] |= ~moving
    unit = np.zeros_like(seg)
    unit[moving] = seg[moving] / length[moving, None]
    turn = np.linalg.norm(unit[1:] - unit[:-1], axis=1) > CORNER_TOLERANCE
    breaks[1:-1] |= turn & moving[1:] & moving[:-1]
    return moving, breaks


def _profile(length: float, direction: FloatArray, vlim: FloatArray, alim: FloatArray) -> Any:
    """TOPP-RA on the straight line ``s -> s * direction``, ``s`` in ``[0, length]``, from
    rest to rest: ``(s, sd)`` at the grid points, or None when no timing exists."""
    import toppra
    import toppra.algorithm
    import toppra.constraint

    grid = np.linspace(0.0, length, GRIDPOINTS)
    # A spline through three collinear, evenly spaced points is that line exactly.
    path = toppra.SplineInterpolator(
        grid[[0, GRIDPOINTS // 2, -1]], np.outer(grid[[0, GRIDPOINTS // 2, -1]], direction)
    )
    constraints = [
        toppra.constraint.JointVelocityConstraint(vlim),
        toppra.constraint.JointAccelerationConstraint(
            alim, discretization_scheme=toppra.constraint.DiscretizationType.Collocation
        ),
    ]
    algo = toppra.algorithm.TOPPRA(constraints, path, gridpoints=grid, solver_wrapper="seidel")
    _, sd, _ = algo.compute_parameterization(0.0, 0.0)[:3]
    if sd is None or not np.all(np.isfinite(sd)):
        return None
    sd = np.maximum(np.asarray(sd, dtype=float), 0.0)
    sd[0] = sd[-1] = 0.0
    return grid, sd


def _tau(ds: FloatArray, sd0: FloatArray, acc: FloatArray) -> FloatArray:
    """Time to advance ``ds`` from path speed ``sd0`` at constant path acceleration."""
    root = np.sqrt(np.maximum(sd0**2 + 2.0 * acc * ds, 0.0))
    den = sd0 + root
    return np.where(den > 0, 2.0 * ds / np.where(den > 0, den, 1.0), 0.0)


def retime_polyline(
    q: ArrayLike,
    seconds: ArrayLike,
    stops: Sequence[int],
    velocity_limits: FloatArray,
    acceleration_limits: FloatArray,
    step: float = RETIME_STEP,
) -> Retimed:
    """Time-optimal timing of the polyline through ``q`` (see the module docstring).

    ``seconds`` (the input's own times) give the durations of dwells (samples where the
    robot stands still); ``stops`` are the samples where the robot must be at rest; ``step``
    is the largest time between two output samples.

    Raises
    ------
    ArgumentError
        No timing exists (TOPP-RA found none), or it would need too many samples.
    """
    x = np.asarray(q, dtype=float)
    sec = np.asarray(seconds, dtype=float)
    n = len(x)
    if n < 2:
        zero = np.zeros_like(x)
        return Retimed(
            np.zeros(n), x.copy(), zero, zero.copy(), np.zeros(n, np.int64), np.zeros(n),
            np.arange(n, dtype=np.int64),
        )  # fmt: skip
    moving, breaks = _corners(x)
    breaks[np.asarray([s for s in stops if 0 <= s < n], dtype=np.int64)] = True
    cuts = np.flatnonzero(breaks)
    out_t: list[FloatArray] = []
    out_q: list[FloatArray] = []
    out_qd: list[FloatArray] = []
    out_qdd: list[FloatArray] = []
    out_origin: list[IntArray] = []
    out_frac: list[FloatArray] = []
    clock = 0.0
    total = 0
    profiles: dict[tuple[float, ...], Any] = {}
    for a, b in itertools.pairwise(cuts):
        if not moving[a]:
            # standing still between a and b (= a + 1): keep the dwell as it was
            dwell = max(float(sec[b] - sec[a]), 0.0)
            count = max(int(np.ceil(dwell / step)), 1) if dwell > 0 else 0
            times = np.linspace(0.0, dwell, count + 1)[:-1] if count else np.zeros(1)
            out_t.append(clock + times)
            out_q.append(np.repeat(x[a][None, :], len(times), axis=0))
            out_qd.append(np.zeros((len(times), x.shape[1])))
            out_qdd.append(np.zeros((len(times), x.shape[1])))
            out_origin.append(np.full(len(times), a, dtype=np.int64))
            out_frac.append(times / dwell if dwell > 0 else np.zeros(1))
            clock += dwell
            total += len(times)
            continue
        start = x[a]
        delta = x[b] - start
        length = float(np.linalg.norm(delta))
        direction = delta / length
        # grid paths repeat the same pieces (one action, one corner): time each once
        key = (round(length, 12), *np.round(direction, 12).tolist())
        if key not in profiles:
            profiles[key] = _profile(length, direction, velocity_limits, acceleration_limits)
        prof = profiles[key]
        if prof is None:
            raise ArgumentError(
                [Problem("trajectory", f"cannot be retimed: no timing found for samples {a}-{b}")]
            )
        grid, sd = prof
        acc = (sd[1:] ** 2 - sd[:-1] ** 2) / (2.0 * np.diff(grid))
        dur = _tau(np.diff(grid), sd[:-1], acc)
        t_grid = np.concatenate([[0.0], np.cumsum(dur)])
        # the input samples' positions along the line, then their times
        s_in = np.clip((x[a:b] - start) @ direction, 0.0, length)
        # output: the input samples and a regular clock between them
        regular = np.arange(0.0, t_grid[-1], step)
        k_in = np.clip(np.searchsorted(grid, s_in, side="right") - 1, 0, len(acc) - 1)
        t_in = t_grid[k_in] + _tau(s_in - grid[k_in], sd[k_in], acc[k_in])
        times = np.concatenate([t_in, regular])
        is_input = np.concatenate([np.ones(len(t_in), bool), np.zeros(len(regular), bool)])
        order = np.lexsort((~is_input, times))
        times, is_input = times[order], is_input[order]
        # drop regular samples within a microsecond of an input sample
        j = np.clip(np.searchsorted(t_in, times), 1, len(t_in) - 1) if len(t_in) > 1 else None
        if j is None:
            near = np.abs(times - t_in[0])
        else:
            near = np.minimum(np.abs(times - t_in[j]), np.abs(times - t_in[j - 1]))
        keep = is_input | (near > 1e-6)
        times, is_input = times[keep], is_input[keep]
        k = np.clip(np.searchsorted(t_grid, times, side="right") - 1, 0, len(acc) - 1)
        tau = times - t_grid[k]
        s = grid[k] + sd[k] * tau + 0.5 * acc[k] * tau**2
        s[is_input] = s_in  # inputs stay in order: lexsort is stable
        s_dot = np.maximum(sd[k] + acc[k] * tau, 0.0)
        pos = start + np.outer(s, direction)
        pos[is_input] = x[a:b]  # input samples exactly as they were
        origin = a + np.clip(np.searchsorted(s_in, s, side="right") - 1, 0, b - a - 1)
        seg_len = np.linalg.norm(x[origin + 1] - x[origin], axis=1)
        frac = np.clip(np.linalg.norm(pos - x[origin], axis=1) / seg_len, 0.0, 1.0)
        frac[is_input] = 0.0
        out_t.append(clock + times)
        out_q.append(pos)
        out_qd.append(np.outer(s_dot, direction))
        out_qdd.append(np.outer(acc[k], direction))
        out_origin.append(origin.astype(np.int64))
        out_frac.append(frac)
        clock += float(t_grid[-1])
        total += len(times)
        if total > MAX_SAMPLES:
            raise ArgumentError(
                [Problem("step", f"the retimed trajectory would need more than {MAX_SAMPLES:,} "
                         "samples; choose a larger step")]
            )  # fmt: skip
    # the last input sample, at rest
    out_t.append(np.array([clock]))
    out_q.append(x[-1:].copy())
    out_qd.append(np.zeros((1, x.shape[1])))
    out_qdd.append(np.zeros((1, x.shape[1])))
    out_origin.append(np.array([n - 1], dtype=np.int64))
    out_frac.append(np.zeros(1))
    origin_all = np.concatenate(out_origin)
    frac_all = np.concatenate(out_frac)
    first = np.flatnonzero(frac_all == 0.0)
    index = np.full(n, -1, dtype=np.int64)
    # the first output sample of each input sample (reverse so the first one wins)
    index[origin_all[first][::-1]] = first[::-1]
    return Retimed(
        np.concatenate(out_t),
        np.concatenate(out_q),
        np.concatenate(out_qd),
        np.concatenate(out_qdd),
        origin_all,
        frac_all,
        index,
    )

"""The motion a planner produced: configurations over time, a mode per sample, events.

A :class:`Trajectory` is what a user feeds to a controller or a simulator: ``t`` (time
or stage, non-decreasing), ``q`` (one configuration per sample, in the units of code:
workcell units for positions, radians for angles), ``mode`` (per sample, an index into
``modes``: the assembly mode, the carried part, the moving disc, the task), and
``events`` (pick, place, FMP, grasp, switch ... at a sample index).

It saves to and loads from three formats, all without pickles:

Beside ``t`` (in the planner's unit: stage, path length ...) every sample has
``seconds``, physical time: ``stage x stage_duration`` for strategies, else the timing law
of :mod:`cellplan.timing` (a straight segment takes ``max_j |dq_j| / v_j`` at the robot's
speeds ``velocity_limits``). Columns that are periodic (continuous joints, a rotating
robot's heading) are *unwrapped*: consecutive samples differ by the motion actually made
(the shorter way round, as the planners move), never by a jump of a full turn; so
:meth:`Trajectory.sample` interpolates along that motion. :meth:`Trajectory.retime` gives
the time-optimal timing of the same path within velocity and acceleration limits
(TOPP-RA), and :meth:`Trajectory.to_ros2` a ROS 2 ``JointTrajectory``
(:mod:`cellplan.export`).

Events are typed: ``kind`` (pick, place, request ...), ``part``, ``region`` (where),
``target`` (where to: a request's destination, a change's new region), ``detail``
(free text for people) and the sample ``index`` (their ``t`` and ``seconds`` are the
sample's, written beside them in the files).

It saves to and loads from three formats, all without pickles (format version 2; a
version-1 file still loads: its seconds come from the default speeds, its events'
fields from their ``kind:detail`` text):

* CSV: a first comment line ``# cellplan-trajectory 2 {json header}``, then a header
  row ``t,seconds,mode,<columns...>[,qd.<column>...,qdd.<column>...],events`` and one row
  per sample; ``mode`` holds the mode's name and ``events`` the sample's events as a JSON
  list of objects (``kind``, ``part``, ``region``, ``target``, ``detail``). Floats are
  written with 17 significant digits, so a round trip is exact. Read it with any CSV
  reader that skips ``#`` comments (``pandas.read_csv(path, comment="#")``).
* JSON: one object with the header fields and the arrays as lists.
* NPZ: the arrays, and the header as a JSON string (``allow_pickle=False`` loads it).
"""

from __future__ import annotations

import csv
import io
import json
import tokenize
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellplan import export as ros
from cellplan import timing
from cellplan.errors import ArgumentError, PersistenceError, Problem
from cellplan.fileio import atomic_path, write_text

FORMAT = "cellplan-trajectory"
VERSION = 2
#: File versions :meth:`Trajectory.load` reads.
READS = (1, 2)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Event kinds the built-in planners emit (others are allowed: the kind is free text).
EVENT_KINDS = (
    "request",  # a request arrives (strategies)
    "pick",  # FMP that picks a part up (strategies)
    "place",  # FMP that delivers a part (strategies)
    "fmp_refused",  # the exact region test refused an FMP the grid allowed (strategies)
    "source_change",  # a waiting request's source changes (strategies, type 3)
    "destination_change",  # a carried part's destination changes (strategies, type 2)
    "grasp",  # the robot grasps a disc (sequential assembly)
    "switch",  # the moving disc changes (sequential assembly)
    "escape",  # k lowered after a stuck stage (assembly)
    "finish",  # the place rule finishes a sequential run that stopped short (assembly)
    "spread",  # all discs scaled apart before the place rule (assembly)
    "task",  # a task starts (adaptive)
    "arrive",  # a task's goal is reached (adaptive)
    "fail",  # a task failed (adaptive)
    "change",  # the workcell changed (adaptive)
)

#: Event kinds where the robot is at rest (a fine motion, a grasp, a task's ends):
#: :meth:`Trajectory.retime` keeps them as stops.
STOP_KINDS = ("pick", "place", "reject", "fmp_failed", "grasp", "switch", "task", "arrive", "fail")


@dataclass(frozen=True)
class Event:
    """Something that happens at sample ``index`` of a trajectory.

    ``part`` is the part (or disc) it concerns, ``region`` where it happens (a source,
    destination or goal), ``target`` where it leads (a request's destination, a change's
    new region), ``detail`` free text for people. Empty strings when they do not apply.
    """

    index: int
    kind: str
    detail: str = ""
    part: str = ""
    region: str = ""
    target: str = ""

    @staticmethod
    def from_text(index: int, kind: str, detail: str = "") -> Event:
        """An event with its fields read from the ``detail`` text the built-in planners
        write (and version-1 files hold): ``P1 from S1 to D1`` (request), ``P1 at S2``
        (pick, place, reject, fmp_failed), ``S1 to S2`` (source/destination change),
        ``disc 3`` (grasp), ``disc 1 -> disc 2`` (switch), a goal (task, arrive, fail)."""
        part = region = target = ""
        if kind == "request" and " from " in detail and " to " in detail:
            part, _, rest = detail.partition(" from ")
            region, _, target = rest.partition(" to ")
        elif kind in ("pick", "place", "reject", "fmp_failed") and " at " in detail:
            part, _, rest = detail.partition(" at ")
            region = rest.split(",", 1)[0]
        elif kind in ("source_change", "destination_change") and " to " in detail:
            region, _, target = detail.partition(" to ")
        elif kind == "grasp":
            part = detail
        elif kind == "switch" and " -> " in detail:
            part = detail.partition(" -> ")[2]
        elif kind in ("task", "arrive", "fail"):
            region = detail
        return Event(int(index), kind, detail, part.strip(), region.strip(), target.strip())

    def fields(self) -> dict[str, str]:
        """``kind``, ``part``, ``region``, ``target``, ``detail`` (the typed fields)."""
        return {
            "kind": self.kind,
            "part": self.part,
            "region": self.region,
            "target": self.target,
            "detail": self.detail,
        }


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A motion: samples ``(t, seconds, q, mode)`` and events; see the module docstring.

    Attributes
    ----------
    t
        ``(T,)`` time or stage of each sample in the planner's unit, non-decreasing.
    q
        ``(T, dim)`` configurations (radians for angles; periodic columns unwrapped).
    mode
        ``(T,)`` index into ``modes`` for each sample.
    modes
        Names of the modes (``NR``, ``<P1,S1,D1,W>``, ``all discs``, ``disc 3``, a goal ...).
    columns
        Names of the ``q`` columns: the joint names (a URDF's, ``q1..qn`` for a planar
        arm, ``x``, ``y``, ``theta``, ``disc1.x`` ...).
    units
        Unit of each column: ``"workcell"`` (the scenario's length unit) or ``"rad"``.
    time_unit
        Unit of ``t``: ``"stage"`` (strategies), ``"flow"`` (navigation-function flow
        time), ``"s"``, ``"step"``, or ``"path"`` (cumulative joint-space path length).
    events
        :class:`Event` s in order of their index.
    meta
        Plain scalars describing the run (planner, scenario, seed ...).
    seconds
        ``(T,)`` physical time of each sample, from 0; None: ``(t - t[0]) *
        stage_duration`` when that is given, else the timing law at ``velocity_limits``.
    periodic
        Per column, whether it is an angle on the circle (unwrapped on construction);
        empty: none is.
    stage_duration
        Seconds per unit of ``t`` when ``seconds`` is ``t`` scaled (strategies), else None.
    velocity_limits, acceleration_limits
        Per column, the robot's top speed (units/s, rad/s) and acceleration (units/s^2,
        rad/s^2); empty: the defaults of :func:`cellplan.timing.default_limits`.
    qd, qdd
        ``(T, dim)`` velocities and accelerations at the samples when known (a retimed
        trajectory), else None.
    """

    t: FloatArray
    q: FloatArray
    mode: IntArray
    modes: tuple[str, ...]
    columns: tuple[str, ...]
    units: tuple[str, ...]
    time_unit: str = "stage"
    events: tuple[Event, ...] = ()
    meta: Mapping[str, str | int | float | bool] = field(default_factory=dict)
    seconds: FloatArray | None = None
    periodic: tuple[bool, ...] = ()
    stage_duration: float | None = None
    velocity_limits: tuple[float, ...] = ()
    acceleration_limits: tuple[float, ...] = ()
    qd: FloatArray | None = None
    qdd: FloatArray | None = None

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t, dtype=np.float64).reshape(-1)
        q = np.ascontiguousarray(self.q, dtype=np.float64)
        if q.ndim == 1:
            q = q.reshape(len(t), -1) if len(t) else q.reshape(0, len(self.columns))
        mode = np.ascontiguousarray(self.mode, dtype=np.int64).reshape(-1)
        columns = tuple(str(c) for c in self.columns)
        unit_names = tuple(str(u) for u in self.units)
        periodic = tuple(bool(p) for p in self.periodic) or (False,) * len(columns)
        if len(periodic) == len(columns) and q.ndim == 2 and q.shape[1] == len(columns):
            if any(periodic) and len(q) > 1 and np.all(np.isfinite(q)):
                # the shorter way round between samples: the motion the planners make
                q = q.copy()
                cols = np.flatnonzero(periodic)
                q[:, cols] = np.unwrap(q[:, cols], axis=0)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "mode", mode)
        object.__setattr__(self, "modes", tuple(str(m) for m in self.modes))
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "units", unit_names)
        object.__setattr__(self, "events", tuple(self.events))
        object.__setattr__(self, "meta", dict(self.meta))
        object.__setattr__(self, "periodic", periodic)
        speed, accel = timing.default_limits(unit_names)
        vlim = tuple(float(v) for v in self.velocity_limits) or tuple(speed.tolist())
        alim = tuple(float(v) for v in self.acceleration_limits) or tuple(accel.tolist())
        object.__setattr__(self, "velocity_limits", vlim)
        object.__setattr__(self, "acceleration_limits", alim)
        if self.stage_duration is not None:
            object.__setattr__(self, "stage_duration", float(self.stage_duration))
        for name in ("qd", "qdd"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, np.ascontiguousarray(value, dtype=np.float64))
        problems = self._problems()
        if problems:
            raise ValueError("invalid trajectory: " + "; ".join(problems))
        if self.seconds is None:
            if self.stage_duration is not None:
                sec = (t - (t[0] if len(t) else 0.0)) * self.stage_duration
            else:
                sec = timing.path_seconds(q, vlim)
        else:
            sec = np.ascontiguousarray(self.seconds, dtype=np.float64).reshape(-1)
        object.__setattr__(self, "seconds", sec)
        problems = self._time_problems()
        if problems:
            raise ValueError("invalid trajectory: " + "; ".join(problems))

    def _problems(self) -> list[str]:
        out = []
        n = len(self.t)
        dim = len(self.columns)
        if self.q.ndim != 2 or self.q.shape[0] != n:
            out.append(f"q has shape {self.q.shape}; expected ({n}, dim)")
        elif self.q.shape[1] != dim:
            out.append(f"q has {self.q.shape[1]} columns but {dim} column names")
        if len(self.units) != dim:
            out.append(f"{len(self.units)} units for {dim} columns")
        if len(self.periodic) != dim:
            out.append(f"{len(self.periodic)} periodic flags for {dim} columns")
        for name in ("velocity_limits", "acceleration_limits"):
            lim = np.asarray(getattr(self, name), dtype=float)
            if lim.shape != (dim,) or not np.all(np.isfinite(lim)) or np.any(lim <= 0):
                out.append(f"{name} needs {dim} positive finite values")
        if self.stage_duration is not None and not (
            np.isfinite(self.stage_duration) and self.stage_duration >= 0
        ):
            out.append("stage_duration must be a finite number >= 0")
        if self.mode.shape != (n,):
            out.append(f"mode has shape {self.mode.shape}; expected ({n},)")
        elif n and (self.mode.min() < 0 or self.mode.max() >= len(self.modes)):
            out.append("mode indices outside the list of modes")
        if n > 1 and np.any(np.diff(self.t) < 0):
            out.append("t decreases")
        if not np.all(np.isfinite(self.t)) or not np.all(np.isfinite(self.q)):
            out.append("t and q must be finite")
        for name in ("qd", "qdd"):
            value = getattr(self, name)
            if value is not None and (value.shape != (n, dim) or not np.all(np.isfinite(value))):
                out.append(f"{name} must be finite, of shape ({n}, {dim})")
        if (self.qd is None) != (self.qdd is None):
            out.append("qd and qdd come together")
        for e in self.events:
            if not 0 <= e.index < max(n, 1):
                out.append(f"event {e.kind!r} at index {e.index} outside the samples")
            if not e.kind:
                out.append("an event needs a kind")
        for name in self.columns:
            if name in ("t", "seconds", "mode", "events") or "," in name:
                out.append(f"column name {name!r} is reserved or contains a comma")
        return out

    def _time_problems(self) -> list[str]:
        sec = self.seconds
        assert sec is not None
        if sec.shape != self.t.shape:
            return [f"seconds has shape {sec.shape}; expected {self.t.shape}"]
        if not np.all(np.isfinite(sec)):
            return ["seconds must be finite (speeds too small for this path?)"]
        if len(sec) > 1 and np.any(np.diff(sec) < 0):
            return ["seconds decrease"]
        return []

    # --- queries ---------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dim(self) -> int:
        """Number of configuration columns."""
        return int(self.q.shape[1])

    @property
    def duration(self) -> float:
        """``t[-1] - t[0]`` (0 for fewer than two samples)."""
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def duration_s(self) -> float:
        """Seconds from the first sample to the last."""
        sec = self.seconds
        assert sec is not None
        return float(sec[-1] - sec[0]) if len(sec) > 1 else 0.0

    def __repr__(self) -> str:
        """Short: samples, columns, time unit, seconds, events and modes; no arrays."""
        shown = ", ".join(self.columns[:REPR_COLUMNS])
        if self.dim > REPR_COLUMNS:
            shown += ", ..."
        return (
            f"Trajectory({len(self)} samples x {self.dim} columns [{shown}], "
            f"t in {self.time_unit}, {self.duration_s:.3g} s, {len(self.events)} events, "
            f"{len(self.modes)} modes)"
        )

    def _repr_png_(self) -> bytes:
        """The :meth:`plot` as PNG bytes, for notebooks."""
        fig = self.plot()
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=100)
        return buffer.getvalue()

    @property
    def mode_names(self) -> list[str]:
        """The mode name of every sample (an attribute, like :attr:`modes` and :attr:`events`)."""
        return [self.modes[i] for i in self.mode]

    def events_of(self, kind: str) -> list[Event]:
        """The events of one kind."""
        return [e for e in self.events if e.kind == kind]

    def event_time(self, event: Event) -> tuple[float, float]:
        """``(t, seconds)`` of an event (its sample's)."""
        sec = self.seconds
        assert sec is not None
        return float(self.t[event.index]), float(sec[event.index])

    def sample(self, times: Sequence[float] | FloatArray, clock: str = "t") -> FloatArray:
        """Configurations at ``times`` by linear interpolation (clamped at the ends).

        ``clock`` is ``"t"`` (the planner's unit) or ``"seconds"``. Periodic columns are
        unwrapped, so the interpolation follows the motion actually made (the planners'
        own straight segments between samples).
        """
        ts = np.asarray(times, dtype=float).reshape(-1)
        if len(self.t) == 0:
            raise ValueError("empty trajectory")
        if clock not in ("t", "seconds"):
            raise ValueError(f"clock is 't' or 'seconds', not {clock!r}")
        base = self.t if clock == "t" else self.seconds
        assert base is not None
        return np.stack([np.interp(ts, base, self.q[:, j]) for j in range(self.dim)], axis=1)

    def length(self) -> float:
        """Euclidean length of the polyline through ``q`` (units mixed as in ``q``)."""
        if len(self.q) < 2:
            return 0.0
        return float(np.sum(np.linalg.norm(np.diff(self.q, axis=0), axis=1)))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Trajectory):
            return NotImplemented
        return (
            self._header() == other._header()
            and np.array_equal(self.t, other.t)
            and np.array_equal(self.seconds, other.seconds)  # type: ignore[arg-type]
            and np.array_equal(self.q, other.q)
            and np.array_equal(self.mode, other.mode)
            and _same(self.qd, other.qd)
            and _same(self.qdd, other.qdd)
            and self.events == other.events
        )

    __hash__ = None  # type: ignore[assignment]

    # --- timing ----------------------------------------------------------------------------

    def stops(self) -> list[int]:
        """Sample indices of the events where the robot rests (:data:`STOP_KINDS`)."""
        return sorted({e.index for e in self.events if e.kind in STOP_KINDS})

    def retime(
        self,
        velocity_limits: ArrayLike | None = None,
        acceleration_limits: ArrayLike | None = None,
        position_limits: tuple[ArrayLike, ArrayLike] | None = None,
        step: float = timing.RETIME_STEP,
    ) -> Trajectory:
        """The same path with the fastest timing within the limits (TOPP-RA).

        Parameters
        ----------
        velocity_limits, acceleration_limits
            Per column (one number: every column), units/s and units/s^2 in code units
            (rad/s for angles); default: the trajectory's own (the scenario's or the URDF's).
        position_limits
            ``(lower, upper)`` per column: a path that leaves them is refused.
        step
            Largest gap between two samples of the result, seconds.

        The path is cut at corners (a polyline can only be followed exactly by stopping
        there), at :meth:`stops` and where the robot stands still (dwells keep their
        seconds); each straight piece is timed from rest to rest
        (:func:`cellplan.timing.retime_polyline`). Every sample stays a sample (its
        events move with it); ``t`` of new samples is interpolated along their segment.
        The result carries ``qd`` and ``qdd``; its ``meta`` gains ``retimed: true``.

        Raises
        ------
        ArgumentError
            A limit that is not positive and finite or of the wrong length, a path that
            leaves ``position_limits``, or a path TOPP-RA cannot time (one line each).
        """
        vlim = timing.check_limits(
            self.velocity_limits if velocity_limits is None else velocity_limits,
            self.dim,
            "velocity_limits",
        )
        alim = timing.check_limits(
            self.acceleration_limits if acceleration_limits is None else acceleration_limits,
            self.dim,
            "acceleration_limits",
        )
        if not (np.isfinite(step) and step > 0):
            raise ArgumentError([Problem("step", f"must be a positive number, got {step!r}")])
        if position_limits is not None:
            self._check_positions(position_limits)
        sec = self.seconds
        assert sec is not None
        res = timing.retime_polyline(self.q, sec, self.stops(), vlim, alim, step)
        nxt = np.minimum(res.origin + 1, len(self.t) - 1)
        t = self.t[res.origin] + res.fraction * (self.t[nxt] - self.t[res.origin])
        t = np.maximum.accumulate(t) if len(t) else t
        events = tuple(replace(e, index=int(res.index[e.index])) for e in self.events)
        return Trajectory(
            t,
            res.q,
            self.mode[res.origin],
            self.modes,
            self.columns,
            self.units,
            self.time_unit,
            events,
            {**self.meta, "retimed": True},
            seconds=res.seconds,
            periodic=self.periodic,
            stage_duration=None,
            velocity_limits=tuple(vlim.tolist()),
            acceleration_limits=tuple(alim.tolist()),
            qd=res.qd,
            qdd=res.qdd,
        )

    def _check_positions(self, limits: tuple[ArrayLike, ArrayLike]) -> None:
        try:
            lo, hi = (np.asarray(v, dtype=float).reshape(-1) for v in limits)
        except (TypeError, ValueError):
            raise ArgumentError([Problem("position_limits", "expected (lower, upper)")]) from None
        if lo.shape != (self.dim,) or hi.shape != (self.dim,):
            raise ArgumentError(
                [Problem("position_limits", f"expected {self.dim} lower and upper values")]
            )
        tol = 1e-9 * (1.0 + np.abs(lo) + np.abs(hi))
        out = (self.q < lo - tol) | (self.q > hi + tol)
        if np.any(out):
            i, j = (int(v) for v in np.argwhere(out)[0])
            raise ArgumentError(
                [
                    Problem(
                        "trajectory",
                        f"cannot be retimed: it leaves the joint limits ({self.columns[j]} = "
                        f"{self.q[i, j]:.6g} at sample {i}, outside [{lo[j]:.6g}, {hi[j]:.6g}])",
                    )
                ]
            )

    def velocities(self) -> tuple[FloatArray, FloatArray]:
        """``(qd, qdd)``: the trajectory's own, else finite differences over seconds."""
        if self.qd is not None and self.qdd is not None:
            return self.qd, self.qdd
        sec = self.seconds
        assert sec is not None
        return timing.finite_velocities(sec, self.q)

    def to_ros2(
        self, path: str | Path | None = None, fmt: str = "ros2-yaml", frame_id: str = ""
    ) -> Any:
        """A ROS 2 ``trajectory_msgs/msg/JointTrajectory``.

        Without ``path``: the message as a dict (the layout of ``ros2 topic pub``). With
        ``path``: written there as ``fmt`` (``ros2-yaml``, or ``ros2-bag``: a rosbag2
        folder, MCAP storage, with a ``sensor_msgs/msg/JointState`` stream); returns the
        path. See :mod:`cellplan.export`.
        """
        if path is None:
            return ros.joint_trajectory(self, frame_id)
        return ros.export(self, fmt, path, frame_id)

    # --- files -----------------------------------------------------------------------------

    def _header(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "time_unit": self.time_unit,
            "columns": list(self.columns),
            "units": list(self.units),
            "periodic": list(self.periodic),
            "modes": list(self.modes),
            "stage_duration": self.stage_duration,
            "velocity_limits": list(self.velocity_limits),
            "acceleration_limits": list(self.acceleration_limits),
            "derivatives": self.qd is not None,
            "meta": dict(self.meta),
        }

    def _event_rows(self) -> list[dict[str, Any]]:
        out = []
        for e in self.events:
            t, s = self.event_time(e)
            out.append({"index": e.index, **e.fields(), "t": t, "seconds": s})
        return out

    def to_dict(self) -> dict[str, Any]:
        """The JSON form: header fields plus ``t``, ``seconds``, ``q``, ``mode``, ``events``
        (each with its typed fields, ``t`` and ``seconds``) and, when known, ``qd``, ``qdd``."""
        sec = self.seconds
        assert sec is not None
        out = self._header()
        out.update(
            t=self.t.tolist(),
            seconds=sec.tolist(),
            q=self.q.tolist(),
            mode=self.mode.tolist(),
            events=self._event_rows(),
        )
        if self.qd is not None and self.qdd is not None:
            out.update(qd=self.qd.tolist(), qdd=self.qdd.tolist())
        return out

    def _csv_columns(self) -> list[str]:
        names = ["t", "seconds", "mode", *self.columns]
        if self.qd is not None:
            names += [f"qd.{c}" for c in self.columns] + [f"qdd.{c}" for c in self.columns]
        return [*names, "events"]

    def to_csv_text(self) -> str:
        """The CSV form (see the module docstring)."""
        sec = self.seconds
        assert sec is not None
        buf = io.StringIO()
        buf.write(f"# {FORMAT} {VERSION} {json.dumps(self._header(), sort_keys=True)}\n")
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(self._csv_columns())
        at: dict[int, list[dict[str, str]]] = {}
        for e in self.events:
            at.setdefault(e.index, []).append(e.fields())
        for i in range(len(self.t)):
            extra: list[str] = []
            if self.qd is not None and self.qdd is not None:
                extra = [_num(v) for v in self.qd[i]] + [_num(v) for v in self.qdd[i]]
            writer.writerow(
                [
                    _num(self.t[i]),
                    _num(sec[i]),
                    self.modes[self.mode[i]],
                    *(_num(v) for v in self.q[i]),
                    *extra,
                    json.dumps(at[i], separators=(",", ":")) if i in at else "",
                ]
            )
        return buf.getvalue()

    def save(self, path: str | Path) -> Path:
        """Write ``.csv``, ``.json`` or ``.npz`` (by suffix), atomically; returns the path."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".csv":
            write_text(path, self.to_csv_text())
        elif suffix == ".json":
            write_text(path, json.dumps(self.to_dict()) + "\n")
        elif suffix == ".npz":
            rows = self._event_rows()
            arrays: dict[str, Any] = {
                "header": np.array(json.dumps(self._header())),
                "t": self.t,
                "seconds": self.seconds,
                "q": self.q,
                "mode": self.mode,
                "event_index": np.array([r["index"] for r in rows], dtype=np.int64),
                "event_t": np.array([r["t"] for r in rows], dtype=np.float64),
                "event_seconds": np.array([r["seconds"] for r in rows], dtype=np.float64),
            }
            for key in EVENT_TEXT:
                arrays[f"event_{key}"] = np.array([r[key] for r in rows], dtype=str)
            if self.qd is not None:
                arrays.update(qd=self.qd, qdd=self.qdd)
            with atomic_path(path) as tmp, open(tmp, "wb") as fh:
                np.savez_compressed(fh, **arrays)
        else:
            raise ValueError(
                f"unsupported trajectory file type {path.suffix!r}; use .csv, .json or .npz"
            )
        return path

    @staticmethod
    def load(path: str | Path) -> Trajectory:
        """Read a trajectory written by :meth:`save` (format version 2, or 1).

        Raises
        ------
        PersistenceError
            The file is unreadable, not a trajectory, of a version this cellplan does not
            read, or inconsistent (one line naming it).
        """
        path = Path(path)
        where = str(path)
        try:
            suffix = path.suffix.lower()
            if suffix == ".csv":
                return _from_csv(path.read_text(encoding="utf-8"))
            if suffix == ".json":
                return _from_dict(json.loads(path.read_text(encoding="utf-8")))
            if suffix == ".npz":
                with np.load(path, allow_pickle=False) as z:
                    return _from_dict(_npz_dict(z))
        except PersistenceError:
            raise
        except (
            OSError,
            ValueError,
            KeyError,
            TypeError,
            IndexError,
            UnicodeDecodeError,
            EOFError,
            zipfile.BadZipFile,
            zlib.error,
            NotImplementedError,  # a zip member's foreign compression method
            tokenize.TokenError,  # a .npy header numpy cannot tokenize (an open bracket)
            SyntaxError,
        ) as exc:
            msg = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise PersistenceError([Problem(where, f"not a readable trajectory: {msg}")]) from None
        raise PersistenceError([Problem(where, "expected a .csv, .json or .npz trajectory")])

    # --- combining and drawing -------------------------------------------------------------

    @staticmethod
    def concatenate(parts: Sequence[Trajectory]) -> Trajectory:
        """Join trajectories with the same columns end to end (modes merged by name).

        Each part's ``t`` and ``seconds`` are shifted so that they continue from the
        previous part's end. Limits and periodic flags are the first part's.
        """
        if not parts:
            raise ValueError("nothing to concatenate")
        first = parts[0]
        modes: list[str] = []
        ts: list[FloatArray] = []
        secs: list[FloatArray] = []
        qs: list[FloatArray] = []
        ms: list[IntArray] = []
        events: list[Event] = []
        offset, offset_s, base = 0.0, 0.0, 0
        for part in parts:
            if part.columns != first.columns or part.time_unit != first.time_unit:
                raise ValueError("trajectories to concatenate need the same columns and time unit")
            sec = part.seconds
            assert sec is not None
            index = {name: _index(modes, name) for name in part.modes}
            remap = np.array([index[name] for name in part.modes], dtype=np.int64)
            shift = offset - (part.t[0] if len(part) else 0.0)
            shift_s = offset_s - (sec[0] if len(part) else 0.0)
            ts.append(part.t + shift)
            secs.append(sec + shift_s)
            qs.append(part.q)
            ms.append(remap[part.mode] if len(part) else part.mode)
            events.extend(replace(e, index=e.index + base) for e in part.events)
            if len(part):
                offset = float(part.t[-1] + shift)
                offset_s = float(sec[-1] + shift_s)
            base += len(part)
        durations = {p.stage_duration for p in parts}
        derivatives = all(p.qd is not None for p in parts)
        return Trajectory(
            np.concatenate(ts),
            np.concatenate(qs),
            np.concatenate(ms),
            tuple(modes),
            first.columns,
            first.units,
            first.time_unit,
            tuple(events),
            first.meta,
            seconds=np.concatenate(secs),
            periodic=first.periodic,
            stage_duration=durations.pop() if len(durations) == 1 else None,
            velocity_limits=first.velocity_limits,
            acceleration_limits=first.acceleration_limits,
            qd=np.concatenate([p.qd for p in parts]) if derivatives else None,
            qdd=np.concatenate([p.qdd for p in parts]) if derivatives else None,
        )

    def plot(self, path: str | Path | None = None, ax: Any = None) -> Any:
        """Draw each configuration column against ``t`` with the events marked.

        Returns the matplotlib figure; with ``path`` it is also saved there.
        """
        from cellplan.plots import plot_trajectory

        return plot_trajectory(self, path=path, ax=ax)


#: Columns a :class:`Trajectory`'s repr names before "...".
REPR_COLUMNS = 6

#: The text fields of an event in the files.
EVENT_TEXT = ("kind", "part", "region", "target", "detail")


def _same(a: FloatArray | None, b: FloatArray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b))


def _index(names: list[str], name: str) -> int:
    if name not in names:
        names.append(name)
    return names.index(name)


def _num(v: float) -> str:
    return repr(float(v))


def _check_header(header: Mapping[str, Any]) -> int:
    if header.get("format") != FORMAT:
        raise ValueError(f"format is {header.get('format')!r}, not {FORMAT!r}")
    version = header.get("version")
    if version not in READS or isinstance(version, bool):
        reads = " and ".join(str(v) for v in READS)
        raise ValueError(f"version {version!r}; this cellplan reads versions {reads}")
    return int(version)


def _event(row: Mapping[str, Any], version: int) -> Event:
    if version == 1:
        return Event.from_text(int(row["index"]), str(row["kind"]), str(row.get("detail", "")))
    text = {key: str(row.get(key, "")) for key in EVENT_TEXT}
    return Event(int(row["index"]), **text)


def _npz_dict(z: Any) -> dict[str, Any]:
    header = json.loads(str(z["header"]))
    version = _check_header(header)
    keys = EVENT_TEXT if version > 1 else ("kind", "detail")
    columns = {key: z[f"event_{key}"] for key in keys}
    events = [
        {"index": int(i), **{key: str(columns[key][k]) for key in keys}}
        for k, i in enumerate(z["event_index"])
    ]
    data = {**header, "t": z["t"], "q": z["q"], "mode": z["mode"], "events": events}
    if version > 1:
        data["seconds"] = z["seconds"]
        if header.get("derivatives"):
            data.update(qd=z["qd"], qdd=z["qdd"])
    return data


def _from_dict(data: Mapping[str, Any]) -> Trajectory:
    if not isinstance(data, Mapping):
        raise ValueError("expected a JSON object")
    version = _check_header(data)
    columns = tuple(data["columns"])
    q = np.asarray(data["q"], dtype=float)
    if q.size == 0:
        q = q.reshape(0, len(columns))
    events = tuple(_event(e, version) for e in data["events"])
    # version 1 has none of the fields below: seconds from the default speeds, no periodic
    # columns, the default limits, no derivatives (the module docstring)
    v2 = version > 1
    derivatives = v2 and bool(data["derivatives"])
    duration = data["stage_duration"] if v2 else None
    return Trajectory(
        np.asarray(data["t"], dtype=float),
        q,
        np.asarray(data["mode"], dtype=np.int64),
        tuple(data["modes"]),
        columns,
        tuple(data["units"]),
        str(data["time_unit"]),
        events,
        dict(data.get("meta", {})),
        seconds=np.asarray(data["seconds"], dtype=float) if v2 else None,
        periodic=tuple(bool(p) for p in data["periodic"]) if v2 else (),
        stage_duration=None if duration is None else float(duration),
        velocity_limits=tuple(float(v) for v in data["velocity_limits"]) if v2 else (),
        acceleration_limits=tuple(float(v) for v in data["acceleration_limits"]) if v2 else (),
        qd=np.asarray(data["qd"], dtype=float).reshape(q.shape) if derivatives else None,
        qdd=np.asarray(data["qdd"], dtype=float).reshape(q.shape) if derivatives else None,
    )


def _from_csv(text: str) -> Trajectory:
    first, _, rest = text.partition("\n")
    prefix = f"# {FORMAT} "
    if not first.startswith(prefix):
        raise ValueError(f"first line must start with {prefix.strip()!r}")
    header = json.loads(first[len(prefix) :].split(" ", 1)[1])
    version = _check_header(header)
    rows = list(csv.reader(io.StringIO(rest)))
    columns = tuple(header["columns"])
    dim = len(columns)
    derivatives = version > 1 and bool(header.get("derivatives"))
    if version == 1:
        expected = ["t", "mode", *columns, "events"]
    else:
        expected = ["t", "seconds", "mode", *columns]
        if derivatives:
            expected += [f"qd.{c}" for c in columns] + [f"qdd.{c}" for c in columns]
        expected.append("events")
    if not rows or rows[0] != expected:
        raise ValueError("header row does not match the columns named in the first line")
    lead = 1 if version == 1 else 2  # t[, seconds] before mode
    modes = list(header["modes"])
    t: list[float] = []
    sec: list[float] = []
    values: list[list[float]] = []
    mode: list[int] = []
    events: list[dict[str, Any]] = []
    for i, row in enumerate(rows[1:]):
        if len(row) != len(expected):
            raise ValueError(f"row {i + 1} has {len(row)} fields, expected {len(expected)}")
        t.append(float(row[0]))
        if version > 1:
            sec.append(float(row[1]))
        if row[lead] not in modes:
            raise ValueError(f"row {i + 1}: unknown mode {row[lead]!r}")
        mode.append(modes.index(row[lead]))
        values.append([float(v) for v in row[lead + 1 : -1]])
        if version == 1:
            for item in filter(None, row[-1].split("|")):
                kind, _, detail = item.partition(":")
                events.append({"index": i, "kind": kind, "detail": detail})
        elif row[-1]:
            items = json.loads(row[-1])
            if not isinstance(items, list) or not all(isinstance(e, dict) for e in items):
                raise ValueError(f"row {i + 1}: events must be a JSON list of objects")
            events.extend({**e, "index": i} for e in items)
    width = dim * (3 if derivatives else 1)
    arr = np.asarray(values, dtype=float).reshape(len(t), width)
    data: dict[str, Any] = {**header, "t": t, "q": arr[:, :dim], "mode": mode, "events": events}
    if version > 1:
        data["seconds"] = sec
        if derivatives:
            data.update(qd=arr[:, dim : 2 * dim], qdd=arr[:, 2 * dim :])
    return _from_dict(data)

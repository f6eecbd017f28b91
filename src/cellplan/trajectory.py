"""The motion a planner produced: configurations over time, a mode per sample, events.

A :class:`Trajectory` is what a user feeds to a controller or a simulator: ``t`` (time
or stage, non-decreasing), ``q`` (one configuration per sample, in the units of code:
workcell units for positions, radians for angles), ``mode`` (per sample, an index into
``modes``: the assembly mode, the carried part, the moving disc, the task), and
``events`` (pick, place, FMP, grasp, switch ... at a sample index).

It saves to and loads from three formats, all without pickles:

* CSV: a first comment line ``# cellplan-trajectory 1 {json header}``, then a header
  row ``t,mode,<columns...>,events`` and one row per sample; ``mode`` holds the mode's
  name and ``events`` the sample's events as ``kind:detail`` joined by ``|``. Floats are
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellplan.errors import PersistenceError, Problem
from cellplan.fileio import atomic_path, write_text

FORMAT = "cellplan-trajectory"
VERSION = 1
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
    "task",  # a task starts (adaptive)
    "arrive",  # a task's goal is reached (adaptive)
    "fail",  # a task failed (adaptive)
    "change",  # the workcell changed (adaptive)
)


@dataclass(frozen=True)
class Event:
    """Something that happens at sample ``index`` of a trajectory."""

    index: int
    kind: str
    detail: str = ""


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A motion: samples ``(t, q, mode)`` and events; see the module docstring.

    Attributes
    ----------
    t
        ``(T,)`` time or stage of each sample, non-decreasing.
    q
        ``(T, dim)`` configurations (radians for angles).
    mode
        ``(T,)`` index into ``modes`` for each sample.
    modes
        Names of the modes (``NR``, ``<P1,S1,D1,W>``, ``all discs``, ``disc 3``, a goal ...).
    columns
        Names of the ``q`` columns (``x``, ``y``, ``theta``, ``q1``, ``disc1.x`` ...).
    units
        Unit of each column: ``"workcell"`` (the scenario's length unit) or ``"rad"``.
    time_unit
        ``"stage"`` (strategies), ``"flow"`` (navigation-function flow time), ``"s"``,
        ``"step"``, or ``"path"`` (cumulative joint-space path length).
    events
        :class:`Event` s in order of their index.
    meta
        Plain scalars describing the run (planner, scenario, seed ...).
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

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t, dtype=np.float64).reshape(-1)
        q = np.ascontiguousarray(self.q, dtype=np.float64)
        if q.ndim == 1:
            q = q.reshape(len(t), -1) if len(t) else q.reshape(0, len(self.columns))
        mode = np.ascontiguousarray(self.mode, dtype=np.int64).reshape(-1)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "mode", mode)
        object.__setattr__(self, "modes", tuple(str(m) for m in self.modes))
        object.__setattr__(self, "columns", tuple(str(c) for c in self.columns))
        object.__setattr__(self, "units", tuple(str(u) for u in self.units))
        object.__setattr__(self, "events", tuple(self.events))
        object.__setattr__(self, "meta", dict(self.meta))
        problems = self._problems()
        if problems:
            raise ValueError("invalid trajectory: " + "; ".join(problems))

    def _problems(self) -> list[str]:
        out = []
        n = len(self.t)
        if self.q.ndim != 2 or self.q.shape[0] != n:
            out.append(f"q has shape {self.q.shape}; expected ({n}, dim)")
        elif self.q.shape[1] != len(self.columns):
            out.append(f"q has {self.q.shape[1]} columns but {len(self.columns)} column names")
        if len(self.units) != len(self.columns):
            out.append(f"{len(self.units)} units for {len(self.columns)} columns")
        if self.mode.shape != (n,):
            out.append(f"mode has shape {self.mode.shape}; expected ({n},)")
        elif n and (self.mode.min() < 0 or self.mode.max() >= len(self.modes)):
            out.append("mode indices outside the list of modes")
        if n > 1 and np.any(np.diff(self.t) < 0):
            out.append("t decreases")
        if not np.all(np.isfinite(self.t)) or not np.all(np.isfinite(self.q)):
            out.append("t and q must be finite")
        for e in self.events:
            if not 0 <= e.index < max(n, 1):
                out.append(f"event {e.kind!r} at index {e.index} outside the samples")
            if "|" in e.kind or ":" in e.kind or "|" in e.detail or "\n" in e.detail:
                out.append(f"event {e.kind!r}: kind may not contain '|' or ':', detail no '|'")
        for name in self.columns:
            if name in ("t", "mode", "events") or "," in name:
                out.append(f"column name {name!r} is reserved or contains a comma")
        return out

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

    def mode_names(self) -> list[str]:
        """The mode name of every sample."""
        return [self.modes[i] for i in self.mode]

    def events_of(self, kind: str) -> list[Event]:
        """The events of one kind."""
        return [e for e in self.events if e.kind == kind]

    def sample(self, times: Sequence[float] | FloatArray) -> FloatArray:
        """Configurations at ``times`` by linear interpolation (clamped at the ends).

        Angles are interpolated as plain numbers, which is what the planners' own
        straight segments do between samples.
        """
        ts = np.asarray(times, dtype=float).reshape(-1)
        if len(self.t) == 0:
            raise ValueError("empty trajectory")
        return np.stack([np.interp(ts, self.t, self.q[:, j]) for j in range(self.dim)], axis=1)

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
            and np.array_equal(self.q, other.q)
            and np.array_equal(self.mode, other.mode)
            and self.events == other.events
        )

    __hash__ = None  # type: ignore[assignment]

    # --- files -----------------------------------------------------------------------------

    def _header(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "time_unit": self.time_unit,
            "columns": list(self.columns),
            "units": list(self.units),
            "modes": list(self.modes),
            "meta": dict(self.meta),
        }

    def to_dict(self) -> dict[str, Any]:
        """The JSON form: header fields plus ``t``, ``q``, ``mode`` and ``events`` lists."""
        out = self._header()
        out.update(
            t=self.t.tolist(),
            q=self.q.tolist(),
            mode=self.mode.tolist(),
            events=[{"index": e.index, "kind": e.kind, "detail": e.detail} for e in self.events],
        )
        return out

    def to_csv_text(self) -> str:
        """The CSV form (see the module docstring)."""
        buf = io.StringIO()
        buf.write(f"# {FORMAT} {VERSION} {json.dumps(self._header(), sort_keys=True)}\n")
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(["t", "mode", *self.columns, "events"])
        at: dict[int, list[str]] = {}
        for e in self.events:
            at.setdefault(e.index, []).append(f"{e.kind}:{e.detail}" if e.detail else e.kind)
        for i in range(len(self.t)):
            writer.writerow(
                [
                    _num(self.t[i]),
                    self.modes[self.mode[i]],
                    *(_num(v) for v in self.q[i]),
                    "|".join(at.get(i, [])),
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
            with atomic_path(path) as tmp, open(tmp, "wb") as fh:
                np.savez_compressed(
                    fh,
                    header=np.array(json.dumps(self._header())),
                    t=self.t,
                    q=self.q,
                    mode=self.mode,
                    event_index=np.array([e.index for e in self.events], dtype=np.int64),
                    event_kind=np.array([e.kind for e in self.events], dtype=str),
                    event_detail=np.array([e.detail for e in self.events], dtype=str),
                )
        else:
            raise ValueError(
                f"unsupported trajectory file type {path.suffix!r}; use .csv, .json or .npz"
            )
        return path

    @staticmethod
    def load(path: str | Path) -> Trajectory:
        """Read a trajectory written by :meth:`save`.

        Raises
        ------
        PersistenceError
            The file is unreadable, not a trajectory, or inconsistent (one line naming it).
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
                    header = json.loads(str(z["header"]))
                    events = [
                        {"index": int(i), "kind": str(k), "detail": str(d)}
                        for i, k, d in zip(
                            z["event_index"], z["event_kind"], z["event_detail"], strict=True
                        )
                    ]
                    return _from_dict(
                        {**header, "t": z["t"], "q": z["q"], "mode": z["mode"], "events": events}
                    )
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

        Each part's ``t`` is shifted so that it continues from the previous part's end.
        """
        if not parts:
            raise ValueError("nothing to concatenate")
        first = parts[0]
        modes: list[str] = []
        ts: list[FloatArray] = []
        qs: list[FloatArray] = []
        ms: list[IntArray] = []
        events: list[Event] = []
        offset, base = 0.0, 0
        for part in parts:
            if part.columns != first.columns or part.time_unit != first.time_unit:
                raise ValueError("trajectories to concatenate need the same columns and time unit")
            index = {name: _index(modes, name) for name in part.modes}
            remap = np.array([index[name] for name in part.modes], dtype=np.int64)
            shift = offset - (part.t[0] if len(part) else 0.0)
            ts.append(part.t + shift)
            qs.append(part.q)
            ms.append(remap[part.mode] if len(part) else part.mode)
            events.extend(Event(e.index + base, e.kind, e.detail) for e in part.events)
            if len(part):
                offset = float(part.t[-1] + shift)
            base += len(part)
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
        )

    def plot(self, path: str | Path | None = None, ax: Any = None) -> Any:
        """Draw each configuration column against ``t`` with the events marked.

        Returns the matplotlib figure; with ``path`` it is also saved there.
        """
        from cellplan.plots import plot_trajectory

        return plot_trajectory(self, path=path, ax=ax)


def _index(names: list[str], name: str) -> int:
    if name not in names:
        names.append(name)
    return names.index(name)


def _num(v: float) -> str:
    return repr(float(v))


def _check_header(header: Mapping[str, Any]) -> None:
    if header.get("format") != FORMAT:
        raise ValueError(f"format is {header.get('format')!r}, not {FORMAT!r}")
    if header.get("version") != VERSION:
        raise ValueError(f"version {header.get('version')!r}; this cellplan reads {VERSION}")


def _from_dict(data: Mapping[str, Any]) -> Trajectory:
    if not isinstance(data, Mapping):
        raise ValueError("expected a JSON object")
    _check_header(data)
    columns = tuple(data["columns"])
    q = np.asarray(data["q"], dtype=float)
    if q.size == 0:
        q = q.reshape(0, len(columns))
    return Trajectory(
        np.asarray(data["t"], dtype=float),
        q,
        np.asarray(data["mode"], dtype=np.int64),
        tuple(data["modes"]),
        columns,
        tuple(data["units"]),
        str(data["time_unit"]),
        tuple(Event(int(e["index"]), str(e["kind"]), str(e["detail"])) for e in data["events"]),
        dict(data.get("meta", {})),
    )


def _from_csv(text: str) -> Trajectory:
    first, _, rest = text.partition("\n")
    prefix = f"# {FORMAT} "
    if not first.startswith(prefix):
        raise ValueError(f"first line must start with {prefix.strip()!r}")
    header = json.loads(first[len(prefix) :].split(" ", 1)[1])
    _check_header(header)
    rows = list(csv.reader(io.StringIO(rest)))
    columns = tuple(header["columns"])
    if not rows or rows[0] != ["t", "mode", *columns, "events"]:
        raise ValueError("header row does not match the columns named in the first line")
    modes = list(header["modes"])
    t: list[float] = []
    q: list[list[float]] = []
    mode: list[int] = []
    events: list[dict[str, Any]] = []
    for i, row in enumerate(rows[1:]):
        if len(row) != len(columns) + 3:
            raise ValueError(f"row {i + 1} has {len(row)} fields, expected {len(columns) + 3}")
        t.append(float(row[0]))
        if row[1] not in modes:
            raise ValueError(f"row {i + 1}: unknown mode {row[1]!r}")
        mode.append(modes.index(row[1]))
        q.append([float(v) for v in row[2:-1]])
        for item in filter(None, row[-1].split("|")):
            kind, _, detail = item.partition(":")
            events.append({"index": i, "kind": kind, "detail": detail})
    q_arr = np.asarray(q, dtype=float).reshape(len(t), len(columns))
    return _from_dict({**header, "t": t, "q": q_arr, "mode": mode, "events": events})

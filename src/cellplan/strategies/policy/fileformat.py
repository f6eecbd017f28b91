"""The strategy file format (``cellplan solve -o strategy.npz``), declared once and checked.

A strategy file is a NumPy ``.npz`` archive (never a pickle) holding the arrays of the
layered MDP (:class:`~cellplan.strategies.model.mdp.LayeredMDP`), the cost-to-go ``values``
and a JSON metadata string ``meta``. :data:`META` is the schema of the metadata and
:data:`ARRAYS` the format of every array (dtype, shape in the sizes below, range of
values); :func:`read_strategy` checks a file against both with
:func:`cellplan.arrayfile.read_arrays`, then checks what ties the arrays together, so
that no array reaches a compiled kernel unless every index it holds is in range:

* sizes: ``d`` axes, ``N`` cells (product of ``grid.shape``), ``M`` modes (``2R + 1``
  for ``R`` requests, plus the X modes of failures; or NR and the Q modes of
  simultaneous requests), ``R`` request types, ``T`` heading slices, ``C = 2 ** d``
  stencil corners, ``P`` stages of the period, from the metadata; ``K`` move classes,
  ``A`` actions per class, ``B`` branches, ``O`` FMP options and ``G`` FMP outcomes, from
  the arrays (``K <= M``, ``A <= 62``, ``M <= B <= M * M``, ``M - 1 <= O <= M * M``,
  ``M - P <= G <= M * M``);
* the grid arrays equal the metadata's grid; the spacing is ``(upper - lower) / shape``;
* the stencil tables (``offs``, ``fr``, ``coff``, ``cw``, ``interior``) equal the tables
  recomputed from ``disp`` and the grid, so every flat offset a kernel adds stays inside
  the grid;
* each mode's branches are a probability distribution; the FMP options (``opt_ptr``)
  start at 0, never decrease and end at ``O``, one per mode (the identity) unless the
  model is that of simultaneous requests; each option's outcomes are a probability
  distribution over successors the model can produce (Section V and VI-3: the FMP
  successors follow the mode order NR, W, C, X; Section VI-2: a pick of a waiting
  request or the delivery of the carried one); the live states are free, the cost-to-go
  is finite on the live states and NaN elsewhere;
* time-varying models (Section VI-1, :mod:`.periodic`): ``meta.period`` ``P`` divides the
  ``M`` modes into ``P`` phases of ``M / P`` (the layer of mode ``m`` at phase ``t`` is
  ``t * M / P + m``); every phase repeats the modes of phase 0, ``meta.phases`` gives each
  layer's phase (``-1`` in a stationary model, whose period is 1), each branch leads to the
  next phase, each FMP to its mode's successor at a phase shift that is the same at every
  phase, and ``meta.belts`` names sources or destinations of the modes, with finite
  velocities;
* with a scenario: its digest and its request list (the modes; with simultaneous
  requests, also ``max_pending``; with a period, also the period and the belts).

Every problem is one :class:`~cellplan.errors.PersistenceError` line naming the file and
the array or metadata field (the CLI exits 2).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, MutableMapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cellplan.arrayfile import ArraySpec, read_arrays
from cellplan.errors import PersistenceError, Problem, ScenarioError
from cellplan.schema import CELLS_RANGE
from cellplan.setup import as_setup
from cellplan.strategies.model.mdp import build_model, estimate_memory
from cellplan.strategies.model.section import MAX_NOISE_OUTCOMES, MAX_PENDING, MAX_PERIOD
from cellplan.strategies.model.stencils import MAX_DIM
from cellplan.strategies.model.transitions import forbid_snapping
from cellplan.validity import ValiditySpace

if TYPE_CHECKING:
    from cellplan.strategies.model.mdp import Mode

FORMAT = "cellplan-strategy"
VERSION = 4
"""Version 2 (failure modes, Section VI-3) added the FMP outcome arrays and the X modes;
version 3 (simultaneous requests, Section VI-2) the FMP options ``opt_ptr`` (``tf`` and the
outcomes by option) and the Q modes; version 4 (time-varying models, Section VI-1) adds
``meta.period``, ``meta.phases`` and ``meta.belts``."""
#: Actions per move class: the valid-move bitmask is one int64 per cell.
MAX_ACTIONS = 62
#: Most grid cells of a strategy (a product of axes: checked before any size is used).
MAX_CELLS = 2**40
#: The metadata string's length limit (characters).
MAX_META_CHARS = 1_000_000
#: The largest magnitude of any loss, time or value in a strategy file: the square root
#: of the largest float64, so that a product of two (the solver's ``D g``) or a sum over
#: any grid (at most 2^40 cells) stays finite (docs/reliability.md, issue 36).
MAX_MAGNITUDE = 1e150
#: The arrays :func:`check_geometry` compares with the model of the scenario: the moves,
#: the free space of each move class, the collision-free moves and the live states.
GEOMETRY_ARRAYS = ("disp", "nact", "vcls", "free", "valid", "live")

Finite = Annotated[float, Field(allow_inf_nan=False)]
Name = Annotated[str, Field(max_length=200)]


class _Strict(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


class GridMeta(_Strict):
    """The grid: cells per axis, the box, the periodic axes."""

    shape: list[Annotated[int, Field(ge=CELLS_RANGE[0], le=CELLS_RANGE[1])]] = Field(
        min_length=1, max_length=MAX_DIM
    )
    lower: list[Finite]
    upper: list[Finite]
    periodic: list[bool]


class StrategyMeta(_Strict):
    """The metadata string ``meta`` of a strategy file (JSON)."""

    format: Literal["cellplan-strategy"]
    version: Literal[4]
    scenario_digest: Annotated[str, Field(max_length=128)]
    scenario_name: Name
    gain: Finite
    gain_lower: float
    gain_upper: float
    span: float
    sweeps: Annotated[int, Field(ge=0)]
    full_sweeps: Annotated[int, Field(ge=0)]
    outer_iterations: Annotated[int, Field(ge=0)]
    status: Name
    stable: bool
    policy_changes: Annotated[int, Field(ge=0)]
    method: Name
    seconds: Annotated[float, Field(ge=0)]
    regions: Literal["contact", "enclosure"] | None = None
    transitions: Literal["snap", "no-snap"] | None = None
    home: list[Finite] | None = None
    start: list[Finite] | None = None
    axes: list[Name] | None = None
    heading_axis: Annotated[int, Field(ge=-1, lt=MAX_DIM)]
    stage_time: Annotated[float, Field(gt=0, allow_inf_nan=False)]
    arrival: Annotated[float, Field(ge=0, le=1)]
    # kind, part, source, destination; an X mode adds its reject region and what follows,
    # a Q mode its waiting requests ("part,source,destination", at most MAX_PENDING).
    modes: list[Annotated[list[Name], Field(min_length=4, max_length=4 + MAX_PENDING)]] = Field(
        min_length=3, max_length=100_001
    )
    labels: list[list[Name]]
    grid: GridMeta
    # Time-varying models (Section VI-1): the stages of the period, each mode's phase (-1
    # in a stationary model), and the velocity [vx, vy] of each region on a belt.
    period: Annotated[int, Field(ge=1, le=MAX_PERIOD)]
    phases: list[Annotated[int, Field(ge=-1, lt=MAX_PERIOD)]] = Field(max_length=100_001)
    belts: dict[Name, Annotated[list[Finite], Field(min_length=2, max_length=2)]] = Field(
        max_length=1000
    )


#: The arrays of a strategy file, in reading order (an array that first meets a size read
#: from the file comes before the arrays whose ranges use it).
ARRAYS: dict[str, ArraySpec] = {
    "meta": ArraySpec("str", max_chars=MAX_META_CHARS, doc="JSON metadata (StrategyMeta)"),
    "shape": ArraySpec("int64", ("d",), str(CELLS_RANGE[0]), str(CELLS_RANGE[1])),
    "lower": ArraySpec("float64", ("d",), doc="grid box, lower corner"),
    "upper": ArraySpec("float64", ("d",), doc="grid box, upper corner"),
    "spacing": ArraySpec("float64", ("d",), doc="cell size per axis"),
    "periodic": ArraySpec("bool", ("d",), doc="axes that wrap round"),
    "free": ArraySpec("bool", ("K", "N"), doc="free bitmap of each move class"),
    "disp": ArraySpec("float64", ("K", "A", "d"), doc="displacement of each action"),
    "branch_layer": ArraySpec("int64", ("B",), "0", "M - 1", doc="next mode of each branch"),
    "cost": ArraySpec("float64", ("M",), "0", doc="loss per stage, eq. (7)"),
    "vcls": ArraySpec("int64", ("M",), "0", "K - 1", doc="move class of each mode"),
    "fmp_next": ArraySpec("int64", ("M",), "-1", "M - 1", doc="mode after FMP (-1: none)"),
    "tf": ArraySpec("float64", ("O", "N"), "0", inf=True, doc="FMP time per option (inf: none)"),
    "opt_ptr": ArraySpec("int64", ("M + 1",), "0", "O", doc="FMP options of each mode"),
    "branch_ptr": ArraySpec("int64", ("M + 1",), "0", "B", doc="branches of each mode"),
    "branch_prob": ArraySpec("float64", ("B",), "0", "1", doc="probability of each branch"),
    "nact": ArraySpec("int64", ("K",), "1", "A", doc="actions of each move class"),
    "valid": ArraySpec("int64", ("K", "N"), "0", doc="bitmask of collision-free actions"),
    "offs": ArraySpec("int64", ("K", "A", "T", "d"), doc="whole cells of each move"),
    "fr": ArraySpec("float64", ("K", "A", "T", "d"), "0", "1", doc="fractional cells"),
    "coff": ArraySpec("int64", ("K", "A", "T", "2 ** d"), doc="flat stencil offsets"),
    "cw": ArraySpec("float64", ("K", "A", "T", "2 ** d"), "0", "1", doc="stencil weights"),
    "interior": ArraySpec("bool", ("K", "N"), doc="cells whose stencils stay inside"),
    "live": ArraySpec("bool", ("M", "N"), doc="states of the MDP"),
    "request_prob": ArraySpec("float64", ("R",), "0", "1", doc="probability of each request"),
    "out_layer": ArraySpec("int64", ("G",), "0", "M - 1", doc="mode after each FMP outcome"),
    "out_ptr": ArraySpec("int64", ("O + 1",), "0", "G", doc="outcomes of each FMP option"),
    "out_prob": ArraySpec("float64", ("G",), "0", "1", doc="probability of each FMP outcome"),
    "out_cost": ArraySpec("float64", ("G",), "0", doc="extra loss of each outcome (rework)"),
    "noise_prob": ArraySpec("float64", ("J",), "0", "1", doc="noisy landings of a move"),
    "values": ArraySpec("float64", ("M", "N"), nan=True, doc="cost-to-go (NaN off live)"),
}

#: Sizes read from the file, with their limits (M, the mode count, is known by then).
SIZE_LIMITS: dict[str, tuple[int | str, int | str]] = {
    "K": (1, "M"),
    "A": (1, MAX_ACTIONS * (1 + MAX_NOISE_OUTCOMES)),  # moves, then their noisy landings
    "B": ("M", "M * M"),
    "O": ("M - 1", "M * M"),
    "G": ("M - P", "M * M"),  # NR has no FMP at any of the P phases
    "J": (1, MAX_NOISE_OUTCOMES),
}


def read_strategy(
    path: str | Path, scenario: Any = None, cell: ValiditySpace | None = None
) -> tuple[dict[str, Any], dict]:
    """Read and check a strategy file; returns ``(meta, arrays)``.

    With ``scenario``, the metadata is checked against it before any other array is
    inflated (its digest, modes and C-space box), and the arrays against the model
    cellplan builds itself for it on the file's grid (:func:`check_geometry`; ``cell`` is
    the scenario's workcell, built from it when not given).

    Raises
    ------
    PersistenceError
        One line naming the file and the array or metadata field at fault.
    """
    where = str(path)
    sizes: dict[str, int] = {}
    limits: dict[str, tuple[int, int]] = {}
    found: dict[str, Any] = {}

    def fail(message: str) -> PersistenceError:
        return PersistenceError([Problem(where, message)])

    def from_meta(arrays: dict[str, np.ndarray], known: MutableMapping[str, int]) -> None:
        meta = _parse_meta(str(arrays["meta"]), fail)
        grid = meta.grid
        d = len(grid.shape)
        if not (len(grid.lower) == len(grid.upper) == len(grid.periodic) == d):
            raise fail("meta.grid: shape, lower, upper and periodic differ in length")
        if not all(lo < hi for lo, hi in zip(grid.lower, grid.upper, strict=True)):
            raise fail("meta.grid: lower must be below upper on every axis")
        M = len(meta.modes)
        first = meta.modes[: _phase_layout(meta, fail)]  # the modes of phase 0
        kinds = [m[0] for m in first]
        if kinds[0] == "NR" and len(first) > 1 and set(kinds[1:]) == {"Q"}:
            if meta.period > 1:
                raise fail("meta.period: a model of simultaneous requests has period 1")
            found["pending"] = _pending_keys(meta.modes, fail)
            R = len({w for key in found["pending"] for w in key[0]})
        else:
            R = kinds.count("W")
            X = len(first) - 1 - 2 * R
            if X < 0 or kinds != ["NR"] + ["W"] * R + ["C"] * R + ["X"] * X:
                raise fail(
                    "meta.modes: expected NR, then the W modes, then the C modes, then the X "
                    "modes (or NR, then the Q modes of simultaneous requests)"
                )
            if any(len(m) != (6 if m[0] == "X" else 4) for m in first):
                raise fail("meta.modes: X modes have 6 fields, the others 4")
            if any(m[5] not in ("fetch", "request") for m in first[1 + 2 * R :]):
                raise fail("meta.modes: an X mode must end in 'fetch' or 'request'")
        _check_belts(meta, first, fail)
        h = meta.heading_axis
        if h >= d or (h >= 0 and (d < 3 or h < 2)):
            raise fail(f"meta.heading_axis: {h} is not an angle axis of a {d}-axis grid")
        for name in ("home", "start", "axes"):
            value = getattr(meta, name)
            if value is not None and len(value) != d:
                raise fail(f"meta.{name}: expected {d} values, got {len(value)}")
        n_cells = math.prod(grid.shape)  # Python integers: no int64 wrap-around
        if n_cells > MAX_CELLS:
            raise fail(f"meta.grid.shape: {n_cells:.3g} cells (at most {MAX_CELLS:.3g})")
        known.update(
            d=d,
            N=n_cells,
            M=M,
            R=R,
            P=meta.period,
            T=grid.shape[h] if h >= 0 else 1,
        )
        for key, (lo, hi) in SIZE_LIMITS.items():
            limits[key] = (_size(lo, known), _size(hi, known))
        found["meta"] = meta
        if scenario is not None:  # before the arrays it sizes are inflated
            _check_scenario(meta, scenario, fail, found.get("pending"))
            # The scenario's own workcell, 2-D or 3-D (the checks below read it through
            # the validity interface).
            found["cell"] = cell if cell is not None else as_setup(scenario).workcell
            _check_box(meta, found["cell"], fail)

    def working(known: Mapping[str, int]) -> int:
        need = check_memory(known)
        if scenario is not None:
            est = estimate_memory(scenario, found["cell"], found["meta"].grid.shape)
            need += est.terms["model"] + est.terms["building"] + est.terms["tables"]
        return need

    arrays = read_arrays(
        path,
        ARRAYS,
        sizes,
        limits,
        first=("meta",),
        after_first=from_meta,
        what="a strategy file",
        working=working,
    )
    meta: StrategyMeta = found["meta"]
    pending: list[PendingKey] | None = found.get("pending")
    _check_consistency(meta, arrays, sizes, fail, pending)
    _check_magnitudes(meta, arrays, fail)
    if scenario is not None:
        check_geometry(meta, arrays, scenario, found["cell"], fail)
    del arrays["meta"]
    return meta.model_dump(), arrays


def check_memory(sizes: Mapping[str, int]) -> int:
    """Bytes the checks of :func:`read_strategy` allocate beside the arrays: the class
    bitmap of every mode, its negation and the mask (bool ``(M, N)`` each), the values at
    the live states and their NaN test (float64 and bool ``(M, N)``), the valid masks
    shifted and compared (int64 and bool ``(K, N)``)."""
    M, N, K = sizes["M"], sizes["N"], sizes["K"]
    return (3 + 8 + 1) * M * N + (8 + 1) * K * N


def _size(value: int | str, sizes: MutableMapping[str, int]) -> int:
    from cellplan.arrayfile import evaluate

    return value if isinstance(value, int) else evaluate(value, sizes)


def _parse_meta(text: str, fail: Any) -> StrategyMeta:
    try:
        raw = json.loads(text)
    except (json.JSONDecodeError, RecursionError):
        raise fail("meta: not valid JSON") from None
    if not isinstance(raw, dict):
        raise fail("meta: expected a JSON object")
    old = raw.get("version")
    if raw.get("format") == FORMAT and type(old) is int and 1 <= old < VERSION:
        raise fail(
            f"a strategy file of version {old} (an older cellplan); solve the scenario again "
            f"to write version {VERSION}"
        )
    if raw.get("format") != FORMAT or raw.get("version") != VERSION:
        raise fail(
            f"not a cellplan strategy file (format {str(raw.get('format'))[:40]!r} "
            f"version {str(raw.get('version'))[:20]!r}; expected {FORMAT!r} version {VERSION})"
        )
    try:
        return StrategyMeta.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"])
        return_msg = " ".join(str(err["msg"]).split())[:160]
        raise fail(f"meta.{loc}: {return_msg}") from None


def _phase_layout(meta: StrategyMeta, fail: Any) -> int:
    """The modes per phase of a (possibly time-varying, Section VI-1) model, checked: the
    period divides the modes, every phase repeats the modes of phase 0, and each layer's
    phase is that of the layout ``t * (M / period) + m`` (-1 throughout with period 1)."""
    T, M = meta.period, len(meta.modes)
    if len(meta.phases) != M:
        raise fail(f"meta.phases: {len(meta.phases)} values; expected {M}, one per mode")
    if M % T:
        raise fail(
            f"meta.period: {T} stages do not divide the {M} modes (the modes are the period's "
            "phases times the modes of one phase)"
        )
    per_phase = M // T
    expected = np.arange(M) // per_phase if T > 1 else np.full(M, -1)
    wrong = np.flatnonzero(np.asarray(meta.phases) != expected)
    if len(wrong):
        i = int(wrong[0])
        raise fail(
            f"meta.phases.{i}: {meta.phases[i]}; expected {int(expected[i])} (the layer of "
            f"mode m at phase t is t * {per_phase} + m{'' if T > 1 else '; -1: no period'})"
        )
    for i in range(per_phase, M):
        if meta.modes[i] != meta.modes[i % per_phase]:
            raise fail(
                f"meta.modes.{i}: differs from mode {i % per_phase}, its copy at phase 0 "
                "(every phase has the modes of phase 0)"
            )
    return per_phase


def _check_belts(meta: StrategyMeta, modes: list[list[str]], fail: Any) -> None:
    """The belts of a time-varying model move sources or destinations of its modes."""
    if meta.belts and meta.period == 1:
        raise fail("meta.belts: a stationary model (period 1) has no belts")
    regions = {m[2] for m in modes} | {m[3] for m in modes}
    travel = (meta.period - 1) * meta.stage_time
    for name, velocity in meta.belts.items():
        if not name or name not in regions:
            raise fail(f"meta.belts.{name[:60]}: not a source or destination of the modes")
        if not all(math.isfinite(v * travel) for v in velocity):
            raise fail(
                f"meta.belts.{name}: a velocity of {max(map(abs, velocity)):g} carries the "
                "region beyond any finite position within the period"
            )


#: A mode of simultaneous requests (Section VI-2): the waiting requests and the carried
#: one (``"part,source,destination"``, ``""`` when empty); the waiting requests are a
#: multiset, sorted (two requests of one type may wait). NR is ``((), "")``.
PendingKey = tuple[tuple[str, ...], str]


def _pending_keys(modes: list[list[str]], fail: Any) -> list[PendingKey]:
    """The modes of a model of simultaneous requests (NR, then Q modes), checked.

    They must be every mode ``(Q, r)`` of ``R`` request types (those the modes name) and at
    most ``k`` open requests (the most any mode holds), once each: a set of distinct valid
    modes is all of them exactly when there are :func:`~.section.mode_counts` of them. The
    order is free (the arrays name modes by index); the scenario check compares it.
    """
    from cellplan.strategies.model.section import mode_counts

    if len(modes[0]) != 4 or any(modes[0][1:]):
        raise fail("meta.modes: NR has 4 fields, the last three empty")
    keys: list[PendingKey] = [((), "")]
    for i, m in enumerate(modes[1:], start=1):
        carried = m[1:4]
        if any(carried) and not all(carried):
            raise fail(
                f"meta.modes.{i}: a Q mode names the part, source and destination it "
                "carries, or none of them"
            )
        waiting = m[4:]
        bad = [w for w in waiting if len(w.split(",")) != 3 or not all(w.split(","))]
        if bad:
            raise fail(
                f"meta.modes.{i}: waiting request {bad[0][:60]!r} is not 'part,source,destination'"
            )
        key = (tuple(sorted(waiting)), ",".join(carried) if all(carried) else "")
        if not key[0] and not key[1]:
            raise fail(f"meta.modes.{i}: a Q mode with no open request (only NR has none)")
        keys.append(key)
    if len(set(keys)) != len(keys):
        raise fail("meta.modes: a Q mode appears twice")
    names = {w for key in keys for w in key[0]}
    if any(key[1] not in names for key in keys[1:] if key[1]):
        raise fail("meta.modes: a carried request that never waits")
    k = max(len(key[0]) + bool(key[1]) for key in keys)
    expected = sum(mode_counts(len(names), k))
    if len(keys) != expected:
        raise fail(
            f"meta.modes: {len(keys)} modes; up to {k} open requests of {len(names)} types "
            f"make {expected}"
        )
    return keys


def _check_consistency(
    meta: StrategyMeta,
    a: dict,
    sizes: dict[str, int],
    fail: Any,
    pending: list[PendingKey] | None = None,
) -> None:
    from cellplan.strategies.model.mdp import corner_tables, stencil_tables, table_rows

    grid = meta.grid
    M, K, B, N = sizes["M"], sizes["K"], sizes["B"], sizes["N"]
    if a["shape"].tolist() != grid.shape:
        raise fail("shape: differs from meta.grid.shape")
    for name in ("lower", "upper"):
        if not np.array_equal(a[name], np.asarray(getattr(grid, name), float)):
            raise fail(f"{name}: differs from meta.grid.{name}")
    if a["periodic"].tolist() != grid.periodic:
        raise fail("periodic: differs from meta.grid.periodic")
    span = a["upper"] - a["lower"]
    if not np.allclose(a["spacing"], span / a["shape"], rtol=1e-12, atol=0):
        raise fail("spacing: is not (upper - lower) / shape")
    if not (np.abs(a["disp"]) <= span).all():
        raise fail("disp: a move longer than the grid box")
    ptr = a["branch_ptr"]
    if ptr[0] != 0 or ptr[-1] != B or (np.diff(ptr) < 1).any():
        raise fail("branch_ptr: expected 0, increasing, ending at the number of branches")
    sums = np.add.reduceat(a["branch_prob"], ptr[:-1])
    if not np.allclose(sums, 1.0, atol=1e-9):
        raise fail("branch_prob: the branches of a mode do not sum to 1")
    T = meta.period
    per_phase = M // T
    if T > 1:
        phase = np.repeat(np.arange(M) // per_phase, np.diff(ptr))
        if (a["branch_layer"] // per_phase != (phase + 1) % T).any():
            raise fail(
                "branch_layer: a branch that does not lead to the next phase (every stage "
                "of a time-varying model advances the phase by one)"
            )
    R, n_options = sizes["R"], sizes["O"]
    opt = a["opt_ptr"]
    if opt[0] != 0 or opt[-1] != n_options or (np.diff(opt) < 0).any():
        raise fail("opt_ptr: expected 0, non-decreasing, ending at the number of FMP options")
    if pending is not None:
        _check_options(meta, a, pending, fail)
    else:
        if not np.array_equal(opt, np.arange(M + 1)):
            raise fail(
                "opt_ptr: expected one FMP option per mode (0, 1, ..., M) in a model "
                "without simultaneous requests"
            )
        # Each phase's NR, W and C modes (the X modes' FMP: _check_outcomes).
        nxt = a["fmp_next"].reshape(T, per_phase)[:, : 1 + 2 * R]
        expected_next = np.concatenate([[-1], np.arange(R) + 1 + R, np.zeros(R, np.int64)])
        if not (
            (nxt[:, 0] == -1).all()
            and (nxt[:, 1:] >= 0).all()
            and (nxt[:, 1:] % per_phase == expected_next[1:]).all()
        ):
            raise fail("fmp_next: the FMP successors do not follow the mode order")
        shift = (nxt[:, 1:] // per_phase - np.arange(T)[:, None]) % T
        if (shift != shift[0]).any():
            raise fail(
                "fmp_next: the FMP of a mode advances the phase by different stages at "
                "different phases"
            )
        _check_outcomes(a, R, M, per_phase, fail)
    if len(meta.labels) != K:
        raise fail(f"meta.labels: expected {K} lists (one per move class), got {len(meta.labels)}")
    nact = a["nact"]
    if (nact > MAX_ACTIONS).any():
        raise fail(f"nact: more than {MAX_ACTIONS} actions in a move class")
    if ((a["valid"] >> nact[:, None]) != 0).any():
        raise fail("valid: marks an action beyond the class's action count")
    noise = a["noise_prob"]
    if not np.isclose(noise.sum(), 1.0, atol=1e-9):
        raise fail("noise_prob: the landings of a move do not sum to 1")
    rows = table_rows(nact, len(noise))
    if (rows > a["disp"].shape[1]).any():
        raise fail("nact: more moves (with their noisy landings) than rows of disp")
    heading = meta.heading_axis
    offs, fr = stencil_tables(a["disp"], heading, a["shape"], a["lower"], a["spacing"])
    coff, cw, interior = corner_tables(offs, fr, rows, a["shape"])
    for name, mine, exact in (
        ("offs", offs, True),
        ("fr", fr, False),
        ("coff", coff, True),
        ("cw", cw, False),
        ("interior", interior, True),
    ):
        same = (
            np.array_equal(a[name], mine)
            if exact
            else np.allclose(a[name], mine, rtol=0, atol=1e-9)
        )
        if not same:
            raise fail(f"{name}: differs from the table computed from disp and the grid")
    live = a["live"]
    if (live & ~a["free"][a["vcls"]]).any():
        raise fail("live: a live state in a blocked cell")
    values = a["values"]
    if not np.isfinite(values[live]).all():
        raise fail("values: not finite at a live state")
    if not np.isnan(values[~live]).all():
        raise fail("values: expected NaN off the live states")
    if not live[::per_phase].any():  # NR at every phase
        raise fail("live: no live state in NR")
    del M, N


def _check_magnitudes(meta: StrategyMeta, a: dict, fail: Any) -> None:
    """Losses, times, values and the gain within what a solve can produce.

    ``L``, the most one stage can lose by (7), is the largest ``cost`` or the largest
    finite FMP time plus the largest rework (``out_cost``); the gain, an average of
    stage losses, lies in ``[0, L]``; a value (the expected loss to come, relative to a
    reference state) is at most ``S L / p`` in magnitude, for ``S`` live states, each
    entered an expected ``1 / p`` times at most, ``p`` the rarest event's probability
    (the smallest positive branch, FMP outcome or landing probability); every number is
    at most :data:`MAX_MAGNITUDE`.
    """
    tf = a["tf"]
    finite_tf = tf[np.isfinite(tf)]
    for name, arr in (("cost", a["cost"]), ("tf", finite_tf), ("out_cost", a["out_cost"])):
        if arr.size and float(arr.max()) > MAX_MAGNITUDE:
            raise fail(f"{name}: value {float(arr.max()):.3g} above {MAX_MAGNITUDE:.0e}")
    rework = float(a["out_cost"].max()) if a["out_cost"].size else 0.0
    fmp = float(finite_tf.max()) if finite_tf.size else 0.0
    loss = max(float(a["cost"].max()), fmp + rework)
    if not 0.0 <= meta.gain <= loss * (1 + 1e-9):
        raise fail(
            f"meta.gain: {meta.gain:.6g} outside [0, {loss:.6g}], the most one stage can lose"
        )
    probs = np.concatenate([a["branch_prob"], a["out_prob"], a["noise_prob"]])
    rarest = float(probs[probs > 0].min())
    states = int(a["live"].sum())
    bound = min(states * loss / rarest, MAX_MAGNITUDE)
    values = a["values"][a["live"]]
    worst = float(np.abs(values).max()) if values.size else 0.0
    if worst > bound:
        raise fail(
            f"values: magnitude {worst:.3g} above {bound:.3g} ({states} live states x the "
            f"most one stage can lose, {loss:.3g}, / the rarest event's probability, "
            f"{rarest:.3g})"
        )


def _check_box(meta: StrategyMeta, cell: ValiditySpace, fail: Any) -> None:
    """The grid's box is the robot's C-space box (:meth:`cellplan.cspace.Grid.for_robot`)."""
    robot = cell.robot
    grid = meta.grid
    if len(grid.shape) != robot.dim:
        raise fail(
            f"meta.grid.shape: {len(grid.shape)} axes, the scenario's robot has {robot.dim}; "
            "solve this scenario again"
        )
    box = (list(map(float, robot.lower)), list(map(float, robot.upper)), list(robot.periodic))
    if (grid.lower, grid.upper, grid.periodic) != box:
        raise fail(
            "meta.grid: the box (lower, upper, periodic) differs from the scenario robot's "
            "C-space box; solve this scenario again"
        )


def check_geometry(
    meta: StrategyMeta, a: Mapping[str, np.ndarray], scenario: Any, cell: ValiditySpace, fail: Any
) -> None:
    """The moves, free space, collision-free moves and live states of the file are those
    cellplan computes itself for ``scenario`` on the file's grid.

    A digest is not a proof: a strategy solved for another workcell (an obstacle left
    out) and given this scenario's digest, or one with blocked cells marked free, would
    otherwise drive the robot through an obstacle. This builds the model as ``solve``
    does (:func:`~cellplan.strategies.model.mdp.build_model` on ``meta.grid.shape``, without
    snapping moves when the file says ``no-snap``), about what ``cellplan validate``
    spends, and compares :data:`GEOMETRY_ARRAYS` and where FMP is allowed (``tf``).
    """
    shape = list(meta.grid.shape)
    try:
        mdp = build_model(scenario, cell, shape)
        if meta.transitions == "no-snap":
            mdp = forbid_snapping(mdp)
    except ScenarioError as exc:
        problem = exc.problems[0]
        raise fail(
            f"the scenario cannot be solved on this file's grid {shape} ({problem.field}: "
            f"{problem.message}); solve this scenario again"
        ) from None
    mine: dict[str, np.ndarray] = {name: np.asarray(getattr(mdp, name)) for name in GEOMETRY_ARRAYS}
    mine["tf"] = np.isfinite(mdp.tf)
    theirs = dict(a) | {"tf": np.isfinite(a["tf"])}
    for name in (*GEOMETRY_ARRAYS, "tf"):
        ours, file = mine[name], np.asarray(theirs[name])
        if ours.shape != file.shape:
            raise fail(
                f"{name}: shape {file.shape}, the scenario's model on this grid has "
                f"{ours.shape}; this file does not match the scenario's geometry (solve it "
                "again)"
            )
        differ = ours != file
        if not differ.any():
            continue
        where = ""
        if name in ("free", "valid", "live", "tf") and file.ndim == 2:
            row, flat = (int(i) for i in np.argwhere(differ)[0])
            idx = tuple(int(i) for i in np.unravel_index(flat, tuple(shape)))
            centre = mdp.lower + (np.asarray(idx) + 0.5) * mdp.spacing
            what = (
                "move class"
                if name in ("free", "valid")
                else "mode"
                if name == "live"
                else "option"
            )
            label = mdp.modes[row].label if name == "live" else str(row)
            q = ", ".join(f"{v:.4g}" for v in centre)
            where = f" (first: {what} {label}, cell {idx}, q = ({q}))"
            if name == "free" and (file & ~ours).any():
                where = (
                    f"; it marks free {int((file & ~ours).sum())} cells the workcell blocks" + where
                )
        raise fail(
            f"{name}: {int(differ.sum())} entries differ from the model cellplan computes "
            f"for this scenario on its grid{where}; this file does not match the "
            "scenario's geometry (solve it again)"
        )


def _check_outcomes(a: dict, R: int, M: int, per_phase: int, fail: Any) -> None:
    """The FMP outcomes follow the model's rules (Section V, and VI-3 for failures), at
    every phase of a time-varying model (Section VI-1: ``per_phase`` modes a phase; the
    successor's mode is its layer modulo ``per_phase``, at any phase)."""
    ptr, layer, prob, cost = a["out_ptr"], a["out_layer"], a["out_prob"], a["out_cost"]
    G = len(layer)
    counts = np.diff(ptr)
    if ptr[0] != 0 or ptr[-1] != G or (counts < 0).any():
        raise fail("out_ptr: expected 0, non-decreasing, ending at the number of outcomes")
    nr = np.arange(M) % per_phase == 0
    if (counts[nr] != 0).any() or (counts[~nr] < 1).any():
        raise fail("out_ptr: NR has no FMP and every other mode has at least one outcome")
    if not np.isfinite(cost).all():
        raise fail("out_cost: not finite")
    starts = ptr[:-1][~nr]  # NR's outcomes are empty: these split the outcomes by mode
    sums = np.add.reduceat(prob, starts)
    if not np.allclose(sums, 1.0, atol=1e-9):
        raise fail("out_prob: the FMP outcomes of a mode do not sum to 1")
    if not np.array_equal(layer[starts], a["fmp_next"][~nr]):
        raise fail("out_layer: the first outcome of a mode's FMP is not its fmp_next")
    base = layer % per_phase
    for ell in np.flatnonzero(~nr):
        m = ell % per_phase
        if m <= 2 * R:  # retry in place, or reject (X)
            rest = base[ptr[ell] + 1 : ptr[ell + 1]]
            ok = ((rest == m) | (rest > 2 * R)).all()
        else:
            ok = ((base[ptr[ell] : ptr[ell + 1]] >= 1) & (base[ptr[ell] : ptr[ell + 1]] <= R)).all()
        if not ok:
            raise fail(f"out_layer: mode {ell} has an FMP outcome the model cannot produce")


def _check_options(meta: StrategyMeta, a: dict, keys: list[PendingKey], fail: Any) -> None:
    """The FMP options of simultaneous requests (Section VI-2, :mod:`.pending`).

    NR has none; each option's outcomes are a distribution (at least one); ``fmp_next`` is
    the first outcome of a mode's first option (-1 without options); an empty mode
    ``(Q, none)`` picks each waiting request type once (``(Q - r, r)``), a carrying mode
    ``(Q, r)`` has at most one option, the delivery (``(Q, none)``).
    """
    opt = a["opt_ptr"]
    ptr, layer, prob, cost = a["out_ptr"], a["out_layer"], a["out_prob"], a["out_cost"]
    n_opt = np.diff(opt)
    if n_opt[0] != 0:
        raise fail("opt_ptr: NR has no FMP option")
    if ptr[0] != 0 or ptr[-1] != len(layer) or (np.diff(ptr) < 1).any():
        raise fail(
            "out_ptr: expected 0, increasing (every FMP option has an outcome), ending at "
            "the number of outcomes"
        )
    if not np.isfinite(cost).all():
        raise fail("out_cost: not finite")
    if len(ptr) > 1 and not np.allclose(np.add.reduceat(prob, ptr[:-1]), 1.0, atol=1e-9):
        raise fail("out_prob: the outcomes of an FMP option do not sum to 1")
    has = n_opt > 0
    first = np.full(len(n_opt), -1, np.int64)
    first[has] = layer[ptr[opt[:-1][has]]]
    if not np.array_equal(a["fmp_next"], first):
        raise fail(
            "fmp_next: not the first outcome of the mode's first FMP option (-1 without one)"
        )
    index = {key: m for m, key in enumerate(keys)}
    for m in range(1, len(keys)):
        waiting, carried = keys[m]
        if carried:
            allowed = {index[(waiting, "")]}
        else:
            allowed = {index[(_without(waiting, w), w)] for w in set(waiting)}
        if n_opt[m] > len(allowed):
            label = mode_of(meta.modes[m]).label
            raise fail(f"opt_ptr: mode {label} has {n_opt[m]} FMP options (at most {len(allowed)})")
        outs = layer[ptr[opt[m]] : ptr[opt[m + 1]]].tolist()
        firsts = layer[ptr[opt[m] : opt[m + 1]]].tolist()
        if not set(outs) <= allowed or len(set(firsts)) != len(firsts):
            label = mode_of(meta.modes[m]).label
            raise fail(
                f"out_layer: mode {label} has an FMP outcome the model cannot produce (a "
                "pick of each waiting request once, or the delivery of the carried one)"
            )


def _without(waiting: tuple[str, ...], w: str) -> tuple[str, ...]:
    """The multiset ``waiting`` less one ``w``."""
    rest = list(waiting)
    rest.remove(w)
    return tuple(rest)


def _check_scenario(
    meta: StrategyMeta,
    scenario: Any,
    fail: Any,
    pending: list[PendingKey] | None = None,
) -> None:
    if meta.scenario_digest != scenario.digest():
        raise fail(
            f"this strategy was computed for a different scenario "
            f"({meta.scenario_name or 'unnamed'}, digest {meta.scenario_digest[:12]}); "
            "solve this scenario again"
        )
    section = getattr(scenario, "strategy", None)
    if section is None:  # pragma: no cover - the digest already differs
        return
    requests = section.request_list(scenario)
    if pending is not None or section.simultaneous():
        _check_pending_scenario(meta, requests, section.max_pending, fail)
        return
    T = section.period
    if meta.period != T:
        raise fail(
            f"meta.period: {meta.period} stages, the scenario's period is {T}; solve this "
            "scenario again"
        )
    belts = {name: [float(v) for v in b.velocity] for name, b in section.belts.items()}
    if meta.belts != belts:
        raise fail(
            f"meta.belts: {sorted(meta.belts)[:5]} differ from the scenario's belts "
            f"{sorted(belts)[:5]} or their velocities; solve this scenario again"
        )
    expected = [("NR", "", "", "")]
    expected += [("W", p, s, d) for p, s, d, _ in requests]
    expected += [("C", p, s, d) for p, s, d, _ in requests]
    first = meta.modes[: len(meta.modes) // T]
    if [tuple(m) for m in first if m[0] != "X"] != expected:
        raise fail(
            f"meta.modes: {len(first)} modes, the scenario's requests give "
            f"{len(expected)}; solve this scenario again"
        )


def _check_pending_scenario(
    meta: StrategyMeta, requests: list[tuple[str, str, str, float]], k: int, fail: Any
) -> None:
    """The modes are those :func:`~.pending.assemble_pending` builds for the scenario."""
    from cellplan.strategies.model.mdp import Mode
    from cellplan.strategies.variants.pending import pending_modes

    names = [f"{p},{s},{d}" for p, s, d, _ in requests]
    expected = []
    for q, r in pending_modes(len(requests), k):
        carried = requests[r][:3] if r >= 0 else ("", "", "")
        waiting = tuple(names[i] for i in q)
        expected.append(Mode("Q", *carried, waiting=waiting).label if q or r >= 0 else "NR")
    got = [mode_of(m).label for m in meta.modes]
    if got != expected:
        raise fail(
            f"meta.modes: {len(got)} modes that differ from the {len(expected)} of the "
            f"scenario's {len(requests)} requests with max_pending {k}; solve this scenario "
            "again"
        )


def mode_of(fields: list[str]) -> Mode:
    """The mode of a ``meta.modes`` entry: kind, part, source, destination, then for an X
    mode its reject region and what follows, for a Q mode its waiting requests."""
    from cellplan.strategies.model.mdp import Mode

    kind, part, source, destination, *rest = fields
    if kind == "Q":
        return Mode(kind, part, source, destination, waiting=tuple(rest))
    if kind == "X":
        return Mode(kind, part, source, destination, reject=rest[0], after=rest[1])
    return Mode(kind, part, source, destination)

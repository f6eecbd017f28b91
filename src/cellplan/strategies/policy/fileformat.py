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
from typing import Any

import numpy as np
from pydantic import ValidationError

from cellplan.arrayfile import read_arrays
from cellplan.errors import PersistenceError, Problem
from cellplan.setup import as_setup
from cellplan.strategies.model.layered import mode_of
from cellplan.strategies.model.memory import estimate_memory
from cellplan.strategies.policy.filemeta import (
    ARRAYS,
    FORMAT,
    MAX_ACTIONS,
    MAX_CELLS,
    MAX_MAGNITUDE,
    SIZE_LIMITS,
    VERSION,
    StrategyMeta,
)
from cellplan.strategies.policy.filescenario import check_box, check_geometry, check_scenario
from cellplan.strategies.variants.pending_files import PendingKey, check_options, pending_keys
from cellplan.strategies.variants.periodic_files import (
    check_belts,
    check_phase_branches,
    phase_layout,
)
from cellplan.validity import ValiditySpace

#: Re-exported: the declaration (:mod:`.filemeta`) and a ``meta.modes`` entry's mode are
#: reached through this module.
__all__ = [
    "ARRAYS",
    "FORMAT",
    "MAX_MAGNITUDE",
    "VERSION",
    "StrategyMeta",
    "check_geometry",
    "mode_of",
    "read_strategy",
]


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
        R = _check_modes(meta, fail, found)
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
            check_scenario(meta, scenario, fail, found.get("pending"))
            # The scenario's own workcell, 2-D or 3-D (the checks below read it through
            # the validity interface).
            found["cell"] = cell if cell is not None else as_setup(scenario).workcell
            check_box(meta, found["cell"], fail)

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


def _check_modes(meta: StrategyMeta, fail: Any, found: dict[str, Any]) -> int:
    """The layout of ``meta.modes``, checked; returns ``R``, the request types. The modes
    of simultaneous requests (NR, then Q modes) go to ``found["pending"]``."""
    first = meta.modes[: phase_layout(meta, fail)]  # the modes of phase 0
    kinds = [m[0] for m in first]
    if kinds[0] == "NR" and len(first) > 1 and set(kinds[1:]) == {"Q"}:
        if meta.period != 1:
            raise fail("meta.period: a model of simultaneous requests has period 1")
        found["pending"] = pending_keys(meta.modes, fail)
        return len({w for key in found["pending"] for w in key[0]})
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
    check_belts(meta, first, fail)
    return R


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


def _check_consistency(
    meta: StrategyMeta,
    a: dict,
    sizes: dict[str, int],
    fail: Any,
    pending: list[PendingKey] | None = None,
) -> None:
    from cellplan.strategies.model.tables import corner_tables, stencil_tables, table_rows

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
    check_phase_branches(meta, a, fail)
    R, n_options = sizes["R"], sizes["O"]
    opt = a["opt_ptr"]
    if opt[0] != 0 or opt[-1] != n_options or (np.diff(opt) < 0).any():
        raise fail("opt_ptr: expected 0, non-decreasing, ending at the number of FMP options")
    if pending is not None:
        check_options(meta, a, pending, fail)
    else:
        _check_fmp_order(a, M, R, T, fail)
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


def _check_fmp_order(a: dict, M: int, R: int, T: int, fail: Any) -> None:
    """One FMP option per mode, and each phase's NR, W and C modes' successors in the
    mode order (the X modes' FMP: :func:`_check_outcomes`)."""
    per_phase = M // T
    if not np.array_equal(a["opt_ptr"], np.arange(M + 1)):
        raise fail(
            "opt_ptr: expected one FMP option per mode (0, 1, ..., M) in a model "
            "without simultaneous requests"
        )
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
            "fmp_next: the FMP of a mode advances the phase by different stages at different phases"
        )
    _check_outcomes(a, R, M, per_phase, fail)


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

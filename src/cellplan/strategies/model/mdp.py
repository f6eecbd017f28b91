"""The layered MDP of the strategies paper (Sections III-IV) on a C-space grid.

State space ``X = C x M`` (Section III-A): the modes are NR plus ``<p,s,d,W>`` and
``<p,s,d,C>`` for every requestable (part, source, destination), ``2R + 1`` in all, plus
with failure modes (Section VI-3) the ``<p,s,d,X:R>`` modes of a rejected part carried to
a reject region ``R`` (:func:`_failure_outcomes`).
Each mode is a *layer*: a copy of the grid restricted to that mode's free space,
equations (1)-(3) (:func:`cellplan.cspace.free_bitmap` with ``avoid_sources``):

* NR: the robot alone, every source an obstacle (3);
* ``<p,s,d,W>``: the robot alone, the sources other than ``s`` obstacles (1);
* ``<p,s,d,C>``: robot plus part ``p``, the sources other than ``s`` obstacles (2).

Transitions (Section III-B): from NR a request arrives with probability ``P`` per stage
and is ``(p,s,d)`` with probability ``pi_r`` (type 1); in ``<p,s,d,C>`` the destination
changes to another of the same part and source (type 2); in ``<p,s,d,W>`` the source
changes to another of the same part and destination (type 3). FMP moves
``<p,s,d,W> -> <p,s,d,C>`` inside source ``s`` and ``<p,s,d,C> -> NR`` inside destination
``d`` with probability one. The loss is equation (7).

A layer's *live* states are the free cells from which its request can be finished
(computed by :func:`cellplan.strategies.model.domain.live_layer`); the MDP is defined on live
states only, which keeps it unichain-friendly and lets the input checks name a request
that can never be served.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from cellplan import units
from cellplan.errors import Problem, ScenarioError
from cellplan.strategies.model.actions import ActionSet, action_set, with_noise
from cellplan.strategies.model.bundles import Grid, Layers, Model, Moves, Outcomes, single_outcomes
from cellplan.strategies.model.domain import live_layer
from cellplan.strategies.model.motion import valid_moves

NR = "NR"


@dataclass(frozen=True)
class Mode:
    """An assembly mode: ``NR``, or ``<part, source, destination, W|C>`` (Section II-C),
    or ``<part, source, destination, X:region>``: carrying a rejected part to the reject
    region (failure modes, Section VI-3), or with simultaneous requests (Section VI-2) the
    set of open requests and the one carried (kind ``Q``, label ``{P1,S1,D1; P2,S2,D1} +
    <P1,S1,D2>``)."""

    kind: str  # "NR", "W", "C", "X" or "Q"
    part: str = ""
    source: str = ""
    destination: str = ""
    reject: str = ""  # X: the reject region
    after: str = ""  # X: "fetch" or "request" (Section VI-3)
    # Q (simultaneous requests, Section VI-2): the open requests not yet picked up, as
    # "part,source,destination"; part, source and destination name the carried request.
    waiting: tuple[str, ...] = ()
    # The phase of the period in a time-varying model (Section VI-1); -1: stationary.
    phase: int = -1

    @property
    def label(self) -> str:
        if self.phase >= 0:
            return f"{replace(self, phase=-1).label}@{self.phase}"
        if self.kind == NR:
            return NR
        if self.kind == "Q":
            text = "{" + "; ".join(self.waiting) + "}"
            if self.part:
                text += f" + <{self.part},{self.source},{self.destination}>"
            return text
        kind = self.kind
        if kind == "X":
            kind = f"X:{self.reject}" + (":request" if self.after == "request" else "")
        return f"<{self.part},{self.source},{self.destination},{kind}>"


@dataclass(frozen=True)
class Failure:
    """The failure model of one FMP (Section VI-3): fails with ``probability``; a failure is
    retried in place after ``rework`` (``reject`` empty) or the part is carried to the
    reject region ``reject``, followed by a fetch or a new request (``after``)."""

    probability: float
    rework: float = 0.0
    reject: str = ""
    after: str = "fetch"


@dataclass(frozen=True)
class Failures:
    """Failures of every request's FMPs, and the geometry of the reject regions."""

    pick: Sequence[Failure | None]  # per request, FMP at its source
    drop: Sequence[Failure | None]  # per request, FMP at its destination
    reject_drop: Mapping[tuple[str, str], np.ndarray]  # (part, region): where it is dropped
    tf_reject: Mapping[str, np.ndarray]  # fine-motion time field of each reject region


@dataclass
class LayeredMDP:
    """Arrays of the discretised MDP; :meth:`kernel_args` bundles them for the kernels."""

    shape: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    spacing: np.ndarray
    periodic: np.ndarray
    modes: list[Mode]
    cost: np.ndarray  # (M,)
    vcls: np.ndarray  # (M,) move class per layer
    fmp_next: np.ndarray  # (M,) -1 for none
    tf: np.ndarray  # (M, N) inf where FMP is not allowed
    branch_ptr: np.ndarray
    branch_layer: np.ndarray
    branch_prob: np.ndarray
    free: np.ndarray  # (K, N) bitmap of each move class
    disp: np.ndarray  # (K, A, dim)
    nact: np.ndarray  # (K,)
    heading_axis: int
    valid: np.ndarray  # (K, N) int64 bitmask of collision-free moves
    offs: np.ndarray  # (K, A, T, dim) integer part of each move in cell units (per heading slice)
    fr: np.ndarray  # (K, A, T, dim) fractional part
    coff: np.ndarray  # (K, A, T, 2^dim) flat offsets of the stencil corners (interior cells)
    cw: np.ndarray  # (K, A, T, 2^dim) their multilinear weights
    interior: np.ndarray  # (K, N) cells whose every move stencil stays inside the grid
    live: np.ndarray  # (M, N)
    stage_time: float
    arrival: float
    request_prob: np.ndarray  # (R,)
    labels: list[tuple[str, ...]] = field(default_factory=list)
    # FMP outcomes when some FMP can fail (Section VI-3); None: the Section V outcomes.
    outcomes: Outcomes | None = None
    # (J,) probabilities of the noisy outcomes of every move (Section VI-4); [1]: exact.
    noise_prob: np.ndarray = field(default_factory=lambda: np.ones(1))
    # (M + 1,) FMP options of each mode (simultaneous requests, Section VI-2): ``tf`` and
    # the outcomes are then per option, ``(O, N)``; None: one option per mode, ``o = m``.
    opt_ptr: np.ndarray | None = None
    # Time-varying models (Section VI-1): the stages of the period (the layers are
    # ``phase * (n_modes // period) + mode``) and the velocity of each region on a belt.
    period: int = 1
    belts: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    @property
    def n_modes(self) -> int:
        return len(self.modes)

    @property
    def n_requests(self) -> int:
        return sum(1 for m in self.modes if m.kind == "W" and m.phase <= 0)

    @property
    def modes_per_phase(self) -> int:
        """The assembly modes of one phase (all of them in a stationary model)."""
        return self.n_modes // self.period

    def layer(self, mode: int, phase: int = 0) -> int:
        """The layer of ``mode`` (an index among the first :attr:`modes_per_phase`) at
        ``phase`` of the period (taken modulo the period; Section VI-1)."""
        return (phase % self.period) * self.modes_per_phase + mode

    def w_layer(self, r: int) -> int:
        return 1 + r

    def c_layer(self, r: int) -> int:
        return 1 + self.n_requests + r

    @property
    def options(self) -> np.ndarray:
        """``(M + 1,)``: the FMP options of mode ``m`` are ``options[m]:options[m+1]``."""
        if self.opt_ptr is not None:
            return self.opt_ptr
        return np.arange(self.n_modes + 1, dtype=np.int64)

    def fmp_allowed(self, m: int) -> np.ndarray:
        """``(N,)`` bool: the cells where some FMP option of mode ``m`` is allowed."""
        ptr = self.options
        return np.asarray((self.tf[ptr[m] : ptr[m + 1]] < np.inf).any(axis=0))

    def grid(self) -> Grid:
        """The grid bundle of the kernels."""
        return Grid(self.shape, self.lower, self.upper, self.spacing, self.periodic)

    def kernel_args(self) -> Model:
        """The model arrays as the kernels take them: one named bundle (:mod:`.bundles`)."""
        moves = Moves(
            free=self.free,
            disp=self.disp,
            nact=self.nact,
            heading_axis=int(self.heading_axis),
            valid=self.valid,
            offs=self.offs,
            fr=self.fr,
            coff=self.coff,
            cw=self.cw,
            interior=self.interior,
            noise_prob=self.noise_prob,
        )
        out = self.fmp_outcomes()
        layers = Layers(
            live=self.live,
            vcls=self.vcls,
            cost=self.cost,
            fmp_next=self.fmp_next,
            opt_ptr=self.options,
            tf=self.tf,
            branch_ptr=self.branch_ptr,
            branch_layer=self.branch_layer,
            branch_prob=self.branch_prob,
            out_ptr=out.ptr,
            out_layer=out.layer,
            out_prob=out.prob,
            out_cost=out.cost,
            dense=np.zeros((0, 0), np.int64),
        )
        return Model(self.grid(), moves, layers)

    def fmp_outcomes(self) -> Outcomes:
        """The outcomes of every mode's FMP (the Section V ones unless failures are modelled)."""
        return self.outcomes if self.outcomes is not None else single_outcomes(self.fmp_next)

    def is_simple(self) -> bool:
        """Whether every FMP has the single certain outcome of Section V.

        and every move lands where it is commanded (no noise, Section VI-4). The structured
        solver relies on it (a carrying layer's FMP ends in NR, a waiting layer's in its
        carrying layer, a move's landing stencil is one table row); other models are solved
        by policy iteration. A model with FMP options (Section VI-2) is not simple either.
        """
        if len(self.noise_prob) > 1 or self.opt_ptr is not None or self.period > 1:
            return False
        if self.outcomes is None:
            return True
        out = self.outcomes
        return bool(
            np.array_equal(out.ptr, single_outcomes(self.fmp_next).ptr)
            and np.array_equal(out.layer, self.fmp_next[self.fmp_next >= 0])
            and (out.prob == 1.0).all()
            and (out.cost == 0.0).all()
        )

    def has_changes(self) -> bool:
        """Whether destination or source changes couple the W/C layers (Section III-B)."""
        for m in range(1, self.n_modes):
            for b in range(self.branch_ptr[m], self.branch_ptr[m + 1]):
                if self.branch_layer[b] != m and self.branch_prob[b] > 0:
                    return True
        return False


@dataclass(frozen=True)
class Geometry:
    """Bitmaps of one problem on a grid (flattened, C order)."""

    free_nr: np.ndarray
    free_w: Mapping[str, np.ndarray]  # by source
    free_c: Mapping[tuple[str, str], np.ndarray]  # by (part, source)
    pick: Mapping[tuple[str, str], np.ndarray]  # cells where FMP picks part p at source s
    drop: Mapping[tuple[str, str], np.ndarray]  # cells where FMP drops part p at destination d
    tf_pick: Mapping[tuple[str, str], np.ndarray]  # fine-motion time field (per cell)
    tf_drop: Mapping[tuple[str, str], np.ndarray]


def request_fields(
    geometry: Geometry, requests: Sequence[tuple[str, str, str, float]]
) -> np.ndarray:
    """``(2R + 1, N)``: the fine-motion time ``t_f`` of the FMP of NR (none), of each W
    mode (the pick) and of each C mode (the delivery), ``inf`` where it is not allowed.

    A pick needs a configuration in the source region that is free both while waiting
    and while carrying the part; a delivery one in the destination region free both
    while carrying and in NR (equations (1)-(3)).
    """
    R = len(requests)
    tf = np.full((1 + 2 * R, geometry.free_nr.size), np.inf)
    for r, (p, s, d, _) in enumerate(requests):
        pick = (
            geometry.pick[(p, s)].ravel()
            & geometry.free_w[s].ravel()
            & geometry.free_c[(p, s)].ravel()
        )
        tf[1 + r, pick] = geometry.tf_pick[(p, s)].ravel()[pick]
        drop = (
            geometry.drop[(p, d)].ravel()
            & geometry.free_c[(p, s)].ravel()
            & geometry.free_nr.ravel()
        )
        tf[1 + R + r, drop] = geometry.tf_drop[(p, d)].ravel()[drop]
    return tf


def assemble(
    *,
    shape: Sequence[int],
    lower: Sequence[float] | np.ndarray,
    upper: Sequence[float] | np.ndarray,
    periodic: Sequence[bool],
    requests: Sequence[tuple[str, str, str, float]],
    geometry: Geometry,
    actions_empty: ActionSet,
    actions_carrying: Mapping[str, ActionSet],
    stage_time: float,
    arrival: float,
    destination_change: float = 0.0,
    source_change: float = 0.0,
    failures: Failures | None = None,
) -> LayeredMDP:
    """Build the layered MDP from bitmaps (the part that does not need a workcell).

    Layer order: NR, then ``W`` of each request, then ``C`` of each request, then the
    ``X`` modes of failures that reject a part (one per request, reject region and what
    follows the rejection).
    """
    shape_a = np.asarray(shape, np.int64)
    lower_a = np.asarray(lower, float)
    upper_a = np.asarray(upper, float)
    spacing = (upper_a - lower_a) / shape_a
    periodic_a = np.asarray(periodic, np.bool_)
    ncell = int(np.prod(shape_a))
    R = len(requests)
    modes = [Mode(NR)]
    modes += [Mode("W", p, s, d) for p, s, d, _ in requests]
    modes += [Mode("C", p, s, d) for p, s, d, _ in requests]
    # X modes (Section VI-3): carrying a rejected part of request r to a reject region.
    x_index: dict[tuple[int, str, str], int] = {}
    if failures is not None:
        for r in range(R):
            for f in (failures.pick[r], failures.drop[r]):
                if f is not None and f.reject and (r, f.reject, f.after) not in x_index:
                    x_index[(r, f.reject, f.after)] = len(modes)
                    p, s, d, _ = requests[r]
                    modes.append(Mode("X", p, s, d, f.reject, f.after))
    M = len(modes)

    classes = MoveClasses()
    move_class = classes.add
    vcls = np.zeros(M, np.int64)
    cost = np.full(M, stage_time)
    cost[0] = 0.0  # equation (7): no loss while no request waits
    fmp_next = np.full(M, -1, np.int64)
    tf = np.full((M, ncell), np.inf)
    vcls[0] = move_class(geometry.free_nr.ravel(), actions_empty)
    for r, (p, s, _d, _) in enumerate(requests):
        w, c = 1 + r, 1 + R + r
        vcls[w] = move_class(geometry.free_w[s].ravel(), actions_empty)
        vcls[c] = move_class(geometry.free_c[(p, s)].ravel(), actions_carrying[p])
        fmp_next[w] = c
        fmp_next[c] = 0
    tf[: 1 + 2 * R] = request_fields(geometry, requests)

    for (r, reject, _after), x in x_index.items():
        assert failures is not None
        p, s, d, _ = requests[r]
        vcls[x] = move_class(geometry.free_c[(p, s)].ravel(), actions_carrying[p])
        into = geometry.free_c[(p, s)].ravel() & failures.reject_drop[(p, reject)].ravel()
        tf[x, into] = failures.tf_reject[reject].ravel()[into]
        fmp_next[x] = 1 + r

    # Branches (Section III-B).
    probs = np.array([q for *_, q in requests], float)
    ptr = [0]
    layers: list[int] = []
    bprob: list[float] = []
    layers.append(0)
    bprob.append(1.0 - arrival)
    for r in range(R):
        if arrival * probs[r] > 0.0:
            layers.append(1 + r)
            bprob.append(arrival * probs[r])
    ptr.append(len(layers))
    for kind, change in (("W", source_change), ("C", destination_change)):
        for r, (p, s, d, _) in enumerate(requests):
            m = (1 if kind == "W" else 1 + R) + r
            if kind == "W":
                others = [
                    i
                    for i, (p2, s2, d2, _) in enumerate(requests)
                    if p2 == p and d2 == d and s2 != s
                ]
            else:
                others = [
                    i
                    for i, (p2, s2, d2, _) in enumerate(requests)
                    if p2 == p and s2 == s and d2 != d
                ]
            if change <= 0.0:
                others = []
            stay = 1.0 - (change if others else 0.0)
            layers.append(m)
            bprob.append(stay)
            for i in others:
                layers.append((1 if kind == "W" else 1 + R) + i)
                bprob.append(change / len(others))
            ptr.append(len(layers))
    for x in x_index.values():
        layers.append(x)
        bprob.append(1.0)
        ptr.append(len(layers))
    outcomes = None
    if failures is not None:
        outcomes = _failure_outcomes(requests, probs, x_index, failures)
        for x in x_index.values():
            fmp_next[x] = outcomes.layer[outcomes.ptr[x]]
    return finish_model(
        grid=Grid(shape_a, lower_a, upper_a, spacing, periodic_a),
        modes=modes,
        classes=classes,
        vcls=vcls,
        cost=cost,
        fmp_next=fmp_next,
        tf=tf,
        branches=(ptr, layers, bprob),
        outcomes=outcomes,
        noise_prob=actions_empty.noise_prob,
        heading_axis=actions_empty.heading_axis,
        stage_time=stage_time,
        arrival=arrival,
        request_prob=probs,
    )


class MoveClasses:
    """Move classes ``k``: a free bitmap and an action set each, deduplicated by content."""

    def __init__(self) -> None:
        self.keys: dict[bytes, int] = {}
        self.free: list[np.ndarray] = []
        self.actions: list[ActionSet] = []

    def add(self, free: np.ndarray, acts: ActionSet) -> int:
        """The class of this bitmap and action set (a new one if it is not known yet)."""
        key = hashlib.sha1(free.tobytes() + acts.disp.tobytes()).digest()
        if key not in self.keys:
            self.keys[key] = len(self.free)
            self.free.append(free)
            self.actions.append(acts)
        return self.keys[key]


def finish_model(
    *,
    grid: Grid,
    modes: list[Mode],
    classes: MoveClasses,
    vcls: np.ndarray,
    cost: np.ndarray,
    fmp_next: np.ndarray,
    tf: np.ndarray,
    branches: tuple[Sequence[int], Sequence[int], Sequence[float]],
    outcomes: Outcomes | None,
    noise_prob: np.ndarray,
    heading_axis: int,
    stage_time: float,
    arrival: float,
    request_prob: np.ndarray,
    opt_ptr: np.ndarray | None = None,
) -> LayeredMDP:
    """The move tables (valid moves, stencils) and the live states of a layered MDP whose
    modes, classes, FMP options and branches (``(ptr, layer, prob)``) are given."""
    shape_a, lower_a, upper_a, spacing, periodic_a = grid
    ncell = int(np.prod(shape_a))
    M = len(modes)
    ptr, layers, bprob = branches
    cls_free, cls_actions = classes.free, classes.actions
    K = len(cls_free)
    A = max(a.disp.shape[0] for a in cls_actions)
    dim = len(shape_a)
    disp = np.zeros((K, A, dim))
    nact = np.zeros(K, np.int64)
    for k, acts in enumerate(cls_actions):
        disp[k, : acts.disp.shape[0]] = acts.disp
        nact[k] = acts.commanded
    J = len(noise_prob)
    free = np.stack(cls_free).astype(np.bool_)
    valid = np.zeros((K, ncell), np.int64)
    for k in range(K):
        na = int(nact[k])
        if J == 1:
            valid[k] = valid_moves(free[k], disp[k, :na], heading_axis, grid)
            continue
        # A noisy move is allowed where every outcome's swept motion is free (Section VI-4).
        valid[k] = (1 << na) - 1
        for j in range(J):
            rows = na + np.arange(na) * J + j
            valid[k] &= valid_moves(
                free[k], np.ascontiguousarray(disp[k, rows]), heading_axis, grid
            )
    offs, fr = stencil_tables(disp, heading_axis, shape_a, lower_a, spacing)
    coff, cw, interior = corner_tables(offs, fr, table_rows(nact, J), shape_a)
    live = np.zeros((M, ncell), np.bool_)
    for m in range(M):
        live[m] = free[vcls[m]]
    mdp = LayeredMDP(
        shape=shape_a,
        lower=lower_a,
        upper=upper_a,
        spacing=spacing,
        periodic=periodic_a,
        modes=modes,
        cost=cost,
        vcls=vcls,
        fmp_next=fmp_next,
        tf=tf,
        branch_ptr=np.asarray(ptr, np.int64),
        branch_layer=np.asarray(layers, np.int64),
        branch_prob=np.asarray(bprob, float),
        free=free,
        disp=disp,
        nact=nact,
        heading_axis=heading_axis,
        valid=valid,
        offs=offs,
        fr=fr,
        coff=coff,
        cw=cw,
        interior=interior,
        live=live,
        stage_time=stage_time,
        arrival=arrival,
        request_prob=request_prob,
        labels=[a.labels for a in cls_actions],
        outcomes=outcomes,
        noise_prob=np.asarray(noise_prob, float),
        opt_ptr=opt_ptr,
    )
    compute_live(mdp)
    return mdp


def _failure_outcomes(
    requests: Sequence[tuple[str, str, str, float]],
    probs: np.ndarray,
    x_index: Mapping[tuple[int, str, str], int],
    failures: Failures,
) -> Outcomes:
    """The FMP outcomes of every mode with failures (Section VI-3), in mode order.

    A failure with probability ``f`` splits the FMP's certain outcome: success with
    ``1 - f``, and with ``f`` either the same state again at the rework cost (retry in
    place) or the X mode of the rejected part. An X mode's FMP (the drop in the reject
    region) leads to the request's W mode (fetch a replacement), or to the W modes of the
    requests for the same part and destination, by their request probabilities.
    """
    R = len(requests)
    ptr = [0]
    layer: list[int] = []
    prob: list[float] = []
    cost: list[float] = []

    def add(succ: int, m: int, r: int, f: Failure | None) -> None:
        if f is None or f.probability <= 0.0:
            layer.append(succ)
            prob.append(1.0)
            cost.append(0.0)
            return
        layer.extend([succ, x_index[(r, f.reject, f.after)] if f.reject else m])
        prob.extend([1.0 - f.probability, f.probability])
        cost.extend([0.0, 0.0 if f.reject else f.rework])

    ptr.append(0)  # NR: no FMP
    for r in range(R):
        add(1 + R + r, 1 + r, r, failures.pick[r])
        ptr.append(len(layer))
    for r in range(R):
        add(0, 1 + R + r, r, failures.drop[r])
        ptr.append(len(layer))
    for r, _, after in x_index:
        p, _, d, _ = requests[r]
        same = [i for i, (p2, _, d2, _) in enumerate(requests) if p2 == p and d2 == d]
        weights = probs[same]
        if after == "request" and weights.sum() > 0:
            for i, w in zip(same, weights / weights.sum(), strict=True):
                if w > 0:
                    layer.append(1 + i)
                    prob.append(float(w))
                    cost.append(0.0)
        else:
            layer.append(1 + r)
            prob.append(1.0)
            cost.append(0.0)
        ptr.append(len(layer))
    return Outcomes(
        np.asarray(ptr, np.int64),
        np.asarray(layer, np.int64),
        np.asarray(prob, float),
        np.asarray(cost, float),
    )


def stencil_tables(
    disp: np.ndarray, heading_axis: int, shape: np.ndarray, lower: np.ndarray, spacing: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each move from a cell centre in cell units, split into integer and fractional parts.

    Robot-frame moves (``heading_axis >= 0``) get one entry per orientation slice.
    """
    K, A, dim = disp.shape
    if heading_axis >= 0:
        n_t = int(shape[heading_axis])
        theta = lower[heading_axis] + (np.arange(n_t) + 0.5) * spacing[heading_axis]
        ct, st = np.cos(theta), np.sin(theta)
        steps = np.broadcast_to(disp[:, :, None, :], (K, A, n_t, dim)).copy()
        steps[..., 0] = disp[:, :, None, 0] * ct - disp[:, :, None, 1] * st
        steps[..., 1] = disp[:, :, None, 0] * st + disp[:, :, None, 1] * ct
    else:
        steps = disp[:, :, None, :].copy()
    cells = steps / spacing
    offs = np.floor(cells)
    fr = cells - offs
    # Moves of a whole number of cells land on a centre; keep them exact.
    up = fr > 1.0 - 1e-9
    offs[up] += 1.0
    fr[up | (fr < 1e-9)] = 0.0
    return offs.astype(np.int64), np.ascontiguousarray(fr)


def table_rows(nact: np.ndarray, outcomes: int) -> np.ndarray:
    """Rows of the move tables each class uses: its ``A`` commanded moves, and with noise
    (``outcomes = J > 1``, Section VI-4) the ``A J`` noisy landings after them."""
    return nact if outcomes == 1 else nact * (1 + outcomes)


def corner_tables(
    offs: np.ndarray, fr: np.ndarray, rows: np.ndarray, shape: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat corner offsets and weights of every move stencil, and the cells where they apply.

    A cell is *interior* for a move class when every move's stencil, taken without
    clamping or wrapping, stays inside the grid; the kernels then skip the per-axis
    stencil arithmetic (the fast path of the sweeps).
    """
    K, A, T, dim = offs.shape
    strides = np.array([int(np.prod(shape[j + 1 :])) for j in range(dim)], np.int64)
    ncorner = 1 << dim
    coff = np.zeros((K, A, T, ncorner), np.int64)
    cw = np.ones((K, A, T, ncorner))
    for kk in range(ncorner):
        for j in range(dim):
            bit = (kk >> (dim - 1 - j)) & 1
            coff[..., kk] += (offs[..., j] + bit) * strides[j]
            cw[..., kk] *= fr[..., j] if bit else 1.0 - fr[..., j]
    # Largest weights first: the kernels stop at the first zero weight (a move along one
    # joint axis, for example, has 2 corners of 8 with weight).
    order = np.argsort(-cw, axis=-1, kind="stable")
    coff = np.ascontiguousarray(np.take_along_axis(coff, order, axis=-1))
    cw = np.ascontiguousarray(np.take_along_axis(cw, order, axis=-1))
    ncell = int(np.prod(shape))
    idx = np.indices(tuple(int(n) for n in shape)).reshape(dim, ncell)
    interior = np.zeros((K, ncell), np.bool_)
    for k in range(K):
        used = offs[k, : rows[k]]
        lo = used.min(axis=(0, 1))
        hi = used.max(axis=(0, 1)) + 1
        ok = np.ones(ncell, bool)
        for j in range(dim):
            ok &= (idx[j] + lo[j] >= 0) & (idx[j] + hi[j] <= shape[j] - 1)
        interior[k] = ok
    return coff, cw, interior


def compute_live(mdp: LayeredMDP) -> None:
    """Restrict ``mdp.live`` to the states that can finish their request (in place).

    Repeats :func:`_live_pass` until nothing changes, remembering each layer's inputs so
    that a later pass skips the layers whose inputs did not change. A time-varying model
    (Section VI-1) has its own: :func:`cellplan.strategies.variants.periodic.periodic_live`.
    """
    if mdp.period > 1:
        from cellplan.strategies.variants.periodic import periodic_live

        periodic_live(mdp)
        return
    fmp_ok = mdp.tf < np.inf
    settled: list[tuple[Any, ...] | None] = [None] * mdp.n_modes
    for _ in range(100):
        if not _live_pass(mdp, mdp.live, fmp_ok, settled):
            return
    raise RuntimeError("live-state computation did not settle")  # pragma: no cover


def _live_pass(
    mdp: LayeredMDP,
    live: np.ndarray,
    fmp_ok: np.ndarray,
    settled: list[tuple[Any, ...] | None] | None = None,
) -> bool:
    """One shrinking pass of ``live`` over every layer; True if anything changed.

    :func:`.domain.live_layer` is a function of a few rows of ``live`` and ``fmp_ok``
    (its *inputs*), and running it on its own output changes nothing. So a layer whose
    inputs equal, byte for byte, those of a layer already done in this pass copies that
    layer's result: aliased or repeated destinations give many requests with identical
    layers, and a scenario with 100 copies of a destination took 124 s to build without
    this. A layer whose inputs equal those it had when it settled (``settled[m]``, kept
    across passes by :func:`compute_live`) is skipped. Rows are compared by a 128-bit
    BLAKE2 digest.
    """
    model = mdp.kernel_args()
    out = mdp.fmp_outcomes()
    row_digest: dict[tuple[int, int], bytes] = {}

    options = mdp.options

    def digest(which: int, m: int) -> bytes:
        key = (which, m)
        if key not in row_digest:
            row = live[m] if which == 0 else fmp_ok[m]  # fmp_ok: by option
            row_digest[key] = hashlib.blake2b(row.tobytes(), digest_size=16).digest()
        return row_digest[key]

    def inputs(m: int) -> tuple[Any, ...]:
        lo, hi = mdp.branch_ptr[m], mdp.branch_ptr[m + 1]
        branches = [int(L) for L in mdp.branch_layer[lo:hi][mdp.branch_prob[lo:hi] > 0]]
        # The kernel needs every branch supported, so their order does not matter.
        others = tuple(sorted(digest(0, L) for L in branches if L != m))
        fmp: tuple[Any, ...] | None = None
        if mdp.fmp_next[m] >= 0:
            fmp = ()
            for o in range(options[m], options[m + 1]):
                lo, hi = out.ptr[o], out.ptr[o + 1]
                landing = sorted({int(L) for L in out.layer[lo:hi][out.prob[lo:hi] > 0]})
                fmp += ((digest(1, o), tuple((L == m, digest(0, L)) for L in landing)),)
        return (int(mdp.vcls[m]), digest(0, m), fmp, m in branches, others)

    done: dict[tuple[Any, ...], int] = {}
    changed = False
    for m in range(mdp.n_modes):
        key = inputs(m)
        if settled is not None and settled[m] == key:
            continue
        rep = done.get(key)
        if rep is None:
            layer_changed = bool(live_layer(live, fmp_ok, model, m))
            done[key] = m
        else:
            layer_changed = not np.array_equal(live[m], live[rep])
            live[m] = live[rep]
        if layer_changed:
            changed = True
            row_digest.pop((0, m), None)
        if settled is not None:
            settled[m] = inputs(m)
    return changed


def live_problems(mdp: LayeredMDP) -> list[Problem]:
    """One problem per request that can never be served (checked before solving); for a
    time-varying model, :func:`cellplan.strategies.variants.periodic.periodic_problems`."""
    if mdp.period > 1:
        from cellplan.strategies.variants.periodic import periodic_problems

        return periodic_problems(mdp)
    problems = []
    R = mdp.n_requests
    live = mdp.live
    if not mdp.live[0].any():
        problems.append(Problem("strategy", "no configuration in NR can serve every request"))
        problems.extend(_split_problems(mdp))
        # NR is empty as soon as one request cannot be served, and every layer that ends
        # in NR empties with it: judge each request on its own instead (issue 35 part 5),
        # by the same live-state rule with NR left unconstrained.
        live = _each_request_live(mdp)
    for r in range(R):
        mode = mdp.modes[1 + r]
        where = f"strategy.requests <{mode.part},{mode.source},{mode.destination}>"
        if not (mdp.tf[mdp.c_layer(r)] < np.inf).any():
            problems.append(
                Problem(
                    where,
                    f"part {mode.part!r} cannot be delivered anywhere in destination "
                    f"{mode.destination!r} (no free configuration in the region)",
                )
            )
        elif not (mdp.tf[mdp.w_layer(r)] < np.inf).any():
            problems.append(
                Problem(
                    where,
                    f"part {mode.part!r} cannot be picked up anywhere in source "
                    f"{mode.source!r} (no free configuration in the region)",
                )
            )
        elif not live[mdp.c_layer(r)].any():
            problems.append(
                Problem(
                    where,
                    f"destination {mode.destination!r} is unreachable while carrying {mode.part!r}",
                )
            )
        elif not live[mdp.w_layer(r)].any():
            problems.append(
                Problem(
                    where,
                    f"source {mode.source!r} is unreachable, or its part cannot reach "
                    f"destination {mode.destination!r} from there",
                )
            )
    for m, mode in enumerate(mdp.modes):
        if mode.kind == "X" and not mdp.live[m].any():
            problems.append(
                Problem(
                    "strategy.failures",
                    f"part {mode.part!r} (from {mode.source}) cannot be carried to reject region "
                    f"{mode.reject!r} and dropped there",
                )
            )
    return problems


def _each_request_live(mdp: LayeredMDP) -> np.ndarray:
    """The live states of each layer when NR is not required to serve every request: the
    passes of :func:`compute_live` with NR's row held at its free cells, so a request's
    C layer is live where its part can be carried to its destination and delivered, and
    its W layer where the robot can then pick it up and do so, whatever the other
    requests can do. Used to name only the requests that cannot be served."""
    # NR without its arrivals: it need not reach every request's source, only stay free.
    prob = mdp.branch_prob.copy()
    lo, hi = mdp.branch_ptr[0], mdp.branch_ptr[1]
    prob[lo:hi] = np.where(mdp.branch_layer[lo:hi] == 0, 1.0, 0.0)
    alone = replace(mdp, branch_prob=prob)
    live = np.stack([mdp.free[mdp.vcls[m]] for m in range(mdp.n_modes)])
    fmp_ok = mdp.tf < np.inf
    for _ in range(100):
        if not _live_pass(alone, live, fmp_ok):
            break
    return live


def _split_problems(mdp: LayeredMDP) -> list[Problem]:
    """Name the (destination, next source) pairs that a split free space separates.

    Recomputes one round of the live states with NR unconstrained: a W state is then live
    when the robot can go from it to its source and deliver. If no delivery configuration
    of destination d is live for the W layer of source s, a request from s arriving just
    after a delivery at d could never be served, which empties NR (not unichain).
    """
    live = np.stack([mdp.free[mdp.vcls[m]] for m in range(mdp.n_modes)])
    _live_pass(mdp, live, mdp.tf < np.inf)
    seen = set()
    out = []
    R = mdp.n_requests
    for r in range(R):
        d = mdp.modes[mdp.c_layer(r)].destination
        drop = mdp.tf[mdp.c_layer(r)] < np.inf
        for r2 in range(R):
            s2 = mdp.modes[mdp.w_layer(r2)].source
            if (d, s2) in seen or not drop.any():
                continue
            if not (live[mdp.w_layer(r2)] & drop).any():
                seen.add((d, s2))
                out.append(
                    Problem(
                        f"destinations.{d}",
                        f"after a delivery at {d} the robot cannot reach source {s2} (the free "
                        "configuration space splits; check joint limits, obstacles, grid cells)",
                    )
                )
    return out


def fine_motion_field(spec: Any, tool_xy: np.ndarray) -> np.ndarray:
    """``t_f`` per cell from a :class:`~.section.FineMotionSpec` (Fig. 5)."""
    time = float(spec.time)
    point = spec.point
    rate = float(spec.rate)
    out = np.full(len(tool_xy), time)
    if point is not None and rate > 0:
        out += rate * np.hypot(tool_xy[:, 0] - point[0], tool_xy[:, 1] - point[1])
    return out


def start_problems(
    mdp: LayeredMDP, start: Sequence[float] | np.ndarray, blocking: Sequence[str] = ()
) -> list[Problem]:
    """A problem when ``start`` (the robot's start) is not a live state of NR, so no
    run of the strategy could begin there (checked before solving). ``blocking`` names
    the sources the empty robot touches at ``start``: sources are obstacles while the
    robot is empty (equation (1)), so the line names them."""
    q = np.asarray(start, float)
    idx = np.floor((q - mdp.lower) / mdp.spacing).astype(np.int64)
    idx = np.where(mdp.periodic, idx % mdp.shape, np.clip(idx, 0, mdp.shape - 1))
    if mdp.live[0, int(np.ravel_multi_index(tuple(idx), tuple(mdp.shape)))]:
        return []
    shape = " x ".join(str(int(n)) for n in mdp.shape)
    if blocking:
        names = ", ".join(blocking)
        return [
            Problem(
                "robot.start",
                f"lies outside the strategy's domain: the robot touches source {names} there, "
                "and sources are obstacles while the robot is empty (equation (1) of the "
                "paper); start it outside the source regions",
            )
        ]
    return [
        Problem(
            "robot.start",
            f"lies outside the strategy's domain on the {shape} grid: from its cell no request "
            "can be served (blocked at this resolution, or cut off from the sources and "
            "destinations)",
        )
    ]


def build_model(
    scenario: Any,
    cell: Any,
    cells: Sequence[int] | None = None,
    start: Sequence[float] | np.ndarray | None = None,
) -> LayeredMDP:
    """The layered MDP of a scenario with a ``strategy:`` section.

    With ``start`` (the robot's start, as the planner passes it), also checks that a run
    can begin there (:func:`start_problems`). ``cellplan validate`` runs this same
    function, so it refuses exactly what ``cellplan solve`` refuses before solving.

    Raises
    ------
    ScenarioError
        When a request can never be served (a region no configuration reaches, a part
        that cannot be carried anywhere, an unreachable destination), one problem each,
        or the start is outside the strategy's domain.
    """
    from cellplan.cspace import Grid, free_bitmap, region_bitmap

    sec = scenario.strategy
    if sec is None:
        raise ScenarioError([Problem("strategy", "the scenario has no strategy section")])
    robot = cell.robot
    shape = grid_shape(scenario, cell, cells)
    if len(shape) != robot.dim:
        raise ScenarioError([Problem("strategy.cells", f"needs {robot.dim} entries")])
    grid = Grid.for_robot(robot, shape)
    requests = sec.request_list(scenario)
    parts = sorted({p for p, *_ in requests})
    sources = sorted({s for _, s, *_ in requests})
    # Regions on a belt are never obstacles (Section VI-1; strategies/variants/periodic.py).
    belts = sec.belts if sec.time_varying() else {}

    def others(source: str | None) -> list[str]:
        return [s for s in cell.sources_except(source) if s not in belts]

    free_nr = free_bitmap(cell, grid, None, others(None))
    free_w = {s: free_bitmap(cell, grid, None, others(s)) for s in sources}
    free_c = {
        (p, s): free_bitmap(cell, grid, p, others(s))
        for p in parts
        for s in sources
        if any(r[0] == p and r[1] == s for r in requests)
    }
    pts = grid.points()
    tool = cell.tool_position(pts)[:, :2]

    def tf_of(region: str) -> np.ndarray:
        spec = sec.fine_motion_regions.get(region, sec.fine_motion)
        return fine_motion_field(spec, tool)

    # Regions written twice (a YAML alias, a copied block) are tested once: each test
    # poses the robot at every grid cell.
    tested: dict[tuple[str, str | None], np.ndarray] = {}

    def in_region(name: str, carrying: str | None) -> np.ndarray:
        spec = (scenario.sources | scenario.destinations)[name]
        key = (spec.model_dump_json(), carrying)
        if key not in tested:
            tested[key] = region_bitmap(cell, grid, name, sec.regions, None, carrying)
        return tested[key]

    pick = {}
    tf_pick = {}
    for p, s in free_c:
        pick[(p, s)] = in_region(s, None)
        tf_pick[(p, s)] = tf_of(s)
    drop = {}
    tf_drop = {}
    for p, _, d, _ in requests:
        if (p, d) not in drop:
            drop[(p, d)] = in_region(d, p)
            tf_drop[(p, d)] = tf_of(d)
    geometry = Geometry(free_nr, free_w, free_c, pick, drop, tf_pick, tf_drop)
    if sec.simultaneous():
        from cellplan.strategies.model.bundles import Grid as KernelGrid
        from cellplan.strategies.variants.pending import assemble_pending, pending_problems

        empty, carrying = action_sets(sec, robot, parts)
        shape_a = np.asarray(shape, np.int64)
        lower = np.asarray(grid.lower, float)
        upper = np.asarray(grid.upper, float)
        mdp = assemble_pending(
            grid=KernelGrid(
                shape_a, lower, upper, (upper - lower) / shape_a, np.asarray(grid.periodic, bool)
            ),
            requests=requests,
            geometry=geometry,
            actions_empty=empty,
            actions_carrying=carrying,
            stage_time=sec.stage_time,
            arrival=sec.arrival.per_stage(sec.stage_time),
            max_pending=sec.max_pending,
            urgency=sec.urgency,
        )
        return _checked(mdp, pending_problems(mdp, requests), start, cell, others(None))
    failures = None
    if sec.failures:

        def failure(region: str, part: str) -> Failure | None:
            f = sec.failure_at(region, part)
            if f is None:
                return None
            return Failure(
                float(f.probability),
                float(f.rework or 0.0),
                f.reject_region or "",
                f.after_reject or "fetch",
            )

        pick_f = [failure(s, p) for p, s, _, _ in requests]
        drop_f = [failure(d, p) for p, _, d, _ in requests]
        rejected = {
            (requests[r][0], f.reject)
            for r, fs in enumerate(zip(pick_f, drop_f, strict=True))
            for f in fs
            if f is not None and f.reject
        }
        failures = Failures(
            pick_f,
            drop_f,
            {(p, b): in_region(b, p) for p, b in rejected},
            {b: tf_of(b) for _, b in rejected},
        )
    empty, carrying = action_sets(sec, robot, parts)
    dst = sec.destination_change.per_stage(sec.stage_time) if sec.destination_change else 0.0
    src = sec.source_change.per_stage(sec.stage_time) if sec.source_change else 0.0
    mdp = assemble(
        shape=shape,
        lower=grid.lower,
        upper=grid.upper,
        periodic=grid.periodic,
        requests=requests,
        geometry=geometry,
        actions_empty=empty,
        actions_carrying=carrying,
        stage_time=sec.stage_time,
        arrival=sec.arrival.per_stage(sec.stage_time),
        destination_change=dst,
        source_change=src,
        failures=failures,
    )
    if sec.time_varying():  # the checks refuse failures and changes with it
        mdp = _periodic_model(scenario, cell, grid, requests, geometry, mdp)
    return _checked(mdp, live_problems(mdp), start, cell, others(None))


def _periodic_model(
    scenario: Any,
    cell: Any,
    grid: Any,
    requests: list[tuple[str, str, str, float]],
    geometry: Geometry,
    base: LayeredMDP,
) -> LayeredMDP:
    """The time-varying model of a scenario (Section VI-1, :mod:`.periodic`): the Section
    V model ``base`` on ``geometry`` (phase 0), and the pick and delivery regions at every
    phase."""
    from cellplan.strategies.variants.periodic import assemble_periodic, belt_offset

    sec = scenario.strategy
    T = sec.period
    velocity = {name: (float(b.velocity[0]), float(b.velocity[1])) for name, b in sec.belts.items()}
    pts = grid.points()
    kind = sec.regions

    def moved(name: str, carrying: str | None, t: int) -> np.ndarray:
        offset = belt_offset(velocity[name], t, sec.stage_time)
        return cell.in_region(pts, name, kind, None, carrying, offset)

    fields = np.empty((T, base.n_modes, base.n_cells))
    for t in range(T):
        pick = dict(geometry.pick)
        drop = dict(geometry.drop)
        if t > 0:
            for p, s in pick:
                if s in velocity:
                    pick[(p, s)] = moved(s, None, t)
            for p, d in drop:
                if d in velocity:
                    drop[(p, d)] = moved(d, p, t)
        fields[t] = request_fields(replace(geometry, pick=pick, drop=drop), requests)

    def stages(region: str) -> int:
        spec = sec.fine_motion_regions.get(region, sec.fine_motion)
        return int(np.floor(float(spec.time) / sec.stage_time + 0.5))  # half up

    fmp_stages = [0] + [stages(s) for _, s, _, _ in requests] + [stages(d) for *_, d, _ in requests]
    return assemble_periodic(
        base,
        fields=fields,
        arrival=sec.arrival_by_phase(),
        fmp_stages=fmp_stages,
        belts=velocity,
    )


def _checked(
    mdp: LayeredMDP,
    problems: list[Problem],
    start: Sequence[float] | np.ndarray | None,
    cell: Any = None,
    sources: Sequence[str] = (),
) -> LayeredMDP:
    """``mdp``, unless a request can never be served or the start is outside its domain
    (naming the ``sources`` the empty robot touches there, by ``cell``'s exact test)."""
    if not problems and start is not None:
        problems = start_problems(mdp, start)
        if problems and cell is not None:
            q = np.asarray(start, float)[None, :]
            # A start clear of the fixed obstacles but touching a source (an obstacle
            # while the robot is empty) gets a line naming the source.
            clear = not bool(cell.collides(q, None, [])[0])
            blocking = [s for s in sources if clear and bool(cell.collides(q, None, [s])[0])]
            problems = start_problems(mdp, start, blocking)
    if problems:
        raise ScenarioError(problems)
    return mdp


def grid_shape(scenario: Any, cell: Any, cells: Sequence[int] | None = None) -> tuple[int, ...]:
    """Cells per axis of the model: ``cells``, else ``strategy.cells``, else
    ``cspace.cells``, else the robot kind's default."""
    sec = scenario.strategy
    return tuple(
        int(n) for n in (cells or sec.cells or scenario.cspace.cells or cell.default_cells)
    )


def _bitmap_peak(cell: Any, shape: tuple[int, ...], parts: Sequence[str]) -> int:
    """Working bytes of the largest C-space bitmap :func:`build_model` computes."""
    from cellplan.cspace import Grid
    from cellplan.cspace import estimate_memory as bitmap_memory

    if len(shape) != cell.robot.dim:
        return 0  # build_model refuses this grid before computing any bitmap
    grid = Grid.for_robot(cell.robot, shape)
    return max(bitmap_memory(cell, grid, carrying) for carrying in [None, *parts])


def action_sets(
    sec: Any, robot: Any, parts: Sequence[str]
) -> tuple[ActionSet, dict[str, ActionSet]]:
    """The motion actions while empty, and while carrying each part (speed factor)."""
    kind = robot.kind if robot.kind in ("point", "translating", "rotating") else "arm"
    common = dict(
        speed=sec.speed,
        stage_time=sec.stage_time,
        headings=sec.actions.headings,
        turn_speed_deg=sec.turn_speed,
    )
    empty = action_set(kind, robot.dim, **common)
    carrying = {
        p: action_set(kind, robot.dim, factor=sec.carry_speed_factor.get(p, 1.0), **common)
        for p in parts
    }
    if sec.noise is not None:
        noise = sec.noise
        prob = np.array([o.probability for o in noise.outcomes], float)
        given = [o.offset for o in noise.outcomes]
        if noise.frame == "world":  # angles in degrees in the file
            offsets = np.stack([units.config_from_file(robot.axis_names, v) for v in given])
        else:
            offsets = np.array(given, float)
        empty = with_noise(empty, offsets, prob, noise.frame)
        carrying = {p: with_noise(a, offsets, prob, noise.frame) for p, a in carrying.items()}
    return empty, carrying


#: SuperLU's factors of policy iteration's recurrent class, in entries (its own count,
#: ``SuperLU.nnz``), per place of the policy's matrix on a stationary model: at most 2.9
#: measured on the 8 models it was fitted on, 1.5 on 5 held out (:func:`estimate_memory`).
STATIONARY_FILL = 4
#: The same on a time-varying model, per ``(layers x cells)^(4/3)`` (the fill of a 3-D
#: grid: the grid and the ring of phases): at most 3.05 measured on the 9 tiny-cell
#: models it was fitted on, 2.0 on 7 held out, ``strategies_conveyor`` among them.
PERIODIC_FILL = 4.0


@dataclass(frozen=True)
class MemoryEstimate:
    """Bytes a solve will hold at its peak, from the arrays it allocates (count x dtype).

    ``terms`` names each group of arrays with its bytes; ``total`` is the model's arrays
    plus the larger of the building step's and the solver's working arrays (they are not
    alive together): ``solver`` for the structured and general solvers, ``policy`` for
    policy iteration (``method``), with ``factors``, the sparse LU factors it keeps.
    """

    cells: int
    modes: int
    classes: int
    actions: int
    terms: Mapping[str, int]

    method: str = "structured"

    @property
    def total(self) -> int:
        t = self.terms
        solver = t["policy"] + t["factors"] if self.method == "policy" else t["solver"]
        return t["model"] + t["tables"] + max(t["building"], solver)


def estimate_memory(
    scenario: Any, cell: Any, cells: Sequence[int] | None = None, method: str | None = None
) -> MemoryEstimate:
    """The memory of :func:`build_model` and the solver on this grid, before allocating.

    Counts, per grid cell (``N``), with ``M`` modes (NR, two per request, the X modes of
    rejected parts), ``K`` move classes (at most NR, one per source and one per carried
    (part, source)), ``A`` actions (with their noisy landings), ``d`` axes:

    * model (:class:`LayeredMDP`, alive throughout): ``tf`` float64 ``(O, N)`` (``O`` FMP
      options: ``M`` but with simultaneous requests, whose ``M`` and ``O`` follow
      ``max_pending``, :func:`~cellplan.strategies.model.section.mode_counts`), ``live``
      bool ``(M, N)``, ``free`` and ``interior`` bool ``(K, N)``, ``valid`` int64 ``(K, N)``;
    * building (:func:`build_model`): the geometry's bitmaps (bool: NR, one per source,
      two per (part, source), one per (part, destination)) and fine-motion fields
      (float64 per (part, source) and (part, destination)), the cell centres and tool
      poses (float64 ``(N, 2 d + 3)``: the centres are computed twice), the stacked
      class bitmaps (two bool ``(K, N)``), and :func:`corner_tables`' index grid
      (int64 ``(d + 1, N)``);
    * solver (its peak is the final certificate, :func:`~.solver._finish`): ``h`` and
      ``D`` float64 and the policy int16 ``(M, N)``, the NR action sums ``E`` and ``ED``
      float64 ``(N, A + 1)``, NR's values and ``D`` before a sweep (float64 ``N`` each,
      read across its slabs), a trial copy of ``h``, the certificate's Bellman sweep (value,
      int64 policy, gap: three ``(M, N)`` of 8 bytes), the stability test's slack (two
      float64 temporaries), its mask (bool) and shifted values (float64), and its second
      Bellman sweep (three more 8-byte ``(M, N)``);
      or, if larger, the bitmaps plus the working arrays of the largest single
      :func:`~cellplan.cspace.free_bitmap` call (:func:`cellplan.cspace.estimate_memory`;
      the calls run one after another, and dominate on small grids);
    * tables: the stencil tables, float64/int64 ``(K, A, T, d)`` twice and
      ``(K, A, T, 2^d)`` twice (small);
    * policy (policy iteration, :mod:`~.policy_iteration`, in place of ``solver`` when
      ``method`` is ``policy``, or ``auto`` with failure modes or noise, which ``auto``
      solves by policy iteration; ``method`` defaults to ``strategy.solver.method``): with
      ``S <= M N`` live states and ``Z = 2^d J N sum_m B_m`` places for the rows of a
      policy's matrix (``B_m`` the branches of mode ``m``: NR has one per request and
      itself, a W or C layer itself and the requests it can change into; ``J`` landings
      per move with noise, else 1; an X mode of failure modes has one branch),
      the state index (int64 ``(M, N)``), the values, the certificate's three sweeps and
      the value-iteration copies (five more float64 ``(M, N)``), 44 bytes per state
      (state list, row starts, counts, cost, index pointers), 33 per place (its row and
      position, column, value, mask), and per stored entry (at most ``Z``) 44 bytes: the
      packed CSR (float64 + int32), its int64 and int32 copies, and the last matrix, alive
      while the next is assembled; plus, as the term ``factors``, the SuperLU factors of
      the recurrent class (12 bytes per entry; :data:`STATIONARY_FILL` ``Z`` entries).
      ``tracemalloc`` does not see SuperLU's own allocations: the tests compare its peak
      with the other terms and SuperLU's count of its entries with ``factors``;
    * a time-varying model (Section VI-1, :mod:`.periodic`) has the layers of every phase
      of its period ``P``: ``M`` and ``O`` are ``P`` times those of one phase (the move
      classes are shared) and so are the places ``Z``; the building step adds the phase-0
      model, one phase's fields, a moved region's test and four bool ``(M, N)`` of the
      live-state pass over the phases; ``auto`` solves it by policy iteration, whose
      recurrent class is then a ring of layers through the phases, a 3-D grid, whose
      SuperLU fill grows as its size to the 4/3: at most :data:`PERIODIC_FILL`
      ``(M N)^(4/3)`` entries.

    The test ``test_memory_estimate_matches_measured_allocations`` compares it with the
    peak measured by ``tracemalloc``.
    """
    sec = scenario.strategy
    robot = cell.robot
    shape = grid_shape(scenario, cell, cells)
    d = len(shape)
    N = int(np.prod(shape, dtype=object))
    requests = sec.request_list(scenario)
    R = len(requests)
    M = 2 * R + 1 + sec.reject_modes(requests)
    parts = sorted({p for p, *_ in requests})
    S = len({s for _, s, *_ in requests})
    PS = len({(p, s) for p, s, *_ in requests})
    PD = len({(p, dd) for p, _, dd, _ in requests})
    K = min(M, 1 + S + PS)
    n_opt = M  # FMP options: one per mode but with simultaneous requests
    if sec.simultaneous():
        from cellplan.strategies.model.section import mode_counts
        from cellplan.strategies.variants.pending import option_count

        M = sum(mode_counts(R, sec.max_pending))
        n_opt = option_count(R, sec.max_pending)
        K = min(M, 2 ** min(S, 20) + PS)  # a class per set of sources, per (part, source)
    # A time-varying model (Section VI-1): the layers of every phase, classes shared.
    P = sec.period if sec.time_varying() else 1
    per_phase = M
    M, n_opt = P * M, P * n_opt
    empty, carrying = action_sets(sec, robot, parts)
    A = max([empty.disp.shape[0], *(a.disp.shape[0] for a in carrying.values())])
    heading = empty.heading_axis
    T = shape[heading] if heading >= 0 else 1
    bitmaps = 1 + S + 2 * PS + PD
    places = P * policy_places(requests, sec, N, d)
    # SuperLU's factors of the recurrent class: a few entries per place on a stationary
    # model (STATIONARY_FILL); over a period the class is a ring of layers, a 3-D grid
    # whose fill grows as its size to the 4/3 (PERIODIC_FILL).
    lu_fill = STATIONARY_FILL * places
    if P > 1:
        # (M N)^(4/3) as M N times its integer cube root: no float overflows on any grid.
        cube_root = int(math.exp(math.log(M * N) / 3)) + 1
        lu_fill = max(lu_fill, int(PERIODIC_FILL * M * N * cube_root))
    building = N * (bitmaps + 8 * (PS + PD) + 8 * (2 * d + 3) + 2 * K + 8 * (d + 1))
    if P > 1:
        # The phase-0 model (its tf float64, live bool (M0, N)), the phases' fields (the
        # model's tf, counted there), one phase's fields and a moved region's test
        # (float64 (M0, N) and the posed bodies, float64 (N, 4 d)), and the live-state
        # pass over the phases (four bool (M, N): candidates, FMP cells, the pass and
        # the model's copy).
        building += N * (9 * per_phase + 8 * per_phase + 32 * d + 4 * M)
    terms = {
        "model": N * (8 * n_opt + M + K + K + 8 * K),
        "building": max(building, N * bitmaps + _bitmap_peak(cell, shape, parts)),
        "solver": N * (18 * M + 16 * (A + 1) + 16 + 8 * M + 24 * M + 16 * M + M + 8 * M + 24 * M),
        "tables": K * A * T * (16 * d + 16 * 2**d),
        "policy": 100 * M * N + (33 + 44) * places,
        # SuperLU's factors (C memory, which tracemalloc does not see): 12 bytes an entry.
        "factors": 12 * lu_fill,
    }
    chosen = sec.solver.method if method is None else method
    # auto picks policy iteration for the Section VI models (solver.solve).
    policy = chosen == "policy" or (
        chosen == "auto"
        and bool(sec.failures or sec.noise or sec.simultaneous() or sec.time_varying())
    )
    return MemoryEstimate(N, M, K, A, terms, "policy" if policy else "structured")


def policy_places(requests: Sequence[Any], sec: Any, N: int, d: int) -> int:
    """Room for the rows of a policy's matrix (:func:`estimate_memory`): ``2^d N sum_m B_m``."""
    R = len(requests)
    landings = len(sec.noise.outcomes) if sec.noise is not None else 1
    if sec.simultaneous():  # every mode: itself and at most one arrival per request type
        from cellplan.strategies.model.section import mode_counts

        modes = sum(mode_counts(R, sec.max_pending))
        return (1 << d) * landings * N * modes * (1 + R)
    branches = 1 + R  # NR: itself and one per request
    for change, same in ((sec.source_change, (0, 2)), (sec.destination_change, (0, 1))):
        for p, s, dd, _ in requests:
            key = (p, s, dd)
            others = (
                sum(
                    1
                    for p2, s2, d2, _ in requests
                    if (p2, s2, d2)[same[0]] == key[same[0]]
                    and (p2, s2, d2)[same[1]] == key[same[1]]
                    and (p2, s2, d2) != key
                )
                if change is not None
                else 0
            )
            branches += 1 + others
    branches += sec.reject_modes(requests)  # an X mode (Section VI-3): itself only
    return (1 << d) * landings * N * branches

"""The layered MDP's data (Sections III-IV of the strategies paper): modes and arrays.

:class:`LayeredMDP` holds the discretised MDP of :mod:`.mdp` (which builds it): a *layer*
per mode (a copy of the C-space grid), the move classes and their tables, the branches
of Section III-B and the FMP outcomes. ``variants`` are the active Section VI variants
the model was built with (:class:`~cellplan.strategies.model.spec.ModelRules`): the
live-state rule and the unservable-request check of :mod:`.live` ask them first.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from cellplan.strategies.model.actions import ActionSet
from cellplan.strategies.model.bundles import Grid, Layers, Model, Moves, Outcomes, single_outcomes

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
    # The active Section VI variants the model was built with (ModelRules of .spec):
    # their live-state rule and request check apply wherever the model goes.
    variants: tuple[Any, ...] = ()

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
    def has_options(self) -> bool:
        """Whether an FMP chooses among options (their table ``opt_ptr`` was built).

        A property of the model's shape, asked by the queries that take one option at a time."""
        return self.opt_ptr is not None

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
        # Noisy landings, FMP options or layers over several phases are not Section V's shape.
        if (
            len(self.noise_prob) > 1
            or self.opt_ptr is not None
            or self.modes_per_phase < self.n_modes
        ):
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


def mode_of(fields: list[str]) -> Mode:
    """The mode of a ``meta.modes`` entry: kind, part, source, destination, then for an X
    mode its reject region and what follows, for a Q mode its waiting requests."""
    kind, part, source, destination, *rest = fields
    if kind == "Q":
        return Mode(kind, part, source, destination, waiting=tuple(rest))
    if kind == "X":
        return Mode(kind, part, source, destination, reject=rest[0], after=rest[1])
    return Mode(kind, part, source, destination)

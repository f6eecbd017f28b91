"""The strategy file's declaration: its metadata schema and its arrays.

:data:`ARRAYS` is the format of every array of a strategy file (dtype, shape in the sizes
of :mod:`.fileformat`, range of values), :class:`StrategyMeta` the schema of its JSON
metadata; :func:`~.fileformat.read_strategy` checks a file against both.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from cellplan.arrayfile import ArraySpec
from cellplan.schema import CELLS_RANGE
from cellplan.strategies.model.stencils import MAX_DIM
from cellplan.strategies.section import MAX_NOISE_OUTCOMES, MAX_PENDING, MAX_PERIOD

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
    # The solver tolerance of the solve (absent from files written before it was recorded).
    tolerance: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
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

"""What a strategy tells the robot to do: typed actions, one or a batch.

:meth:`~cellplan.strategies.policy.strategy.Strategy.action` answers with an
:class:`Action` (one configuration) or an :class:`Actions` bundle (an ``(n, dim)`` array
of them, like the workcell's queries): the kind of action (``move``, ``stay``, ``pick``,
``drop``), the move's index and its C-space step, the region of a pick or a drop. The
simulators and the executor work on the integer code underneath (:attr:`Action.code`:
``FMP`` -2, ``STAY`` -1, a move's index, or an FMP option's
:func:`~cellplan.strategies.model.stencils.fmp_code`), which every typed action carries.

The FMP of a mode (Section II-C, equation (6)) is a pick where the robot is empty and a
drop where it carries a part (a delivery; with failures, Section VI-3, a rejected part
dropped in its reject region): :func:`fmp_target` says which, and where.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Literal, cast

import numpy as np

from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.layered import Mode
from cellplan.strategies.model.points import action_values_at, fmp_options_at
from cellplan.strategies.model.stencils import (
    FMP_CODE,
    OUTSIDE_CODE,
    STAY_CODE,
    cell_containing,
    fmp_code,
)

#: The integer codes of the FMP (option 0) and of staying (the kernels' named constants).
FMP = FMP_CODE
STAY = STAY_CODE
#: Why there is no action (the state is outside the strategy's domain).
OUTSIDE = "no action is available here (the state is outside the strategy's domain)"

ActionKind = Literal["move", "stay", "pick", "drop"]


def fmp_target(mode: Mode, option: int) -> tuple[str, str | None]:
    """The region of FMP ``option`` in ``mode`` and the part carried into it (None: a pick).

    A W mode picks at its source; a C mode drops its part at its destination, an X mode
    (Section VI-3) at its reject region. A mode of simultaneous requests (Section VI-2)
    that carries one drops it at its destination; while empty, its options are the
    distinct waiting request types in the order of ``mode.waiting``, each picked at its
    source.
    """
    if mode.kind == "X":
        return mode.reject, mode.part
    if mode.waiting and not mode.part:
        waiting = list(dict.fromkeys(mode.waiting))
        return waiting[option].split(",")[1], None
    if mode.kind == "W":
        return mode.source, None
    return mode.destination, mode.part


@dataclass(frozen=True)
class Action:
    """One action of a strategy at one configuration.

    Attributes
    ----------
    kind
        ``move`` (one of the mode's motions, equation (5)), ``stay``, ``pick`` or ``drop``
        (the FMP, Section II-C).
    code
        The integer code the simulators use: ``FMP`` (-2), ``STAY`` (-1), a move's index,
        or ``fmp_code(option)`` for option ``option >= 1`` (Section VI-2).
    move
        The move's index in the mode's action set (-1 unless ``kind`` is ``move``).
    step
        The move's C-space displacement from the configuration (zeros unless a move).
    region
        The region of a pick or a drop (``""`` otherwise).
    option
        The FMP option (0 for the single FMP of a mode; with simultaneous requests, which
        waiting request type a pick serves); -1 unless a pick or a drop.
    """

    kind: ActionKind
    code: int
    move: int = -1
    step: tuple[float, ...] = ()
    region: str = ""
    option: int = -1

    @property
    def is_fmp(self) -> bool:
        """Whether the action is the fine motion (a pick or a drop)."""
        return self.kind in ("pick", "drop")


@dataclass(frozen=True, eq=False)
class Actions:
    """A batch of actions, one per configuration, as arrays (fields as :class:`Action`).

    ``kind`` and ``region`` are string arrays, ``code``, ``move`` and ``option`` integer
    arrays of shape ``(n,)``, ``step`` a float array of shape ``(n, dim)``. Indexing gives
    one :class:`Action`; iterating gives them in order.
    """

    kind: np.ndarray
    code: np.ndarray
    move: np.ndarray
    step: np.ndarray
    region: np.ndarray
    option: np.ndarray

    def __len__(self) -> int:
        return len(self.code)

    def __getitem__(self, i: int) -> Action:
        return Action(
            kind=cast(ActionKind, str(self.kind[i])),
            code=int(self.code[i]),
            move=int(self.move[i]),
            step=tuple(float(v) for v in self.step[i]),
            region=str(self.region[i]),
            option=int(self.option[i]),
        )

    def __iter__(self) -> Iterator[Action]:
        return (self[i] for i in range(len(self)))

    @staticmethod
    def of(actions: list[Action], dim: int) -> Actions:
        """The bundle of a list of actions of ``dim``-dimensional configurations."""
        return Actions(
            kind=np.array([a.kind for a in actions], dtype="<U4"),
            code=np.array([a.code for a in actions], dtype=np.int64),
            move=np.array([a.move for a in actions], dtype=np.int64),
            step=np.array([a.step for a in actions], dtype=float).reshape(len(actions), dim),
            region=np.array([a.region for a in actions], dtype=str),
            option=np.array([a.option for a in actions], dtype=np.int64),
        )


def fmp_option_of(code: int) -> int:
    """The FMP option of an action code (-1: not an FMP): ``FMP`` is option 0, option
    ``j >= 1`` is ``-3 - j`` (:func:`~cellplan.strategies.model.stencils.fmp_code`)."""
    if code == FMP:
        return 0
    return OUTSIDE_CODE - code if code < OUTSIDE_CODE else -1


def typed(code: int, mode: Mode, step: np.ndarray) -> Action:
    """The :class:`Action` of action ``code`` in ``mode``; ``step`` is its displacement
    (used only for a move)."""
    option = fmp_option_of(code)
    if option >= 0:
        region, part = fmp_target(mode, option)
        kind: ActionKind = "drop" if part is not None else "pick"
        return Action(kind, int(code), step=(0.0,) * len(step), region=region, option=option)
    if code == STAY:
        return Action("stay", STAY, step=(0.0,) * len(step))
    return Action("move", int(code), move=int(code), step=tuple(step.tolist()))


def actions_of(codes: np.ndarray, steps: np.ndarray, mode: Mode) -> Actions:
    """The :class:`Actions` of the action ``codes`` (int64, ``(n,)``) in ``mode``, as
    :func:`typed` makes each: ``steps`` ``(n, dim)`` the moves' displacements (zero rows
    for every other code)."""
    option = np.where(codes == FMP, 0, np.where(codes < OUTSIDE_CODE, OUTSIDE_CODE - codes, -1))
    kind = np.where(codes >= 0, "move", "stay").astype("<U4")
    targets = {int(j): fmp_target(mode, int(j)) for j in np.unique(option[option >= 0])}
    region = np.full(len(codes), "", dtype=f"<U{max([1, *(len(r) for r, _ in targets.values())])}")
    for j, (name, part) in targets.items():
        kind[option == j] = "drop" if part is not None else "pick"
        region[option == j] = name
    return Actions(
        kind=kind,
        code=codes.astype(np.int64),
        move=np.where(codes >= 0, codes, -1).astype(np.int64),
        step=np.asarray(steps, dtype=float),
        region=region,
        option=option.astype(np.int64),
    )


def option_or_motion(
    q: np.ndarray,
    mode: int,
    h: np.ndarray,
    live: np.ndarray,
    model: Model,
    out: np.ndarray,
    forbid_fmp: bool = False,
    option_test: Callable[[np.ndarray, int, int], np.ndarray] | None = None,
) -> tuple[int, float]:
    """Equation (9) at ``q`` in a mode with FMP options (simultaneous requests, Section
    VI-2): the best of the motions, stay and the FMP options, on the values ``h`` (the
    strategy's, or an executor's corrected copy). Returns ``(action, value)``: the action
    as :meth:`Strategy.action` (``fmp_code(j)`` for option ``j``, FMP first on a tie) and
    its right-hand side of (9).

    An option is offered where the grid cell of ``q`` allows it and, with ``option_test``
    (``(points, mode, j) -> bool array``, :meth:`.regions.RegionTest.option`), where the
    exact region test of the
    request it serves passes at ``q`` (its source for a pick, its destination with the
    part for a delivery): the same rule as the single FMP of the other models, so a
    delivery the workcell refuses is never chosen. Raises ``ValueError`` when no action
    is available.
    """
    action_values_at(q, mode, h, live, 0.0, False, model, out)
    lay = model.layers
    o0, o1 = int(lay.opt_ptr[mode]), int(lay.opt_ptr[mode + 1])
    allowed = np.full(o1 - o0, not forbid_fmp, np.bool_)
    if option_test is not None and not forbid_fmp:
        g = model.grid
        c = int(cell_containing(q, g.shape, g.lower, g.spacing, g.periodic))
        point = np.asarray(q, dtype=float)[None, :]
        for j in np.flatnonzero(np.isfinite(lay.tf[o0:o1, c])):
            allowed[j] = bool(option_test(point, mode, int(j))[0])
    j, fval = fmp_options_at(q, mode, h, live, allowed, model)
    motions = out[1:]
    best_motion = float(np.nanmin(motions)) if not np.all(np.isnan(motions)) else np.inf
    if j >= 0 and not (best_motion < fval):
        return int(fmp_code(j)), float(fval)
    if np.all(np.isnan(motions)):
        raise ValueError(OUTSIDE)
    i = int(np.nanargmin(motions))
    return (STAY if i == 0 else i - 1), best_motion


def best_action(vals: np.ndarray) -> int:
    """Index convention of :meth:`Strategy.action` from an ``action_values`` vector."""
    if np.all(np.isnan(vals)):
        raise ValueError(OUTSIDE)
    i = int(np.nanargmin(vals))
    return FMP if i == 0 else STAY if i == 1 else i - 2

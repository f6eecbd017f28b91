"""The solved motion strategy: optimal actions at any real-valued state, saved as .npz.

Section IV-B of the strategies paper: "the optimal action can be obtained from any
real-valued location x though the use of (9), linear interpolation, and the
approximate representation of L*". :meth:`Strategy.action` does exactly that: one
evaluation of the right-hand side of equation (9) at ``(q, m)``, each successor's
cost-to-go interpolated multilinearly between grid cells, colliding motions excluded by
the swept check of :func:`cellplan.strategies.model.motion.motion_ok`.

A strategy file is a NumPy ``.npz`` archive (no pickle): the MDP arrays, the cost-to-go,
and a JSON metadata string (scenario digest, grid, gain, convergence). Loading it against a
scenario whose digest differs raises :class:`~cellplan.errors.PersistenceError`.
"""

from __future__ import annotations

import json
import operator
import re
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from cellplan import units
from cellplan.errors import ArgumentError, PersistenceError, Problem, ScenarioError
from cellplan.fileio import atomic_path
from cellplan.strategies.model.bundles import Model, Outcomes
from cellplan.strategies.model.mdp import LayeredMDP, Mode
from cellplan.strategies.model.motion import motion_ok
from cellplan.strategies.model.points import action_values_at, compiled_for, fmp_options_at, query
from cellplan.strategies.model.stencils import (
    MAX_DIM,
    cell_containing,
    displacement,
    fmp_code,
    wrap,
)
from cellplan.strategies.policy.fileformat import FORMAT, VERSION, mode_of
from cellplan.strategies.solve.solver import SolveResult

FMP = -2
STAY = -1

_ARRAY_FIELDS = [
    f.name
    for f in fields(LayeredMDP)
    if f.name
    not in (
        "modes",
        "labels",
        "heading_axis",
        "stage_time",
        "arrival",
        "outcomes",
        "opt_ptr",
        "period",
        "belts",
    )
]
#: The FMP outcome arrays of a strategy file (:class:`~.bundles.Outcomes`, by field).
_OUTCOME_ARRAYS = {"out_ptr": "ptr", "out_layer": "layer", "out_prob": "prob", "out_cost": "cost"}


class _QueryArgs(NamedTuple):
    """What :meth:`Strategy.action` passes to the query kernel, prepared once."""

    mdp: LayeredMDP
    values: np.ndarray
    model: Model
    h0: np.ndarray  # the values with 0 for NaN, C-ordered
    live: np.ndarray
    out: np.ndarray  # the kernel's scratch row of action values
    kernel: Any  # points.query compiled for these arguments' types


@dataclass
class Strategy:
    """A stationary optimal strategy gamma* (Section III-B) with its cost-to-go.

    Attributes
    ----------
    mdp
        The discretised model it was computed on.
    values
        ``(M, N)`` relative cost-to-go (NaN outside the live states).
    meta
        Scenario digest and name, gain and its bounds, convergence figures.
    """

    mdp: LayeredMDP
    values: np.ndarray
    meta: dict[str, Any]

    def __repr__(self) -> str:
        """One line: grid, modes, gain and the solve's status (no arrays)."""
        shape = " x ".join(str(int(n)) for n in self.mdp.shape)
        gain = self.meta.get("gain")
        text = f"{gain:.6g} per stage" if isinstance(gain, (int, float)) else "unknown"
        status = self.meta.get("status", "unknown")
        name = self.meta.get("scenario_name")
        where = f"{name!r}, " if name else ""
        return (
            f"Strategy({where}{shape} cells, {self.mdp.n_modes} modes, gain {text}, "
            f"status {status})"
        )

    @staticmethod
    def from_solution(mdp: LayeredMDP, result: SolveResult, scenario: Any = None) -> Strategy:
        """Wrap a solve; ``scenario`` (a :class:`~cellplan.scenario.Scenario`) sets the digest."""
        meta = {
            "format": FORMAT,
            "version": VERSION,
            "scenario_digest": scenario.digest() if scenario is not None else "",
            "scenario_name": getattr(scenario, "name", ""),
            "gain": result.gain,
            "gain_lower": result.gain_lower,
            "gain_upper": result.gain_upper,
            "span": result.span,
            "sweeps": result.sweeps,
            "full_sweeps": result.full_sweeps,
            "outer_iterations": result.outer_iterations,
            "status": str(result.status),
            "stable": result.stable,
            "policy_changes": result.policy_changes,
            "method": result.method,
            "seconds": result.seconds,
        }
        return Strategy(mdp, result.values, meta)

    # --- queries ---------------------------------------------------------------------------

    @property
    def gain(self) -> float:
        """Long-run expected loss (waiting time) per stage."""
        return float(self.meta["gain"])

    @property
    def modes(self) -> list[Mode]:
        return self.mdp.modes

    @property
    def live(self) -> np.ndarray:
        return self.mdp.live

    def mode_index(self, text: str, phase: int | None = None) -> int:
        """A mode from ``NR``, ``"1,1,1,W"`` (1-based indices in the scenario file's order,
        the paper's notation) or ``"<P1,S1,D1,W>"`` (names, as mode labels print; the X
        modes of failures, Section VI-3, by their labels such as ``<P1,S1,D1,X:R1>``).

        With simultaneous requests (Section VI-2) a mode is named by its label as it
        prints, ``"{P1,S1,D1; P1,S2,D1} + <P1,S1,D2>"`` (the waiting requests, then the
        carried one); spaces, and the order of the waiting requests, do not matter.

        In a time-varying model (Section VI-1) a mode is a layer ``(mode, phase)``: the
        phase follows an ``@`` (``"<P1,S1,D1,W>@3"``, ``"NR@5"``, ``"1,1,1,W@3"``, as the
        labels print) or is given as ``phase`` (the CLI's ``--phase``); without either it
        is 0. A stationary model has phase 0 only. Returns the layer's index.
        """
        text = text.strip()
        named, at, tail = text.rpartition("@")
        if at:
            if not tail.strip().isdigit():
                raise PersistenceError(
                    [Problem("--mode", f"expected a phase number after '@', got {text!r}")]
                )
            if phase is not None and phase != int(tail):
                raise PersistenceError(
                    [Problem("--phase", f"{phase} differs from the phase {int(tail)} of {text!r}")]
                )
            text, phase, field = named.strip(), int(tail), "--mode"
        else:
            field = "--phase"
        mdp = self.mdp
        phase = 0 if phase is None else phase
        if not 0 <= phase < mdp.period:
            if mdp.period == 1:
                message = f"{phase}: this strategy is stationary (no period); its one phase is 0"
            else:
                message = f"{phase} is outside the period (phases 0 to {mdp.period - 1})"
            raise PersistenceError([Problem(field, message)])
        return mdp.layer(self._base_index(text), phase)

    def _base_index(self, text: str) -> int:
        """The index among the modes of one phase (all modes of a stationary model)."""
        modes = [replace(m, phase=-1) for m in self.modes[: self.mdp.modes_per_phase]]
        if text.upper() == "NR":
            return 0
        for i, m in enumerate(modes):
            if m.label == text or m.label == f"<{text}>":
                return i  # every label, the X modes of failures included
        if text.startswith("{"):
            return self._pending_index(text, modes)
        items = [t.strip() for t in text.strip("<>").split(",")]
        if len(items) != 4 or items[3].upper() not in ("W", "C"):
            expected = (
                "NR or a mode label such as '{P1,S1,D1} + <P1,S2,D1>'"
                if any(m.kind == "Q" for m in modes)
                else "NR or 'p,s,d,W|C'"
            )
            raise PersistenceError([Problem("--mode", f"expected {expected}, got {text!r}")])
        # The modes follow the scenario's request list, so first appearance is file order.
        parts = list(dict.fromkeys(m.part for m in modes[1:]))
        sources = list(dict.fromkeys(m.source for m in modes[1:]))
        dests = list(dict.fromkeys(m.destination for m in modes[1:]))
        names = []
        for item, pool in zip(items[:3], (parts, sources, dests), strict=True):
            if item.isdigit() and 1 <= int(item) <= len(pool):
                names.append(pool[int(item) - 1])
            else:
                names.append(item)
        for i, m in enumerate(modes):
            if (m.part, m.source, m.destination, m.kind) == (*names, items[3].upper()):
                return i
        raise self._no_mode(text, modes)

    def _pending_index(self, text: str, modes: list[Mode]) -> int:
        """A Q mode (simultaneous requests) from its label, spaces and order free."""
        found = re.fullmatch(r"\{([^{}<>]*)\}(?:\+<([^{}<>]*)>)?", "".join(text.split()))
        if found is None:
            raise PersistenceError(
                [
                    Problem(
                        "--mode",
                        f"expected a mode label such as '{{P1,S1,D1}} + <P1,S2,D1>', got {text!r}",
                    )
                ]
            )
        key = (tuple(sorted(w for w in found.group(1).split(";") if w)), found.group(2) or "")
        for i, m in enumerate(modes):
            carried = f"{m.part},{m.source},{m.destination}" if m.part else ""
            if m.kind in ("NR", "Q") and (tuple(sorted(m.waiting)), carried) == key:
                return i
        raise self._no_mode(text, modes)

    def _no_mode(self, text: str, modes: list[Mode], shown: int = 12) -> PersistenceError:
        labels = [m.label for m in modes]
        known = ", ".join(labels[:shown])
        if len(labels) > shown:
            known += f", ... ({len(labels)} modes)"
        if self.mdp.period > 1:
            known += f"; at phases 0 to {self.mdp.period - 1}, e.g. {labels[-1]}@1"
        return PersistenceError(
            [Problem("--mode", f"no mode {text!r} in this strategy (modes: {known})")]
        )

    def cell_of(self, q: np.ndarray) -> int:
        """Flat index of the grid cell containing ``q`` (clamped to the grid on bounded axes)."""
        return self._cell_of(checked_state(self.mdp, q)[0])

    def _cell_of(self, q: np.ndarray) -> int:
        """:meth:`cell_of` for a ``q`` already checked (:func:`checked_state`)."""
        mdp = self.mdp
        idx = np.floor((q - mdp.lower) / mdp.spacing).astype(np.int64)
        for j in range(len(idx)):
            idx[j] = (
                idx[j] % mdp.shape[j] if mdp.periodic[j] else min(max(idx[j], 0), mdp.shape[j] - 1)
            )
        return int(np.ravel_multi_index(tuple(idx), tuple(mdp.shape)))

    def action_values(
        self,
        q: np.ndarray,
        mode: int,
        values: np.ndarray | None = None,
        fmp_allowed: bool | None = None,
    ) -> np.ndarray:
        """Right-hand side of (9) per action: ``[FMP, stay, move 0, ...]`` (NaN: unavailable).

        ``values`` replaces the cost-to-go (the baselines use this); ``fmp_allowed`` overrides
        the region test (by default the cell containing ``q`` must allow FMP).
        """
        mdp = self.mdp
        q, mode = checked_state(self.mdp, q, mode)
        if values is not None and np.shape(values) != mdp.live.shape:
            raise ArgumentError(
                [Problem("values", f"expected shape {mdp.live.shape}, got {np.shape(values)}")]
            )
        c = self._cell_of(q)
        tf_here = float(mdp.tf[mode, c])
        if fmp_allowed is None:
            fmp_allowed = bool(np.isfinite(tf_here))
        out = np.empty(2 + mdp.disp.shape[1])
        if values is None:
            h_clean, live = self._h0, mdp.live
        else:
            # Baseline value layers: prepared once per array (queries run every stage).
            cache = self.__dict__.setdefault("_prepared", {})
            key = id(values)
            if key not in cache or cache[key][0] is not values:
                cache[key] = (values, np.nan_to_num(values, nan=0.0), np.isfinite(values))
            _, h_clean, live = cache[key]
        action_values_at(
            q,
            mode,
            h_clean,
            live,
            tf_here if np.isfinite(tf_here) else 0.0,
            fmp_allowed,
            self._model,
            out,
        )
        return out

    @property
    def _model(self) -> Model:
        """The model bundle of the point kernels (built once; queries run every stage)."""
        return self._query_args().model

    @property
    def _h0(self) -> np.ndarray:
        return self._query_args().h0

    def _query_args(self) -> _QueryArgs:
        """What every query passes to the kernels, prepared once per model and values
        (rebuilt if either attribute is replaced)."""
        cached: _QueryArgs | None = self.__dict__.get("_query_cache")
        if cached is None or cached.mdp is not self.mdp or cached.values is not self.values:
            mdp = self.mdp
            model = mdp.kernel_args()
            h0 = np.ascontiguousarray(np.nan_to_num(self.values, nan=0.0))
            live = np.ascontiguousarray(mdp.live)
            out = np.empty(2 + mdp.disp.shape[1])
            q = np.zeros(len(mdp.shape))
            kernel = compiled_for(query, (q, 0, h0, live, False, model, out))
            cached = _QueryArgs(mdp, self.values, model, h0, live, out, kernel)
            self.__dict__["_query_cache"] = cached
        return cached

    def __getstate__(self) -> dict[str, Any]:
        """What pickling keeps: everything but the query cache, whose compiled kernel does
        not pickle and is rebuilt on the first query (:meth:`_query_args`)."""
        return {k: v for k, v in self.__dict__.items() if k != "_query_cache"}

    def attach(self, cell: Any) -> Strategy:
        """Confirm every FMP that :meth:`action` returns with the workcell's exact region test.

        The grid offers FMP wherever a cell's centre lies in the region; at a real
        configuration near the region's edge the exact test
        (:meth:`~cellplan.workcell.Workcell.in_region`) may refuse it. With a workcell
        attached, :meth:`action` never returns an FMP the workcell refuses: it returns the
        best motion instead. Planners attach their workcell; returns ``self``.
        """
        from cellplan.strategies.sim.simulate import region_test

        self.__dict__["_fmp_test"] = region_test(self, cell, self.meta.get("regions", "contact"))
        return self

    def action(self, q: np.ndarray, mode: int, forbid_fmp: bool = False) -> int:
        """The optimal action at ``(q, mode)``: ``FMP`` (-2), ``STAY`` (-1) or a move index;
        with FMP options (simultaneous requests, Section VI-2) option ``j >= 1`` is
        ``-3 - j`` (:func:`~cellplan.strategies.model.stencils.fmp_option` decodes it).

        One compiled evaluation of equation (9), a few microseconds: the compiled code is
        called directly (:func:`~cellplan.strategies.model.points.compiled_for`). With a workcell
        :meth:`attach` ed, an FMP is returned only where the exact region test allows it.
        ``mode`` is a layer index or a mode's name (:meth:`mode_index`: ``"NR"``,
        ``"<P1,S1,D1,W>"`` ...). Raises :class:`~cellplan.errors.ArgumentError` for a ``q``
        that is not a finite configuration of the grid's dimension or an unknown ``mode``, and
        ``ValueError`` when no action is available (``q`` outside the live states).
        """
        q, mode = checked_state(self.mdp, q, mode, finite=self.mdp.opt_ptr is not None)
        args = self._query_args()
        if self.mdp.opt_ptr is not None:
            return self._best_option_or_motion(q, mode, args.out, forbid_fmp)
        u = args.kernel(q, mode, args.h0, args.live, bool(forbid_fmp), args.model, args.out)
        if u == -10:
            raise ArgumentError([Problem("q", "contains NaN or infinite values")])
        if u == -9:
            raise ValueError(
                "no action is available here (the state is outside the strategy's domain)"
            )
        test = self.__dict__.get("_fmp_test")
        if u == FMP and test is not None:
            point = np.asarray(q, dtype=float)[None, :]
            if not test(point, mode)[0]:
                return self.action(q, mode, forbid_fmp=True)
        return int(u)

    def _best_option_or_motion(
        self, q: np.ndarray, mode: int, out: np.ndarray, forbid_fmp: bool = False
    ) -> int:
        """:meth:`action` for a model with FMP options (simultaneous requests, Section VI-2):
        the best of the motions, stay and every FMP option the grid cell of ``q`` allows
        (FMP first on a tie). Returns ``fmp_code(j)`` for option ``j``. With a workcell
        :meth:`attach` ed, each option is confirmed by the exact region test of the
        request it serves (:meth:`~.simulate.RegionTest.option`), as a single FMP is."""
        test = self.__dict__.get("_fmp_test")
        option_test = test.option if test is not None else None
        u, _ = option_or_motion(
            self.mdp, q, mode, self._h0, self.mdp.live, self._model, out, forbid_fmp, option_test
        )
        return u

    def cell_centre(self, q: np.ndarray) -> np.ndarray:
        """Centre of the grid cell containing ``q``."""
        mdp = self.mdp
        idx = np.array(np.unravel_index(self.cell_of(q), tuple(mdp.shape)))
        return np.asarray(mdp.lower + (idx + 0.5) * mdp.spacing)

    def next_configuration(
        self, q: np.ndarray, mode: int, action: int, landing: int | None = None
    ) -> np.ndarray:
        """Where a move (or stay/FMP) takes the robot, equation (5) and its variants.

        With noisy motion (Section VI-4), ``landing`` ``j`` gives the move's ``j``-th
        outcome (:mod:`.noisy`), guarded: where its swept motion from ``q`` is blocked (a
        landing free from the cell centre can be blocked from an off-centre ``q``), the
        robot stops where it is. None gives the commanded move.
        """
        q, mode = checked_state(self.mdp, q, mode)
        q = q.copy()
        mdp = self.mdp
        k = mdp.vcls[mode]
        n_moves = int(mdp.nact[k])
        if not isinstance(action, (int, np.integer)) or not FMP <= action < n_moves:
            raise ArgumentError(
                [Problem("action", f"expected FMP (-2), stay (-1) or a move in [0, {n_moves})"
                         f" of this mode, got {action!r}")]
            )  # fmt: skip
        if action < 0:
            return q
        row = int(action)
        n_landings = len(mdp.noise_prob)
        if landing is not None and n_landings > 1:
            if not isinstance(landing, (int, np.integer)) or not 0 <= landing < n_landings:
                raise ArgumentError(
                    [
                        Problem(
                            "landing", f"expected an outcome in [0, {n_landings}), got {landing!r}"
                        )
                    ]
                )
            row = n_moves + row * n_landings + int(landing)
        dq = np.empty(len(q))
        displacement(q, mdp.disp[k, row], mdp.heading_axis, dq)
        if row != action and not motion_ok(
            q,
            dq,
            mdp.free[k],
            mdp.shape,
            mdp.lower,
            mdp.upper,
            mdp.spacing,
            mdp.periodic,
            np.empty(3 * MAX_DIM, np.int64),
        ):
            return q
        q = q + dq
        wrap(q, mdp.lower, mdp.upper, mdp.periodic)
        return q

    def move_vector(self, q: np.ndarray, mode: int, action: int) -> np.ndarray:
        """The C-space displacement of an action (zero for stay and FMP)."""
        return self.next_configuration(q, mode, action) - np.asarray(q, float)

    # --- persistence -----------------------------------------------------------------------

    def save(self, path: str | Path) -> Path:
        """Write the strategy as a compressed .npz (atomically, no pickle)."""
        mdp = self.mdp
        arrays = {name: np.asarray(getattr(mdp, name)) for name in _ARRAY_FIELDS}
        arrays["values"] = self.values
        # One layout for every model: the identity (one option per mode) without options.
        arrays["opt_ptr"] = np.asarray(mdp.options, np.int64)
        out = mdp.fmp_outcomes()
        for name, attr in _OUTCOME_ARRAYS.items():
            arrays[name] = np.asarray(getattr(out, attr))
        meta = dict(self.meta)
        meta.update(
            heading_axis=mdp.heading_axis,
            stage_time=mdp.stage_time,
            arrival=mdp.arrival,
            modes=[_mode_fields(m) for m in mdp.modes],
            labels=[list(lab) for lab in mdp.labels],
            period=mdp.period,
            phases=[m.phase for m in mdp.modes],
            belts={name: [float(v) for v in vel] for name, vel in mdp.belts.items()},
            grid={
                "shape": mdp.shape.tolist(),
                "lower": mdp.lower.tolist(),
                "upper": mdp.upper.tolist(),
                "periodic": mdp.periodic.tolist(),
            },
        )
        arrays["meta"] = np.array(json.dumps(meta))
        path = Path(path)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]
        return path

    @staticmethod
    def load(path: str | Path, scenario: Any = None) -> Strategy:
        """Read a strategy file; with ``scenario``, refuse one made for a different scenario.

        Every array is checked against the declared format before use
        (:func:`cellplan.strategies.policy.fileformat.read_strategy`: dtypes, shapes, ranges of
        every index, consistency of the tables, the metadata schema); a file that fails
        raises :class:`~cellplan.errors.PersistenceError` naming the file and the field.
        """
        from cellplan.strategies.policy.fileformat import read_strategy

        meta, arrays = read_strategy(path, scenario)
        modes = [
            replace(mode_of(m), phase=p) for m, p in zip(meta["modes"], meta["phases"], strict=True)
        ]
        kw = {name: arrays[name] for name in _ARRAY_FIELDS}
        opt_ptr = arrays["opt_ptr"]
        if np.array_equal(opt_ptr, np.arange(len(modes) + 1)):
            opt_ptr = None  # one option per mode: the model is as it was built (is_simple)
        mdp = LayeredMDP(
            modes=modes,
            labels=[tuple(lab) for lab in meta["labels"]],
            heading_axis=int(meta["heading_axis"]),
            stage_time=float(meta["stage_time"]),
            arrival=float(meta["arrival"]),
            outcomes=Outcomes(**{attr: arrays[name] for name, attr in _OUTCOME_ARRAYS.items()}),
            opt_ptr=opt_ptr,
            period=int(meta["period"]),
            belts={name: (float(v[0]), float(v[1])) for name, v in meta["belts"].items()},
            **kw,
        )
        # Optional fields absent from older files stay absent (the defaults apply).
        meta = {k: v for k, v in meta.items() if v is not None}
        return Strategy(mdp, arrays["values"], meta)


def _mode_fields(mode: Mode) -> list[str]:
    """A mode as the strategy file stores it: kind, part, source, destination, and for X
    modes the reject region and what follows the rejection, for Q modes (simultaneous
    requests, Section VI-2) the waiting requests."""
    fields = [mode.kind, mode.part, mode.source, mode.destination]
    if mode.kind == "X":
        return [*fields, mode.reject, mode.after]
    return [*fields, *mode.waiting] if mode.kind == "Q" else fields


def option_or_motion(
    mdp: LayeredMDP,
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
    (``(points, mode, j) -> bool array``, :meth:`.simulate.RegionTest.option`), where the
    exact region test of the
    request it serves passes at ``q`` (its source for a pick, its destination with the
    part for a delivery): the same rule as the single FMP of the other models, so a
    delivery the workcell refuses is never chosen. Raises ``ValueError`` when no action
    is available.
    """
    action_values_at(q, mode, h, live, 0.0, False, model, out)
    o0, o1 = int(mdp.options[mode]), int(mdp.options[mode + 1])
    allowed = np.full(o1 - o0, not forbid_fmp, np.bool_)
    if option_test is not None and not forbid_fmp:
        g = model.grid
        c = int(cell_containing(q, g.shape, g.lower, g.spacing, g.periodic))
        point = np.asarray(q, dtype=float)[None, :]
        for j in np.flatnonzero(np.isfinite(mdp.tf[o0:o1, c])):
            allowed[j] = bool(option_test(point, mode, int(j))[0])
    j, fval = fmp_options_at(q, mode, h, live, allowed, model)
    motions = out[1:]
    best_motion = float(np.nanmin(motions)) if not np.all(np.isnan(motions)) else np.inf
    if j >= 0 and not (best_motion < fval):
        return int(fmp_code(j)), float(fval)
    if np.all(np.isnan(motions)):
        raise ValueError("no action is available here (the state is outside the strategy's domain)")
    i = int(np.nanargmin(motions))
    return (STAY if i == 0 else i - 1), best_motion


def best_action(vals: np.ndarray) -> int:
    """Index convention of :meth:`Strategy.action` from an ``action_values`` vector."""
    if np.all(np.isnan(vals)):
        raise ValueError("no action is available here (the state is outside the strategy's domain)")
    i = int(np.nanargmin(vals))
    return FMP if i == 0 else STAY if i == 1 else i - 2


def solve_scenario(
    scenario: Any,
    cell: Any,
    *,
    cells: list[int] | None = None,
    method: str | None = None,
    progress: Any = None,
    snap: bool = True,
    start: Any = None,
) -> tuple[Strategy, SolveResult]:
    """Build the model of a scenario's ``strategy:`` section, solve it, wrap the result.

    The solver settings come from ``strategy.solver`` (``method`` overrides its method).
    ``snap=False`` removes the moves whose interpolation snaps the robot sideways
    (:func:`~cellplan.strategies.model.transitions.forbid_snapping`). With ``start``, a start
    outside the strategy's domain is refused before solving
    (:func:`~cellplan.strategies.model.mdp.start_problems`).
    """
    from cellplan.strategies.model.mdp import build_model
    from cellplan.strategies.model.transitions import forbid_snapping
    from cellplan.strategies.solve.solver import method_problem, solve

    sec = scenario.strategy
    mdp = build_model(scenario, cell, cells, start=start)
    if not snap:
        mdp = forbid_snapping(mdp)
    problem = method_problem(mdp, method or sec.solver.method, sec.solver.damping)
    if problem is not None:
        if method is not None:
            raise ArgumentError([Problem("method", problem)])
        raise ScenarioError([Problem("strategy.solver.method", problem)])
    result = solve(
        mdp,
        method or sec.solver.method,
        sec.solver.tolerance,
        sec.solver.max_sweeps,
        sec.solver.damping,
        progress,
    )
    strategy = Strategy.from_solution(mdp, result, scenario)
    strategy.meta["regions"] = sec.regions
    strategy.meta["transitions"] = "snap" if snap else "no-snap"
    if sec.home is None:
        home = cell.robot.start.tolist()
    else:
        home = units.config_from_file(cell.robot.axis_names, sec.home).tolist()
    strategy.meta["home"] = [float(v) for v in home]
    strategy.meta["start"] = [float(v) for v in cell.robot.start]
    return strategy, result


def checked_state(
    mdp: LayeredMDP, q: Any, mode: Any = None, finite: bool = True
) -> tuple[np.ndarray, int]:
    """``q`` as a float ``(d,)`` array and ``mode`` as a layer index of ``mdp`` (0 when
    None), or an :class:`~cellplan.errors.ArgumentError` naming what is wrong: the point
    kernels index the model's arrays with both unchecked.

    ``finite=False`` leaves the test for NaN and infinities to the caller (the query kernel
    does it for a fraction of what numpy takes, and a query runs every stage).
    """
    d = len(mdp.shape)
    try:
        arr = np.ascontiguousarray(q, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError([Problem("q", "expected an array of numbers")]) from None
    if arr.shape != (d,):
        raise ArgumentError(
            [Problem("q", f"expected a configuration of shape ({d},), got {np.shape(q)}")]
        )
    if finite and not np.isfinite(arr).all():
        raise ArgumentError([Problem("q", "contains NaN or infinite values")])
    if mode is None:
        return arr, 0
    if isinstance(mode, str):
        # A mode by name, as Strategy.mode_index reads it ("NR", "<P1,S1,D1,W>",
        # "1,1,1,W", a Q label, "...@phase"); its error names the API's argument.
        try:
            return arr, Strategy(mdp, np.empty(0), {}).mode_index(mode)
        except PersistenceError as exc:
            raise ArgumentError([Problem("mode", p.message) for p in exc.problems]) from None
    try:
        m = operator.index(mode)
    except TypeError:
        m = -1
    if not 0 <= m < mdp.n_modes or isinstance(mode, bool):
        raise ArgumentError(
            [
                Problem(
                    "mode",
                    f"expected a layer index in [0, {mdp.n_modes}), got {mode!r} (or a mode "
                    "name such as 'NR')",
                )
            ]
        )
    return arr, m

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

import operator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from cellplan import units
from cellplan.errors import ArgumentError, PersistenceError, Problem, ScenarioError
from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.mdp import LayeredMDP, Mode, build_model
from cellplan.strategies.model.motion import motion_ok
from cellplan.strategies.model.points import action_values_at, compiled_for, queries, query
from cellplan.strategies.model.spec import compiled
from cellplan.strategies.model.stencils import (
    MAX_DIM,
    NO_ACTION_CODE,
    NOT_FINITE_CODE,
    displacement,
    wrap,
)
from cellplan.strategies.model.transitions import forbid_snapping
from cellplan.strategies.policy.decisions import (
    FMP,
    OUTSIDE,
    STAY,
    Action,
    Actions,
    actions_of,
    option_or_motion,
    typed,
)
from cellplan.strategies.policy.fileformat import FORMAT, VERSION
from cellplan.strategies.policy.modenames import mode_index
from cellplan.strategies.policy.persist import read_model, write_strategy
from cellplan.strategies.policy.regions import region_test
from cellplan.strategies.solve.solver import SolveResult, method_problem, solve


class _QueryArgs(NamedTuple):
    """What :meth:`Strategy.action` passes to the query kernel, prepared once."""

    mdp: LayeredMDP
    values: np.ndarray
    model: Model
    h0: np.ndarray  # the values with 0 for NaN, C-ordered
    live: np.ndarray
    out: np.ndarray  # the kernel's scratch row of action values
    kernel: Any  # points.query compiled for these arguments' types
    batch: Any  # points.queries compiled likewise, for C-ordered (n, d) batches


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
        """A layer's index from a mode's name (:func:`~.modenames.mode_index`: ``NR``,
        ``"1,1,1,W"``, ``"<P1,S1,D1,W>"``, a Q or X label, ``"...@phase"`` ...)."""
        return mode_index(self.mdp, text, phase)

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

    def in_domain(self, q: np.ndarray, mode: int | str = 0) -> bool:
        """Whether ``(q, mode)`` is in the strategy's domain: the grid cell of ``q`` is
        live in the layer (Section IV: the states from which every request can be served).

        The one rule of the domain (issue 35): :meth:`action` answers no action outside
        it, and ``cellplan simulate`` refuses a start outside it, in every model.
        """
        q, m = checked_state(self.mdp, q, mode)
        return bool(self.mdp.live[m, self._cell_of(q)])

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
            rows = np.zeros((1, len(q)))
            codes = np.zeros(1, np.int64)
            batch = compiled_for(queries, (rows, 0, h0, live, False, model, codes, rows))
            cached = _QueryArgs(mdp, self.values, model, h0, live, out, kernel, batch)
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
        self.__dict__["_fmp_test"] = region_test(self, cell, self.meta.get("regions", "contact"))
        return self

    def action(self, q: Any, mode: int | str = 0) -> Action | Actions:
        """What the strategy does at ``(q, mode)``: one step of equation (9) (Section IV-B).

        ``q`` is one configuration ``(dim,)``, answered by an :class:`~.decisions.Action`,
        or ``n`` of them ``(n, dim)``, answered by an :class:`~.decisions.Actions` bundle
        (like the workcell's queries); ``mode`` is a layer index or a mode's name
        (:meth:`mode_index`: ``"NR"``, ``"<P1,S1,D1,W>"`` ...), the same for every row.
        An action says what to do: ``kind`` ``move`` (with the move's index and its C-space
        ``step``), ``stay``, ``pick`` or ``drop`` (with the ``region``, and with
        simultaneous requests the ``option``: which request a pick serves); ``code`` is the
        integer code of :meth:`action_code`.

        With a workcell :meth:`attach` ed, a pick or drop is returned only where the exact
        region test allows it. Raises :class:`~cellplan.errors.ArgumentError` for a ``q``
        that is not finite configurations of the grid's dimension or an unknown ``mode``,
        and ``ValueError`` when a configuration is outside the strategy's domain
        (:meth:`in_domain`; the simulator refuses such a start by the same rule).
        """
        mdp = self.mdp
        shape = q.shape if isinstance(q, np.ndarray) else np.shape(q)  # an array: no copy
        if len(shape) == 2 and shape[1] == len(mdp.shape) and shape[0] > 0:
            return self._actions(q, mode)
        # The query kernel tests q for NaN and infinities (as action_code does).
        row, m = checked_state(mdp, q, mode, finite=mdp.has_options)
        code = self._code(row, m, False)
        if code < 0:
            return typed(code, mdp.modes[m], row)  # the step is zero: row gives its length
        disp = mdp.disp[mdp.vcls[m], code]
        if mdp.heading_axis >= 0:  # robot-frame moves (problem 3): the step turns with q
            step = np.empty(len(row))
            displacement(row, disp, mdp.heading_axis, step)
            return typed(code, mdp.modes[m], step)
        return typed(code, mdp.modes[m], disp)

    def _actions(self, q: Any, mode: int | str) -> Actions:
        """:meth:`action` for a batch of configurations ``(n, dim)``: one compiled loop over
        the rows (:func:`~cellplan.strategies.model.points.queries`), the FMPs confirmed by
        the attached region test in one call, the answers assembled as arrays."""
        mdp = self.mdp
        try:
            arr = np.ascontiguousarray(q, dtype=float)
        except (TypeError, ValueError):
            raise ArgumentError([Problem("q", "expected an array of numbers")]) from None
        _, m = checked_state(mdp, arr[0], mode, finite=False)
        if not np.isfinite(arr).all():
            raise ArgumentError([Problem("q", "contains NaN or infinite values")])
        if mdp.has_options:  # FMP options (Section VI-2): one row at a time
            rows = [self._code(row, m, False) for row in arr]
            return actions_of(np.array(rows, np.int64), np.zeros(arr.shape), mdp.modes[m])
        codes, steps = self._codes(arr, m, False)
        test = self.__dict__.get("_fmp_test")
        fmp = np.flatnonzero(codes == FMP)
        if test is not None and len(fmp):
            refused = fmp[~np.asarray(test(arr[fmp], m), dtype=bool)]
            if len(refused):
                codes[refused], steps[refused] = self._codes(arr[refused], m, True)
        if (codes == NO_ACTION_CODE).any():
            raise ValueError(OUTSIDE)
        return actions_of(codes, steps, mdp.modes[m])

    def _codes(self, arr: np.ndarray, m: int, forbid_fmp: bool) -> tuple[np.ndarray, np.ndarray]:
        """The kernel's codes and move steps of the rows of ``arr`` (checked) in layer ``m``."""
        args = self._query_args()
        codes = np.empty(len(arr), np.int64)
        steps = np.empty(arr.shape)
        args.batch(arr, m, args.h0, args.live, forbid_fmp, args.model, codes, steps)
        return codes, steps

    def action_code(self, q: np.ndarray, mode: int | str, forbid_fmp: bool = False) -> int:
        """:meth:`action` at one configuration as its integer code: ``FMP`` (-2), ``STAY``
        (-1) or a move index; with FMP options (simultaneous requests, Section VI-2)
        option ``j >= 1`` is ``-3 - j`` (:func:`~.decisions.fmp_option_of` decodes it).

        One compiled evaluation of equation (9), a few microseconds: the compiled code is
        called directly (:func:`~cellplan.strategies.model.points.compiled_for`); the
        simulators and the experiments step through it. ``forbid_fmp`` leaves the FMP out.
        Raises as :meth:`action`.
        """
        q, mode = checked_state(self.mdp, q, mode, finite=self.mdp.has_options)
        return self._code(q, mode, forbid_fmp)

    def _code(self, q: np.ndarray, mode: int, forbid_fmp: bool) -> int:
        """:meth:`action_code` at a state checked by :func:`checked_state` (finiteness is
        the kernel's test)."""
        args = self._query_args()
        if self.mdp.has_options:
            if not self.mdp.live[mode, self._cell_of(q)]:
                raise ValueError(OUTSIDE)  # the query kernel's rule (in_domain)
            return self._best_option_or_motion(q, mode, args.out, forbid_fmp)
        u = args.kernel(q, mode, args.h0, args.live, bool(forbid_fmp), args.model, args.out)
        if u == NOT_FINITE_CODE:
            raise ArgumentError([Problem("q", "contains NaN or infinite values")])
        if u == NO_ACTION_CODE:
            raise ValueError(OUTSIDE)
        test = self.__dict__.get("_fmp_test")
        if u == FMP and test is not None:
            point = np.asarray(q, dtype=float)[None, :]
            if not test(point, mode)[0]:
                return self._code(q, mode, True)
        return int(u)

    def _best_option_or_motion(
        self, q: np.ndarray, mode: int, out: np.ndarray, forbid_fmp: bool = False
    ) -> int:
        """:meth:`action` for a model with FMP options (simultaneous requests, Section VI-2):
        the best of the motions, stay and every FMP option the grid cell of ``q`` allows
        (FMP first on a tie). Returns ``fmp_code(j)`` for option ``j``. With a workcell
        :meth:`attach` ed, each option is confirmed by the exact region test of the
        request it serves (:meth:`~.regions.RegionTest.option`), as a single FMP is."""
        test = self.__dict__.get("_fmp_test")
        option_test = test.option if test is not None else None
        u, _ = option_or_motion(
            q, mode, self._h0, self.mdp.live, self._model, out, forbid_fmp, option_test
        )
        return u

    def cell_centre(self, q: np.ndarray) -> np.ndarray:
        """Centre of the grid cell containing ``q``."""
        mdp = self.mdp
        idx = np.array(np.unravel_index(self.cell_of(q), tuple(mdp.shape)))
        return np.asarray(mdp.lower + (idx + 0.5) * mdp.spacing)

    def next_configuration(
        self, q: np.ndarray, mode: int, action: int | Action, landing: int | None = None
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
        if isinstance(action, Action):
            action = action.code if action.kind == "move" else STAY  # a pick or drop stays
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
            q, dq, mdp.free[k], mdp.grid(), np.empty(3 * MAX_DIM, np.int64)
        ):
            return q
        q = q + dq
        wrap(q, mdp.lower, mdp.upper, mdp.periodic)
        return q

    def move_vector(self, q: np.ndarray, mode: int, action: int | Action) -> np.ndarray:
        """The C-space displacement of an action (zero for stay and FMP)."""
        return self.next_configuration(q, mode, action) - np.asarray(q, float)

    def save(self, path: str | Path) -> Path:
        """Write the strategy as a compressed .npz (atomically, no pickle;
        :func:`~.persist.write_strategy`)."""
        return write_strategy(path, self.mdp, self.values, self.meta)

    @staticmethod
    def load(path: str | Path, scenario: Any = None) -> Strategy:
        """Read a strategy file; with ``scenario``, refuse one made for a different scenario.

        Every array is checked against the declared format before use
        (:func:`cellplan.strategies.policy.fileformat.read_strategy`: dtypes, shapes, ranges of
        every index, consistency of the tables, the metadata schema); a file that fails
        raises :class:`~cellplan.errors.PersistenceError` naming the file and the field.
        """
        return Strategy(*read_model(path, scenario))


def solve_scenario(
    problem: Any,
    cell: Any,
    *,
    cells: list[int] | None = None,
    method: str | None = None,
    progress: Any = None,
    snap: bool = True,
    start: Any = None,
    solver: Any = None,
) -> tuple[Strategy, SolveResult]:
    """Build the model of a scenario's ``strategy:`` section, solve it, wrap the result.

    ``problem`` is the scenario or its compiled section (:func:`~.spec.compiled`; the
    planner compiles it once for the memory check and the build).

    The solver settings are ``solver`` (a :class:`~cellplan.strategies.section.SolverSpec`,
    the planner's options resolved against the scenario), else ``strategy.solver``;
    ``method`` overrides the method (and a refused one is blamed on the option).
    ``snap=False`` removes the moves whose interpolation snaps the robot sideways
    (:func:`~cellplan.strategies.model.transitions.forbid_snapping`). With ``start``, a start
    outside the strategy's domain is refused before solving
    (:func:`~cellplan.strategies.model.mdp.start_problems`).
    """
    spec = compiled(problem)
    scenario, sec = spec.scenario, spec.section
    settings = solver if solver is not None else sec.solver
    mdp = build_model(spec, cell, cells, start=start)
    if not snap:
        mdp = forbid_snapping(mdp)
    problem = method_problem(mdp, method or settings.method, settings.damping)
    if problem is not None:
        if method is not None:
            raise ArgumentError([Problem("method", problem)])
        raise ScenarioError([Problem("strategy.solver.method", problem)])
    result = solve(
        mdp,
        method or settings.method,
        settings.tolerance,
        settings.max_sweeps,
        settings.damping,
        progress,
    )
    strategy = Strategy.from_solution(mdp, result, scenario)
    strategy.meta["regions"] = sec.regions
    # What a solve derived from this one solves to (pending_sim.single_request_strategy).
    strategy.meta["tolerance"] = float(settings.tolerance)
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
            return arr, mode_index(mdp, mode)
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

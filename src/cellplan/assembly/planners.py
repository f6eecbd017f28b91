"""The assembly planners (Whitcomb & Koditschek 1991): each algorithm as a common :class:`Result`.

``assembly.gradient`` (Section 4.1), ``assembly.sequential`` (Section 4.2) and
``assembly.control`` (Section 3.4), registered in :mod:`cellplan.assembly.plugin` with
the option models of :mod:`cellplan.assembly.options`. Each ``plan_*`` function builds
the :class:`~cellplan.assembly.problems.DiscProblem` of the scenario's ``discs:``
section, resolves the options (``None``: the section's value), runs the algorithm and
returns a :class:`~cellplan.core.Result`:

* ``status`` and ``message`` from the algorithm (solved; stuck, with the kind of
  critical point and the k it was at; budget exhausted, with the budget);
* ``stats``: the path-length ratio (Section 5.1; footnote 6 for the sequential
  algorithm), minimum clearance, escapes, switches, steps, wall time;
* ``solution``: the run itself (:class:`~cellplan.assembly.flows.FlowResult`,
  :class:`~cellplan.assembly.sequential.SequentialResult` or
  :class:`~cellplan.assembly.control.ControlResult`), its ``problem`` attribute the
  :class:`DiscProblem`;
* ``trajectory``: the disc centres (columns ``disc1.x, disc1.y, ...``, workcell units)
  against the path length in R^2n (gradient, sequential: ``time_unit="path"``) or the
  simulated time (control: ``"s"``); mode ``all discs`` or ``disc i`` (the moving disc,
  1-based like the columns); events ``escape`` (k lowered, detail ``k=...``) and, for
  the sequential algorithm, ``grasp`` and ``switch``.

The normalised system's own time (Section 3.3) is not used as the time axis: near the
goal ``grad phi`` underflows and that time reaches 1e43-1e170 on the bundled problems;
its log10 is the ``log10_flow_time`` statistic.

:func:`run_gradient`, :func:`run_sequential` and :func:`run_control` do the same on a
:class:`DiscProblem` with every parameter given (benchmarks, tests).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.options import (
    SEQUENTIAL_TOLERANCE,
    ControlOptions,
    GradientOptions,
    SequentialOptions,
)
from cellplan.core import Progress, Result, Stat, Status
from cellplan.trajectory import Event, Trajectory

if TYPE_CHECKING:
    from cellplan.assembly.control import ControlResult
    from cellplan.assembly.flows import FlowResult, Stage
    from cellplan.assembly.problems import DiscProblem
    from cellplan.assembly.section import DiscsSection
    from cellplan.assembly.sequential import SequentialResult
    from cellplan.setup import Setup

Array = NDArray[np.float64]

#: Default number of k-halvings after a stuck stage, read from the options model (the one
#: source; 6 halvings take k = 1024 down to 16 at most).
ESCAPES: int = GradientOptions.model_fields["escapes"].default
#: Default escape of the gradient planner, read from the options model (the one source).
ESCAPE: str = GradientOptions.model_fields["escape"].default
#: Default integrator of the gradient planner (the options model is the one source).
INTEGRATOR: str = GradientOptions.model_fields["integrator"].default


# --- the planners' run functions (registered in plugin.py) -----------------------------------


def _problem(setup: Setup) -> tuple[DiscProblem, DiscsSection]:
    from cellplan.assembly.problems import problem_from_section

    section = setup.section("discs")
    return problem_from_section(section, setup.scenario), section


def _given(value: float | None, default: float) -> float:
    return float(default if value is None else value)


def _k(value: float | None, section: DiscsSection, problem: DiscProblem) -> float:
    """The k of a run: the option, else the section's ``k``, else the default-k rule
    (:func:`layout.rule_k`, the one place the rule lives)."""
    from cellplan.assembly.layout import rule_k

    if value is not None:
        return float(value)
    if section.k is not None:
        return float(section.k)
    return rule_k(problem.radii, problem.workspace)


def plan_gradient(setup: Setup, options: GradientOptions, progress: Progress | None) -> Result:
    """``assembly.gradient``: the gradient algorithm (Section 4.1) on the scenario's discs."""
    problem, section = _problem(setup)
    k = _k(options.k, section, problem)
    if progress is not None:
        progress(0.0, None, f"gradient flow, {problem.n} discs, k={k:g}")
    result = run_gradient(
        problem,
        k,
        _given(options.epsilon, section.epsilon),
        _given(options.tolerance, section.tolerance),
        options.escapes,
        escape=options.escape,
        integrator=options.integrator,
        step_max=options.step_max,
        scenario=setup.name,
    )
    if progress is not None:
        progress(1.0, 1.0, result.status.value)
    return result


def plan_sequential(setup: Setup, options: SequentialOptions, progress: Progress | None) -> Result:
    """``assembly.sequential``: one disc at a time (Section 4.2), rule ``paper`` or ``place``."""
    problem, section = _problem(setup)
    k = _k(options.k, section, problem)
    tol = _given(options.tolerance, max(section.tolerance, SEQUENTIAL_TOLERANCE))
    if progress is not None:
        progress(0.0, None, f"sequential ({options.rule}), {problem.n} discs, k={k:g}")
    result = run_sequential(
        problem,
        k,
        options.rule,
        _given(options.epsilon, section.epsilon),
        tol,
        options.escapes,
        scenario=setup.name,
        finish=options.finish,
    )
    if progress is not None:
        progress(1.0, 1.0, result.status.value)
    return result


def plan_control(setup: Setup, options: ControlOptions, progress: Progress | None) -> Result:
    """``assembly.control``: the double-integrator controller (Section 3.4) on the discs."""
    problem, section = _problem(setup)
    k = _k(options.k, section, problem)
    if progress is not None:
        progress(0.0, None, f"controlled assembly, {problem.n} discs, k={k:g}")
    result = run_control(
        problem, k, _given(options.tolerance, section.tolerance), scenario=setup.name
    )
    if progress is not None:
        progress(1.0, 1.0, result.status.value)
    return result


# --- the algorithms on a DiscProblem ---------------------------------------------------------


def run_gradient(
    problem: DiscProblem,
    k: float,
    epsilon: float,
    tol: float,
    escapes: int = ESCAPES,
    *,
    escape: str = ESCAPE,
    integrator: str = INTEGRATOR,
    step_max: float | None = None,
    scenario: str = "",
) -> Result:
    """The gradient assembly algorithm (Section 4.1); ratio in the R^2n norm (Section 5.1).

    A run stuck at a spurious minimum is finished by the place rule (``escape="place"``)
    or continues at k/2, k/4, ... (``"halve-k"``, at most ``escapes`` times; Section
    3.2); ``escapes=0``: the flow at k alone (see :func:`flows.gradient_flow`). The
    statistics say so: ``solved_at_k`` (1.0 when the flow at the given k alone reached
    the goal), ``escapes`` (escape stages taken), ``k_final``, ``placed`` (grasps of
    the place rule, 0 without it); ``ratio`` is over the whole path, every stage
    included. ``integrator``: ``implicit``, ``rk4`` or ``auto``
    (:func:`flows.choose_method`); the statistic ``rk4`` says which ran (1.0: RK4).
    ``step_max``: the implicit step's largest step in R^2n (``None``: the rule
    :func:`flows.step_max_rule`; statistic ``step_max``).
    """
    from cellplan.assembly.flows import FlowSettings, choose_method, gradient_flow, step_max_rule

    t0 = time.perf_counter()
    method = choose_method(problem) if integrator == "auto" else integrator
    step = step_max_rule(problem.n) if step_max is None else float(step_max)
    res = gradient_flow(
        problem,
        k,
        epsilon,
        tol,
        settings=FlowSettings(method=method, step_max=step),  # type: ignore[arg-type]
        escapes=escapes,
        escape=escape,  # type: ignore[arg-type]
    )
    straight = float(np.linalg.norm(problem.start - problem.goal))
    first = res.stages[0]
    stats: dict[str, Stat] = {
        "ratio": res.length() / straight if straight > 0 else 1.0,
        "k": float(k),
        "rk4": method == "rk4",
        "step_max": step,
        "solved_at_k": first.status is Status.SOLVED,
        "escapes": int(res.escapes),
        "k_final": float(res.stages[-1].k),
        "placed": int(res.placement.switches if res.placement is not None else 0),
        "length": res.length(),
        "min_clearance": _exact_clearance(problem, res.path),
        "min_clearance_vertices": res.min_clearance,
        "steps": int(res.steps),
        "evaluations": int(res.evaluations),
        "log10_flow_time": float(res.log_time / np.log(10.0)) if np.isfinite(res.log_time) else 0.0,
        "stuck_error": float(np.linalg.norm(_stuck_point(res) - problem.goal))
        if res.escapes
        else 0.0,
        "final_error": float(np.linalg.norm(res.end - problem.goal)),
        "wall_s": time.perf_counter() - t0,
    }
    meta = _meta(scenario, problem, k, epsilon, tol)
    if res.placement is None:
        events = _escape_events(res.stages, _stage_starts(res.stages))
        traj = _trajectory(
            res.path,
            _arc_length(res.path),
            "path",
            np.zeros(len(res.path), dtype=np.int64),
            ("all discs",),
            events,
            meta,
        )
        message = _flow_message(res.status, res.reason, res.stages, stats, "steps")
    else:
        traj = _placed_trajectory(res.path, res.steps, res.placement, meta)
        message = _place_message(res.status, res.stages, stats)
    return Result(res.status, message, stats=stats, solution=res, trajectory=traj)


def run_sequential(
    problem: DiscProblem,
    k: float,
    rule: str,
    epsilon: float,
    tol: float = SEQUENTIAL_TOLERANCE,
    escapes: int = ESCAPES,
    *,
    scenario: str = "",
    finish: str = "none",
) -> Result:
    """Sequential assembly (Section 4.2); ratio over summed disc distances (footnote 6).

    Rule ``paper``: a stuck T map (every disc blocked away from the goal, or no progress
    over 2 n switches) continues at k/2, k/4, ... (at most ``escapes`` times; Section
    3.2, see :func:`sequential.sequential_assembly`); ``solved_at_k``, ``escapes`` and
    ``k_final`` say so, as for the gradient planner, and ``switches`` counts every grasp
    of every stage. The ``place`` rule does not lower k.

    ``finish="place"`` (the planner's default; issue 35): a run that stopped short is
    finished by the place rule (:func:`sequential.finish_with_place`: from where it
    stopped, else after spreading the discs one at a time), as the gradient planner's
    escape; ``placed`` counts the finish's grasps (0 without it) and
    ``switches_per_disc_paper`` (paper rule) the T map's own. ``finish="none"``: the
    rule alone.
    """
    from cellplan.assembly.sequential import finish_with_place, sequential_assembly

    t0 = time.perf_counter()
    res = sequential_assembly(
        problem,
        k,
        rule,  # type: ignore[arg-type]
        epsilon=epsilon,
        tol=tol,
        escapes=escapes if rule == "paper" else 0,
    )
    if finish == "place" and res.status is not Status.SOLVED:
        res = finish_with_place(problem, res, k, epsilon=epsilon)
    straight = float(np.sum(np.linalg.norm(problem.start - problem.goal, axis=1)))
    stats: dict[str, Stat] = {
        "ratio": float(np.sum(res.disc_lengths())) / straight if straight > 0 else 1.0,
        "switches": int(res.switches),
        "switches_per_disc": res.switches / problem.n,
        "switches_per_disc_within_0.1": res.switches_within(problem.goal, 0.1) / problem.n,
        "solved_at_k": bool(res.solved_at_k),
        "escapes": int(res.escapes),
        "k_final": float(res.k_final),
        "min_clearance": _exact_clearance(problem, res.path),
        "min_clearance_vertices": res.min_clearance,
        "evaluations": int(res.evaluations),
        "final_error": float(np.linalg.norm(res.path[-1] - problem.goal)),
        "wall_s": time.perf_counter() - t0,
    }
    stats["placed"] = int(res.placed)
    if rule == "paper":
        stats["switches_per_disc_paper"] = (res.switches - res.placed) / problem.n
    traj = _sequential_trajectory(res, _meta(scenario, problem, k, epsilon, tol, rule=rule))
    if res.finished:
        message = _finish_message(res, stats, rule)
    else:
        message = _flow_message(res.status, res.reason, res.stages, stats, "switches")
    return Result(res.status, message, stats=stats, solution=res, trajectory=traj)


def run_control(problem: DiscProblem, k: float, tol: float, *, scenario: str = "") -> Result:
    """The double-integrator controller of Section 3.4, simulated to rest at the goal."""
    from cellplan.assembly.control import simulate_control

    t0 = time.perf_counter()
    res = simulate_control(problem, k, tol=tol)
    straight = float(np.linalg.norm(problem.start - problem.goal))
    stats: dict[str, Stat] = {
        "ratio": res.length() / straight if straight > 0 else 1.0,
        "min_clearance": _exact_clearance(problem, res.path),
        "min_clearance_vertices": res.min_clearance,
        "steps": int(res.steps),
        "settling_time": float(res.times[-1]),
        "wall_s": time.perf_counter() - t0,
    }
    traj = _trajectory(
        res.path,
        res.times,
        "s",
        np.zeros(len(res.path), dtype=np.int64),
        ("all discs",),
        (),
        _meta(scenario, problem, k, None, tol),
    )
    return Result(
        res.status, _control_message(res, stats), stats=stats, solution=res, trajectory=traj
    )


def _exact_clearance(problem: DiscProblem, path: Array) -> float:
    """The statistic ``min_clearance``: the smallest gap along the path taken straight
    between its rows, exact over every segment (:func:`navigation.path_min_clearance`;
    issue 35). ``min_clearance_vertices`` is the run's own figure, taken at the rows
    (and, for the place rule's straight moves, exactly along them)."""
    from cellplan.assembly.navigation import path_min_clearance

    return path_min_clearance(path, problem.radii, problem.workspace)


# --- messages --------------------------------------------------------------------------------


def _flow_message(
    status: Status,
    reason: str,
    stages: Sequence[Stage],
    stats: Mapping[str, Stat],
    unit: str,
) -> str:
    """One line: what the run achieved, or where and why it stopped short of the goal."""
    k0, k_end = stages[0].k, stages[-1].k
    lowered = len(stages) - 1
    times = "once" if lowered == 1 else f"{lowered} times"
    quality = f"ratio {stats['ratio']:.3f}, min clearance {stats['min_clearance']:.3g}"
    if status is Status.SOLVED:
        if lowered:
            return (
                f"assembled: {quality}; k lowered {times} from {k0:g} to {k_end:g} after the "
                f"run was stuck {_where(stages[0].reason, k0)}"
            )
        return f"assembled at k={k0:g}: {quality}"
    if status is Status.STUCK and lowered:
        head = (
            f"stuck {_where(stages[0].reason, k0)}; lowered k {times} to {k_end:g}, "
            f"still stuck {_where(reason, k_end)}"
        )
    elif status is Status.STUCK:
        head = f"stuck {_where(reason, k0)}"
    else:
        head = f"budget spent at k={k_end:g} ({reason})"
        if lowered:
            head += f", k lowered {times} from {k0:g}"
    return f"{head}; {stats['final_error']:.3g} from the goal after {int(stats[unit])} {unit}"


def _stuck_point(res: FlowResult) -> Array:
    """Where the last flow stage stopped before an escape."""
    if res.stuck_at is not None:
        return res.stuck_at
    return res.path[sum(s.steps for s in res.stages[:-1])]


def _place_message(status: Status, stages: Sequence[Stage], stats: Mapping[str, Stat]) -> str:
    """One line for a flow finished (or not) by the place rule (from the stuck point, or
    after that failed, from the start)."""
    flow, place = stages[0], stages[1]
    quality = f"ratio {stats['ratio']:.3f}, min clearance {stats['min_clearance']:.3g}"
    why = (
        f"the flow was stuck {_where(flow.reason, flow.k)} {stats['stuck_error']:.3g} from "
        f"the goal after {flow.steps} steps"
    )
    if len(stages) == 2 and status is Status.SOLVED:
        return f"assembled: {quality}; {why}, the place rule finished in {place.steps} grasps"
    failed = f"the place rule from there stopped after {place.steps} grasps ({place.reason})"
    if len(stages) == 2:
        return f"{why}; {failed}, {stats['final_error']:.3g} from the goal"
    last = stages[2]
    if status is Status.SOLVED:
        return (
            f"assembled: {quality}; {why}, {failed}; after the cluster was spread the place "
            f"rule finished in {last.steps} grasps"
        )
    return (
        f"{why}; {failed}; after the cluster was spread the place rule stopped too after "
        f"{last.steps} grasps ({last.reason}), {stats['final_error']:.3g} from the goal"
    )


def _finish_message(res: SequentialResult, stats: Mapping[str, Stat], rule: str) -> str:
    """One line for a run finished (or not) by the place rule (issue 35)."""
    paper = res.stages[: len(res.stages) - res.finished]
    finish = res.stages[len(paper) :]
    last = paper[-1]
    lowered = len(paper) - 1
    grasps = sum(s.steps for s in paper)
    who = "the paper's T map" if rule == "paper" else "the place rule"
    why = f"{who} stopped at k={last.k:g} ({last.reason or last.status.value})"
    if lowered:
        why += f" after k was lowered {'once' if lowered == 1 else f'{lowered} times'}"
    why += f", after {grasps} switches"
    quality = f"ratio {stats['ratio']:.3f}, min clearance {stats['min_clearance']:.3g}"
    spread = " after the discs were spread" if len(finish) > 1 else ""
    if res.status is Status.SOLVED:
        return (
            f"assembled: {quality}; {why}; the place rule finished{spread} in {res.placed} grasps"
        )
    return (
        f"{why}; the place rule{spread} stopped too ({finish[-1].reason}), "
        f"{stats['final_error']:.3g} from the goal"
    )


def _where(reason: str, k: float) -> str:
    """``at a spurious minimum at k=32``, ``at a saddle ...``, or ``at k=32 (reason)``."""
    if reason in ("spurious minimum", "saddle"):
        return f"at a {reason} at k={k:g}"
    return f"at k={k:g} ({reason or 'no reason given'})"


def _control_message(res: ControlResult, stats: Mapping[str, Stat]) -> str:
    if res.status is Status.SOLVED:
        return (
            f"at rest at the goal after t={stats['settling_time']:.3g}: ratio "
            f"{stats['ratio']:.3f}, min clearance {stats['min_clearance']:.3g}"
        )
    if res.status is Status.STUCK:
        return (
            f"the step collapsed at t={stats['settling_time']:.3g} (no step keeps the "
            "energy from growing within the gap bound)"
        )
    return (
        f"not at rest at the goal after t={stats['settling_time']:.3g} "
        f"({int(stats['steps'])} steps): the simulation budget is spent"
    )


# --- trajectories ----------------------------------------------------------------------------


def disc_columns(n: int, dim: int = 2) -> tuple[str, ...]:
    """``disc1.x, disc1.y, ..., discn.y``: the columns of an assembly trajectory
    (spheres, ``dim`` 3: ``disc1.x, disc1.y, disc1.z, ...``)."""
    return tuple(f"disc{i + 1}.{axis}" for i in range(n) for axis in "xyz"[:dim])


def _arc_length(path: Array) -> Array:
    """Cumulative length in R^2n along ``path`` (m, n, 2), 0 at the start."""
    # explicit width: a run that starts within tolerance has a one-point path
    seg = np.linalg.norm(np.diff(path, axis=0).reshape(len(path) - 1, path[0].size), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def _meta(
    scenario: str,
    problem: DiscProblem,
    k: float,
    epsilon: float | None,
    tol: float,
    rule: str = "",
) -> dict[str, Any]:
    meta: dict[str, Any] = {"scenario": scenario, "n": problem.n, "k": k, "tolerance": tol}
    if problem.dim != 2:
        meta["dim"] = problem.dim
    if epsilon is not None:
        meta["epsilon"] = epsilon
    if rule:
        meta["rule"] = rule
    return meta


def _trajectory(
    path: Array,
    t: Array,
    time_unit: str,
    mode: NDArray[np.int64],
    modes: tuple[str, ...],
    events: Sequence[Event],
    meta: dict[str, Any],
) -> Trajectory:
    """The trajectory of a run on ``path`` ``(m, n, d)``: columns ``disc1.x, disc1.y, ...``
    (spheres, d = 3: ``disc1.x, disc1.y, disc1.z, ...``), one per coordinate of each disc."""
    n, dim = path.shape[1], path.shape[2]
    # typed fields (part: the disc) from the text the event lines write
    typed = [Event.from_text(e.index, e.kind, e.detail) for e in events]
    return Trajectory(
        t=t,
        q=path.reshape(len(path), dim * n),
        mode=mode,
        modes=modes,
        columns=disc_columns(n, dim),
        units=("workcell",) * (dim * n),
        time_unit=time_unit,
        events=tuple(sorted(typed, key=lambda e: e.index)),
        meta=meta,
        # a controller's run is timed in seconds already; else the default disc speeds
        seconds=np.asarray(t, float) - float(t[0]) if time_unit == "s" and len(t) else None,
    )


def _stage_starts(stages: Sequence[Stage]) -> list[int]:
    """Sample index at which each stage of a gradient run starts (``steps`` rows each)."""
    return [int(v) for v in np.concatenate([[0], np.cumsum([s.steps for s in stages])])[:-1]]


def _escape_events(
    stages: Sequence[Stage], starts: Sequence[int], finished: int = 0
) -> list[Event]:
    """One ``escape`` event where each stage after the first starts (k lowered), and a
    ``finish`` event where each of the last ``finished`` stages starts (the sequential
    rule's place-rule finish, issue 35: not a lowered k; detail ``place rule`` or
    ``place rule after spreading the discs``)."""
    first_finish = len(stages) - finished
    return [
        Event(int(start), "finish", stage.reason.split(":", 1)[0])
        if i >= first_finish
        else Event(int(start), "escape", f"k={stage.k:g}")
        for i, (stage, start) in enumerate(zip(stages, starts, strict=True))
        if i > 0
    ]


def _placed_trajectory(
    path: Array, flow_steps: int, place: SequentialResult, meta: dict[str, Any]
) -> Trajectory:
    """A flow (rows ``0..flow_steps``, mode ``all discs``) finished by the place rule
    (one disc moving per row: mode ``disc i``), possibly after one spreading move of all
    discs (mode ``all discs``); events ``escape``, ``spread`` and ``grasp``."""
    n = path.shape[1]
    modes = ("all discs", *(f"disc {i + 1}" for i in range(n)))
    mode = np.zeros(len(path), dtype=np.int64)
    events = [Event(flow_steps, "escape", "place rule")]
    row = len(path) - len(place.path)  # where the place rule's run starts
    if row > flow_steps:
        events.append(Event(flow_steps, "spread", "all discs scaled about the goals' centroid"))
    for g in place.grasps:
        events.append(Event(row, "grasp", f"disc {g.disc + 1}"))
        mode[row + 1 : row + len(g.path)] = g.disc + 1
        row += len(g.path) - 1
    return _trajectory(path, _arc_length(path), "path", mode, modes, events, meta)


def _sequential_trajectory(res: SequentialResult, meta: dict[str, Any]) -> Trajectory:
    """Rows of the sequential path; mode = the disc moving into each row (1-based)."""
    lengths = [len(g.path) - 1 for g in res.grasps]
    starts = np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)])  # row of each pick
    discs = sorted({g.disc for g in res.grasps})
    modes = tuple(f"disc {i + 1}" for i in discs) or ("all discs",)
    mode_of = {d: j for j, d in enumerate(discs)}
    mode = np.zeros(len(res.path), dtype=np.int64)
    events: list[Event] = []
    previous = -1
    for j, g in enumerate(res.grasps):
        a, b = int(starts[j]), int(starts[j + 1])
        mode[a + 1 : b + 1] = mode_of[g.disc]
        if j == 0:
            mode[0] = mode_of[g.disc]
        if previous >= 0 and previous != g.disc:
            events.append(Event(a, "switch", f"disc {previous + 1} -> disc {g.disc + 1}"))
        events.append(Event(a, "grasp", f"disc {g.disc + 1}"))
        previous = g.disc
    grasp_starts = [
        int(starts[min(sum(s.steps for s in res.stages[:i]), len(lengths))])
        for i in range(len(res.stages))
    ]
    events.extend(_escape_events(res.stages, grasp_starts, res.finished))
    return _trajectory(res.path, _arc_length(res.path), "path", mode, modes, events, meta)

"""The ``strategies`` planner: solve a scenario for its optimal strategy, then run it once.

Registered in :mod:`cellplan.strategies.plugin`; ``cellplan.plan(setup, "strategies")``
calls :func:`run_strategies`. The planner computes the stationary optimal strategy of
Section IV (average-cost dynamic programming on the layered MDP, equation (9)) and, so
that the result carries a motion like every planner's, simulates that strategy from the
robot's start for ``sample_stages`` stages of the stochastic assembly process (Section
III-B): the result's trajectory is that sample run; its ``solution`` is the
:class:`~cellplan.strategies.policy.strategy.Strategy`, which answers ``action(q, mode)`` at any
real-valued state.

This module is imported whenever a scenario is loaded: it imports the algorithm modules
only inside :func:`run_strategies`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated

from pydantic import Field

from cellplan.core import Options, Progress, Result, Status
from cellplan.errors import ArgumentError, Problem
from cellplan.schema import Cells
from cellplan.strategies.section import MAX_STAGES, SolverMethod, SolverSpec
from cellplan.strategies.sim.options import SimulationOptions

#: Re-exported: the longest run, a limit of the section.
__all__ = ["MAX_STAGES", "StrategiesOptions", "run_strategies", "solver_settings"]

if TYPE_CHECKING:
    import numpy as np

    from cellplan.setup import Setup
    from cellplan.strategies.model.mdp import LayeredMDP
    from cellplan.strategies.model.memory import MemoryEstimate
    from cellplan.strategies.model.spec import ProblemSpec

Method = SolverMethod

#: ``cellplan simulate``'s run length and seed when not given (``cellplan.simulate`` takes
#: both explicitly); the longest run it accepts is :data:`~.section.MAX_STAGES`.
SIMULATE_STAGES = 400
SIMULATE_SEED = 0


class StrategiesOptions(Options):
    """Options of the ``strategies`` planner (each default is the one source of it)."""

    method: Method | None = Field(
        None,
        description="solver: auto, structured (layered, Sec. IV; Section V models only), "
        "policy (policy iteration) or general (relative value iteration); None: the "
        "scenario's strategy.solver.method",
    )
    tolerance: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = Field(
        None,
        description="stop when the gain's certified bracket is narrower; None: the "
        "scenario's strategy.solver.tolerance",
    )
    max_sweeps: Annotated[int, Field(ge=1, le=10_000_000)] | None = Field(
        None,
        description="give up (not converged) after this many sweeps; None: the scenario's "
        "strategy.solver.max_sweeps",
    )
    damping: Annotated[float, Field(gt=0, le=1)] | None = Field(
        None,
        description="relaxation of the outer fixed point on the gain (1: none); None: the "
        "scenario's strategy.solver.damping",
    )
    cells: tuple[Cells, ...] | None = Field(
        None,
        description="grid cells per C-space axis; None: strategy.cells, else cspace.cells, "
        "else the robot kind's default",
    )
    snap: bool = Field(
        True,
        description="False drops the moves whose interpolation snaps the robot sideways "
        "(stricter transition law, docs/strategies.md)",
    )
    sample_stages: Annotated[int, Field(ge=1, le=MAX_STAGES)] = Field(
        200, description="stages of the sample run from the robot's start (the trajectory)"
    )
    seed: Annotated[int, Field(ge=0)] = Field(0, description="seed of the sample run")


def solver_settings(options: StrategiesOptions, scenario: SolverSpec) -> SolverSpec:
    """The solver's settings of one run: each option given, else the scenario's
    ``strategy.solver`` value (the one default of each)."""
    return SolverSpec(
        method=options.method if options.method is not None else scenario.method,
        tolerance=options.tolerance if options.tolerance is not None else scenario.tolerance,
        max_sweeps=options.max_sweeps if options.max_sweeps is not None else scenario.max_sweeps,
        damping=options.damping if options.damping is not None else scenario.damping,
    )


def check_cells(cells: Sequence[int] | None, dim: int, field: str = "cells") -> None:
    """An :class:`ArgumentError` unless ``cells`` is None or has one entry per C-space axis."""
    if cells is not None and len(cells) != dim:
        raise ArgumentError(
            [
                Problem(
                    field,
                    f"needs {dim} values (one per C-space axis), got {len(cells)}",
                )
            ]
        )


BUILD_SECONDS_PER_CELL_MODE = 20e-6
"""Seconds to build the model per grid cell and mode (what ``validate`` and the start of a
solve spend; the solve's sweeps come on top, with a progress bar). Measured with
``cellplan validate`` on strategies_tiny at 256 x 256 and 512 x 512 cells (5 modes):
18-21 us on the shared 2-core machine (load about 4)."""


def check_memory(
    setup: Setup,
    cells: Sequence[int] | None,
    method: str | None = None,
    spec: ProblemSpec | None = None,
) -> MemoryEstimate:
    """Refuse a grid whose model and solve cannot fit in memory, before allocating it.

    The estimate is :func:`~cellplan.strategies.model.memory.estimate_memory` (the arrays the
    model and the solver allocate); the refusal names the cells and where they came from.
    ``spec`` is the scenario's compiled section when the caller has it (else compiled here).
    Also refuses a model whose build (:func:`build_seconds`) would pass the time limit.
    Returns the estimate.
    """
    from cellplan import budget
    from cellplan.errors import ScenarioError
    from cellplan.strategies.model.mdp import grid_shape
    from cellplan.strategies.model.memory import estimate_memory

    scenario, cell = setup.scenario, setup.workcell
    shape = grid_shape(scenario, cell, cells)
    est = estimate_memory(spec if spec is not None else scenario, cell, cells, method)
    where = "cells" if cells is not None else "strategy.cells"
    error = ArgumentError if cells is not None else ScenarioError
    budget.require(
        est.total, f"{where} {','.join(map(str, shape))}", f"for {est.modes} modes", error
    )
    budget.require_time(
        build_seconds(est),
        f"{where} {','.join(map(str, shape))}",
        f"to build the model of {est.modes} modes",
        error,
    )
    return est


def build_seconds(est: MemoryEstimate) -> float:
    """Estimated seconds to build the model of ``est`` (the reference machine's
    :data:`BUILD_SECONDS_PER_CELL_MODE` per grid cell and mode)."""
    return est.cells * est.modes * BUILD_SECONDS_PER_CELL_MODE


def run_strategies(
    setup: Setup, options: StrategiesOptions, progress: Progress | None = None
) -> Result:
    """Solve ``setup``'s strategy section (Section IV) and simulate the strategy once.

    Returns
    -------
    Result
        ``SOLVED`` when the solver's span test passed (the gain is certified to the
        scenario's tolerance) and the sample run served its requests;
        ``NOT_CONVERGED`` when the solver stopped at ``strategy.solver.max_sweeps``;
        ``FAILED`` when the solve converged but its policy keeps requests open for ever
        (a recurrent class without NR:
        :func:`~cellplan.strategies.solve.policy_iteration.stranded_modes`), or the
        sample run left a request waiting longer than its bound (see
        :func:`~cellplan.strategies.sim.simulate.simulate_result`).
        ``stats`` holds the solve's figures (gain and its bracket, span, sweeps,
        seconds ...) and the sample run's metrics prefixed ``sim_``.
    """
    from cellplan.strategies.policy.strategy import solve_scenario
    from cellplan.strategies.sim.simulate import simulate_result

    section = setup.section("strategy")
    cell = setup.workcell
    check_cells(options.cells, cell.robot.dim)
    settings = solver_settings(options, section.solver)
    spec = section.compile(setup.scenario)  # once: the memory check and the build read it
    check_memory(setup, options.cells, settings.method, spec)

    def report(sweep: int, residual: float, gain: float) -> None:
        assert progress is not None
        progress(float(sweep), None, f"sweep {sweep}  residual {residual:.3g}  gain {gain:.6f}")

    strategy, solved = solve_scenario(
        spec,
        cell,
        cells=list(options.cells) if options.cells is not None else None,
        method=options.method,
        solver=settings,
        progress=report if progress is not None else None,
        snap=options.snap,
        start=cell.robot.start,  # the sample run starts there
    )
    strategy.attach(cell)  # the public query then refuses FMPs the exact region test refuses
    # The axis names travel with the strategy (and its file), so a run without the
    # workcell still labels its trajectory's columns and units.
    strategy.meta["axes"] = list(cell.robot.axis_names)
    if progress is not None:
        progress(float(solved.sweeps), float(solved.sweeps), "sample run")
    sample = simulate_result(
        strategy,
        options.sample_stages,
        options.seed,
        SimulationOptions(regions=section.regions),
        cell=cell,
        robot_spec=setup.scenario.robot,  # seconds at the scenario's robot.speed
    )
    stats = dict(solved.stats())
    stats.update({f"sim_{k}": v for k, v in sample.stats.items()})
    bracket = f"[{solved.gain_lower:.4f}, {solved.gain_upper:.4f}]"
    if not solved.converged:
        status = Status.NOT_CONVERGED
        message = (
            f"did not converge within {settings.max_sweeps} sweeps (span "
            f"{solved.span:.3g} >= tolerance {settings.tolerance:g}; gain bracket "
            f"{bracket})"
        )
    elif held := _held_open(strategy.mdp, _stranded(strategy.mdp, solved.policy)):
        status = Status.FAILED
        message = f"gain {solved.gain:.4f} per stage, but {held}"
    elif not sample.success:
        status = Status.FAILED
        message = f"gain {solved.gain:.4f} per stage, but the sample run failed: {sample.message}"
    else:
        status = Status.SOLVED
        message = (
            f"gain {solved.gain:.4f} per stage (bracket {bracket}), {solved.method}, "
            f"{solved.sweeps} sweeps"
        )
    assert sample.trajectory is not None
    return Result(
        status,
        message,
        stats=stats,
        solution=strategy,
        trajectory=sample.trajectory,
    )


def _stranded(mdp: LayeredMDP, policy: np.ndarray) -> list[int]:
    """:func:`~cellplan.strategies.solve.policy_iteration.stranded_modes` where it can find
    any: not in a Section V model (:meth:`LayeredMDP.is_simple`), whose requests all weigh
    one, so that holding one open for ever costs the most any policy can (one request's
    loss per stage) and the optimum never does; this also spares the structured solver's
    large grids a chain it never builds."""
    # Imported here like run_strategies' algorithm modules (load time: module docstring).
    from cellplan.strategies.solve.policy_iteration import stranded_modes

    if mdp.is_simple():
        return []
    return [int(m) for m in stranded_modes(mdp, policy)]


def _held_open(mdp: LayeredMDP, modes: Sequence[int]) -> str:
    """Why an optimal policy is no strategy: it keeps requests open for ever in
    ``modes`` (:func:`~cellplan.strategies.solve.policy_iteration.stranded_modes`); empty
    when there are none."""
    if len(modes) == 0:
        return ""
    names = ", ".join(mdp.modes[int(m)].label for m in modes[:3])
    more = f" and {len(modes) - 3} more" if len(modes) > 3 else ""
    text = f"the strategy keeps requests open for ever (modes {names}{more})"
    if any(m.kind == "Q" for m in mdp.modes):
        text += (
            ": a request that arrives while strategy.max_pending are open is turned away "
            "at no cost, so holding the least urgent ones open pays here; raise "
            "strategy.max_pending, lower strategy.arrival or bring strategy.urgency closer"
        )
    return text

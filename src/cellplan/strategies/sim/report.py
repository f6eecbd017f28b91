"""What a simulated run is measured against and how it is reported: the wait bound, the
trajectory, the exact collision check and the verdict of
:func:`~cellplan.strategies.sim.simulate.simulate_result` (docs/strategies.md,
"Simulation status").
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cellplan import timing, units
from cellplan.core import Status
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.sim.records import Simulation, carried_part, open_requests
from cellplan.trajectory import Event, Trajectory

#: A request that waits longer than this many crossings of the C-space box (at the slowest
#: speed, plus a pick and a place) counts as starved; see :func:`wait_bound`.
WAIT_CROSSINGS = 10.0


def wait_bound(strategy: Strategy) -> float:
    """The default bound on a request's waiting time (time units) in :func:`simulate_result`.

    ``WAIT_CROSSINGS`` times the time the robot needs to cross the C-space box once along
    every axis at its slowest speed (its step per stage in each mode's action set), plus
    the largest fine-motion time twice (a pick and a place). A served request under the
    optimal strategy waits for a path between two regions and two FMPs (Section III-C), so
    a wait beyond this bound means that the strategy (or its execution) is not serving it.

    Where several requests can be open at once (Section VI-2) a request may be served
    after each of the others, and the weighted loss lets the urgent ones go first: the
    bound is that of one request times the most requests a mode holds open
    (:func:`open_requests`; 1 in every other model). Issue 35's seed 1235 served a P1
    request after 820 stages behind urgent P2 deliveries, 1.2 times the one-request
    bound, with no lock-up.
    """
    mdp = strategy.mdp
    dim = len(mdp.shape)
    step = np.abs(np.asarray(mdp.disp, float))  # (classes, actions, dim)
    if mdp.heading_axis >= 0:
        # Robot-frame translation: a step along the heading moves either workcell axis.
        planar = np.linalg.norm(step[:, :, :2], axis=2)
        step[:, :, 0] = planar
        step[:, :, 1] = planar
    per_axis = step.max(axis=1).min(axis=0)  # the slowest class's largest step per axis
    extent = np.asarray(mdp.upper, float) - np.asarray(mdp.lower, float)
    stages = float(sum(extent[j] / per_axis[j] for j in range(dim) if per_axis[j] > 0))
    tf = np.asarray(mdp.tf, float)
    finite = tf[np.isfinite(tf)]
    tf_max = float(finite.max()) if finite.size else 0.0
    one = WAIT_CROSSINGS * stages * float(mdp.stage_time) + 2.0 * tf_max
    return one * max(1, max(open_requests(m) for m in mdp.modes))


def axis_names(strategy: Strategy, cell: Any = None) -> tuple[str, ...]:
    """Names of the configuration axes: the workcell's, else those the strategy records.

    A strategy file written before the planner recorded them falls back on the layout of
    its grid: ``x, y, theta`` for a robot-frame action set, else ``x, y`` for a 2-D box
    beyond two full turns, else ``q1 ... qn``.
    """
    if cell is not None:
        return tuple(cell.robot.axis_names)
    axes = strategy.meta.get("axes")
    dim = len(strategy.mdp.shape)
    if isinstance(axes, list) and len(axes) == dim:
        return tuple(str(a) for a in axes)
    mdp = strategy.mdp
    if mdp.heading_axis >= 0 and dim == 3:
        return ("x", "y", "theta")
    extent = np.asarray(mdp.upper, float) - np.asarray(mdp.lower, float)
    if dim == 2 and np.any(extent > 2.0 * units.ANGLE_LIMIT):
        return ("x", "y")
    return tuple(f"q{j + 1}" for j in range(dim))


def to_trajectory(
    strategy: Strategy,
    sim: Simulation,
    cell: Any = None,
    meta: Mapping[str, str | int | float | bool] | None = None,
    robot_spec: Any = None,
) -> Trajectory:
    """A simulated run as a :class:`~cellplan.trajectory.Trajectory`.

    ``t`` is the stage, ``q`` the configuration (radians for angles; periodic axes
    unwrapped), ``mode`` the assembly mode of each stage (``NR``, ``<P1,S1,D1,W>`` ...),
    and the events are the simulation's (:attr:`Simulation.events`), typed. ``seconds``
    is ``stage x stage_duration``: the time of the longest step of any action at the
    robot's speeds (``robot_spec``: the scenario's robot section; else the URDF's or the
    default speeds), :func:`cellplan.timing.stage_duration`.
    """
    names = axis_names(strategy, cell)
    axis_units = units.axis_units(names)
    robot = cell.robot if cell is not None else None
    _, vlim, alim = timing.robot_motion(robot_spec, robot, names, axis_units)
    mdp = strategy.mdp
    dim = len(mdp.shape)
    step = np.abs(np.asarray(mdp.disp, float)).reshape(-1, dim)
    if mdp.heading_axis >= 0:
        # Robot-frame translation: a step along the heading may move either workcell axis.
        planar = np.linalg.norm(step[:, :2], axis=1)
        step[:, 0] = planar
        step[:, 1] = planar
    return Trajectory(
        t=np.arange(len(sim.modes), dtype=float),
        q=sim.q,
        mode=sim.modes,
        modes=tuple(m.label for m in mdp.modes),
        columns=names,
        units=axis_units,
        time_unit="stage",
        events=tuple(Event.from_text(k, kind, detail) for k, kind, detail in sim.events),
        meta=dict(meta or {}),
        periodic=tuple(bool(p) for p in np.asarray(mdp.periodic).reshape(-1)),
        stage_duration=timing.stage_duration(step, vlim),
        velocity_limits=vlim,
        acceleration_limits=alim,
    )


#: Samples of a checked motion per grid cell it crosses (:func:`first_collision`).
SAMPLES_PER_CELL = 4


#: Segments checked in one batch (bounds the samples held at once).
COLLISION_BATCH = 4096


def first_collision(strategy: Strategy, sim: Simulation, cell: Any) -> tuple[int, str] | None:
    """The first sample of a run whose motion there collides with the workcell, exactly.

    The check the grid cannot give for a strategy it did not build: each stage's straight
    motion ``q[k] -> q[k + 1]`` (and the start) is tested against the workcell's
    obstacles and bounds (the sources are not obstacles here: the robot picks inside
    them) with the part of the stage's mode, sampled :data:`SAMPLES_PER_CELL` times per
    grid cell of workspace travel (:meth:`~cellplan.workcell.Workcell.motion_collides`).
    A strategy solved for this workcell never collides (its free cells are collision-free
    in their whole box, cspace.py); one that does was solved for another.

    Returns ``(k, description)`` for the first colliding sample ``k`` (0: the start), or
    None.
    """
    mdp = strategy.mdp
    modes = mdp.modes
    names = tuple(cell.robot.axis_names)
    cell_travel = cell.robot.workspace_step(np.diag(np.asarray(mdp.spacing, float)))
    step = float(cell_travel[cell_travel > 0].min()) / SAMPLES_PER_CELL
    q, ms = sim.q, sim.modes

    def describe(k: int, m: int) -> str:
        part = carried_part(modes[m])
        holding = f" carrying {part}" if part else ""
        shown = ", ".join(f"{n} {v:.4g}" for n, v in zip(names, q[k], strict=True))
        return f"the robot{holding} collides with the workcell at {shown} in mode {modes[m].label}"

    m0 = int(ms[0])
    if cell.collides(q[:1], carried_part(modes[m0]), "none")[0]:
        return 0, describe(0, m0)
    moved = np.flatnonzero(np.any(q[1:] != q[:-1], axis=1))
    parts = np.array([carried_part(modes[int(m)]) or "" for m in ms[:-1]], dtype=object)
    first: int | None = None
    for part in sorted(set(parts[moved].tolist())):
        ks = moved[parts[moved] == part]
        for lo in range(0, len(ks), COLLISION_BATCH):
            batch = ks[lo : lo + COLLISION_BATCH]
            if first is not None and batch[0] >= first:
                break
            hit = cell.motion_collides(
                q[batch], q[batch + 1], step, part or None, "none", certified=False
            )
            if hit.any():
                k = int(batch[np.argmax(hit)])
                first = k if first is None else min(first, k)
                break
    if first is None:
        return None
    return first + 1, describe(first + 1, int(ms[first]))


def _configuration(
    given: ArrayLike | None, recorded: Any, names: tuple[str, ...], field: str
) -> np.ndarray | None:
    if given is not None:
        return units.check_configurations(given, names, field)[0]
    if recorded is not None:
        return np.asarray(recorded, dtype=float)
    return None


def _verdict(
    strategy: Strategy, sim: Simulation, metrics: Mapping[str, float], bound: float
) -> tuple[Status, str]:
    stages = len(sim.actions)
    if not sim.requests:
        return Status.SOLVED, f"no request arrived in {stages} stages"
    late = [(i, r) for i, r in enumerate(sim.requests) if r.waiting > bound]
    if late:
        i, r = late[0]
        state = "still open" if r.delivery < 0 else f"delivered at stage {r.delivery}"
        return (
            Status.FAILED,
            f"request {i + 1} (<{r.part},{r.source},{r.destination}>, arrived at stage "
            f"{r.arrival}) waited {r.waiting:g} > {bound:g} ({state}); "
            f"{len(late)} request(s) over the bound",
        )
    served = int(metrics["served"])
    open_part = (
        f" ({int(metrics['open_requests'])} open after {metrics['open_wait']:g})"
        if metrics["open_requests"]
        else ""
    )
    wait = f"mean wait {metrics['mean_wait']:.2f}, " if served else ""
    return (
        Status.SOLVED,
        f"served {served} of {len(sim.requests)} requests{open_part}, {wait}"
        f"loss {metrics['loss_per_stage']:.3f} per stage (gain {strategy.gain:.3f})",
    )

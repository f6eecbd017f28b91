"""Sequential assembly executed by a URDF arm (Whitcomb & Koditschek 1991, Section 4.2).

The paper's discs are a first step toward real assembly; here the parts are pucks on a
robot's table and the arm carries them:

1. the sequential algorithm (:func:`sequential.sequential_assembly`, Section 4.2,
   equations (10)-(16)) assembles the discs in the table plane, one disc per grasp,
   each disc planned as its part's *footprint* (:func:`footprint_problem`: the radius
   of the sphere cover the arm is checked with), so that parts the plan keeps apart
   stay apart for the certified checks;
2. each grasp (one disc's move) becomes a *pick* above the disc where it stands and a
   *place* above the next point of its path, the grasp's end (the robot carries the
   part through the air; the planar path decides where each part goes, and in which
   order);
3. four arm motions per grasp: ``approach`` (the empty arm to the pick) and
   ``transfer`` (carrying, from above the pick to above the place, ``lift`` metres up)
   are queries of the adaptive planner's
   :class:`~cellplan.adaptive.experience.ExperiencePlanner` (Chen 1994, Figure 1), so
   its experience graph grows as the assembly proceeds; ``lift`` and ``lower`` are
   straight joint-space lines to the nearby IK solution. Standing parts are objects of
   the planner's workcell, removed while held and added back where they are put down
   (Section 2.3: subgoals attached to them follow);
4. every segment of the arm path is certified collision-free by
   :meth:`~cellplan.workcell3d.Workcell3D.motion_collides`, the carried part attached
   to the tool frame between pick and place, at a step finer than the planner's. The
   experience planner's transfer query holds the part too (``carrying``: Reach, Solve,
   the repair and its re-check are made with the part attached), so this is a second,
   independent check; a segment that fails it makes the run fail, named in the message.

Where the papers are silent (docs/assembly.md, "Sequential assembly executed by the
arm"): the tool points down (:data:`~cellplan.adaptive.world3d.DOWN`) at ``hover``
metres above the disc's centre, and part ``i`` (the scenario's ``parts:`` in file
order) is disc ``i``, its shape given in the tool frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from cellplan import solids
from cellplan.adaptive.experience import ExperiencePlanner
from cellplan.adaptive.world3d import DOWN
from cellplan.assembly.layout import CircleWorkspace, legality_problems, rule_k
from cellplan.assembly.problems import DiscProblem
from cellplan.assembly.robot_options import RobotAssemblyOptions
from cellplan.assembly.sequential import SequentialResult, sequential_assembly
from cellplan.core import Progress, Result, Status
from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.scene3d import held_from_events
from cellplan.setup import Setup
from cellplan.trajectory import Event, Trajectory
from cellplan.workcell3d import Workcell3D

__all__ = [
    "ArmMove",
    "RobotAssembly",
    "RobotAssemblyOptions",
    "held_parts",
    "plan_robot",
    "tool_pose",
]

Array = NDArray[np.float64]

#: Sampling step (metres of the cover's travel) of the certification of every segment.
CERTIFY_STEP = 0.01
#: Most grasps a run may plan for the arm (each is two experience-planner queries).
MAX_GRASPS = 60
#: The same plane: discs whose centres' heights differ by more than this are refused.
PLANE_TOL = 1e-9


@dataclass
class ArmMove:
    """One arm query of a grasp: ``approach`` (the empty arm to the pick), then carrying:
    ``lift`` (straight up), ``transfer`` (to above the place), ``lower``."""

    grasp: int
    part: str
    leg: str
    checks: int
    vertices: int
    solve_calls: int
    certified: bool
    path: Array  # (m, dim) the query's executed joint-space path


@dataclass
class RobotAssembly:
    """The planar plan, the arm moves and the experience planner (its graph)."""

    plan: SequentialResult
    moves: list[ArmMove] = field(default_factory=list)
    planner: ExperiencePlanner | None = None

    def checks_per_move(self) -> Array:
        """Collision checks of each part's move (its four arm queries), in grasp order
        (Chen's cost measure); a move cut short by a failure counts what it made."""
        out = np.zeros(max((m.grasp + 1 for m in self.moves), default=0))
        for m in self.moves:
            out[m.grasp] += m.checks
        return out


def tool_pose(xy: Array, z: float, hover: float) -> Array:
    """The ``(4, 4)`` tool pose over a disc centre ``(x, y)`` at height ``z``: pointing
    down, ``hover`` metres above it."""
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(DOWN, float).reshape(3, 3)
    pose[:3, 3] = (float(xy[0]), float(xy[1]), z + hover)
    return pose


def planar_problem(setup: Setup) -> tuple[DiscProblem, float, list[str]]:
    """The discs in the table plane, its height, the part of each disc.

    Raises
    ------
    ScenarioError
        One problem per mistake: not a 3-D cell with a URDF arm, a generated or
        ball-less section, discs off one horizontal plane, a part count that differs.
    """
    sc = setup.scenario
    problems: list[Problem] = []
    if not isinstance(setup.workcell, Workcell3D):
        raise ScenarioError([Problem("robot", "assembly.robot needs a 3-D cell with a URDF arm")])
    section = setup.section("discs")
    if section.discs is None:
        problems.append(Problem("discs.generate", "assembly.robot takes listed discs"))
    if section.boundary.type != "disc":
        problems.append(Problem("discs.boundary", "assembly.robot takes a disc boundary"))
    if problems:
        raise ScenarioError(problems)
    assert section.discs is not None and section.boundary.type == "disc"
    z = float(section.boundary.center[2])
    for i, d in enumerate(section.discs):
        for which in ("start", "goal"):
            h = float(getattr(d, which)[2])
            if abs(h - z) > PLANE_TOL:
                problems.append(
                    Problem(
                        f"discs.discs[{i}].{which}",
                        f"z = {h:g} is off the table plane z = {z:g} (the boundary's centre)",
                    )
                )
    parts = list(sc.parts)
    if len(parts) != len(section.discs):
        problems.append(
            Problem("parts", f"gives {len(parts)} parts for {len(section.discs)} discs (one each)")
        )
    if problems:
        raise ScenarioError(problems)
    radii = np.array([d.radius for d in section.discs], float)
    start = np.array([d.start[:2] for d in section.discs], float)
    goal = np.array([d.goal[:2] for d in section.discs], float)
    ws = CircleWorkspace(np.array(section.boundary.center[:2], float), section.boundary.radius)
    return DiscProblem(radii, start, goal, ws), z, parts


def footprint_problem(problem: DiscProblem, cell: Workcell3D, parts: list[str]) -> DiscProblem:
    """The planar problem with each disc as its part's footprint: the radius of the
    sphere cover the arm is checked with (:meth:`Workcell3D.collides`), about the tool
    axis, plus the certification's sampling step, so that parts the planar plan keeps
    apart stay apart for the certified checks too."""
    radii = np.array(
        [
            float(np.max(np.linalg.norm(cell.part(p).centers[:, :2], axis=1) + cell.part(p).radii))
            + CERTIFY_STEP
            for p in parts
        ]
    )
    return DiscProblem(
        np.maximum(radii, problem.radii), problem.start, problem.goal, problem.workspace
    )


def _standing(cell: Workcell3D, part: str, xy: Array, z: float, hover: float) -> solids.Solid:
    """The part's solid where it stands (its tool-frame shape under the tool pose)."""
    return cell.part(part).solid.transformed(tool_pose(xy, z, hover))


def _holdable(
    planner: ExperiencePlanner,
    cell: Workcell3D,
    parts: list[str],
    problem: DiscProblem,
    z: float,
    hover: float,
) -> list[Problem]:
    """One problem per start or goal the arm cannot reach, or where it cannot hold the part
    without collision (IK from the arm's start; the part attached)."""
    problems = []
    q0 = planner.position
    for i, part in enumerate(parts):
        for which, xy in (("start", problem.start[i]), ("goal", problem.goal[i])):
            where = f"discs.discs[{i}].{which}"
            try:
                q = planner.world.pose_goal(tool_pose(xy, z, hover), q0)
            except ArgumentError as exc:
                problems.append(Problem(where, f"part {part}: {exc.problems[0].message}"))
                continue
            if cell.collides(q[None, :], carrying=part, avoid_sources="none")[0]:
                problems.append(
                    Problem(
                        where,
                        f"the arm cannot hold part {part} here without collision (its shape "
                        f"{hover:g} m below the tool meets the table or an obstacle)",
                    )
                )
    return problems


def plan_robot(setup: Setup, options: RobotAssemblyOptions, progress: Progress | None) -> Result:
    """``assembly.robot``: the sequential assembly, each grasp a pick and a place by the arm.

    Returns a :class:`Result` whose trajectory is the arm's whole path (``pick`` and
    ``place`` events naming the part; mode ``carrying <part>`` between them), whose
    solution is a :class:`RobotAssembly`, and whose stats give the checks per arm move
    (``checks_first_third``, ``checks_last_third``), the graph's final size and the
    grasp count.
    """
    t0 = time.perf_counter()
    given, z, parts = planar_problem(setup)
    cell = setup.workcell
    assert isinstance(cell, Workcell3D)
    section = setup.section("discs")
    problem = footprint_problem(given, cell, parts)
    problems = [
        Problem(
            f"discs.discs[{i}].{which}",
            f"part {parts[i]}, as its sphere cover's footprint (radius "
            f"{problem.radii[i]:.3g} m): {msg}",
        )
        for which, pos in (("start", problem.start), ("goal", problem.goal))
        for i, msg in legality_problems(pos, problem.radii, problem.workspace, "discs.discs")
    ]
    if problems:
        raise ScenarioError(problems)
    planner = ExperiencePlanner(setup, repair=options.repair, seed=options.seed)
    problems = _holdable(planner, cell, parts, problem, z, options.hover)
    if problems:
        raise ScenarioError(problems)
    k = options.k if options.k is not None else section.k
    if k is None:
        k = rule_k(problem.radii, problem.workspace)
    if progress is not None:
        progress(0.0, None, f"sequential ({options.rule}) in the table plane, {problem.n} parts")
    seq = sequential_assembly(problem, float(k), options.rule)
    run = RobotAssembly(seq, planner=planner)
    if seq.status is not Status.SOLVED or len(seq.grasps) > MAX_GRASPS:
        why = seq.reason or f"{len(seq.grasps)} grasps (more than {MAX_GRASPS})"
        return Result(
            Status.FAILED,
            f"the planar assembly did not finish: {why}",
            "assembly.robot",
            {"grasps": len(seq.grasps)},
            run,
            None,
            options.model_dump(),
        )
    # Standing parts are objects of the planner's workcell (Chen, Section 2.3: subgoals
    # attached to them follow them when they move).
    where = problem.start.copy()
    for i, part in enumerate(parts):
        planner.add(part, _standing(cell, part, where[i], z, options.hover))
    samples: list[Array] = []
    template: Trajectory | None = None
    q_now = planner.position
    vertices = len(planner.graph)
    events: list[Event] = []
    modes: list[str] = []
    status, note = Status.SOLVED, ""
    for g, grasp in enumerate(seq.grasps):
        i, part = grasp.disc, parts[grasp.disc]
        dest = grasp.path[-1]
        # The empty arm to the pick; carrying: straight up, across, straight down (a
        # joint-space line between two low poses sags, and the held part with it).
        legs = (
            ("approach", where[i], 0.0),
            ("lift", where[i], options.lift),
            ("transfer", dest, options.lift),
            ("lower", dest, 0.0),
        )
        for leg, xy, up in legs:
            carrying = leg != "approach"
            pose = tool_pose(xy, z, options.hover + up)
            if leg in ("lift", "lower"):
                # Straight up or down: the joint-space line to the nearby IK solution,
                # certified with the part attached at CERTIFY_STEP. Not a query: through
                # the graph's vertex a line between two low poses would swing the part
                # about. The IK is the bare arm's: the planner's certified clearance with
                # the part (its lever-bound balls, 5 cm above the table) refuses the low
                # poses that the exact certification accepts.
                planner.world.hold(None)
                try:
                    q_to = planner.world.pose_goal(pose, q_now)
                except ArgumentError as exc:
                    status, note = Status.FAILED, f"grasp {g}, {leg} of part {part}: {exc}"
                    break
                traj = _straight(template, q_now, q_to)
                res = Result(
                    Status.SOLVED, "", "", {"checks": 0, "vertices": vertices, "solve_calls": 0}
                )
            else:
                try:
                    res = planner.plan(q_now, pose, carrying=part if carrying else None)
                except ArgumentError as exc:
                    # a lifted pose or an intermediate place (a parking spot, the end of
                    # a flow) that no free IK solution reaches: the run stops there
                    status, note = Status.FAILED, f"grasp {g}, {leg} of part {part}: {exc}"
                    break
                assert res.trajectory is not None
                traj = res.trajectory
                template = template or traj
                vertices = int(res.stats["vertices"])
            certified = bool(
                len(traj) < 2
                or not np.any(
                    planner.world.workcell().motion_collides(
                        traj.q[:-1],
                        traj.q[1:],
                        CERTIFY_STEP,
                        carrying=part if carrying else None,
                        avoid_sources="none",
                    )
                )
            )
            q_now = traj.q[-1].copy()
            run.moves.append(
                ArmMove(
                    g,
                    part,
                    leg,
                    int(res.stats["checks"]),
                    int(res.stats["vertices"]),
                    int(res.stats["solve_calls"]),
                    certified,
                    traj.q,
                )
            )
            if not res.success or not certified:
                status = Status.FAILED
                note = (
                    f"grasp {g}, {leg} of part {part}: {res.message}"
                    if not res.success
                    else f"grasp {g}: the {leg} path of part {part} fails the certification "
                    "with the part attached"
                )
                break
            # each query starts where the last one ended: that sample is kept once
            new = traj.q if not samples else traj.q[1:]
            samples.extend(new)
            modes.extend([f"carrying {part}" if carrying else "empty"] * len(new))
            end = len(samples) - 1
            if leg == "lower":
                events.append(
                    Event(end, "place", f"{part} at grasp {g}", part=part, region=f"grasp {g}")
                )
                where[i] = dest
                planner.add(part, _standing(cell, part, where[i], z, options.hover))
            elif leg == "approach":
                events.append(
                    Event(end, "pick", f"{part} at grasp {g}", part=part, region=f"grasp {g}")
                )
                planner.remove(part)
        if status is not Status.SOLVED:
            break
        if progress is not None:
            progress(g + 1.0, float(len(seq.grasps)), f"grasp {g + 1} of {len(seq.grasps)}")
    trajectory = (
        _joined(template, np.array(samples), modes, events, setup.name)
        if template is not None and samples
        else None
    )
    checks = run.checks_per_move()
    third = max(len(checks) // 3, 1)
    stats: dict[str, float | int] = {
        "grasps": len(seq.grasps),
        "arm_moves": len(run.moves),
        "checks": int(checks.sum()),
        "checks_first_third": float(checks[:third].mean()) if len(checks) else 0.0,
        "checks_last_third": float(checks[-third:].mean()) if len(checks) else 0.0,
        "vertices": run.moves[-1].vertices if run.moves else 0,
        "solve_calls": sum(m.solve_calls for m in run.moves),
        "seconds": time.perf_counter() - t0,
    }
    if status is Status.SOLVED:
        message = (
            f"assembled {problem.n} parts in {len(seq.grasps)} grasps by the arm: "
            f"{int(checks.sum())} collision checks, |V|={stats['vertices']}"
        )
    else:
        message = note
    return Result(status, message, "assembly.robot", stats, run, trajectory, options.model_dump())


def held_parts(trajectory: Trajectory) -> list[str | None]:
    """The part held at each sample (``None``: empty), from the trajectory's pick and place
    events (:func:`cellplan.scene3d.held_from_events`, the one reading ``cellplan view``
    uses too); what :func:`cellplan.scene3d.cell_scene` takes as ``carrying``."""
    return held_from_events(trajectory.events, len(trajectory))


def _straight(template: Trajectory | None, q0: Array, q1: Array) -> Trajectory:
    """A straight joint-space segment as a trajectory like the planner's (``t`` the
    joint-space length)."""
    assert template is not None  # every grasp starts with a planner query
    q = np.array([q0, q1], float)
    return Trajectory(
        np.array([0.0, float(np.linalg.norm(q1 - q0))]),
        q,
        np.zeros(2, dtype=np.int64),
        template.modes,
        template.columns,
        template.units,
        template.time_unit,
        (),
        {},
        periodic=template.periodic,
        velocity_limits=template.velocity_limits,
        acceleration_limits=template.acceleration_limits,
    )


def _joined(
    template: Trajectory, q: Array, modes: list[str], events: list[Event], name: str
) -> Trajectory:
    """The arm's whole path: ``t`` the joint-space length (as the planner's queries),
    modes ``empty`` / ``carrying <part>``, pick/place events. A sample that repeats the one
    before (a query already at its goal) is dropped, so that time strictly increases;
    an event on it moves to the sample kept."""
    step = np.linalg.norm(np.diff(q, axis=0), axis=1)
    keep = np.concatenate([[True], step > 0.0])
    index = np.cumsum(keep) - 1  # each sample's index among those kept
    names = tuple(dict.fromkeys(modes))
    mode = np.array([names.index(m) for m in modes], dtype=np.int64)[keep]
    return Trajectory(
        np.concatenate([[0.0], np.cumsum(step[keep[1:]])]),
        q[keep],
        mode,
        names,
        template.columns,
        template.units,
        template.time_unit,
        tuple(replace(e, index=int(index[e.index])) for e in events),
        {"scenario": name, "planner": "assembly.robot"},
        periodic=template.periodic,
        velocity_limits=template.velocity_limits,
        acceleration_limits=template.acceleration_limits,
    )

"""Disc assembly problems: from a ``discs:`` section, or generated from a seed.

A :class:`DiscProblem` holds radii, start and goal centres and the workspace. The
generator follows Section 5 of the paper: random legal starts (Figs. 3-4), packed
goal patterns of chosen difficulty ``beta(d)`` (Fig. 5: from 1e-2 to 1e-44 for seven
discs) and random permutations of the goal positions as starts (Section 5.2.2).

The workspaces, legality and goal patterns live in :mod:`cellplan.assembly.layout`
(light to import: the scenario check uses them) and are re-exported here.
:func:`generated_setup` and :func:`random_setup` build a scenario with a ``discs:
generate:`` section, so that a generated problem is planned like any file.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cellplan.assembly.layout import (
    DEFAULT_FILL,
    BoxWorkspace,
    CircleWorkspace,
    Workspace,
    boundary_from_section,
    clearances,
    default_workspace,
    gap_for_beta,
    generator_problems,
    hex_pattern,
    legality_problems,
    log10_beta_pairs,
    stack_pattern,
    workspace_center,
)
from cellplan.errors import ArgumentError, Problem, ScenarioError
from cellplan.schema import COORD_LIMIT

if TYPE_CHECKING:
    from cellplan.assembly.section import DiscsSection, GeneratorSpec
    from cellplan.scenario import Scenario
    from cellplan.setup import Setup

__all__ = [
    "DEFAULT_FILL",
    "BoxWorkspace",
    "CircleWorkspace",
    "DiscProblem",
    "Workspace",
    "boundary_from_section",
    "default_workspace",
    "gap_for_beta",
    "generate_problem",
    "generated_goals",
    "generated_setup",
    "generator_problems",
    "hex_pattern",
    "legality_problems",
    "log10_beta_pairs",
    "problem_from_section",
    "random_legal",
    "random_permutation",
    "random_setup",
    "validate_problem",
    "workspace_center",
]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class DiscProblem:
    """n discs with radii (n,), start and goal centres (n, 2), in a workspace.

    Spheres: centres (n, 3) in a 3-D workspace (``dim`` 3); the same algorithms run in
    R^{3n}.
    """

    radii: Array
    start: Array
    goal: Array
    workspace: Workspace

    @property
    def n(self) -> int:
        return int(self.radii.shape[0])

    @property
    def dim(self) -> int:
        """2 for discs, 3 for spheres."""
        return int(self.goal.shape[1])

    @functools.cached_property
    def goal_gap(self) -> float:
        """Smallest gap between two goals (``inf`` for one disc), computed once."""
        gaps, _ = clearances(self.goal, self.radii, self.workspace)
        return float(np.min(gaps))

    def with_start(self, start: Array) -> DiscProblem:
        return DiscProblem(self.radii, np.asarray(start, dtype=float), self.goal, self.workspace)


# --- random starts and permutations ----------------------------------------------------------


def random_legal(
    n: int,
    radii: Array,
    ws: Workspace,
    rng: np.random.Generator,
    min_gap: float,
    batch: int = 512,
    tries: int = 200,
) -> Array:
    """n random centres inside ``ws``, pairwise gaps above ``min_gap`` (sequential adsorption).

    Candidates are drawn uniformly in batches and tested against the discs already
    placed in one vectorised step.

    Raises
    ------
    ScenarioError
        When a disc cannot be placed (the workspace is too crowded).
    """
    pos = np.zeros((n, ws.dim))
    for i in range(n):
        r = radii[i] + min_gap
        for _ in range(tries):
            cand = _uniform_in(ws, r, batch, rng)
            if i:
                dist = np.linalg.norm(cand[:, None, :] - pos[None, :i, :], axis=2)
                ok = np.all(dist > radii[None, :i] + radii[i] + min_gap, axis=1)
            else:
                ok = np.ones(batch, dtype=bool)
            hits = np.flatnonzero(ok)
            if hits.size:
                pos[i] = cand[hits[0]]
                break
        else:
            raise ScenarioError(
                [
                    Problem(
                        "discs.generate.n", f"cannot place {n} discs: the workspace is too crowded"
                    )
                ]
            )
    return pos


def _uniform_in(ws: Workspace, margin: float, m: int, rng: np.random.Generator) -> Array:
    if ws.dim == 3:
        if isinstance(ws, CircleWorkspace):
            u = rng.standard_normal((m, 3))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            rad = (ws.radius - margin) * np.cbrt(rng.random(m))
            return ws.center + rad[:, None] * u
        return ws.lo + margin + rng.random((m, 3)) * (ws.hi - ws.lo - 2.0 * margin)
    if isinstance(ws, CircleWorkspace):
        rad = (ws.radius - margin) * np.sqrt(rng.random(m))
        ang = 2.0 * math.pi * rng.random(m)
        return ws.center + np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
    return ws.lo + margin + rng.random((m, 2)) * (ws.hi - ws.lo - 2.0 * margin)


def random_permutation(n: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """A random permutation other than the identity (for n > 1)."""
    while True:
        perm = rng.permutation(n)
        if n == 1 or np.any(perm != np.arange(n)):
            return perm


# --- building problems -----------------------------------------------------------------------


def generated_goals(gen: GeneratorSpec, ws: Workspace, rng: np.random.Generator) -> Array:
    """The goal pattern of a generator (hex with gap or beta(d), or random legal)."""
    radii = np.full(gen.n, gen.radius)
    if gen.pattern == "random":
        return random_legal(gen.n, radii, ws, rng, gen.min_start_gap)
    if gen.pattern == "stack":
        return stack_pattern(gen.n, gen.radius, gen.gap, workspace_center(ws))
    gap = (
        gen.gap
        if gen.log10_beta_goal is None
        else gap_for_beta(gen.n, gen.radius, gen.log10_beta_goal, ws.dim)
    )
    return hex_pattern(gen.n, gen.radius, gap, workspace_center(ws))


def generate_problem(gen: GeneratorSpec, ws: Workspace, seed: int | None = None) -> DiscProblem:
    """A problem from a generator spec; ``seed`` overrides ``gen.seed`` (for sweeps)."""
    rng = np.random.default_rng(gen.seed if seed is None else seed)
    radii = np.full(gen.n, gen.radius)
    goal = generated_goals(gen, ws, rng)
    bad = legality_problems(goal, radii, ws)
    if bad:
        _, msg = bad[0]
        raise ScenarioError([Problem("discs.generate", f"the goal pattern is illegal: {msg}")])
    if gen.starts == "permutation":
        start = goal[random_permutation(gen.n, rng)]
    else:
        start = random_legal(gen.n, radii, ws, rng, gen.min_start_gap)
    return DiscProblem(radii, start, goal, ws)


def problem_from_section(
    section: DiscsSection, scenario: Scenario, seed: int | None = None
) -> DiscProblem:
    """The :class:`DiscProblem` of a validated ``discs:`` section."""
    ws = boundary_from_section(section, scenario)
    if section.discs is not None:
        radii = np.array([d.radius for d in section.discs], dtype=float)
        start = np.array([d.start for d in section.discs], dtype=float)
        goal = np.array([d.goal for d in section.discs], dtype=float)
        return DiscProblem(radii, start, goal, ws)
    assert section.generate is not None
    return generate_problem(section.generate, ws, seed)


def validate_problem(problem: DiscProblem) -> None:
    """Raise :class:`ScenarioError` naming each illegal disc of start or goal."""
    problems = [
        Problem(f"discs[{i}].{which}", msg)
        for which, pos in (("start", problem.start), ("goal", problem.goal))
        for i, msg in legality_problems(pos, problem.radii, problem.workspace, "discs")
    ]
    if problems:
        raise ScenarioError(problems)


# --- scenarios of generated problems ---------------------------------------------------------


def generated_setup(
    generate: Mapping[str, Any], fill: float = DEFAULT_FILL, name: str = "", dim: int = 2
) -> Setup:
    """A scenario whose ``discs:`` section generates a problem, in the default workspace.

    ``dim`` 3: spheres, in the ball of :func:`default_workspace` inside a 3-D cell
    (format version 2).

    ``generate`` holds the fields of :class:`~cellplan.assembly.section.GeneratorSpec`
    to set (the others take the spec's defaults); the boundary is the circle of
    :func:`default_workspace` for ``n``, the disc radius and ``fill``. ``k``,
    ``epsilon`` and ``tolerance`` are left to the section's defaults: planner options
    override them. The result is planned like any scenario file
    (``cellplan.plan(setup, "assembly.gradient")``).

    Raises
    ------
    ScenarioError
        A generator field out of range (named ``discs.generate.<field>``), a goal
        pattern that does not fit, or a workspace too crowded to sample.
    """
    from pydantic import ValidationError

    from cellplan.assembly.section import GeneratorSpec
    from cellplan.scenario import scenario_from_data
    from cellplan.setup import Setup

    try:
        gen = GeneratorSpec.model_validate(dict(generate))
    except ValidationError as exc:
        raise ScenarioError(
            [
                Problem(
                    ".".join(["discs.generate", *(str(x) for x in err["loc"])]),
                    err["msg"].removeprefix("Value error, "),
                )
                for err in exc.errors(include_url=False)
            ]
        ) from None
    if not 0.0 < fill <= 0.5:
        raise ScenarioError([Problem("fill", f"must be in (0, 0.5], got {fill:g}")])
    if dim not in (2, 3):
        raise ScenarioError([Problem("dim", f"must be 2 or 3, got {dim}")])
    ws = default_workspace(gen.n, gen.radius, fill, dim)
    if not ws.radius + 1.0 <= COORD_LIMIT:  # also an infinite radius (fill 5e-324)
        raise ScenarioError(
            [
                Problem(
                    "fill" if fill < DEFAULT_FILL else "discs.generate.radius",
                    f"{gen.n} discs of radius {gen.radius:g} covering {fill:g} of the workspace "
                    f"need one of radius {ws.radius:.3g}, beyond the coordinate limit "
                    f"{COORD_LIMIT:g}",
                )
            ]
        )
    half = math.ceil(ws.radius) + 1.0
    label = name or f"random{gen.n}-seed{gen.seed}"
    if dim == 3:
        label = name or f"spheres{gen.n}-seed{gen.seed}"
        data3 = {
            "cellplan": 2,
            "name": label,
            "description": f"{gen.n} generated spheres filling {fill:g} of a ball",
            "workcell": {
                "bounds": {
                    "xmin": -half,
                    "ymin": -half,
                    "zmin": -half,
                    "xmax": half,
                    "ymax": half,
                    "zmax": half,
                }
            },
            "discs": {
                "boundary": {"type": "disc", "center": [0.0, 0.0, 0.0], "radius": ws.radius},
                "generate": dict(generate),
            },
        }
        return Setup(scenario_from_data(data3, source=label), label)
    data = {
        "cellplan": 1,
        "name": label,
        "description": f"{gen.n} generated discs covering {fill:g} of a circular workspace",
        "workcell": {"bounds": {"xmin": -half, "ymin": -half, "xmax": half, "ymax": half}},
        "discs": {
            "boundary": {"type": "disc", "center": [0.0, 0.0], "radius": ws.radius},
            "generate": dict(generate),
        },
    }
    return Setup(scenario_from_data(data, source=label), label)


#: How :func:`random_setup` names the generator's fields in its problems.
_RANDOM_NAMES = {
    "discs.generate.n": "n",
    "discs.generate.seed": "seed",
    "discs.generate.radius": "radius",
    "discs.generate.log10_beta_goal": "log10_beta",
    "discs.generate.pattern": "pattern",
    "fill": "fill",
    "dim": "dim",
}


def random_setup(
    n: int,
    seed: int | None = None,
    radius: float | None = None,
    fill: float | None = None,
    permutation: bool = False,
    log10_beta: float | None = None,
    dim: int = 2,
    pattern: str | None = None,
) -> Setup:
    """A random disc-assembly scenario (Section 5's problems): what ``assemble --random`` plans.

    n discs of the given radius, goals on a hexagonal cluster (gap 0.1 radius, or the gap
    whose pairwise ``beta(d)`` is ``10**log10_beta``, Fig. 5), starts random legal
    positions or (``permutation``) a random permutation of the goals (Section 5.2.2), in
    a circular workspace the discs cover ``fill`` of. ``None``: the generator's default
    (:class:`~cellplan.assembly.section.GeneratorSpec`; ``fill``: :data:`DEFAULT_FILL`).
    ``dim`` 3: spheres in a ball (the close-packed cluster, or ``pattern="stack"``).

    Raises
    ------
    ArgumentError
        One problem per bad argument, named as the parameter (``n``, ``fill`` ...).
    """
    generate: dict[str, Any] = {"n": n}
    if seed is not None:
        generate["seed"] = seed
    if radius is not None:
        generate["radius"] = radius
    if permutation:
        generate["starts"] = "permutation"
    if log10_beta is not None:
        generate["log10_beta_goal"] = log10_beta
    if pattern is not None:
        generate["pattern"] = pattern
    try:
        return generated_setup(generate, DEFAULT_FILL if fill is None else fill, dim=dim)
    except ScenarioError as exc:
        raise ArgumentError(
            [Problem(_RANDOM_NAMES.get(p.field, p.field), p.message) for p in exc.problems]
        ) from None

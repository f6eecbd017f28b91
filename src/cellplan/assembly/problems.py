"""Disc assembly problems: from a ``discs:`` section, or generated from a seed.

A :class:`DiscProblem` holds radii, start and goal centres and the workspace. The
generator follows Section 5 of the paper: random legal starts (Figs. 3-4), packed
goal patterns of chosen difficulty ``beta(d)`` (Fig. 5: from 1e-2 to 1e-44 for seven
discs) and random permutations of the goal positions as starts (Section 5.2.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from cellplan.errors import Problem, ScenarioError

if TYPE_CHECKING:
    from cellplan.assembly.section import DiscsSection, GeneratorSpec
    from cellplan.scenario import Scenario

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CircleWorkspace:
    """A circular workspace."""

    center: Array
    radius: float

    def area(self) -> float:
        return math.pi * self.radius**2


@dataclass(frozen=True)
class BoxWorkspace:
    """A rectangular workspace ``[lo, hi]``."""

    lo: Array
    hi: Array

    def area(self) -> float:
        return float(np.prod(self.hi - self.lo))


Workspace = CircleWorkspace | BoxWorkspace


@dataclass(frozen=True)
class DiscProblem:
    """n discs with radii (n,), start and goal centres (n, 2), in a workspace."""

    radii: Array
    start: Array
    goal: Array
    workspace: Workspace

    @property
    def n(self) -> int:
        return int(self.radii.shape[0])

    def with_start(self, start: Array) -> DiscProblem:
        return DiscProblem(self.radii, np.asarray(start, dtype=float), self.goal, self.workspace)


def workspace_center(ws: Workspace) -> Array:
    """Centre of the workspace (where patterns are placed)."""
    return ws.center if isinstance(ws, CircleWorkspace) else 0.5 * (ws.lo + ws.hi)


def legality_problems(pos: Array, radii: Array, ws: Workspace) -> list[tuple[int, str]]:
    """``(disc index, message)`` for every disc outside the boundary or touching another.

    Section 2: both start and goal must be legal, no discs touch and all lie strictly
    inside the boundary. A contact between i < j is reported on disc j.
    """
    from cellplan.assembly.navigation import clearances

    out: list[tuple[int, str]] = []
    gaps, bgap = clearances(pos, radii, ws)
    for i in np.flatnonzero(bgap <= 0):
        out.append((int(i), f"disc at ({pos[i, 0]:g}, {pos[i, 1]:g}) with radius "
                            f"{radii[i]:g} is not strictly inside the workspace boundary"))
    ii, jj = np.nonzero(np.triu(gaps <= 0, 1))
    for i, j in zip(ii, jj, strict=True):
        out.append((int(j), f"touches or overlaps disc {int(i)} (gap {gaps[i, j]:.3g})"))
    return out


def boundary_from_section(section: DiscsSection, scenario: Scenario) -> Workspace:
    """The workspace of a ``discs:`` section (its own disc, or the workcell rectangle)."""
    if section.boundary.type == "disc":
        return CircleWorkspace(np.array(section.boundary.center, dtype=float),
                               float(section.boundary.radius))
    bounds = scenario.workcell.bounds
    return BoxWorkspace(np.array([bounds.xmin, bounds.ymin]), np.array([bounds.xmax, bounds.ymax]))


# --- goal patterns ---------------------------------------------------------------------------


def hex_pattern(n: int, radius: float, gap: float, center: Array) -> Array:
    """n goal centres on a triangular lattice (spacing ``2 radius + gap``) nearest ``center``.

    Seven discs give the paper's hexagonal cluster (one disc and a ring of six).
    """
    s = 2.0 * radius + gap
    m = int(math.ceil(math.sqrt(n))) + 2
    ia, ic = np.meshgrid(np.arange(-m, m + 1), np.arange(-m, m + 1), indexing="ij")
    a, c = ia.ravel().astype(float), ic.ravel().astype(float)
    pts = np.stack([a + 0.5 * c, c * math.sqrt(3.0) / 2.0], axis=1)
    r = np.round(np.hypot(pts[:, 0], pts[:, 1]), 9)
    ang = np.round(np.arctan2(pts[:, 1], pts[:, 0]), 9)
    order = np.lexsort((ang, r))[:n]
    return center + s * pts[order]


def log10_beta_pairs(pos: Array, radii: Array) -> float:
    """log10 of the paper's ``beta`` (equation (4), pairs only) at ``pos``."""
    from cellplan.assembly.navigation import log_beta_parts

    pairs, _ = log_beta_parts(pos, radii, None)
    return pairs / math.log(10.0)


def gap_for_beta(n: int, radius: float, log10_beta: float) -> float:
    """The hex-pattern gap whose pairwise ``beta(d)`` has the given log10 (bisection).

    ``beta(d)`` grows monotonically with the gap, so bisection on ``log(gap)`` works.
    """
    radii = np.full(n, radius)
    zero = np.zeros(2)
    lo, hi = math.log(1e-14 * radius), math.log(100.0 * radius)

    def f(log_gap: float) -> float:
        return log10_beta_pairs(hex_pattern(n, radius, math.exp(log_gap), zero), radii) - log10_beta

    if f(lo) > 0 or f(hi) < 0:
        raise ValueError(f"log10 beta(d) = {log10_beta} is out of reach for {n} discs")
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if f(mid) > 0:
            hi = mid
        else:
            lo = mid
    return math.exp(0.5 * (lo + hi))


# --- random starts and permutations ----------------------------------------------------------


def random_legal(n: int, radii: Array, ws: Workspace, rng: np.random.Generator,
                 min_gap: float, batch: int = 512, tries: int = 200) -> Array:
    """n random centres inside ``ws``, pairwise gaps above ``min_gap`` (sequential adsorption).

    Candidates are drawn uniformly in batches and tested against the discs already
    placed in one vectorised step.

    Raises
    ------
    ScenarioError
        When a disc cannot be placed (the workspace is too crowded).
    """
    pos = np.zeros((n, 2))
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
            raise ScenarioError([Problem("discs.generate.n",
                                         f"cannot place {n} discs: the workspace is too crowded")])
    return pos


def _uniform_in(ws: Workspace, margin: float, m: int, rng: np.random.Generator) -> Array:
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
    gap = gen.gap if gen.log10_beta_goal is None else gap_for_beta(
        gen.n, gen.radius, gen.log10_beta_goal)
    return hex_pattern(gen.n, gen.radius, gap, workspace_center(ws))


def generate_problem(gen: GeneratorSpec, ws: Workspace, seed: int | None = None) -> DiscProblem:
    """A problem from a generator spec; ``seed`` overrides ``gen.seed`` (for sweeps)."""
    rng = np.random.default_rng(gen.seed if seed is None else seed)
    radii = np.full(gen.n, gen.radius)
    goal = generated_goals(gen, ws, rng)
    bad = legality_problems(goal, radii, ws)
    if bad:
        i, msg = bad[0]
        raise ScenarioError([Problem("discs.generate",
                                     f"the goal pattern is illegal: disc {i} {msg}")])
    if gen.starts == "permutation":
        start = goal[random_permutation(gen.n, rng)]
    else:
        start = random_legal(gen.n, radii, ws, rng, gen.min_start_gap)
    return DiscProblem(radii, start, goal, ws)


def generator_problems(gen: GeneratorSpec, ws: Workspace) -> list[Problem]:
    """Problems with a generator spec found before any run (pattern fit, crowding)."""
    problems: list[Problem] = []
    if gen.log10_beta_goal is not None and gen.pattern != "hex":
        problems.append(Problem("discs.generate.log10_beta_goal", "needs pattern: hex"))
        return problems
    fill = gen.n * math.pi * (gen.radius + gen.min_start_gap) ** 2 / ws.area()
    if fill > 0.5:
        problems.append(Problem("discs.generate.n", f"{gen.n} discs of radius {gen.radius:g} "
                                f"fill {fill:.0%} of the workspace; at most 50% can be sampled"))
        return problems
    if gen.pattern == "hex":
        try:
            gap = gen.gap if gen.log10_beta_goal is None else gap_for_beta(
                gen.n, gen.radius, gen.log10_beta_goal)
        except ValueError as exc:
            problems.append(Problem("discs.generate.log10_beta_goal", str(exc)))
            return problems
        goal = hex_pattern(gen.n, gen.radius, gap, workspace_center(ws))
        for i, msg in legality_problems(goal, np.full(gen.n, gen.radius), ws):
            problems.append(Problem("discs.generate", f"goal pattern disc {i} {msg}"))
    return problems


def problem_from_section(section: DiscsSection, scenario: Scenario,
                         seed: int | None = None) -> DiscProblem:
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
    problems = [Problem(f"discs[{i}].{which}", msg)
                for which, pos in (("start", problem.start), ("goal", problem.goal))
                for i, msg in legality_problems(pos, problem.radii, problem.workspace)]
    if problems:
        raise ScenarioError(problems)


#: Fraction of the workspace area the discs of a generated problem cover (see docs/assembly.md,
#: "The problem distribution"): the paper gives no workspace, and the path-length ratio of
#: Figs. 3-4 depends on how far out the random starts lie.
DEFAULT_FILL = 0.05


def default_workspace(n: int, radius: float = 1.0, fill: float = DEFAULT_FILL) -> CircleWorkspace:
    """The circular workspace of generated problems: n discs cover ``fill`` of its area.

    Radius ``rho sqrt(n / fill)``: 11.8 for seven unit discs, 14.1 for ten, 31.6 for fifty
    at the default 5%. A constant fill keeps the density of the random starts the same for
    every n, so a larger problem is harder only by its own geometry, not by a more
    crowded sampler.
    """
    if not 0.0 < fill <= 0.5:
        raise ValueError(f"fill must be in (0, 0.5], got {fill}")
    return CircleWorkspace(np.zeros(2), radius * math.sqrt(n / fill))

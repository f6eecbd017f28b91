"""Disc layouts without the navigation function: workspaces, clearances, legality, patterns.

Everything :meth:`~cellplan.assembly.section.DiscsSection.check` needs to validate a
``discs:`` section lives here, so that loading a scenario imports no algorithm module
(no navigation function, no flow, no numba kernel): the workspaces, the pairwise and
boundary terms of ``beta`` (equations (4), (5) and our boundary factor, used for the
clearances and for the goal patterns' difficulty ``beta(d)``), legality (Section 2),
the hexagonal goal patterns of Fig. 5 and the checks of a generator spec.
:mod:`cellplan.assembly.navigation` and :mod:`cellplan.assembly.problems` import these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from cellplan.errors import Problem
from cellplan.scenario3d import Bounds3

if TYPE_CHECKING:
    from cellplan.assembly.section import DiscsSection, GeneratorSpec
    from cellplan.scenario import Scenario

Array = NDArray[np.float64]


def ball_volume(radius: float | Array, dim: int) -> float | Array:
    """Measure of a ``dim``-ball: ``pi r^2`` (a disc), ``4/3 pi r^3`` (a sphere)."""
    if dim == 2:
        return math.pi * radius**2
    return 4.0 / 3.0 * math.pi * radius**3


@dataclass(frozen=True)
class CircleWorkspace:
    """A circular (2-D) or spherical (3-D) workspace: ``center`` has ``dim`` coordinates."""

    center: Array
    radius: float

    @property
    def dim(self) -> int:
        return int(self.center.shape[0])

    def area(self) -> float:
        """The workspace's measure: its area in 2-D, its volume in 3-D."""
        return float(ball_volume(self.radius, self.dim))


@dataclass(frozen=True)
class BoxWorkspace:
    """A rectangular (2-D) or box (3-D) workspace ``[lo, hi]``."""

    lo: Array
    hi: Array

    @property
    def dim(self) -> int:
        return int(self.lo.shape[0])

    def area(self) -> float:
        """The workspace's measure: its area in 2-D, its volume in 3-D."""
        return float(np.prod(self.hi - self.lo))


Workspace = CircleWorkspace | BoxWorkspace


def workspace_center(ws: Workspace) -> Array:
    """Centre of the workspace (where patterns are placed)."""
    return ws.center if isinstance(ws, CircleWorkspace) else 0.5 * (ws.lo + ws.hi)


def scenario_dimension(scenario: Scenario) -> int:
    """2 for a planar workcell (discs), 3 for a 3-D one (spheres): its bounds name ``zmin``."""
    return 3 if isinstance(scenario.workcell.bounds, Bounds3) else 2


def boundary_from_section(section: DiscsSection, scenario: Scenario) -> Workspace:
    """The workspace of a ``discs:`` section (its own disc or ball, or the workcell box).

    Its dimension is the workcell's (:func:`scenario_dimension`). A ball boundary whose
    ``center`` is not given is centred on the origin (the default ``(0, 0)`` is the
    planar one).
    """
    dim = scenario_dimension(scenario)
    if section.boundary.type == "disc":
        given = "center" in section.boundary.model_fields_set
        center = np.array(section.boundary.center, dtype=float) if given else np.zeros(dim)
        return CircleWorkspace(center, float(section.boundary.radius))
    bounds = scenario.workcell.bounds
    if isinstance(bounds, Bounds3):
        return BoxWorkspace(np.array(bounds.lo, dtype=float), np.array(bounds.hi, dtype=float))
    return BoxWorkspace(np.array([bounds.xmin, bounds.ymin]), np.array([bounds.xmax, bounds.ymax]))


# --- the terms of beta (equations (4), (5)) and the clearances --------------------------------


def pair_terms(b: Array, radii: Array) -> tuple[Array, Array, Array]:
    """Pairwise differences, ``beta_ij`` (equation (5)) and centre distances.

    Returns ``D`` (n, n, d) with ``D[i, j] = b_i - b_j``, ``B`` (n, n) with ``B[i, j] =
    beta_ij`` and the diagonal set to 1 (so ``log`` and ``1/B`` ignore it), and the
    distance matrix ``dist`` (n, n).
    """
    diff = b[:, None, :] - b[None, :, :]
    sq = np.einsum("ijk,ijk->ij", diff, diff)
    rsum = radii[:, None] + radii[None, :]
    B = 0.5 * (sq - rsum * rsum)
    np.fill_diagonal(B, 1.0)
    return diff, B, np.sqrt(sq)


def boundary_terms(b: Array, radii: Array, ws: Workspace) -> tuple[Array, Array]:
    """``log beta_0i`` summed per disc (n,) and ``grad_{b_i} log beta_0i`` (n, d).

    Non-positive terms (a disc touching or outside the boundary) give ``nan``/``-inf``.
    For a box, the wall distances enter per axis, lower then upper (the order of the
    sums, so that 2-D results are those of the planar code to the last bit).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        if isinstance(ws, CircleWorkspace):
            rel = b - ws.center
            w = 0.5 * ((ws.radius - radii) ** 2 - np.sum(rel * rel, axis=1))
            return np.log(w), -rel / w[:, None]
        t = _wall_terms(b, radii, ws)
        inv = 1.0 / t
        grad = inv[:, 0::2] - inv[:, 1::2]
        return np.sum(np.log(t), axis=1), grad


def _wall_terms(b: Array, radii: Array, ws: BoxWorkspace) -> Array:
    """Wall distances minus the radius, ``(n, 2 d)``: per axis the lower, then the upper."""
    lo, hi = ws.lo, ws.hi
    cols = []
    for axis in range(b.shape[1]):
        cols.append(b[:, axis] - lo[axis] - radii)
        cols.append(hi[axis] - radii - b[:, axis])
    return np.stack(cols, axis=1)


def log_beta_parts(b: Array, radii: Array, ws: Workspace | None) -> tuple[float, float]:
    """``(log prod_{i<j} beta_ij, log prod_i beta_0i)``; ``-inf``/``nan`` in contact."""
    _, B, _ = pair_terms(b, radii)
    with np.errstate(divide="ignore", invalid="ignore"):
        pairs = 0.5 * float(np.sum(np.log(B)))
    if ws is None:
        return pairs, 0.0
    logs, _ = boundary_terms(b, radii, ws)
    return pairs, float(np.sum(logs))


def clearances(b: Array, radii: Array, ws: Workspace) -> tuple[Array, Array]:
    """Gaps between discs (n, n; diagonal ``inf``) and to the boundary (n,).

    Negative values mean overlap. The boundary gap of a box is the smallest wall gap.
    """
    _, _, dist = pair_terms(b, radii)
    gaps = dist - (radii[:, None] + radii[None, :])
    np.fill_diagonal(gaps, np.inf)
    if isinstance(ws, CircleWorkspace):
        bgap = ws.radius - radii - np.sqrt(np.sum((b - ws.center) ** 2, axis=1))
    else:
        assert isinstance(ws, BoxWorkspace)
        walls = [c for a in range(b.shape[1]) for c in (b[:, a] - ws.lo[a], ws.hi[a] - b[:, a])]
        bgap = np.min(np.stack(walls, axis=1), axis=1) - radii
    return gaps, bgap


def min_clearance(b: Array, radii: Array, ws: Workspace) -> float:
    """Smallest gap between two discs or a disc and the boundary."""
    gaps, bgap = clearances(b, radii, ws)
    return float(min(np.min(gaps), np.min(bgap)))


# --- legality (Section 2) --------------------------------------------------------------------


def legality_problems(
    pos: Array, radii: Array, ws: Workspace, where: str = ""
) -> list[tuple[int, str]]:
    """``(disc index, message)`` for every disc outside the boundary or touching another.

    Section 2: both start and goal must be legal, no discs touch and all lie strictly
    inside the boundary. A contact between i < j is reported on disc j. Messages name
    discs as people count them, from 1 (``disc 1`` is index 0; docs/assembly.md "Disc
    numbers"); ``where`` (e.g. ``discs.discs``) adds the other disc's list entry in the
    scenario file, ``disc 1 (discs.discs[0])``.
    """
    out: list[tuple[int, str]] = []
    gaps, bgap = clearances(pos, radii, ws)
    for i in np.flatnonzero(bgap <= 0):
        out.append(
            (
                int(i),
                f"disc {int(i) + 1} at ({', '.join(f'{c:g}' for c in pos[i])}) with radius "
                f"{radii[i]:g} is not strictly inside the workspace boundary",
            )
        )
    ii, jj = np.nonzero(np.triu(gaps <= 0, 1))
    for i, j in zip(ii, jj, strict=True):
        entry = f"{where}[{int(i)}], " if where else ""
        out.append(
            (
                int(j),
                f"disc {int(j) + 1} touches or overlaps disc {int(i) + 1} "
                f"({entry}gap {gaps[i, j]:.3g})",
            )
        )
    return out


# --- goal patterns (Fig. 5) ------------------------------------------------------------------


def hex_pattern(n: int, radius: float, gap: float, center: Array) -> Array:
    """n goal centres on a triangular lattice (spacing ``2 radius + gap``) nearest ``center``.

    Seven discs give the paper's hexagonal cluster (one disc and a ring of six). With a
    3-D ``center`` the pattern is the close-packed cluster of :func:`close_packed_pattern`.
    """
    if center.shape[0] == 3:
        return close_packed_pattern(n, radius, gap, center)
    s = 2.0 * radius + gap
    m = int(math.ceil(math.sqrt(n))) + 2
    ia, ic = np.meshgrid(np.arange(-m, m + 1), np.arange(-m, m + 1), indexing="ij")
    a, c = ia.ravel().astype(float), ic.ravel().astype(float)
    pts = np.stack([a + 0.5 * c, c * math.sqrt(3.0) / 2.0], axis=1)
    r = np.round(np.hypot(pts[:, 0], pts[:, 1]), 9)
    ang = np.round(np.arctan2(pts[:, 1], pts[:, 0]), 9)
    order = np.lexsort((ang, r))[:n]
    return center + s * pts[order]


def _fcc_points(m: int) -> Array:
    """Face-centred cubic lattice points of unit nearest-neighbour distance, ``|i| <= m``."""
    r = np.arange(-m, m + 1)
    ijk = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    ijk = ijk[np.sum(ijk, axis=1) % 2 == 0]
    return ijk.astype(float) / math.sqrt(2.0)


def close_packed_pattern(n: int, radius: float, gap: float, center: Array) -> Array:
    """n sphere centres of a compact face-centred cubic cluster (spacing ``2 radius + gap``).

    Our 3-D counterpart of the paper's hexagonal cluster (the paper has discs only):
    grown from one sphere at ``center``, each next sphere is the lattice site touching
    the most spheres already placed, ties going to the site nearest the cluster's
    centroid, then to the lowest ``(z, y, x)``; the cluster's centroid is ``center``.
    Four spheres give a tetrahedron, six an octahedron, seven a capped octahedron; every
    sphere touches at least three others (from four on), which makes these goals the
    tight packings of Fig. 5 in 3-D.
    """
    s = 2.0 * radius + gap
    m = int(math.ceil(n ** (1.0 / 3.0))) + 2
    pts = _fcc_points(m)
    pts = pts[np.argsort(np.linalg.norm(pts, axis=1), kind="stable")]
    chosen = [int(np.flatnonzero(np.all(pts == 0.0, axis=1))[0])]
    contacts = np.zeros(len(pts), dtype=np.int64)
    taken = np.zeros(len(pts), dtype=bool)
    for _ in range(n - 1):
        last = chosen[-1]
        taken[last] = True
        contacts += np.abs(np.linalg.norm(pts - pts[last], axis=1) - 1.0) < 1e-9
        centroid = pts[chosen].mean(axis=0)
        dist = np.round(np.linalg.norm(pts - centroid, axis=1), 9)
        score = np.where(taken, -1, contacts)
        order = np.lexsort((pts[:, 0], pts[:, 1], pts[:, 2], dist, -score))
        chosen.append(int(order[0]))
    cluster = pts[chosen]
    out: Array = center + s * (cluster - cluster.mean(axis=0))
    return out


def stack_pattern(n: int, radius: float, gap: float, center: Array) -> Array:
    """A two-layer stack of spheres (spacing ``2 radius + gap``) around ``center``.

    The lower layer is the hexagonal cluster of :func:`hex_pattern` (``ceil(n / 2)``
    spheres, 7 for 13); the upper layer sits in the hollows of one kind (the B
    sites of a close packing, at height ``s sqrt(2/3)``) nearest the axis; the
    centroid is ``center``. 13 spheres give
    7 below and 6 above.
    """
    s = 2.0 * radius + gap
    lower = (n + 1) // 2
    base = hex_pattern(lower, radius, gap, np.zeros(2))
    # the B hollows: the triangular lattice shifted by (s/2, s/(2 sqrt 3))
    hollows = hex_pattern(4 * n, radius, gap, np.zeros(2)) + np.array(
        [0.5 * s, 0.5 * s / math.sqrt(3.0)]
    )
    order = np.lexsort(
        (np.arctan2(hollows[:, 1], hollows[:, 0]), np.round(np.hypot(*hollows.T), 9))
    )
    upper = hollows[order[: n - lower]]
    height = s * math.sqrt(2.0 / 3.0)
    pts = np.concatenate([np.c_[base, np.zeros(lower)], np.c_[upper, np.full(n - lower, height)]])
    out: Array = center + (pts - pts.mean(axis=0))
    return out


def log10_beta_pairs(pos: Array, radii: Array) -> float:
    """log10 of the paper's ``beta`` (equation (4), pairs only) at ``pos``."""
    pairs, _ = log_beta_parts(pos, radii, None)
    return pairs / math.log(10.0)


def gap_for_beta(n: int, radius: float, log10_beta: float, dim: int = 2) -> float:
    """The hex-pattern gap whose pairwise ``beta(d)`` has the given log10 (bisection).

    ``beta(d)`` grows monotonically with the gap, so bisection on ``log(gap)`` works.
    ``dim`` 3: the close-packed cluster of :func:`close_packed_pattern`.
    """
    radii = np.full(n, radius)
    zero = np.zeros(dim)
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


def generator_problems(gen: GeneratorSpec, ws: Workspace) -> list[Problem]:
    """Problems with a generator spec found before any run (pattern fit, crowding)."""
    problems: list[Problem] = []
    if gen.log10_beta_goal is not None and gen.pattern != "hex":
        problems.append(Problem("discs.generate.log10_beta_goal", "needs pattern: hex"))
        return problems
    if gen.pattern == "stack" and ws.dim != 3:
        problems.append(
            Problem("discs.generate.pattern", "stack is a 3-D pattern; this workcell is 2d")
        )
        return problems
    if ws.dim == 2:
        fill = gen.n * math.pi * (gen.radius + gen.min_start_gap) ** 2 / ws.area()
    else:
        fill = gen.n * float(ball_volume(gen.radius + gen.min_start_gap, 3)) / ws.area()
    if fill > 0.5:
        problems.append(
            Problem(
                "discs.generate.n",
                f"{gen.n} discs of radius {gen.radius:g} "
                f"fill {fill:.0%} of the workspace; at most 50% can be sampled",
            )
        )
        return problems
    if gen.pattern == "stack":
        goal = stack_pattern(gen.n, gen.radius, gen.gap, workspace_center(ws))
        for _, msg in legality_problems(goal, np.full(gen.n, gen.radius), ws):
            problems.append(Problem("discs.generate", f"goal pattern: {msg}"))
    if gen.pattern == "hex":
        try:
            gap = (
                gen.gap
                if gen.log10_beta_goal is None
                else gap_for_beta(gen.n, gen.radius, gen.log10_beta_goal, ws.dim)
            )
        except ValueError as exc:
            problems.append(Problem("discs.generate.log10_beta_goal", str(exc)))
            return problems
        goal = hex_pattern(gen.n, gen.radius, gap, workspace_center(ws))
        for _, msg in legality_problems(goal, np.full(gen.n, gen.radius), ws):
            problems.append(Problem("discs.generate", f"goal pattern: {msg}"))
    return problems


#: Fraction of the workspace area the discs of a generated problem cover (see docs/assembly.md,
#: "The problem distribution"): the paper gives no workspace, and the path-length ratio of
#: Figs. 3-4 depends on how far out the random starts lie.
DEFAULT_FILL = 0.05


def default_workspace(
    n: int, radius: float = 1.0, fill: float = DEFAULT_FILL, dim: int = 2
) -> CircleWorkspace:
    """The circular workspace of generated problems: n discs cover ``fill`` of its area.

    ``dim`` 3: the ball that n spheres fill ``fill`` of, radius ``rho (n / fill)^(1/3)``
    (5.19 for seven unit spheres at 5%).

    Radius ``rho sqrt(n / fill)``: 11.8 for seven unit discs, 14.1 for ten, 31.6 for fifty
    at the default 5%. A constant fill keeps the density of the random starts the same for
    every n, so a larger problem is harder only by its own geometry, not by a more
    crowded sampler.
    """
    if not 0.0 < fill <= 0.5:
        raise ValueError(f"fill must be in (0, 0.5], got {fill}")
    if dim == 3:
        return CircleWorkspace(np.zeros(3), radius * (n / fill) ** (1.0 / 3.0))
    return CircleWorkspace(np.zeros(2), radius * math.sqrt(n / fill))


# --- the default k (docs/assembly.md "The default k") ----------------------------------------

#: Constant of the default-k rule ``k = K_RULE_C * n^2 / fill`` (fill: the fraction of the
#: workspace's area the discs cover), fitted on the fitting grid of
#: ``benchmarks/fit_assembly_k.py`` (never on the reporting sets).
K_RULE_C = 0.05
#: The rule's constant for spheres (3-D), fitted on the spheres' own fitting grid
#: (``benchmarks/assembly_sets.py --spheres-fit-k``: 5 and 10 spheres, seeds 1000-1007,
#: never the reporting seeds): at the planar 0.05 the mean ratio was 3.9 (k at its floor
#: of 16, half the flows stuck), at 0.2 1.79, at 0.8 1.49, at 3.2 1.46 with a quarter of
#: the clearance; docs/assembly.md "Spheres".
K_RULE_C_3D = 0.8
#: Smallest k of the rule (small problems: the paper's examples need k of tens).
K_RULE_MIN = 16.0


def workspace_area(ws: Workspace) -> float:
    """Area of the workspace (its volume in 3-D)."""
    if ws.dim == 3:
        return ws.area()
    if isinstance(ws, CircleWorkspace):
        return math.pi * ws.radius**2
    side = ws.hi - ws.lo
    return float(side[0] * side[1])


def rule_k(radii: Array, ws: Workspace) -> float:
    """The default k when neither the caller nor the scenario gives one.

    ``k = K_RULE_C * n^2 / fill`` with ``fill = sum(pi rho_i^2) / area``, at least
    ``K_RULE_MIN``. Why this form: the repulsion in the flow's direction
    ``v = (b - d) - (gamma / k) grad log beta`` (equation (8)) is weighted by
    ``gamma / k``; ``gamma = 1/2 sum ||b_i - d_i||^2`` (equation (3)) of a start spread
    over the workspace is about ``n`` times its squared size ``n rho^2 / fill``, i.e.
    ``n^2 rho^2 / fill``, so k in proportion (in disc radii) keeps that weight the same
    for every n and workspace. Too small a k pushes the discs apart into a far spurious
    minimum, too large a one lets them graze; the constant was fitted on the fitting
    grid (docs/assembly.md, "The default k"). The rule is scale-free (lengths enter only
    through the fill), as the paths are ("What the paper does not fix").

    Spheres: the squared size of a start is ``(n rho^3 / fill)^(2/3)`` with the volume
    fill, so ``k = K_RULE_C_3D * n (n / fill)^(2/3)``, with its own fitted constant.
    """
    n = int(radii.shape[0])
    if ws.dim == 3:
        # the same weight in 3-D: the squared size of the start is (n rho^3 / fill)^(2/3)
        fill3 = float(np.sum(ball_volume(radii, 3))) / workspace_area(ws)
        return max(K_RULE_MIN, K_RULE_C_3D * n * (n / fill3) ** (2.0 / 3.0))
    fill = float(np.sum(math.pi * radii**2)) / workspace_area(ws)
    return max(K_RULE_MIN, K_RULE_C * n * n / fill)

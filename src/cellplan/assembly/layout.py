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


def workspace_center(ws: Workspace) -> Array:
    """Centre of the workspace (where patterns are placed)."""
    return ws.center if isinstance(ws, CircleWorkspace) else 0.5 * (ws.lo + ws.hi)


def boundary_from_section(section: DiscsSection, scenario: Scenario) -> Workspace:
    """The workspace of a ``discs:`` section (its own disc, or the workcell rectangle)."""
    if section.boundary.type == "disc":
        return CircleWorkspace(
            np.array(section.boundary.center, dtype=float), float(section.boundary.radius)
        )
    bounds = scenario.workcell.bounds
    return BoxWorkspace(np.array([bounds.xmin, bounds.ymin]), np.array([bounds.xmax, bounds.ymax]))


# --- the terms of beta (equations (4), (5)) and the clearances --------------------------------


def pair_terms(b: Array, radii: Array) -> tuple[Array, Array, Array]:
    """Pairwise differences, ``beta_ij`` (equation (5)) and centre distances.

    Returns ``D`` (n, n, 2) with ``D[i, j] = b_i - b_j``, ``B`` (n, n) with ``B[i, j] =
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
    """``log beta_0i`` summed per disc (n,) and ``grad_{b_i} log beta_0i`` (n, 2).

    Non-positive terms (a disc touching or outside the boundary) give ``nan``/``-inf``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        if isinstance(ws, CircleWorkspace):
            rel = b - ws.center
            w = 0.5 * ((ws.radius - radii) ** 2 - np.sum(rel * rel, axis=1))
            return np.log(w), -rel / w[:, None]
        lo, hi = ws.lo, ws.hi
        t = np.stack(
            [
                b[:, 0] - lo[0] - radii,
                hi[0] - radii - b[:, 0],
                b[:, 1] - lo[1] - radii,
                hi[1] - radii - b[:, 1],
            ],
            axis=1,
        )
        inv = 1.0 / t
        grad = np.stack([inv[:, 0] - inv[:, 1], inv[:, 2] - inv[:, 3]], axis=1)
        return np.sum(np.log(t), axis=1), grad


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
        bgap = (
            np.min(
                np.stack(
                    [
                        b[:, 0] - ws.lo[0],
                        ws.hi[0] - b[:, 0],
                        b[:, 1] - ws.lo[1],
                        ws.hi[1] - b[:, 1],
                    ],
                    axis=1,
                ),
                axis=1,
            )
            - radii
        )
    return gaps, bgap


def min_clearance(b: Array, radii: Array, ws: Workspace) -> float:
    """Smallest gap between two discs or a disc and the boundary."""
    gaps, bgap = clearances(b, radii, ws)
    return float(min(np.min(gaps), np.min(bgap)))


# --- legality (Section 2) --------------------------------------------------------------------


def legality_problems(pos: Array, radii: Array, ws: Workspace) -> list[tuple[int, str]]:
    """``(disc index, message)`` for every disc outside the boundary or touching another.

    Section 2: both start and goal must be legal, no discs touch and all lie strictly
    inside the boundary. A contact between i < j is reported on disc j.
    """
    out: list[tuple[int, str]] = []
    gaps, bgap = clearances(pos, radii, ws)
    for i in np.flatnonzero(bgap <= 0):
        out.append(
            (
                int(i),
                f"disc at ({pos[i, 0]:g}, {pos[i, 1]:g}) with radius "
                f"{radii[i]:g} is not strictly inside the workspace boundary",
            )
        )
    ii, jj = np.nonzero(np.triu(gaps <= 0, 1))
    for i, j in zip(ii, jj, strict=True):
        out.append((int(j), f"touches or overlaps disc {int(i)} (gap {gaps[i, j]:.3g})"))
    return out


# --- goal patterns (Fig. 5) ------------------------------------------------------------------


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


def generator_problems(gen: GeneratorSpec, ws: Workspace) -> list[Problem]:
    """Problems with a generator spec found before any run (pattern fit, crowding)."""
    problems: list[Problem] = []
    if gen.log10_beta_goal is not None and gen.pattern != "hex":
        problems.append(Problem("discs.generate.log10_beta_goal", "needs pattern: hex"))
        return problems
    fill = gen.n * math.pi * (gen.radius + gen.min_start_gap) ** 2 / ws.area()
    if fill > 0.5:
        problems.append(
            Problem(
                "discs.generate.n",
                f"{gen.n} discs of radius {gen.radius:g} "
                f"fill {fill:.0%} of the workspace; at most 50% can be sampled",
            )
        )
        return problems
    if gen.pattern == "hex":
        try:
            gap = (
                gen.gap
                if gen.log10_beta_goal is None
                else gap_for_beta(gen.n, gen.radius, gen.log10_beta_goal)
            )
        except ValueError as exc:
            problems.append(Problem("discs.generate.log10_beta_goal", str(exc)))
            return problems
        goal = hex_pattern(gen.n, gen.radius, gap, workspace_center(ws))
        for i, msg in legality_problems(goal, np.full(gen.n, gen.radius), ws):
            problems.append(Problem("discs.generate", f"goal pattern disc {i} {msg}"))
    return problems


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


# --- the default k (docs/assembly.md "The default k") ----------------------------------------

#: Constant of the default-k rule ``k = K_RULE_C * n^2 / fill`` (fill: the fraction of the
#: workspace's area the discs cover), fitted on the fitting grid of
#: ``benchmarks/fit_assembly_k.py`` (never on the reporting sets).
K_RULE_C = 0.05
#: Smallest k of the rule (small problems: the paper's examples need k of tens).
K_RULE_MIN = 16.0


def workspace_area(ws: Workspace) -> float:
    """Area of the workspace."""
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
    """
    n = int(radii.shape[0])
    fill = float(np.sum(math.pi * radii**2)) / workspace_area(ws)
    return max(K_RULE_MIN, K_RULE_C * n * n / fill)

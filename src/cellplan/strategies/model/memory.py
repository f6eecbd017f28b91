"""The memory of a model build and its solve, estimated before anything is allocated.

:func:`estimate_memory` counts the arrays of :func:`~.mdp.build_model` and the solver, per
grid cell (``N``), with ``M`` modes (NR, two per request, the X modes of
rejected parts), ``K`` move classes (at most NR, one per source and one per carried
(part, source)), ``A`` actions (with their noisy landings), ``d`` axes:

* model (:class:`~.layered.LayeredMDP`, alive throughout): ``tf`` float64 ``(O, N)`` (``O`` FMP
  options: ``M`` but with simultaneous requests, whose ``M`` and ``O`` follow
  ``max_pending``, :func:`~cellplan.strategies.variants.request_sets.mode_counts`), ``live``
  bool ``(M, N)``, ``free`` and ``interior`` bool ``(K, N)``, ``valid`` int64 ``(K, N)``;
* building (:func:`~.mdp.build_model`): the geometry's bitmaps (bool: NR, one per source,
  two per (part, source), one per (part, destination)) and fine-motion fields
  (float64 per (part, source) and (part, destination)), the cell centres and tool
  poses (float64 ``(N, 2 d + 3)``: the centres are computed twice), the stacked
  class bitmaps (two bool ``(K, N)``), and :func:`~.tables.corner_tables`' index grid
  (int64 ``(d + 1, N)``);
* solver (its peak is the final certificate, :func:`~.solver._finish`): ``h`` and
  ``D`` float64 and the policy int16 ``(M, N)``, the NR action sums ``E`` and ``ED``
  float64 ``(N, A + 1)``, NR's values and ``D`` before a sweep (float64 ``N`` each,
  read across its slabs), a trial copy of ``h``, the certificate's Bellman sweep (value,
  int64 policy, gap: three ``(M, N)`` of 8 bytes), the stability test's slack (two
  float64 temporaries), its mask (bool) and shifted values (float64), and its second
  Bellman sweep (three more 8-byte ``(M, N)``);
  or, if larger, the bitmaps plus the working arrays of the largest single
  :func:`~cellplan.cspace.free_bitmap` call (:func:`cellplan.cspace.estimate_memory`;
  the calls run one after another, and dominate on small grids);
* tables: the stencil tables, float64/int64 ``(K, A, T, d)`` twice and
  ``(K, A, T, 2^d)`` twice (small);
* policy (policy iteration, :mod:`~.policy_iteration`, in place of ``solver`` when
  ``method`` is ``policy``, or ``auto`` with failure modes or noise, which ``auto``
  solves by policy iteration; ``method`` defaults to ``strategy.solver.method``): with
  ``S <= M N`` live states and ``Z = 2^d J N sum_m B_m`` places for the rows of a
  policy's matrix (``B_m`` the branches of mode ``m``: NR has one per request and
  itself, a W or C layer itself and the requests it can change into; ``J`` landings
  per move with noise, else 1; an X mode of failure modes has one branch),
  the state index (int64 ``(M, N)``), the values, the certificate's three sweeps and
  the value-iteration copies (five more float64 ``(M, N)``), 44 bytes per state
  (state list, row starts, counts, cost, index pointers), 33 per place (its row and
  position, column, value, mask), and per stored entry (at most ``Z``) 44 bytes: the
  packed CSR (float64 + int32), its int64 and int32 copies, and the last matrix, alive
  while the next is assembled; plus, as the term ``factors``, the SuperLU factors of
  the recurrent class (12 bytes per entry; :data:`STATIONARY_FILL` ``Z`` entries).
  ``tracemalloc`` does not see SuperLU's own allocations: the tests compare its peak
  with the other terms and SuperLU's count of its entries with ``factors``;
* a time-varying model (Section VI-1, :mod:`cellplan.strategies.variants.periodic`) has
  the layers of every phase of its period ``P``: ``M`` and ``O`` are ``P`` times those
  of one phase (the move classes are shared) and so are the places ``Z``; the building
  step adds the phase-0 model, one phase's fields, a moved region's test and four bool
  ``(M, N)`` of the live-state pass over the phases; ``auto`` solves it by policy
  iteration, whose recurrent class is then a ring of layers through the phases, a 3-D
  grid, whose SuperLU fill grows as its size to the 4/3: at most :data:`PERIODIC_FILL`
  ``(M N)^(4/3)`` entries.

The test ``test_memory_estimate_matches_measured_allocations`` compares it with the
peak measured by ``tracemalloc``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cellplan.cspace import Grid
from cellplan.cspace import estimate_memory as bitmap_memory
from cellplan.strategies.model.mdp import action_sets, grid_shape
from cellplan.strategies.model.spec import LayerCounts, compiled


def _bitmap_peak(cell: Any, shape: tuple[int, ...], parts: Sequence[str]) -> int:
    """Working bytes of the largest C-space bitmap :func:`build_model` computes."""
    if len(shape) != cell.robot.dim:
        return 0  # build_model refuses this grid before computing any bitmap
    grid = Grid.for_robot(cell.robot, shape)
    return max(bitmap_memory(cell, grid, carrying) for carrying in [None, *parts])


#: SuperLU's factors of policy iteration's recurrent class, in entries (its own count,
#: ``SuperLU.nnz``), per place of the policy's matrix on a stationary model: at most 2.9
#: measured on the 8 models it was fitted on, 1.5 on 5 held out (:func:`estimate_memory`).
STATIONARY_FILL = 4
#: The same on a time-varying model, per ``(layers x cells)^(4/3)`` (the fill of a 3-D
#: grid: the grid and the ring of phases): at most 3.05 measured on the 9 tiny-cell
#: models it was fitted on, 2.0 on 7 held out, ``strategies_conveyor`` among them.
PERIODIC_FILL = 4.0


@dataclass(frozen=True)
class MemoryEstimate:
    """Bytes a solve will hold at its peak, from the arrays it allocates (count x dtype).

    ``terms`` names each group of arrays with its bytes; ``total`` is the model's arrays
    plus the larger of the building step's and the solver's working arrays (they are not
    alive together): ``solver`` for the structured and general solvers, ``policy`` for
    policy iteration (``method``), with ``factors``, the sparse LU factors it keeps.
    """

    cells: int
    modes: int
    classes: int
    actions: int
    terms: Mapping[str, int]

    method: str = "structured"

    @property
    def total(self) -> int:
        t = self.terms
        solver = t["policy"] + t["factors"] if self.method == "policy" else t["solver"]
        return t["model"] + t["tables"] + max(t["building"], solver)


def estimate_memory(
    problem: Any, cell: Any, cells: Sequence[int] | None = None, method: str | None = None
) -> MemoryEstimate:
    """The memory of :func:`~.mdp.build_model` and the solver on this grid, before
    allocating: the counts of the module docstring, with the sizes of the compiled
    problem after every active variant's ``layers`` hook (``method`` defaults to
    ``strategy.solver.method``). ``problem`` is the scenario or its compiled section
    (:func:`~.spec.compiled`).
    """
    spec = compiled(problem)
    scenario = spec.scenario
    sec = spec.section
    robot = cell.robot
    shape = grid_shape(scenario, cell, cells)
    d = len(shape)
    N = int(np.prod(shape, dtype=object))
    requests = list(spec.requests)
    R = len(requests)
    parts = spec.parts
    S = len(spec.sources)
    PS = len({(p, s) for p, s, *_ in requests})
    PD = len({(p, dd) for p, _, dd, _ in requests})
    counts = LayerCounts(
        modes=2 * R + 1,
        options=2 * R + 1,  # FMP options: one per mode in Section V
        classes=1 + S + PS,  # NR, one per source, one per carried (part, source)
        branches=section_v_branches(requests, sec),
    )
    for variant in spec.variants:
        counts = variant.layers(sec, requests, counts)
    # A time-varying model (Section VI-1): the layers of every phase, classes shared.
    P = counts.phases
    per_phase = counts.modes
    K = min(per_phase, counts.classes)
    M, n_opt = P * per_phase, P * counts.options
    empty, carrying = action_sets(spec, robot, parts)
    A = max([empty.disp.shape[0], *(a.disp.shape[0] for a in carrying.values())])
    heading = empty.heading_axis
    T = shape[heading] if heading >= 0 else 1
    bitmaps = 1 + S + 2 * PS + PD
    places = P * (1 << d) * counts.landings * N * counts.branches
    # SuperLU's factors of the recurrent class: a few entries per place on a stationary
    # model (STATIONARY_FILL); over a period the class is a ring of layers, a 3-D grid
    # whose fill grows as its size to the 4/3 (PERIODIC_FILL).
    lu_fill = STATIONARY_FILL * places
    if P > 1:
        # (M N)^(4/3) as M N times its integer cube root: no float overflows on any grid.
        cube_root = int(math.exp(math.log(M * N) / 3)) + 1
        lu_fill = max(lu_fill, int(PERIODIC_FILL * M * N * cube_root))
    building = N * (bitmaps + 8 * (PS + PD) + 8 * (2 * d + 3) + 2 * K + 8 * (d + 1))
    if P > 1:
        # The phase-0 model (its tf float64, live bool (M0, N)), the phases' fields (the
        # model's tf, counted there), one phase's fields and a moved region's test
        # (float64 (M0, N) and the posed bodies, float64 (N, 4 d)), and the live-state
        # pass over the phases (four bool (M, N): candidates, FMP cells, the pass and
        # the model's copy).
        building += N * (9 * per_phase + 8 * per_phase + 32 * d + 4 * M)
    terms = {
        "model": N * (8 * n_opt + M + K + K + 8 * K),
        "building": max(building, N * bitmaps + _bitmap_peak(cell, shape, parts)),
        "solver": N * (18 * M + 16 * (A + 1) + 16 + 8 * M + 24 * M + 16 * M + M + 8 * M + 24 * M),
        "tables": K * A * T * (16 * d + 16 * 2**d),
        "policy": 100 * M * N + (33 + 44) * places,
        # SuperLU's factors (C memory, which tracemalloc does not see): 12 bytes an entry.
        "factors": 12 * lu_fill,
    }
    chosen = sec.solver.method if method is None else method
    # auto picks policy iteration for every Section VI model (solver.solve).
    policy = chosen == "policy" or (chosen == "auto" and bool(spec.variants))
    return MemoryEstimate(N, M, K, A, terms, "policy" if policy else "structured")


def section_v_branches(requests: Sequence[Any], sec: Any) -> int:
    """The branches of the Section V modes, summed (:func:`estimate_memory`'s places are
    ``2^d N`` times this, per landing and phase): NR has one per request and itself, a W or
    C layer itself and the requests it can change into."""
    branches = 1 + len(requests)  # NR: itself and one per request
    for change, same in ((sec.source_change, (0, 2)), (sec.destination_change, (0, 1))):
        for p, s, dd, _ in requests:
            key = (p, s, dd)
            others = (
                sum(
                    1
                    for p2, s2, d2, _ in requests
                    if (p2, s2, d2)[same[0]] == key[same[0]]
                    and (p2, s2, d2)[same[1]] == key[same[1]]
                    and (p2, s2, d2) != key
                )
                if change is not None
                else 0
            )
            branches += 1 + others
    return branches

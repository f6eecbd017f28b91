"""Index of the strategies solver's numba kernels, which live in modules by job.

| module | kernels |
|---|---|
| :mod:`.bundles` | the typed, named model bundle every kernel takes (``Model``) |
| :mod:`.law` | the transition law: the value of an action at a cell, written once |
| :mod:`.stencils` | grid indices, multilinear stencils, sweep orders |
| :mod:`.interpolation` | interpolated cost-to-go over live corners (Section IV-B) |
| :mod:`.motion` | swept-motion checks on the free bitmaps |
| :mod:`.domain` | live states (the states that can finish their request) |
| :mod:`.sweeps` | Gauss-Seidel sweeps and policy iteration per layer |
| :mod:`.nr` | NR's sweep in slabs, its stay self-loop solved exactly |
| :mod:`.evaluation` | exact evaluation of a layer's policy (Tarjan order) |
| :mod:`.improvement` | one Jacobi policy-improvement step, vectorised over cells |
| :mod:`.coldstart` | a first policy by Dijkstra's algorithm |
| :mod:`.bellman` | the Jacobi Bellman operator over every state (certificate) |
| :mod:`.points` | equation (9) at a real state: online query, executor lookahead |
| :mod:`.pi_kernels` | policy matrix (CSR), hop distances, back-substitution |

The names below are re-exported for callers written against the single module.
"""

from __future__ import annotations

from cellplan.strategies.model.domain import live_layer
from cellplan.strategies.model.interpolation import interp, supported
from cellplan.strategies.model.motion import motion_ok, valid_moves
from cellplan.strategies.model.points import action_values_at, lookahead, query
from cellplan.strategies.model.stencils import decode, displacement, stencil, table_stencil, wrap
from cellplan.strategies.solve.bellman import bellman_all, bellman_rows
from cellplan.strategies.solve.improvement import improve_layer
from cellplan.strategies.solve.nr import other_branches, sweep_self
from cellplan.strategies.solve.sweeps import (
    dense_cells,
    layer_iteration,
    sweep_layer,
    sweep_policy,
)

__all__ = [
    "action_values_at",
    "bellman_all",
    "bellman_rows",
    "decode",
    "dense_cells",
    "displacement",
    "improve_layer",
    "interp",
    "layer_iteration",
    "live_layer",
    "lookahead",
    "motion_ok",
    "other_branches",
    "query",
    "stencil",
    "supported",
    "sweep_layer",
    "sweep_policy",
    "sweep_self",
    "table_stencil",
    "valid_moves",
    "wrap",
]

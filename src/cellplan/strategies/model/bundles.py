"""Typed, named bundles of the model arrays that the numba kernels read.

The kernels of the strategies solver read a dozen model arrays each. They travel as one
:class:`Model`, a ``typing.NamedTuple`` of three smaller named tuples (numba compiles a
field access such as ``model.layers.live`` to a plain pointer, so naming costs nothing
in the hot loops):

* :class:`Grid`: the uniform grid of cell centres over the C-space (cells are flat
  C-order indices; Section IV-B of the strategies paper interpolates between centres);
* :class:`Moves`: the *move classes*: a free bitmap and an action set each (eq. (5) and
  its variants), with the collision-free actions per cell and the precomputed stencils
  of every move from a cell centre;
* :class:`Layers`: one layer per assembly mode (Section III-A): the live states, the
  loss of eq. (7), the FMP successor and its fine-motion time, the mode-change
  branches of Section III-B, and the FMP's outcomes (one, with probability one, in the
  Section V model; success and failure with failure modes, Section VI-3). A mode's FMP
  may have several *options* (simultaneous requests, Section VI-2: which open request a
  pick serves), each with its own fine-motion field and outcomes; every other model has
  one option per mode, option ``o`` of mode ``m`` being ``o = m``.

:meth:`cellplan.strategies.model.mdp.LayeredMDP.kernel_args` builds the bundle; no module
depends on the order of the fields, only on their names.
"""

from typing import NamedTuple

import numpy as np


class Grid(NamedTuple):
    """A uniform grid of ``prod(shape)`` cells over the box ``[lower, upper]``."""

    shape: np.ndarray  # (d,) int64 cells per axis
    lower: np.ndarray  # (d,) float
    upper: np.ndarray  # (d,) float
    spacing: np.ndarray  # (d,) float, (upper - lower) / shape
    periodic: np.ndarray  # (d,) bool, axes that wrap round (angles)


class Moves(NamedTuple):
    """Move classes ``k``: a free bitmap and its actions ``a`` (at most ``A`` per class).

    ``offs``, ``fr``, ``coff`` and ``cw`` have one slice ``t`` per cell of the heading axis
    when the moves are in the robot frame (``heading_axis >= 0``, problem 3), else one.
    """

    free: np.ndarray  # (K, N) bool, conservative free bitmap (eqs. (1)-(3))
    disp: np.ndarray  # (K, A, d) displacement of each action
    nact: np.ndarray  # (K,) int64 number of actions
    heading_axis: int  # axis of the robot's heading (robot-frame moves), or -1
    valid: np.ndarray  # (K, N) int64 bitmask of the actions collision-free from the centre
    offs: np.ndarray  # (K, A, T, d) int64 whole cells of each move from a centre
    fr: np.ndarray  # (K, A, T, d) its fractional part
    coff: np.ndarray  # (K, A, T, 2^d) int64 flat offsets of the landing stencil's corners
    cw: np.ndarray  # (K, A, T, 2^d) their weights, decreasing (stop at the first zero)
    interior: np.ndarray  # (K, N) bool, cells whose every move stencil stays inside
    noise_prob: np.ndarray  # (J,) noisy outcomes of a move (Section VI-4): row A + a J + j


class Layers(NamedTuple):
    """One layer per mode ``m``: NR (0), then the W layers, then the C layers."""

    live: np.ndarray  # (M, N) bool, the states of the MDP
    vcls: np.ndarray  # (M,) int64 move class
    cost: np.ndarray  # (M,) loss per stage, eq. (7): 0 in NR, the stage time otherwise
    fmp_next: np.ndarray  # (M,) int64 mode after a successful FMP, -1 where none (NR)
    opt_ptr: np.ndarray  # (M + 1,) int64: FMP options of m are opt_ptr[m]:opt_ptr[m+1]
    tf: np.ndarray  # (O, N) fine-motion time of each FMP option, inf where not allowed
    branch_ptr: np.ndarray  # (M + 1,) int64: branches of m are branch_ptr[m]:branch_ptr[m+1]
    branch_layer: np.ndarray  # (B,) int64 next mode of each branch
    branch_prob: np.ndarray  # (B,) its probability (Section III-B)
    out_ptr: np.ndarray  # (O + 1,) int64: outcomes of option o are out_ptr[o]:out_ptr[o+1]
    out_layer: np.ndarray  # (G,) int64 mode after FMP in each outcome
    out_prob: np.ndarray  # (G,) its probability (1 - failure rate, failure rate, ...)
    out_cost: np.ndarray  # (G,) extra loss of the outcome (rework time), added to t_f
    # (M, N) int64, or (0, 0) when not computed: bit a of [m, c] marks a collision-free
    # move from a live interior cell that lands on live corners of the same layer only;
    # the solver skips the corner tests there (:func:`.sweeps.dense_cells`).
    dense: np.ndarray


class Model(NamedTuple):
    """Everything a kernel needs to know about the discretised MDP."""

    grid: Grid
    moves: Moves
    layers: Layers


class Probe(NamedTuple):
    """Scratch space of a point query (:mod:`.points`): the ``2^d`` corners and weights of
    a stencil and the integer and float work space of :func:`.stencils.stencil` and
    :func:`.motion.motion_ok`."""

    idx: np.ndarray  # (2^d,) int64 corners
    w: np.ndarray  # (2^d,) their weights
    ibuf: np.ndarray  # (2 MAX_DIM,) int64, the stencil's work space
    frac: np.ndarray  # (MAX_DIM,) float, the stencil's fractions
    mbuf: np.ndarray  # (3 MAX_DIM,) int64, the swept check's work space


class Search(NamedTuple):
    """The settings and buffers of one lookahead (:func:`.points.lookahead`).

    Sequences of up to ``depth`` motions are scored with ``offset`` (the gain) taken off
    per stage; FMP at the root only with ``fmp_root``. The FMP region test away from the
    root takes two calls: with ``collect`` the configurations where the grid allows FMP
    are written to ``nodes``, without it ``fmp_ok[i]`` says whether FMP is possible at the
    i-th of them. ``seq`` receives the best sequence.
    """

    depth: int
    offset: float
    fmp_root: bool
    collect: bool
    nodes: np.ndarray  # (n, d) float
    fmp_ok: np.ndarray  # (n,) bool
    seq: np.ndarray  # (depth + 1,) int64


class Outcomes(NamedTuple):
    """The outcomes of each FMP option when they are not the Section V ones.

    FMP option ``o`` costs ``t_f(o, x)`` and then, with probability ``prob[g]``, adds
    ``cost[g]`` and moves to mode ``layer[g]`` at the same configuration, for ``g`` in
    ``ptr[o]:ptr[o+1]``; the first outcome is the success (``fmp_next[m]`` for the first
    option of mode ``m``). Without options, option ``o`` is mode ``o``.
    """

    ptr: np.ndarray  # (O + 1,) int64
    layer: np.ndarray  # (G,) int64
    prob: np.ndarray  # (G,) float
    cost: np.ndarray  # (G,) float


def single_outcomes(fmp_next: np.ndarray) -> Outcomes:
    """The Section V outcomes: FMP leads to ``fmp_next[m]`` with probability one."""
    has = fmp_next >= 0
    ptr = np.concatenate([[0], np.cumsum(has)]).astype(np.int64)
    layer = fmp_next[has].astype(np.int64)
    return Outcomes(ptr, layer, np.ones(len(layer)), np.zeros(len(layer)))

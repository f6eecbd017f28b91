"""The layers of a structured solve and its two inner steps (numba kernels in
:mod:`.sweeps` and :mod:`.nr`).

For the current gain ``g`` and NR values, :meth:`Layers.request_layers` solves every C
layer and then every W layer by policy iteration (:func:`.sweeps.layer_iteration`), and
:meth:`Layers.nr_layer` solves NR with its stay self-loop eliminated exactly
(:mod:`.nr`). The outer loop round them is :func:`.solver.solve_structured`.
"""

from __future__ import annotations

import hashlib
import itertools
import logging

import numpy as np

from cellplan.strategies.model.bundles import Model
from cellplan.strategies.model.mdp import LayeredMDP
from cellplan.strategies.solve import evaluation, nr, sweeps
from cellplan.strategies.solve.nr import NRBranches, Slab
from cellplan.strategies.solve.sweeps import Sweep, layer_solve
from cellplan.strategies.solve.threads import Workers

log = logging.getLogger(__name__)

# Warm passes start each layer with an exact evaluation of last pass's policy.
EVAL_FIRST = True
# NR, the one layer solved alone, is swept in this many slabs of rows on the pool's
# threads. A fixed number rather than the thread count, so that the answer does not
# depend on the threads (two threads: one NR sweep 4.75 -> 2.74 ms on P1 at 200 x 200,
# 14.2 -> 8.65 ms on P6; docs/benchmarks.md, seventh session).
NR_SLABS = 2


def _layer_key(mdp: LayeredMDP, m: int, groups: dict[int, int]) -> bytes:
    dig = hashlib.sha1()
    nxt = int(mdp.fmp_next[m])
    dig.update(np.array([mdp.vcls[m], groups.get(nxt, nxt), mdp.cost[m]]).tobytes())
    dig.update(mdp.tf[m].tobytes())
    dig.update(mdp.live[m].tobytes())
    return dig.digest()


class Layers:
    """The state of a structured solve and its two inner steps (C/W layers, then NR).

    ``h`` and ``D = dh/dg`` are ``(M, N)``; ``pol`` the last recorded policy per state.
    """

    def __init__(self, mdp: LayeredMDP, max_sweeps: int, workers: Workers) -> None:
        self.mdp = mdp
        self.model = sweeps.with_dense(mdp.kernel_args())
        self.max_sweeps = max_sweeps
        self.workers = workers
        live = mdp.live
        self.live = live
        self.h = np.zeros(live.shape)
        self.D = np.zeros(live.shape)
        self.pol = np.full(live.shape, -3, np.int16)
        self.sweeps = 0  # full layer sweeps (every action)
        self.evaluations = 0  # exact policy evaluations
        self.coupled = mdp.has_changes()
        R = mdp.n_requests
        self.c_layers = [mdp.c_layer(r) for r in range(R)]
        self.w_layers = [mdp.w_layer(r) for r in range(R)]
        self.order = self.c_layers + self.w_layers
        # Layers with identical data (move class, successor, fine-motion field, live set)
        # are solved once and share values.
        self.groups: dict[int, int] = {}
        reps: dict[bytes, int] = {}
        for m in self.order:
            key = _layer_key(mdp, m, self.groups)
            self.groups[m] = m if self.coupled else reps.setdefault(key, m)
        self.c_reps = [m for m in self.c_layers if self.groups[m] == m]
        self.w_reps = [m for m in self.w_layers if self.groups[m] == m]
        self.copies = {
            m: [k for k in self.order if k != m and self.groups[k] == m] for m in self.order
        }
        # The W layers to solve once a C layer (a representative) is: those picking up
        # into it or into one of its copies (a W layer's FMP leads to its C layer).
        self.w_after: dict[int, list[int]] = {m: [] for m in self.order}
        for w in self.w_reps:
            self.w_after[self.groups[int(mdp.fmp_next[w])]].append(w)
        # The uncoupled model (every move keeps the request) starts coupled groups.
        ptr, lay, prob = mdp.branch_ptr, mdp.branch_layer, mdp.branch_prob
        solo_prob = prob.copy()
        for m in range(1, mdp.n_modes):
            for b in range(ptr[m], ptr[m + 1]):
                solo_prob[b] = 1.0 if lay[b] == m else 0.0
        self.solo_model = self.model._replace(
            layers=self.model.layers._replace(branch_prob=solo_prob)
        )
        # A Dijkstra first policy pays off where Gauss-Seidel from +inf is slow to cross
        # the layer: 3-D joint spaces (8 sweep orders). In the plane 4 orders suffice, and
        # for a robot-frame heading axis its predecessor search costs more than it saves.
        self.cold_dijkstra = len(mdp.shape) >= 3 and mdp.heading_axis < 0
        # NR: its request branches (into the W layers, fixed while NR is solved) are
        # summed once per pass into E (ED for D), per cell and action.
        n_act = int(mdp.nact[mdp.vcls[0]])
        self.E = np.empty((live.shape[1], n_act + 1))
        self.ED = np.empty_like(self.E)
        self.p_self = float(sum(prob[b] for b in range(ptr[0], ptr[1]) if lay[b] == 0))
        self._merge_request_branches()
        # NR is swept in NR_SLABS slabs of rows along the first axis (_nr_sweep).
        self.nr_cells = evaluation.live_cells(live[0])
        rows = int(mdp.shape[0])
        cuts = [rows * k // NR_SLABS for k in range(NR_SLABS + 1)]
        self.nr_slabs = [(a, b) for a, b in itertools.pairwise(cuts) if b > a]
        # Each slab's working copy of NR (:class:`.nr.Slab`).
        self.work_h = np.empty((len(self.nr_slabs), live.shape[1]))
        self.work_D = np.empty_like(self.work_h)
        self.nr_branches = NRBranches(self.E, self.ED, self.p_self)

    # --- step 1: the C and W layers ---------------------------------------------------------

    def start(self, m: int, warm: float | None, dg: float) -> None:
        """Starting values of a C or W layer (see :meth:`request_layers`)."""
        lm = self.live[m]
        if warm is None:
            self.h[m][lm] = np.inf
        else:
            self.h[m][lm] += dg * self.D[m][lm] + warm

    def request_layers(
        self, g: float, accuracy: float, warm: float | None, dg: float, cap: int
    ) -> None:
        """Solve every C layer, then every W layer, for the gain ``g`` and the current NR.

        A C or W layer is a deterministic shortest path with terminal cost (eq. (9) with
        the loss (7) of a stage, ``dt``, and of FMP, ``t_f``):

            h(m, x) = min( t_f(m, x) - g + h(next(m), x),  min_a  dt - g + H_m(x + dx_a) ).

        Gauss-Seidel on a shortest path converges fast from above and creeps up from below.
        The first pass starts from ``+inf`` (``warm`` None); later passes start from the
        last solution moved by the exact change of its old policy's cost under the new g
        (``dg * D``) plus ``warm``, the largest change of the terminal NR values beyond
        that: an upper bound within the spread of those changes. ``cap`` bounds the sweeps
        and evaluations per layer (an inexact solve on early passes).
        """
        if self.coupled:
            for ms in (self.c_layers, self.w_layers):
                self._coupled_group(ms, g, accuracy, warm, dg)
            return
        # C layers read only NR, and a W layer only its own C layer: each C layer is
        # solved in parallel with the others, and its W layers start as soon as it is
        # done (no barrier between the C and the W layers).
        warm_start = EVAL_FIRST and warm is not None

        def solve_one(m: int) -> tuple[int, int]:
            self.start(m, warm, dg)
            opts = layer_solve(
                accuracy, cap, self.max_sweeps, warm_start, cap >= self.max_sweeps,
                self.cold_dijkstra,
            )  # fmt: skip
            counts = sweeps.layer_iteration(m, self.h, self.D, g, self.pol, opts, self.model)
            # Layers with the same data share this solution (before a W layer reads it).
            for copy in self.copies[m]:
                self.h[copy] = self.h[m]
                self.D[copy] = self.D[m]
            return counts

        counts = self.workers.map_chains(solve_one, self.c_reps, self.w_after.__getitem__)
        self.sweeps += sum(c[0] for c in counts.values())
        self.evaluations += sum(c[1] for c in counts.values())
        log.debug("layers: (full sweeps, evaluations) %s", dict(sorted(counts.items())))

    def _gauss_seidel(self, m: int, g: float, accuracy: float, model: Model) -> None:
        d = len(self.mdp.shape)
        for s in range(max(1, self.max_sweeps)):
            change = sweeps.sweep_layer(m, s % (1 << d), self.h, self.D, g, False, True, model)
            self.sweeps += 1
            if change < accuracy:
                return

    def _coupled_group(
        self, ms: list[int], g: float, accuracy: float, warm: float | None, dg: float
    ) -> None:
        """Layers coupled by destination or source changes: Gauss-Seidel rounds over the
        group, started on the first pass from each layer's solution with the changes off."""
        d = len(self.mdp.shape)
        for m in ms:
            self.start(m, warm, dg)
            if warm is None:
                self._gauss_seidel(m, g, accuracy, self.solo_model)
        for s in range(max(1, self.max_sweeps)):
            change = 0.0
            for m in ms:
                flips = s % (1 << d)
                change = max(
                    change,
                    sweeps.sweep_layer(m, flips, self.h, self.D, g, False, True, self.model),
                )
            self.sweeps += len(ms)
            if change < accuracy:
                return

    # --- step 2: NR ---------------------------------------------------------------------------

    def _merge_request_branches(self) -> None:
        """Group NR's request branches whose W layers share one live set.

        A request ``r`` arrives in NR with probability ``P pi_r`` and leads to ``W_r``
        (Section III-B). The interpolation of Section IV-B renormalises a landing point's
        weights over the live corners of the layer it reads, so where the live sets agree
        the weights agree too and ``sum_b P_b H_{W_b}(x')`` is the interpolation of
        ``sum_b P_b h_{W_b}`` over that live set: one interpolation per group instead of
        one per request (problem 1: one group of 8, problem 6: two of 4). ``merged`` is a
        model whose layers are NR and one per group (only ``live`` and the branches of NR
        are read from it: :func:`.nr.other_branches` of layer 0), each group on one
        branch with its total probability; :meth:`_merged_values` fills ``hg`` and ``Dg``
        with the probability-weighted means of the group's values.
        """
        mdp = self.mdp
        ptr, lay, prob = mdp.branch_ptr, mdp.branch_layer, mdp.branch_prob
        groups: dict[bytes, list[int]] = {}
        for b in range(ptr[0], ptr[1]):
            if lay[b] != 0 and prob[b] > 0.0:
                groups.setdefault(self.live[lay[b]].tobytes(), []).append(b)
        self.nr_groups = list(groups.values())
        self.merged: Model | None = None
        if len(self.nr_groups) == sum(len(bs) for bs in self.nr_groups):
            return  # nothing to merge
        n_groups = len(self.nr_groups)
        live = np.empty((n_groups + 1, self.live.shape[1]), np.bool_)
        live[0] = self.live[0]
        for k, bs in enumerate(self.nr_groups):
            live[k + 1] = self.live[lay[bs[0]]]
        self.group_prob = np.array([float(prob[bs].sum()) for bs in self.nr_groups])
        layers = self.model.layers._replace(
            live=live,
            branch_ptr=np.array([0, n_groups + 1], np.int64),
            branch_layer=np.arange(n_groups + 1, dtype=np.int64),
            branch_prob=np.concatenate([[self.p_self], self.group_prob]),
            dense=np.zeros((0, 0), np.int64),
        )
        self.merged = self.model._replace(layers=layers)
        self.hg = np.zeros(live.shape)
        self.Dg = np.zeros(live.shape)

    def _merged_values(self) -> bool:
        """Fill the merged layers' values; False where a W layer still has an unreached
        live state (the groups then read differently, so the branches stay separate)."""
        if self.merged is None:
            return False
        lay, prob = self.mdp.branch_layer, self.mdp.branch_prob
        tmp = np.empty(self.live.shape[1])
        for k, bs in enumerate(self.nr_groups):
            for src, out in ((self.h, self.hg[k + 1]), (self.D, self.Dg[k + 1])):
                # Accumulated member by member, in place: the same sums, in the same order,
                # as a sum over a stacked copy, without the copy (P6: 10 -> 2 ms a group).
                np.multiply(src[lay[bs[0]]], prob[bs[0]], out=out)
                for b in bs[1:]:
                    out += np.multiply(src[lay[b]], prob[b], out=tmp)
                out /= self.group_prob[k]
            # A member at +inf (an unreached state: all probabilities are positive) makes
            # the mean +inf on the group's live set.
            if not np.all(np.isfinite(self.hg[k + 1]), where=self.live[lay[bs[0]]]):
                return False
        return True

    def nr_layer(self, g: float, accuracy: float, cold: bool) -> None:
        """Solve NR for the gain ``g`` with the W layers fixed.

        NR has no loss and a self-loop of probability ``1 - P`` (no request arrives); a
        request ``r`` arrives with probability ``P pi_r`` and leads to ``W_r``. Its stay
        self-loop is eliminated exactly,

            h(NR, x) = min( (-g + E_stay(x)) / P,  min_a  -g + E_a(x) + (1 - P) H_NR(x + dx_a) ),

        with ``E`` the request branches summed once per pass (:func:`.nr.other_branches`).
        The first pass starts from ``+inf``; later ones evaluate last pass's NR policy first.
        Its sweeps run in slabs on the pool (:meth:`_nr_sweep`), its exact evaluations
        (:func:`.evaluation.self_system`, :func:`.evaluation.evaluate`) in this thread.
        """
        n = self.live.shape[1]

        h: np.ndarray = self.h
        D: np.ndarray = self.D
        model = self.model
        if self._merged_values():
            assert self.merged is not None
            h, D, model = self.hg, self.Dg, self.merged

        def branches(r: tuple[int, int]) -> None:
            nr.other_branches(0, h, D, self.E, self.ED, r[0], r[1], model)

        self.workers.map(branches, self.workers.ranges(n))
        if cold:
            self.h[0][self.live[0]] = np.inf
        # Policy iteration, as sweeps.layer_iteration does it for a C or W layer: full
        # sweeps until the minimiser has nearly settled, then an exact evaluation.
        cells, local = self.nr_cells
        full = evaluations = 0
        changed = 0
        evaluate_first = not cold  # last pass's policy, confirmed by a full sweep
        while full + evaluations < max(1, self.max_sweeps):
            if evaluate_first:
                evaluate_first = False
            else:
                change, changed = self._nr_sweep(g, full % (1 << len(self.mdp.shape)), accuracy)
                full += 1
                if change < accuracy:
                    break
            if changed <= sweeps.SETTLED_FRACTION * len(cells):
                system = evaluation.self_system(
                    0, self.h, g, self.nr_branches, self.pol, cells, local, self.model
                )
                evaluation.evaluate(self.h[0], self.D[0], cells, system)
                evaluations += 1
        self.sweeps += full
        self.evaluations += evaluations
        log.debug("NR: full sweeps %d, evaluations %d", full, evaluations)

    def _nr_sweep(self, g: float, flips: int, tie: float) -> tuple[float, int]:
        """One Gauss-Seidel sweep of NR, its slabs of rows on the pool (:func:`.nr.sweep_self`).

        Inside a slab the sweep is Gauss-Seidel; across slabs it reads the values from
        before the sweep, so the slabs can run in any order on any number of threads and
        give the same values. Returns the largest change and how many minimisers changed
        by more than ``tie``.
        """
        changed = np.zeros((len(self.nr_slabs), 1), np.int64)
        for k in range(len(self.nr_slabs)):
            np.copyto(self.work_h[k], self.h[0])
            np.copyto(self.work_D[k], self.D[0])

        def run(k: int) -> float:
            sw = Sweep(flips, True, True, self.pol, 1, changed[k], float(tie))
            slab = Slab(self.nr_slabs[k], self.work_h[k], self.work_D[k])
            return float(
                nr.sweep_self(0, self.h, self.D, g, self.nr_branches, sw, self.model, slab)
            )

        return max(self.workers.map(run, range(len(self.nr_slabs)))), int(changed.sum())

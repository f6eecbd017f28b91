"""The modes of simultaneous requests (Section VI-2) counted and listed: the multisets of
open request types and the carried one, for :mod:`.simultaneous` (the variant),
:mod:`.pending` (its model) and :mod:`.pending_files` (its strategy files)."""

from __future__ import annotations

import math
from itertools import combinations_with_replacement

#: Most requests open at once (Section VI-2); the modes grow as C(R, k).
MAX_PENDING = 8
#: Most modes of a model with simultaneous requests (each is a layer of the grid).
MAX_PENDING_MODES = 20_000
#: The simulator's policies of this model (:mod:`.pending_sim`).
PENDING_POLICIES: tuple[str, ...] = ("optimal", "fcfs", "nearest", "reactive")


def mode_counts(R: int, k: int) -> tuple[int, int]:
    """Modes of simultaneous requests (Section VI-2), ``(empty, carrying)``: the multisets of
    at most ``k`` of ``R`` request types, ``C(R + k, k)``, and ``R`` times those of at most
    ``k - 1``, ``R C(R + k - 1, k - 1)`` (:func:`pending_modes` lists them)."""
    return math.comb(R + k, k), R * math.comb(R + k - 1, k - 1) if k > 0 else 0


def pending_modes(R: int, k: int) -> list[tuple[tuple[int, ...], int]]:
    """Every mode ``(Q, r)`` for ``R`` request types and at most ``k`` open requests.

    ``Q`` is a sorted tuple of request indices (a multiset: an index may repeat), ``r``
    the carried request or -1. Order:
    NR (``((), -1)``) first, then the empty modes by the size of ``Q``, then the
    carrying modes by ``r`` and the size of ``Q``.
    """
    out: list[tuple[tuple[int, ...], int]] = []
    for n in range(k + 1):
        out += [(q, -1) for q in combinations_with_replacement(range(R), n)]
    for r in range(R):
        for n in range(k):
            out += [(q, r) for q in combinations_with_replacement(range(R), n)]
    return out


def option_count(R: int, k: int) -> int:
    """FMP options: one per waiting request type in each empty mode, one per carrying mode."""
    return sum(len(set(q)) if r < 0 else 1 for q, r in pending_modes(R, k))

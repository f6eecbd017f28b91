"""Strategy files of simultaneous requests (Section VI-2): their modes and FMP options.

A file whose modes are NR and the ``Q`` modes of :mod:`.simultaneous` is read with these
checks by :func:`cellplan.strategies.policy.fileformat.read_strategy`: the modes are every
``(Q, r)`` once, the FMP options those :func:`~.pending.assemble_pending` builds, and with
a scenario, the modes those of its requests and ``max_pending``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellplan.strategies.model.layered import Mode, mode_of
from cellplan.strategies.variants.request_sets import mode_counts, pending_modes

#: A mode of simultaneous requests (Section VI-2): the waiting requests and the carried
#: one (``"part,source,destination"``, ``""`` when empty); the waiting requests are a
#: multiset, sorted (two requests of one type may wait). NR is ``((), "")``.
PendingKey = tuple[tuple[str, ...], str]


def pending_keys(modes: list[list[str]], fail: Any) -> list[PendingKey]:
    """The modes of a model of simultaneous requests (NR, then Q modes), checked.

    They must be every mode ``(Q, r)`` of ``R`` request types (those the modes name) and at
    most ``k`` open requests (the most any mode holds), once each: a set of distinct valid
    modes is all of them exactly when there are :func:`~.request_sets.mode_counts` of them. The
    order is free (the arrays name modes by index); the scenario check compares it.
    """
    if len(modes[0]) != 4 or any(modes[0][1:]):
        raise fail("meta.modes: NR has 4 fields, the last three empty")
    keys: list[PendingKey] = [((), "")]
    for i, m in enumerate(modes[1:], start=1):
        carried = m[1:4]
        if any(carried) and not all(carried):
            raise fail(
                f"meta.modes.{i}: a Q mode names the part, source and destination it "
                "carries, or none of them"
            )
        waiting = m[4:]
        bad = [w for w in waiting if len(w.split(",")) != 3 or not all(w.split(","))]
        if bad:
            raise fail(
                f"meta.modes.{i}: waiting request {bad[0][:60]!r} is not 'part,source,destination'"
            )
        key = (tuple(sorted(waiting)), ",".join(carried) if all(carried) else "")
        if not key[0] and not key[1]:
            raise fail(f"meta.modes.{i}: a Q mode with no open request (only NR has none)")
        keys.append(key)
    if len(set(keys)) != len(keys):
        raise fail("meta.modes: a Q mode appears twice")
    names = {w for key in keys for w in key[0]}
    if any(key[1] not in names for key in keys[1:] if key[1]):
        raise fail("meta.modes: a carried request that never waits")
    k = max(len(key[0]) + bool(key[1]) for key in keys)
    expected = sum(mode_counts(len(names), k))
    if len(keys) != expected:
        raise fail(
            f"meta.modes: {len(keys)} modes; up to {k} open requests of {len(names)} types "
            f"make {expected}"
        )
    return keys


def check_options(meta: Any, a: dict, keys: list[PendingKey], fail: Any) -> None:
    """The FMP options of simultaneous requests (Section VI-2, :mod:`.pending`).

    NR has none; each option's outcomes are a distribution (at least one); ``fmp_next`` is
    the first outcome of a mode's first option (-1 without options); an empty mode
    ``(Q, none)`` picks each waiting request type once (``(Q - r, r)``), a carrying mode
    ``(Q, r)`` has at most one option, the delivery (``(Q, none)``).
    """
    opt = a["opt_ptr"]
    ptr, layer, prob, cost = a["out_ptr"], a["out_layer"], a["out_prob"], a["out_cost"]
    n_opt = np.diff(opt)
    if n_opt[0] != 0:
        raise fail("opt_ptr: NR has no FMP option")
    if ptr[0] != 0 or ptr[-1] != len(layer) or (np.diff(ptr) < 1).any():
        raise fail(
            "out_ptr: expected 0, increasing (every FMP option has an outcome), ending at "
            "the number of outcomes"
        )
    if not np.isfinite(cost).all():
        raise fail("out_cost: not finite")
    if len(ptr) > 1 and not np.allclose(np.add.reduceat(prob, ptr[:-1]), 1.0, atol=1e-9):
        raise fail("out_prob: the outcomes of an FMP option do not sum to 1")
    has = n_opt > 0
    first = np.full(len(n_opt), -1, np.int64)
    first[has] = layer[ptr[opt[:-1][has]]]
    if not np.array_equal(a["fmp_next"], first):
        raise fail(
            "fmp_next: not the first outcome of the mode's first FMP option (-1 without one)"
        )
    index = {key: m for m, key in enumerate(keys)}
    for m in range(1, len(keys)):
        waiting, carried = keys[m]
        if carried:
            allowed = {index[(waiting, "")]}
        else:
            allowed = {index[(without(waiting, w), w)] for w in set(waiting)}
        if n_opt[m] > len(allowed):
            label = mode_of(meta.modes[m]).label
            raise fail(f"opt_ptr: mode {label} has {n_opt[m]} FMP options (at most {len(allowed)})")
        outs = layer[ptr[opt[m]] : ptr[opt[m + 1]]].tolist()
        firsts = layer[ptr[opt[m] : opt[m + 1]]].tolist()
        if not set(outs) <= allowed or len(set(firsts)) != len(firsts):
            label = mode_of(meta.modes[m]).label
            raise fail(
                f"out_layer: mode {label} has an FMP outcome the model cannot produce (a "
                "pick of each waiting request once, or the delivery of the carried one)"
            )


def without(waiting: tuple[str, ...], w: str) -> tuple[str, ...]:
    """The multiset ``waiting`` less one ``w``."""
    rest = list(waiting)
    rest.remove(w)
    return tuple(rest)


def check_pending_scenario(
    meta: Any, requests: list[tuple[str, str, str, float]], k: int, fail: Any
) -> None:
    """The modes are those :func:`~.pending.assemble_pending` builds for the scenario."""
    names = [f"{p},{s},{d}" for p, s, d, _ in requests]
    expected = []
    for q, r in pending_modes(len(requests), k):
        carried = requests[r][:3] if r >= 0 else ("", "", "")
        waiting = tuple(names[i] for i in q)
        expected.append(Mode("Q", *carried, waiting=waiting).label if q or r >= 0 else "NR")
    got = [mode_of(m).label for m in meta.modes]
    if got != expected:
        raise fail(
            f"meta.modes: {len(got)} modes that differ from the {len(expected)} of the "
            f"scenario's {len(requests)} requests with max_pending {k}; solve this scenario "
            "again"
        )

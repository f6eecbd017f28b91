"""Live states of the layered MDP: the states from which a request can be finished.

A layer's *live* states are the free cells from which its request can be finished
(:func:`cellplan.strategies.model.domain.live_layer`); the MDP is defined on live states
only, which keeps it unichain-friendly and lets the input checks name a request that can
never be served. A variant with its own rule (a time-varying model, Section VI-1) supplies
it through the model's ``variants`` (:class:`~cellplan.strategies.model.spec.ModelRules`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from cellplan.errors import Problem
from cellplan.strategies.model.domain import live_layer
from cellplan.strategies.model.layered import LayeredMDP


def compute_live(mdp: LayeredMDP) -> None:
    """Restrict ``mdp.live`` to the states that can finish their request (in place).

    Repeats :func:`_live_pass` until nothing changes, remembering each layer's inputs so
    that a later pass skips the layers whose inputs did not change. A variant with a rule
    of its own (a time-varying model, Section VI-1) applies it instead (its ``live`` hook).
    """
    for variant in mdp.variants:
        if variant.live(mdp):
            return
    fmp_ok = mdp.tf < np.inf
    settled: list[tuple[Any, ...] | None] = [None] * mdp.n_modes
    for _ in range(100):
        if not _live_pass(mdp, mdp.live, fmp_ok, settled):
            return
    raise RuntimeError("live-state computation did not settle")  # pragma: no cover


def _live_pass(
    mdp: LayeredMDP,
    live: np.ndarray,
    fmp_ok: np.ndarray,
    settled: list[tuple[Any, ...] | None] | None = None,
) -> bool:
    """One shrinking pass of ``live`` over every layer; True if anything changed.

    :func:`.domain.live_layer` is a function of a few rows of ``live`` and ``fmp_ok``
    (its *inputs*), and running it on its own output changes nothing. So a layer whose
    inputs equal, byte for byte, those of a layer already done in this pass copies that
    layer's result: aliased or repeated destinations give many requests with identical
    layers, and a scenario with 100 copies of a destination took 124 s to build without
    this. A layer whose inputs equal those it had when it settled (``settled[m]``, kept
    across passes by :func:`compute_live`) is skipped. Rows are compared by a 128-bit
    BLAKE2 digest.
    """
    model = mdp.kernel_args()
    out = mdp.fmp_outcomes()
    row_digest: dict[tuple[int, int], bytes] = {}

    options = mdp.options

    def digest(which: int, m: int) -> bytes:
        key = (which, m)
        if key not in row_digest:
            row = live[m] if which == 0 else fmp_ok[m]  # fmp_ok: by option
            row_digest[key] = hashlib.blake2b(row.tobytes(), digest_size=16).digest()
        return row_digest[key]

    def inputs(m: int) -> tuple[Any, ...]:
        lo, hi = mdp.branch_ptr[m], mdp.branch_ptr[m + 1]
        branches = [int(L) for L in mdp.branch_layer[lo:hi][mdp.branch_prob[lo:hi] > 0]]
        # The kernel needs every branch supported, so their order does not matter.
        others = tuple(sorted(digest(0, L) for L in branches if L != m))
        fmp: tuple[Any, ...] | None = None
        if mdp.fmp_next[m] >= 0:
            fmp = ()
            for o in range(options[m], options[m + 1]):
                lo, hi = out.ptr[o], out.ptr[o + 1]
                landing = sorted({int(L) for L in out.layer[lo:hi][out.prob[lo:hi] > 0]})
                fmp += ((digest(1, o), tuple((L == m, digest(0, L)) for L in landing)),)
        return (int(mdp.vcls[m]), digest(0, m), fmp, m in branches, others)

    done: dict[tuple[Any, ...], int] = {}
    changed = False
    for m in range(mdp.n_modes):
        key = inputs(m)
        if settled is not None and settled[m] == key:
            continue
        rep = done.get(key)
        if rep is None:
            layer_changed = bool(live_layer(live, fmp_ok, model, m))
            done[key] = m
        else:
            layer_changed = not np.array_equal(live[m], live[rep])
            live[m] = live[rep]
        if layer_changed:
            changed = True
            row_digest.pop((0, m), None)
        if settled is not None:
            settled[m] = inputs(m)
    return changed


def live_problems(mdp: LayeredMDP) -> list[Problem]:
    """One problem per request that can never be served (checked before solving); a
    variant with a check of its own (a time-varying model) answers instead (its
    ``problems`` hook)."""
    for variant in mdp.variants:
        found = variant.problems(mdp)
        if found is not None:
            return found
    problems = []
    R = mdp.n_requests
    live = mdp.live
    if not mdp.live[0].any():
        problems.append(Problem("strategy", "no configuration in NR can serve every request"))
        problems.extend(_split_problems(mdp))
        # NR is empty as soon as one request cannot be served, and every layer that ends
        # in NR empties with it: judge each request on its own instead (issue 35 part 5),
        # by the same live-state rule with NR left unconstrained.
        live = _each_request_live(mdp)
    for r in range(R):
        mode = mdp.modes[1 + r]
        where = f"strategy.requests <{mode.part},{mode.source},{mode.destination}>"
        if not (mdp.tf[mdp.c_layer(r)] < np.inf).any():
            problems.append(
                Problem(
                    where,
                    f"part {mode.part!r} cannot be delivered anywhere in destination "
                    f"{mode.destination!r} (no free configuration in the region)",
                )
            )
        elif not (mdp.tf[mdp.w_layer(r)] < np.inf).any():
            problems.append(
                Problem(
                    where,
                    f"part {mode.part!r} cannot be picked up anywhere in source "
                    f"{mode.source!r} (no free configuration in the region)",
                )
            )
        elif not live[mdp.c_layer(r)].any():
            problems.append(
                Problem(
                    where,
                    f"destination {mode.destination!r} is unreachable while carrying {mode.part!r}",
                )
            )
        elif not live[mdp.w_layer(r)].any():
            problems.append(
                Problem(
                    where,
                    f"source {mode.source!r} is unreachable, or its part cannot reach "
                    f"destination {mode.destination!r} from there",
                )
            )
    for m, mode in enumerate(mdp.modes):
        if mode.kind == "X" and not mdp.live[m].any():
            problems.append(
                Problem(
                    "strategy.failures",
                    f"part {mode.part!r} (from {mode.source}) cannot be carried to reject region "
                    f"{mode.reject!r} and dropped there",
                )
            )
    return problems


def _each_request_live(mdp: LayeredMDP) -> np.ndarray:
    """The live states of each layer when NR is not required to serve every request: the
    passes of :func:`compute_live` with NR's row held at its free cells, so a request's
    C layer is live where its part can be carried to its destination and delivered, and
    its W layer where the robot can then pick it up and do so, whatever the other
    requests can do. Used to name only the requests that cannot be served."""
    # NR without its arrivals: it need not reach every request's source, only stay free.
    prob = mdp.branch_prob.copy()
    lo, hi = mdp.branch_ptr[0], mdp.branch_ptr[1]
    prob[lo:hi] = np.where(mdp.branch_layer[lo:hi] == 0, 1.0, 0.0)
    alone = replace(mdp, branch_prob=prob)
    live = np.stack([mdp.free[mdp.vcls[m]] for m in range(mdp.n_modes)])
    fmp_ok = mdp.tf < np.inf
    for _ in range(100):
        if not _live_pass(alone, live, fmp_ok):
            break
    return live


def _split_problems(mdp: LayeredMDP) -> list[Problem]:
    """Name the (destination, next source) pairs that a split free space separates.

    Recomputes one round of the live states with NR unconstrained: a W state is then live
    when the robot can go from it to its source and deliver. If no delivery configuration
    of destination d is live for the W layer of source s, a request from s arriving just
    after a delivery at d could never be served, which empties NR (not unichain).
    """
    live = np.stack([mdp.free[mdp.vcls[m]] for m in range(mdp.n_modes)])
    _live_pass(mdp, live, mdp.tf < np.inf)
    seen = set()
    out = []
    R = mdp.n_requests
    for r in range(R):
        d = mdp.modes[mdp.c_layer(r)].destination
        drop = mdp.tf[mdp.c_layer(r)] < np.inf
        for r2 in range(R):
            s2 = mdp.modes[mdp.w_layer(r2)].source
            if (d, s2) in seen or not drop.any():
                continue
            if not (live[mdp.w_layer(r2)] & drop).any():
                seen.add((d, s2))
                out.append(
                    Problem(
                        f"destinations.{d}",
                        f"after a delivery at {d} the robot cannot reach source {s2} (the free "
                        "configuration space splits; check joint limits, obstacles, grid cells)",
                    )
                )
    return out


def start_problems(
    mdp: LayeredMDP, start: Sequence[float] | np.ndarray, blocking: Sequence[str] = ()
) -> list[Problem]:
    """A problem when ``start`` (the robot's start) is not a live state of NR, so no
    run of the strategy could begin there (checked before solving). ``blocking`` names
    the sources the empty robot touches at ``start``: sources are obstacles while the
    robot is empty (equation (1)), so the line names them."""
    q = np.asarray(start, float)
    idx = np.floor((q - mdp.lower) / mdp.spacing).astype(np.int64)
    idx = np.where(mdp.periodic, idx % mdp.shape, np.clip(idx, 0, mdp.shape - 1))
    if mdp.live[0, int(np.ravel_multi_index(tuple(idx), tuple(mdp.shape)))]:
        return []
    shape = " x ".join(str(int(n)) for n in mdp.shape)
    if blocking:
        names = ", ".join(blocking)
        return [
            Problem(
                "robot.start",
                f"lies outside the strategy's domain: the robot touches source {names} there, "
                "and sources are obstacles while the robot is empty (equation (1) of the "
                "paper); start it outside the source regions",
            )
        ]
    return [
        Problem(
            "robot.start",
            f"lies outside the strategy's domain on the {shape} grid: from its cell no request "
            "can be served (blocked at this resolution, or cut off from the sources and "
            "destinations)",
        )
    ]

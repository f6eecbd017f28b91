"""Strategy files of time-varying models (Section VI-1): their phases, belts and branches.

``meta.period`` ``P`` divides the modes, every phase repeats the modes of phase 0, each
layer's phase is that of the layout ``t * (M / P) + m`` (``-1`` with period 1), the belts
move regions of the modes, and every branch leads to the next phase. Read by
:func:`cellplan.strategies.policy.fileformat.read_strategy`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def phase_layout(meta: Any, fail: Any) -> int:
    """The modes per phase of a (possibly time-varying, Section VI-1) model, checked: the
    period divides the modes, every phase repeats the modes of phase 0, and each layer's
    phase is that of the layout ``t * (M / period) + m`` (-1 throughout with period 1)."""
    T, M = meta.period, len(meta.modes)
    if len(meta.phases) != M:
        raise fail(f"meta.phases: {len(meta.phases)} values; expected {M}, one per mode")
    if M % T:
        raise fail(
            f"meta.period: {T} stages do not divide the {M} modes (the modes are the period's "
            "phases times the modes of one phase)"
        )
    per_phase = M // T
    expected = np.arange(M) // per_phase if T > 1 else np.full(M, -1)
    wrong = np.flatnonzero(np.asarray(meta.phases) != expected)
    if len(wrong):
        i = int(wrong[0])
        raise fail(
            f"meta.phases.{i}: {meta.phases[i]}; expected {int(expected[i])} (the layer of "
            f"mode m at phase t is t * {per_phase} + m{'' if T > 1 else '; -1: no period'})"
        )
    for i in range(per_phase, M):
        if meta.modes[i] != meta.modes[i % per_phase]:
            raise fail(
                f"meta.modes.{i}: differs from mode {i % per_phase}, its copy at phase 0 "
                "(every phase has the modes of phase 0)"
            )
    return per_phase


def check_belts(meta: Any, modes: list[list[str]], fail: Any) -> None:
    """The belts of a time-varying model move sources or destinations of its modes."""
    if meta.belts and meta.period == 1:
        raise fail("meta.belts: a stationary model (period 1) has no belts")
    regions = {m[2] for m in modes} | {m[3] for m in modes}
    travel = (meta.period - 1) * meta.stage_time
    for name, velocity in meta.belts.items():
        if not name or name not in regions:
            raise fail(f"meta.belts.{name[:60]}: not a source or destination of the modes")
        if not all(math.isfinite(v * travel) for v in velocity):
            raise fail(
                f"meta.belts.{name}: a velocity of {max(map(abs, velocity)):g} carries the "
                "region beyond any finite position within the period"
            )


def check_phase_branches(meta: Any, a: dict, fail: Any) -> None:
    """Every branch of a time-varying model leads to the next phase (none to check with
    period 1, whose phase is -1 throughout)."""
    T, M = meta.period, len(meta.modes)
    if T == 1:
        return
    per_phase = M // T
    ptr = a["branch_ptr"]
    phase = np.repeat(np.arange(M) // per_phase, np.diff(ptr))
    if (a["branch_layer"] // per_phase != (phase + 1) % T).any():
        raise fail(
            "branch_layer: a branch that does not lead to the next phase (every stage "
            "of a time-varying model advances the phase by one)"
        )

"""Modes by name: the text a user, a CLI option or a strategy file gives for a layer.

:meth:`~cellplan.strategies.policy.strategy.Strategy.mode_index` and the query's mode
argument (:func:`~cellplan.strategies.policy.strategy.checked_state`) read names here: the
paper's notation ``"1,1,1,W"`` (1-based indices in the scenario file's order), a label
as it prints (``"<P1,S1,D1,W>"``, ``NR``, an X mode of failures, a Q mode of
simultaneous requests) and, in a time-varying model, ``"...@phase"``.
"""

from __future__ import annotations

import re
from dataclasses import replace

from cellplan.errors import PersistenceError, Problem
from cellplan.strategies.model.layered import LayeredMDP, Mode


def mode_index(mdp: LayeredMDP, text: str, phase: int | None = None) -> int:
    """A mode from ``NR``, ``"1,1,1,W"`` (1-based indices in the scenario file's order,
    the paper's notation) or ``"<P1,S1,D1,W>"`` (names, as mode labels print; the X
    modes of failures, Section VI-3, by their labels such as ``<P1,S1,D1,X:R1>``).

    With simultaneous requests (Section VI-2) a mode is named by its label as it
    prints, ``"{P1,S1,D1; P1,S2,D1} + <P1,S1,D2>"`` (the waiting requests, then the
    carried one); spaces, and the order of the waiting requests, do not matter.

    In a time-varying model (Section VI-1) a mode is a layer ``(mode, phase)``: the
    phase follows an ``@`` (``"<P1,S1,D1,W>@3"``, ``"NR@5"``, ``"1,1,1,W@3"``, as the
    labels print) or is given as ``phase`` (the CLI's ``--phase``); without either it
    is 0. A stationary model has phase 0 only. Returns the layer's index.
    """
    text = text.strip()
    named, at, tail = text.rpartition("@")
    if at:
        if not tail.strip().isdigit():
            raise PersistenceError(
                [Problem("--mode", f"expected a phase number after '@', got {text!r}")]
            )
        if phase is not None and phase != int(tail):
            raise PersistenceError(
                [Problem("--phase", f"{phase} differs from the phase {int(tail)} of {text!r}")]
            )
        text, phase, field = named.strip(), int(tail), "--mode"
    else:
        field = "--phase"
    phase = 0 if phase is None else phase
    if not 0 <= phase < mdp.period:
        if mdp.period == 1:
            message = f"{phase}: this strategy is stationary (no period); its one phase is 0"
        else:
            message = f"{phase} is outside the period (phases 0 to {mdp.period - 1})"
        raise PersistenceError([Problem(field, message)])
    return mdp.layer(_base_index(mdp, text), phase)


def _base_index(mdp: LayeredMDP, text: str) -> int:
    """The index among the modes of one phase (all modes of a stationary model)."""
    modes = [replace(m, phase=-1) for m in mdp.modes[: mdp.modes_per_phase]]
    if text.upper() == "NR":
        return 0
    for i, m in enumerate(modes):
        if m.label == text or m.label == f"<{text}>":
            return i  # every label, the X modes of failures included
    if text.startswith("{"):
        return _pending_index(mdp, text, modes)
    items = [t.strip() for t in text.strip("<>").split(",")]
    if len(items) != 4 or items[3].upper() not in ("W", "C"):
        expected = (
            "NR or a mode label such as '{P1,S1,D1} + <P1,S2,D1>'"
            if any(m.kind == "Q" for m in modes)
            else "NR or 'p,s,d,W|C'"
        )
        raise PersistenceError([Problem("--mode", f"expected {expected}, got {text!r}")])
    # The modes follow the scenario's request list, so first appearance is file order.
    parts = list(dict.fromkeys(m.part for m in modes[1:]))
    sources = list(dict.fromkeys(m.source for m in modes[1:]))
    dests = list(dict.fromkeys(m.destination for m in modes[1:]))
    names = []
    for item, pool in zip(items[:3], (parts, sources, dests), strict=True):
        if item.isdigit() and 1 <= int(item) <= len(pool):
            names.append(pool[int(item) - 1])
        else:
            names.append(item)
    for i, m in enumerate(modes):
        if (m.part, m.source, m.destination, m.kind) == (*names, items[3].upper()):
            return i
    raise _no_mode(mdp, text, modes)


def _pending_index(mdp: LayeredMDP, text: str, modes: list[Mode]) -> int:
    """A Q mode (simultaneous requests) from its label, spaces and order free."""
    found = re.fullmatch(r"\{([^{}<>]*)\}(?:\+<([^{}<>]*)>)?", "".join(text.split()))
    if found is None:
        raise PersistenceError(
            [
                Problem(
                    "--mode",
                    f"expected a mode label such as '{{P1,S1,D1}} + <P1,S2,D1>', got {text!r}",
                )
            ]
        )
    key = (tuple(sorted(w for w in found.group(1).split(";") if w)), found.group(2) or "")
    for i, m in enumerate(modes):
        carried = f"{m.part},{m.source},{m.destination}" if m.part else ""
        if m.kind in ("NR", "Q") and (tuple(sorted(m.waiting)), carried) == key:
            return i
    raise _no_mode(mdp, text, modes)


def _no_mode(mdp: LayeredMDP, text: str, modes: list[Mode], shown: int = 12) -> PersistenceError:
    labels = [m.label for m in modes]
    known = ", ".join(labels[:shown])
    if len(labels) > shown:
        known += f", ... ({len(labels)} modes)"
    phases = mdp.n_modes // mdp.modes_per_phase  # layers per mode
    if phases > 1:
        known += f"; at phases 0 to {phases - 1}, e.g. {labels[-1]}@1"
    return PersistenceError(
        [Problem("--mode", f"no mode {text!r} in this strategy (modes: {known})")]
    )

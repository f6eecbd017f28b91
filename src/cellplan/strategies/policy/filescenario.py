"""A strategy file checked against a scenario: its digest, modes, C-space box and geometry.

:func:`~.fileformat.read_strategy` calls these with a scenario: the metadata before any
other array is inflated (:func:`check_scenario`, :func:`check_box`), the arrays against the
model cellplan builds itself for the scenario on the file's grid (:func:`check_geometry`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from cellplan.errors import ScenarioError
from cellplan.strategies.model.mdp import build_model
from cellplan.strategies.model.transitions import forbid_snapping
from cellplan.strategies.policy.filemeta import GEOMETRY_ARRAYS, StrategyMeta
from cellplan.strategies.variants.pending_files import PendingKey, check_pending_scenario
from cellplan.validity import ValiditySpace


def check_box(meta: StrategyMeta, cell: ValiditySpace, fail: Any) -> None:
    """The grid's box is the robot's C-space box (:meth:`cellplan.cspace.Grid.for_robot`)."""
    robot = cell.robot
    grid = meta.grid
    if len(grid.shape) != robot.dim:
        raise fail(
            f"meta.grid.shape: {len(grid.shape)} axes, the scenario's robot has {robot.dim}; "
            "solve this scenario again"
        )
    box = (list(map(float, robot.lower)), list(map(float, robot.upper)), list(robot.periodic))
    if (grid.lower, grid.upper, grid.periodic) != box:
        raise fail(
            "meta.grid: the box (lower, upper, periodic) differs from the scenario robot's "
            "C-space box; solve this scenario again"
        )


def check_geometry(
    meta: StrategyMeta, a: Mapping[str, np.ndarray], scenario: Any, cell: ValiditySpace, fail: Any
) -> None:
    """The moves, free space, collision-free moves and live states of the file are those
    cellplan computes itself for ``scenario`` on the file's grid.

    A digest is not a proof: a strategy solved for another workcell (an obstacle left
    out) and given this scenario's digest, or one with blocked cells marked free, would
    otherwise drive the robot through an obstacle. This builds the model as ``solve``
    does (:func:`~cellplan.strategies.model.mdp.build_model` on ``meta.grid.shape``, without
    snapping moves when the file says ``no-snap``), about what ``cellplan validate``
    spends, and compares :data:`GEOMETRY_ARRAYS` and where FMP is allowed (``tf``).
    """
    shape = list(meta.grid.shape)
    try:
        mdp = build_model(scenario, cell, shape)
        if meta.transitions == "no-snap":
            mdp = forbid_snapping(mdp)
    except ScenarioError as exc:
        problem = exc.problems[0]
        raise fail(
            f"the scenario cannot be solved on this file's grid {shape} ({problem.field}: "
            f"{problem.message}); solve this scenario again"
        ) from None
    mine: dict[str, np.ndarray] = {name: np.asarray(getattr(mdp, name)) for name in GEOMETRY_ARRAYS}
    mine["tf"] = np.isfinite(mdp.tf)
    theirs = dict(a) | {"tf": np.isfinite(a["tf"])}
    for name in (*GEOMETRY_ARRAYS, "tf"):
        ours, file = mine[name], np.asarray(theirs[name])
        if ours.shape != file.shape:
            raise fail(
                f"{name}: shape {file.shape}, the scenario's model on this grid has "
                f"{ours.shape}; this file does not match the scenario's geometry (solve it "
                "again)"
            )
        differ = ours != file
        if not differ.any():
            continue
        where = ""
        if name in ("free", "valid", "live", "tf") and file.ndim == 2:
            row, flat = (int(i) for i in np.argwhere(differ)[0])
            idx = tuple(int(i) for i in np.unravel_index(flat, tuple(shape)))
            centre = mdp.lower + (np.asarray(idx) + 0.5) * mdp.spacing
            what = (
                "move class"
                if name in ("free", "valid")
                else "mode"
                if name == "live"
                else "option"
            )
            label = mdp.modes[row].label if name == "live" else str(row)
            q = ", ".join(f"{v:.4g}" for v in centre)
            where = f" (first: {what} {label}, cell {idx}, q = ({q}))"
            if name == "free" and (file & ~ours).any():
                where = (
                    f"; it marks free {int((file & ~ours).sum())} cells the workcell blocks" + where
                )
        raise fail(
            f"{name}: {int(differ.sum())} entries differ from the model cellplan computes "
            f"for this scenario on its grid{where}; this file does not match the "
            "scenario's geometry (solve it again)"
        )


def check_scenario(
    meta: StrategyMeta,
    scenario: Any,
    fail: Any,
    pending: list[PendingKey] | None = None,
) -> None:
    if meta.scenario_digest != scenario.digest():
        raise fail(
            f"this strategy was computed for a different scenario "
            f"({meta.scenario_name or 'unnamed'}, digest {meta.scenario_digest[:12]}); "
            "solve this scenario again"
        )
    section = getattr(scenario, "strategy", None)
    if section is None:  # pragma: no cover - the digest already differs
        return
    spec = section.compile(scenario)
    requests = list(spec.requests)
    # A variant that lays the modes out its own way checks them (simultaneous requests).
    if any(variant.file_modes(meta, spec, fail) for variant in spec.variants):
        return
    if pending is not None:  # the Q modes of simultaneous requests; the scenario has none
        check_pending_scenario(meta, requests, section.max_pending, fail)
        return
    T = section.period
    if meta.period != T:
        raise fail(
            f"meta.period: {meta.period} stages, the scenario's period is {T}; solve this "
            "scenario again"
        )
    belts = {name: [float(v) for v in b.velocity] for name, b in section.belts.items()}
    if meta.belts != belts:
        raise fail(
            f"meta.belts: {sorted(meta.belts)[:5]} differ from the scenario's belts "
            f"{sorted(belts)[:5]} or their velocities; solve this scenario again"
        )
    expected = [("NR", "", "", "")]
    expected += [("W", p, s, d) for p, s, d, _ in requests]
    expected += [("C", p, s, d) for p, s, d, _ in requests]
    first = meta.modes[: len(meta.modes) // T]
    if [tuple(m) for m in first if m[0] != "X"] != expected:
        raise fail(
            f"meta.modes: {len(first)} modes, the scenario's requests give "
            f"{len(expected)}; solve this scenario again"
        )

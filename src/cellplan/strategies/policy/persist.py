"""The strategy file (``.npz``, no pickle): writing a solved model with its values, and
reading one back through the checks of :mod:`cellplan.strategies.policy.fileformat`.

:meth:`~cellplan.strategies.policy.strategy.Strategy.save` and
:meth:`~cellplan.strategies.policy.strategy.Strategy.load` call these.
"""

from __future__ import annotations

import json
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from cellplan.fileio import atomic_path
from cellplan.strategies.model.bundles import Outcomes
from cellplan.strategies.model.mdp import LayeredMDP, Mode
from cellplan.strategies.policy.fileformat import mode_of, read_strategy

_ARRAY_FIELDS = [
    f.name
    for f in fields(LayeredMDP)
    if f.name
    not in (
        "modes",
        "labels",
        "heading_axis",
        "stage_time",
        "arrival",
        "outcomes",
        "opt_ptr",
        "period",
        "variants",  # the model's rules (Section VI variants), not arrays
        "belts",
    )
]
#: The FMP outcome arrays of a strategy file (:class:`~.bundles.Outcomes`, by field).
_OUTCOME_ARRAYS = {"out_ptr": "ptr", "out_layer": "layer", "out_prob": "prob", "out_cost": "cost"}


def write_strategy(
    path: str | Path, mdp: LayeredMDP, values: np.ndarray, meta: dict[str, Any]
) -> Path:
    """Write ``mdp``, its ``values`` and ``meta`` as a compressed ``.npz`` (atomically)."""
    arrays = {name: np.asarray(getattr(mdp, name)) for name in _ARRAY_FIELDS}
    arrays["values"] = values
    # One layout for every model: the identity (one option per mode) without options.
    arrays["opt_ptr"] = np.asarray(mdp.options, np.int64)
    out = mdp.fmp_outcomes()
    for name, attr in _OUTCOME_ARRAYS.items():
        arrays[name] = np.asarray(getattr(out, attr))
    meta = dict(meta)
    meta.update(
        heading_axis=mdp.heading_axis,
        stage_time=mdp.stage_time,
        arrival=mdp.arrival,
        modes=[_mode_fields(m) for m in mdp.modes],
        labels=[list(lab) for lab in mdp.labels],
        period=mdp.period,
        phases=[m.phase for m in mdp.modes],
        belts={name: [float(v) for v in vel] for name, vel in mdp.belts.items()},
        grid={
            "shape": mdp.shape.tolist(),
            "lower": mdp.lower.tolist(),
            "upper": mdp.upper.tolist(),
            "periodic": mdp.periodic.tolist(),
        },
    )
    arrays["meta"] = np.array(json.dumps(meta))
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]
    return path


def read_model(
    path: str | Path, scenario: Any = None
) -> tuple[LayeredMDP, np.ndarray, dict[str, Any]]:
    """The model, values and metadata of a strategy file, every array checked first
    (:func:`~cellplan.strategies.policy.fileformat.read_strategy`; with ``scenario``, a
    file made for another scenario is refused)."""
    meta, arrays = read_strategy(path, scenario)
    modes = [
        replace(mode_of(m), phase=p) for m, p in zip(meta["modes"], meta["phases"], strict=True)
    ]
    kw = {name: arrays[name] for name in _ARRAY_FIELDS}
    opt_ptr = arrays["opt_ptr"]
    if np.array_equal(opt_ptr, np.arange(len(modes) + 1)):
        opt_ptr = None  # one option per mode: the model is as it was built (is_simple)
    mdp = LayeredMDP(
        modes=modes,
        labels=[tuple(lab) for lab in meta["labels"]],
        heading_axis=int(meta["heading_axis"]),
        stage_time=float(meta["stage_time"]),
        arrival=float(meta["arrival"]),
        outcomes=Outcomes(**{attr: arrays[name] for name, attr in _OUTCOME_ARRAYS.items()}),
        opt_ptr=opt_ptr,
        period=int(meta["period"]),
        belts={name: (float(v[0]), float(v[1])) for name, v in meta["belts"].items()},
        **kw,
    )
    # Optional fields absent from older files stay absent (the defaults apply).
    meta = {k: v for k, v in meta.items() if v is not None}
    return mdp, arrays["values"], meta


def _mode_fields(mode: Mode) -> list[str]:
    """A mode as the strategy file stores it: kind, part, source, destination, and for X
    modes the reject region and what follows the rejection, for Q modes (simultaneous
    requests, Section VI-2) the waiting requests."""
    fields = [mode.kind, mode.part, mode.source, mode.destination]
    if mode.kind == "X":
        return [*fields, mode.reject, mode.after]
    return [*fields, *mode.waiting] if mode.kind == "Q" else fields

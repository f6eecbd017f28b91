"""Every degree/radian conversion in cellplan, and the checks on configurations given in code.

The convention: scenario files (and everything a person types: CLI options, YAML) write
angles in **degrees**; code, saved trajectories and strategy files use **radians**. The
conversion happens here and nowhere else, so a reader can find every place where a unit
changes by searching for this module.

A robot's angular axes are the ones not named ``x``, ``y`` or ``z`` (``theta`` of a
rotating body, ``q1 ... qn`` of an arm), unless the robot says axis by axis (a URDF arm's
prismatic joints are lengths).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellplan.errors import ArgumentError, Problem
from cellplan.schema import COORD_LIMIT

FloatArray = NDArray[np.float64]

LENGTH = "workcell"
"""Unit name of positions: the scenario's own length unit."""
ANGLE = "rad"
"""Unit name of angles in code."""

#: The largest magnitude an angle (radians) may have where code takes configurations.
#: Two full turns lets callers pass unwrapped angles; a value in degrees (90, 180) is
#: far outside and is refused with a message saying angles are radians here.
ANGLE_LIMIT = 2.0 * math.pi


def radians(degrees: Any) -> Any:
    """Degrees to radians (scalars stay Python floats, arrays stay arrays)."""
    if np.isscalar(degrees):
        return math.radians(float(degrees))  # type: ignore[arg-type]
    return np.radians(np.asarray(degrees, dtype=float))


def degrees(rad: Any) -> Any:
    """Radians to degrees (scalars stay Python floats, arrays stay arrays)."""
    if np.isscalar(rad):
        return math.degrees(float(rad))  # type: ignore[arg-type]
    return np.degrees(np.asarray(rad, dtype=float))


def angular_axes(
    axis_names: Sequence[str], angular: Sequence[bool] | None = None
) -> tuple[bool, ...]:
    """Which axes of a configuration are angles.

    ``angular``, when given, says it axis by axis (a URDF arm knows which of its joints
    are prismatic); otherwise every axis but ``x``, ``y`` and ``z`` is an angle.
    """
    if angular is not None:
        if len(angular) != len(axis_names):
            raise ValueError("angular needs one flag per axis")
        return tuple(bool(a) for a in angular)
    return tuple(name not in ("x", "y", "z") for name in axis_names)


def axis_units(axis_names: Sequence[str], angular: Sequence[bool] | None = None) -> tuple[str, ...]:
    """The unit of each axis in code: ``"workcell"`` or ``"rad"``."""
    return tuple(ANGLE if a else LENGTH for a in angular_axes(axis_names, angular))


def config_from_file(
    axis_names: Sequence[str], values: Sequence[float], angular: Sequence[bool] | None = None
) -> FloatArray:
    """A configuration as written in a file (degrees for angles) in code units (radians)."""
    q = np.asarray(values, dtype=float).copy()
    mask = np.array(angular_axes(axis_names, angular), dtype=bool)
    q[..., mask] = np.radians(q[..., mask])
    return q


def config_to_file(
    axis_names: Sequence[str], q: ArrayLike, angular: Sequence[bool] | None = None
) -> FloatArray:
    """A configuration in code units as it would be written in a file (degrees for angles)."""
    out = np.asarray(q, dtype=float).copy()
    mask = np.array(angular_axes(axis_names, angular), dtype=bool)
    out[..., mask] = np.degrees(out[..., mask])
    return out


def pose_from_file(
    xyz: Sequence[float], rpy_degrees: Sequence[float]
) -> tuple[FloatArray, FloatArray]:
    """A pose as written in a file (position, roll-pitch-yaw in degrees) in code units."""
    return np.asarray(xyz, dtype=float), np.radians(np.asarray(rpy_degrees, dtype=float))


#: Kinds of numpy dtype a numeric argument may have: signed and unsigned integers and
#: real floats. Booleans, complex numbers (whose imaginary part a float conversion drops),
#: strings and objects are refused rather than converted.
REAL_KINDS = "iuf"


def real_array(value: ArrayLike, name: str, expected: str = "an array of numbers") -> FloatArray:
    """``value`` as a C-contiguous float64 array, or an :class:`ArgumentError` naming ``name``.

    Any real numeric dtype, layout or writability is accepted (a strided or read-only
    array is copied only when it must be); finiteness and ranges are the caller's checks.
    ``expected`` completes the refusal: ``expected <expected>, got dtype <U3``.
    """
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise ArgumentError([Problem(name, f"expected {expected}")]) from None
    if arr.dtype.kind not in REAL_KINDS or (arr.dtype.kind == "f" and _holds_bool(value)):
        got = "booleans" if arr.dtype.kind in "bf" else f"dtype {arr.dtype}"
        raise ArgumentError([Problem(name, f"expected {expected}, got {got}")])
    return np.asarray(arr, dtype=np.float64, order="C")


def _holds_bool(value: Any) -> bool:
    """Whether nested lists or tuples hold a boolean (numpy reads ``[True, 2.5]`` as floats)."""
    if isinstance(value, list | tuple):
        return any(_holds_bool(v) for v in value)
    return isinstance(value, bool | np.bool_)


def real_number(value: Any, name: str) -> float:
    """``value`` as a finite Python float, or an :class:`ArgumentError` naming ``name``.

    Accepts Python and numpy integers and floats; refuses booleans, arrays of more than
    one value, text, NaN and infinities.
    """
    arr = real_array(value, name, "a number")
    if arr.ndim != 0:
        raise ArgumentError([Problem(name, f"expected one number, got shape {arr.shape}")])
    number = float(arr)
    if not math.isfinite(number):
        raise ArgumentError([Problem(name, f"must be a finite number, got {number}")])
    return number


def check_configurations(
    q: ArrayLike,
    axis_names: Sequence[str],
    name: str = "q",
    angular: Sequence[bool] | None = None,
) -> FloatArray:
    """``q`` as a C-contiguous float ``(N, dim)`` array, or an :class:`ArgumentError`.

    Refuses a dtype that is not a real number (:func:`real_array`), a wrong shape,
    non-finite values, positions beyond :data:`cellplan.schema.COORD_LIMIT` (no workcell
    reaches them, and geometry there loses every digit) and angles beyond
    :data:`ANGLE_LIMIT` (the usual sign of degrees passed where radians are expected).
    """
    dim = len(axis_names)
    arr = real_array(q, name)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ArgumentError(
            [Problem(name, f"expected shape (N, {dim}) or ({dim},), got {np.shape(q)}")]
        )
    if not np.all(np.isfinite(arr)):
        raise ArgumentError([Problem(name, "contains NaN or infinite values")])
    mask = np.array(angular_axes(axis_names, angular), dtype=bool)
    if (~mask).any() and arr.size:
        positions = np.abs(arr[:, ~mask])
        if positions.max() > COORD_LIMIT:
            row, col = np.unravel_index(int(np.argmax(positions)), positions.shape)
            axis = [a for a, m in zip(axis_names, mask, strict=True) if not m][col]
            value = arr[row, np.flatnonzero(~mask)[col]]
            raise ArgumentError(
                [
                    Problem(
                        name,
                        f"position {axis}={value:g} is outside [-{COORD_LIMIT:g}, "
                        f"{COORD_LIMIT:g}], beyond any workcell",
                    )
                ]
            )
    if mask.any():
        angles = np.abs(arr[:, mask])
        if angles.size and angles.max() > ANGLE_LIMIT + 1e-9:
            row, col = np.unravel_index(int(np.argmax(angles)), angles.shape)
            axis = [a for a, m in zip(axis_names, mask, strict=True) if m][col]
            value = arr[row, np.flatnonzero(mask)[col]]
            raise ArgumentError(
                [
                    Problem(
                        name,
                        f"angle {axis}={value:g} is outside [-2 pi, 2 pi]; angles are radians "
                        "here (degrees only in scenario files: use cellplan.units.radians)",
                    )
                ]
            )
    return arr

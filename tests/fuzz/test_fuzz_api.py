"""Fuzzing the public API's numeric arguments (issue 36): the Workcell queries.

Each case takes clean configurations of a bundled scenario (a translating body, a
rotating bar, a planar arm) and damages one argument: a special value (NaN, +-inf,
+-1e308, +-5e-324) in one place, another dtype (float32, int64, bool, complex, text,
object), another layout (strided, Fortran order, read-only, a list), or a bad scalar
(step, margin, offset, component). Every query must then either answer exactly as it
answers for a clean contiguous float64 copy of the same values, or raise
:class:`~cellplan.errors.ArgumentError`; any other exception fails. Values with no right
answer (NaN, infinities) must be refused. The default run is a few cases per scenario
with a fixed seed; the ``slow`` run tries ``CELLPLAN_FUZZ_API_EXAMPLES`` per scenario:

    CELLPLAN_FUZZ_API_EXAMPLES=500 pytest -m slow tests/fuzz/test_fuzz_api.py
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from fuzz_harness import FailureLog, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

import cellplan
from cellplan.errors import ArgumentError
from cellplan.workcell import MAX_MOTION_SAMPLES, Workcell

FAST_EXAMPLES = 25
SLOW_EXAMPLES = int(os.environ.get("CELLPLAN_FUZZ_API_EXAMPLES", "500"))
SCENARIOS = ["strategies_tiny", "rotating_bar", "strategies_p5"]

SPECIAL = [math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -5e-324, 0.0, -0.0]
# Scalars for step and margin: valid, extreme, and surely wrong.
SCALARS: list[Any] = [
    *SPECIAL,
    1e-18,
    1e-300,
    0.5,
    1.0,
    -1.0,
    True,
    "0.5",
    0.5 + 0j,
    None,
    np.float32(0.5),
    np.int64(1),
    np.array(0.5),
    np.array([0.5]),
    np.array([0.5, 0.5]),
    [0.5],
]
DTYPES = ["float32", "float16", "int64", "uint8", "bool", "complex128", "str", "object"]
LAYOUTS = ["list", "strided", "fortran", "readonly", "readonly-strided", "tuple-rows"]


@functools.cache
def workcell(name: str) -> Workcell:
    return cellplan.load(name).workcell


def clean_configurations(cell: Workcell, n: int, seed: int) -> np.ndarray:
    """``n`` configurations inside the bounds and joint limits (free or not)."""
    rng = np.random.default_rng(seed)
    robot = cell.robot
    lower = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    upper = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    return lower + rng.random((n, robot.dim)) * (upper - lower)


@dataclass(frozen=True)
class Damage:
    """One damaged argument: ``apply(clean)`` gives what the query receives."""

    what: str
    apply: Callable[[np.ndarray], Any]
    nonfinite: bool = False  # no right answer exists: the query must refuse


def _special(value: float, row: int, col: int) -> Damage:
    def put(q: np.ndarray) -> np.ndarray:
        out = q.copy()
        out[row % len(out), col % out.shape[1]] = value
        return out

    return Damage(f"value {value!r} at [{row}, {col}]", put, not math.isfinite(value))


def _dtype(name: str) -> Damage:
    def convert(q: np.ndarray) -> np.ndarray:
        if name == "str":
            return q.astype(str)
        if name == "object":
            return q.astype(object)
        return q.astype(name)

    return Damage(f"dtype {name}", convert)


def _layout(name: str) -> Damage:
    def arrange(q: np.ndarray) -> Any:
        if name == "list":
            return q.tolist()
        if name == "tuple-rows":
            return tuple(tuple(row) for row in q)
        if name == "fortran":
            return np.asfortranarray(q)
        wide = np.zeros((q.shape[0], 2 * q.shape[1]))
        wide[:, ::2] = q
        out = wide[:, ::2] if "strided" in name else q.copy()
        if "readonly" in name:
            out.flags.writeable = False
        return out

    return Damage(f"layout {name}", arrange)


def damages() -> st.SearchStrategy[Damage]:
    index = st.integers(0, 7)
    return st.one_of(
        st.builds(_special, st.sampled_from(SPECIAL), index, index),
        st.sampled_from(DTYPES).map(_dtype),
        st.sampled_from(LAYOUTS).map(_layout),
    )


def clean_copy(value: Any) -> np.ndarray | None:
    """The same values as a C-contiguous float64 array, or None if they are not numbers."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        return None
    if arr.dtype.kind not in "iuf":
        return None
    return np.array(arr, dtype=np.float64, order="C")


def outcome(call: Callable[[], Any]) -> Any:
    """The query's answer (as a plain array), or the ArgumentError class if refused.

    Any other exception propagates and fails the test.
    """
    try:
        return np.asarray(call()).copy()
    except ArgumentError as exc:
        assert len(exc.problems) >= 1
        for problem in exc.problems:
            assert "\n" not in str(problem)
        return ArgumentError


def assert_same_or_refused(damaged: Any, clean: Any, what: str, must_refuse: bool) -> None:
    if must_refuse:
        assert damaged is ArgumentError, f"{what}: answered {damaged!r} instead of refusing"
        return
    if damaged is ArgumentError:
        return
    assert clean is not ArgumentError, f"{what}: answered although the clean copy is refused"
    np.testing.assert_array_equal(damaged, clean, err_msg=what)


def queries(cell: Workcell, q: Any, other: np.ndarray) -> dict[str, Callable[[], Any]]:
    """Every public query, called with configurations ``q``."""
    region = next(iter([*cell.sources, *cell.destinations]))
    part = next(iter(cell.parts), None)
    return {
        "collides": lambda: cell.collides(q),
        "collides carrying": lambda: cell.collides(q, carrying=part),
        "free": lambda: cell.free(q, avoid_sources="none"),
        "clearance": lambda: cell.clearance(q),
        "in_region contact": lambda: cell.in_region(q, region),
        "in_region enclosure": lambda: cell.in_region(q, region, "enclosure", carrying=part),
        "motion_collides from": lambda: cell.motion_collides(q, other, 0.5),
        "motion_collides to": lambda: cell.motion_collides(other, q, 0.5, certified=False),
    }


def scalar_queries(cell: Workcell, q: np.ndarray, value: Any) -> dict[str, Callable[[], Any]]:
    """Every query taking a scalar or small-vector numeric argument, given ``value``."""
    region = next(iter([*cell.sources, *cell.destinations]))
    other = q[::-1].copy()
    calls = {
        "step": lambda: cell.motion_collides(q, other, value),
        "margin": lambda: cell.collides(q, margin=value),
        "offset": lambda: cell.in_region(q, region, offset=(value, 0.0)),
    }
    if value is not None:  # component=None is the default: every component
        calls["component"] = lambda: cell.in_region(q, region, component=value)
    return calls


def check_damaged_configurations(name: str, damage: Damage, n: int, seed: int) -> None:
    cell = workcell(name)
    q = clean_configurations(cell, n, seed)
    other = clean_configurations(cell, n, seed + 1)
    damaged = damage.apply(q)
    copy = clean_copy(damaged)
    for label, call in queries(cell, damaged, other).items():
        got = outcome(call)
        expected = ArgumentError if copy is None else outcome(queries(cell, copy, other)[label])
        assert_same_or_refused(
            got, expected, f"{name} {label} with {damage.what}", damage.nonfinite
        )


def check_scalar(name: str, value: Any, n: int, seed: int) -> None:
    cell = workcell(name)
    q = clean_configurations(cell, n, seed)
    copy = clean_copy(value)
    nonfinite = copy is not None and not np.all(np.isfinite(copy))
    for label, call in scalar_queries(cell, q, value).items():
        got = outcome(call)
        if copy is None:
            expected = ArgumentError
        else:
            plain = copy.item() if copy.ndim == 0 else copy
            expected = outcome(scalar_queries(cell, q, plain)[label])
        assert_same_or_refused(got, expected, f"{name} {label}={value!r}", nonfinite)
        if label == "step" and got is not ArgumentError:
            # An end in collision makes the whole motion collide, whatever the step.
            ends = cell.collides(q) | cell.collides(q[::-1].copy())
            assert np.all(got[ends]), f"{name} step={value!r}: a colliding end reported free"


class TestWorkcellQueriesFuzz:
    """Damaged numeric arguments: the same answer as a clean float64 copy, or one-line
    ArgumentError; never another exception, never an answer for NaN or infinity."""

    @pytest.mark.parametrize("name", SCENARIOS)
    def test_damaged_configurations(self, name: str) -> None:
        @fuzz_settings(FAST_EXAMPLES)
        @given(damage=damages(), n=st.integers(1, 4), seed=st.integers(0, 2**16))
        def case(damage: Damage, n: int, seed: int) -> None:
            check_damaged_configurations(name, damage, n, seed)

        case()

    @pytest.mark.parametrize("name", SCENARIOS)
    def test_damaged_scalars(self, name: str) -> None:
        @fuzz_settings(FAST_EXAMPLES)
        @given(value=st.sampled_from(SCALARS), n=st.integers(1, 3), seed=st.integers(0, 2**16))
        def case(value: Any, n: int, seed: int) -> None:
            check_scalar(name, value, n, seed)

        case()

    @pytest.mark.slow
    @pytest.mark.parametrize("name", SCENARIOS)
    def test_thousands(self, name: str) -> None:
        log = FailureLog("api", name)

        @fuzz_settings(SLOW_EXAMPLES)
        @given(
            damage=damages(),
            value=st.sampled_from(SCALARS),
            n=st.integers(1, 6),
            seed=st.integers(0, 2**16),
        )
        def case(damage: Damage, value: Any, n: int, seed: int) -> None:
            def both() -> None:
                check_damaged_configurations(name, damage, n, seed)
                check_scalar(name, value, n, seed)

            log.check(both)

        case()
        log.finish()

    def test_every_scalar_once(self) -> None:
        """Each listed scalar on the tiny scenario (the fuzzing above samples them)."""
        for value in SCALARS:
            check_scalar("strategies_tiny", value, 2, 0)

    def test_every_damage_once(self) -> None:
        """Each listed dtype and layout, and NaN in a configuration, on the tiny scenario."""
        for damage in [*map(_dtype, DTYPES), *map(_layout, LAYOUTS), _special(math.nan, 0, 1)]:
            check_damaged_configurations("strategies_tiny", damage, 3, 0)


# --- the reproducers -------------------------------------------------------------------

THROUGH_WALL = (np.array([15.0, 8.0]), np.array([15.0, 22.0]))  # across 'middle' of the tiny cell


def test_wall_is_between_the_motions_ends():
    cell = workcell("strategies_tiny")
    q0, q1 = THROUGH_WALL
    assert not cell.collides(q0)[0] and not cell.collides(q1)[0]
    assert cell.collides([15.0, 14.0])[0]
    assert cell.motion_collides(q0, q1, 0.1)[0]


@pytest.mark.parametrize("step", [1e-18, 1e-300, 5e-324])
def test_tiny_step_through_a_wall_is_refused_not_free(step):
    cell = workcell("strategies_tiny")
    with pytest.raises(ArgumentError) as err:
        cell.motion_collides(*THROUGH_WALL, step)
    (problem,) = err.value.problems
    assert problem.field == "step"
    assert f"{MAX_MOTION_SAMPLES:,}" in problem.message


def test_step_needing_too_much_memory_is_refused_before_allocating(monkeypatch):
    monkeypatch.setenv("CELLPLAN_MEMORY_LIMIT", "1GB")
    cell = workcell("strategies_tiny")
    with pytest.raises(ArgumentError) as err:
        cell.motion_collides(*THROUGH_WALL, 1e-9)  # 14e9 samples: terabytes
    (problem,) = err.value.problems
    assert problem.field == "step"
    assert "needs about" in problem.message


@pytest.mark.parametrize("step", [0.0, -0.0, -1.0, math.nan, math.inf, -math.inf, True, "0.1"])
def test_bad_step_is_one_line(step):
    with pytest.raises(ArgumentError) as err:
        workcell("strategies_tiny").motion_collides(*THROUGH_WALL, step)
    assert [p.field for p in err.value.problems] == ["step"]


@pytest.mark.parametrize("margin", [math.nan, math.inf, -math.inf, -0.5, [math.nan], "0"])
def test_bad_margin_is_refused_not_free(margin):
    cell = workcell("strategies_tiny")
    with pytest.raises(ArgumentError) as err:
        cell.collides([15.0, 14.0], margin=margin)  # inside the wall 'middle'
    assert [p.field for p in err.value.problems] == ["margin"]


def test_margin_per_body_and_huge_margin_still_answer():
    cell = workcell("strategies_tiny")
    free = np.array([15.0, 8.0])
    assert not cell.collides(free, margin=[0.5])[0]
    assert cell.collides(free, margin=1e308)[0]  # no clearance that large exists

"""The units module: the one place angles change unit, and the radians check."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from cellplan import units
from cellplan.errors import ArgumentError

SRC = Path(__file__).resolve().parents[1] / "src" / "cellplan"


def test_round_trip_between_file_and_code_units():
    names = ("x", "y", "theta")
    q = units.config_from_file(names, [1.0, 2.0, 90.0])
    assert np.allclose(q, [1.0, 2.0, math.pi / 2])
    assert np.allclose(units.config_to_file(names, q), [1.0, 2.0, 90.0])
    assert units.axis_units(names) == ("workcell", "workcell", "rad")
    assert units.radians(180.0) == pytest.approx(math.pi)
    assert isinstance(units.degrees(1.0), float)


@pytest.mark.parametrize(
    ("q", "message"),
    [
        ([[90.0, 0.0]], "radians here"),
        ([[0.1]], r"shape \(N, 2\)"),
        ([[np.nan, 0.0]], "NaN"),
        ("abc", "array of numbers"),
    ],
)
def test_check_configurations_names_the_problem(q, message):
    with pytest.raises(ArgumentError, match=message):
        units.check_configurations(q, ("q1", "q2"))


def test_positions_may_be_large():
    q = units.check_configurations([100.0, 250.0], ("x", "y"))
    assert q.shape == (1, 2)


def test_no_conversion_outside_the_units_module():
    pattern = re.compile(r"math\.(radians|degrees)|np\.(radians|degrees|deg2rad|rad2deg)")
    offenders = [
        str(p.relative_to(SRC))
        for p in SRC.rglob("*.py")
        if p.name != "units.py" and pattern.search(p.read_text())
    ]
    assert offenders == []

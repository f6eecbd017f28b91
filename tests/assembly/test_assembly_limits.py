"""Documented limits of ``cellplan assemble`` (GIF frames, generated discs): one line each,
exit 2, nothing written."""

from __future__ import annotations

import pytest

from cellplan.assembly.run import MAX_FRAMES
from cellplan.assembly.section import MAX_GENERATED_DISCS


@pytest.mark.parametrize(
    ("args", "flag"),
    [
        (["--random", "5", "--frames", "100000"], f"--frames: must be in [2, {MAX_FRAMES}]"),
        (["--random", "5", "--frames", "1"], "--frames"),
        (["--random", str(MAX_GENERATED_DISCS + 100)], "--random"),
    ],
)
def test_limits_are_one_line_and_exit_2(cellplan, tmp_path, args, flag):
    out = tmp_path / "out"
    r = cellplan("assemble", *args, "-o", str(out))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0], r.stderr
    assert not out.exists()

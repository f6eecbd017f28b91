"""Documented limits of ``cellplan assemble`` (GIF frames, generated discs): one line each,
exit 2, nothing written."""

from __future__ import annotations

import pytest

from cellplan.assembly.run import MAX_FRAMES
from cellplan.assembly.section import MAX_DISCS


@pytest.mark.parametrize(
    ("args", "flag"),
    [
        (["--random", "5", "--frames", "100000"], f"--frames: must be in [2, {MAX_FRAMES}]"),
        (["--random", "5", "--frames", "1"], "--frames"),
        (["--random", str(MAX_DISCS + 100)], "--random"),
    ],
)
def test_limits_are_one_line_and_exit_2(cellplan, tmp_path, args, flag):
    out = tmp_path / "out"
    r = cellplan("assemble", *args, "-o", str(out))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0], r.stderr
    assert not out.exists()


def test_a_file_listing_more_discs_than_the_limit_is_refused_before_any_pair_is_formed(
    cellplan, tmp_path
):
    import yaml

    n = 3000  # 3000 x 3000 pair arrays were built before the limit (13 GiB at 30,000)
    discs = [
        {"radius": 1.0, "start": [3.0 * (i % 60), 3.0 * (i // 60)], "goal": [3.0 * i, -500.0]}
        for i in range(n)
    ]
    data = {
        "cellplan": 1,
        "name": "many",
        "workcell": {"bounds": {"xmin": -10, "ymin": -600, "xmax": 9100, "ymax": 200}},
        "discs": {"discs": discs},
    }
    path = tmp_path / "many.yaml"
    path.write_text(yaml.safe_dump(data))
    r = cellplan("validate", str(path))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"error: discs.discs: has {n:,} items; at most {MAX_DISCS} allowed"
    ]

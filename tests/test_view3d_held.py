"""The part held between pick and place events, drawn on the tool (issue 31).

:func:`cellplan.scene3d.held_from_events` reads the held part from a trajectory's typed
events; ``cellplan view TRAJ`` and the viewer of ``assemble --algorithm robot`` draw it
through :func:`cellplan.scene3d.cell_scene`. The browser test
(test_view3d_browser.py) opens such a page and follows the part with the tool.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellplan import arm as arms
from cellplan.api import load
from cellplan.scene3d import cell_scene, held_from_events
from cellplan.trajectory import Event, Trajectory
from cellplan.workcell3d import Workcell3D

PICK, PLACE, SAMPLES = 2, 6, 9


def ev(index: int, kind: str, part: str = "P1") -> Event:
    return Event(index, kind, f"{part} at here", part=part, region="here")


def test_pick_to_place_holds_the_part_both_ends_included() -> None:
    held = held_from_events([ev(PICK, "pick"), ev(PLACE, "place")], SAMPLES)
    assert held == [None, None, "P1", "P1", "P1", "P1", "P1", None, None]


def test_reject_ends_a_hold_and_other_events_change_nothing() -> None:
    events = [ev(1, "pick"), ev(2, "fmp_failed"), ev(3, "reject"), ev(4, "request")]
    assert held_from_events(events, 6) == [None, "P1", "P1", "P1", None, None]


def test_place_then_pick_on_one_sample_holds_the_new_part_there() -> None:
    events = [ev(0, "pick", "P1"), ev(2, "place", "P1"), ev(2, "pick", "P2"), ev(4, "place", "P2")]
    assert held_from_events(events, 5) == ["P1", "P1", "P2", "P2", "P2"]


def test_a_cut_trajectory_holds_from_the_start_or_to_the_end() -> None:
    assert held_from_events([ev(1, "place")], 3) == ["P1", "P1", None]
    assert held_from_events([ev(1, "pick")], 3) == [None, "P1", "P1"]
    # a place with no pick after another hold is not guessed at
    events = [ev(0, "pick", "P1"), ev(1, "place", "P1"), ev(3, "place", "P2")]
    assert held_from_events(events, 4) == ["P1", "P1", None, None]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 30), min_size=2, max_size=10, unique=True).map(sorted))
def test_alternating_picks_and_places_hold_exactly_their_intervals(marks: list[int]) -> None:
    # Oracle: pairs (pick, place) of increasing sample indices, one part per pair.
    pairs = list(zip(marks[0::2], marks[1::2], strict=False))
    events = []
    for k, (a, b) in enumerate(pairs):
        events += [ev(a, "pick", f"P{k}"), ev(b, "place", f"P{k}")]
    held = held_from_events(events, 31)
    for i in range(31):
        inside = [f"P{k}" for k, (a, b) in enumerate(pairs) if a <= i <= b]
        assert held[i] == (inside[-1] if inside else None)


def ur5_trajectory() -> tuple[Workcell3D, Trajectory]:
    """9 samples of a straight joint-space motion of ``ur5_cell``'s arm, ``P1`` picked at
    sample 2 and placed at sample 6, half a second apart."""
    cell = load("ur5_cell").workcell
    assert isinstance(cell, Workcell3D)
    q0 = cell.robot.start
    q1 = q0 + np.array([0.9, -0.3, 0.4, 0.0, 0.5, 0.0])[: cell.robot.dim]
    q = q0 + np.linspace(0.0, 1.0, SAMPLES)[:, None] * (q1 - q0)
    dim = cell.robot.dim
    traj = Trajectory(
        0.5 * np.arange(SAMPLES),
        q,
        np.zeros(SAMPLES, dtype=np.int64),
        ("move",),
        tuple(f"j{i}" for i in range(dim)),
        ("rad",) * dim,
        "s",
        (ev(PICK, "pick"), ev(PLACE, "place")),
    )
    return cell, traj


def test_the_part_follows_the_tool_between_pick_and_place_and_stays_put_outside() -> None:
    cell, traj = ur5_trajectory()
    scene = cell_scene(cell, traj.q, traj.t, held_from_events(traj.events, len(traj)))
    part = [i for i, item in enumerate(scene.items) if item.name == "part/P1"]
    assert len(part) == 1
    position = scene.poses[:, part[0], :3, 3]
    tool = arms.tool_pose(cell.robot.arm, traj.q)[:, :3, 3]
    hold = slice(PICK, PLACE + 1)
    np.testing.assert_allclose(position[hold], tool[hold], atol=1e-12)
    np.testing.assert_allclose(position[:PICK], np.repeat(tool[[PICK]], PICK, 0), atol=1e-12)
    after = SAMPLES - PLACE - 1
    np.testing.assert_allclose(position[PLACE + 1 :], np.repeat(tool[[PLACE]], after, 0))
    assert np.ptp(position[hold], axis=0).max() > 0.05  # it moves while held


def test_view_command_draws_the_held_part_and_refuses_unknown_parts(
    tmp_path: Path, cellplan
) -> None:
    _, traj = ur5_trajectory()
    saved = traj.save(tmp_path / "t.json")
    page = tmp_path / "v.html"
    r = cellplan("view", "ur5_cell", "--trajectory", str(saved), "-o", str(page))
    assert r.returncode == 0, r.stderr
    # the held part is drawn (an item named after it); the browser test follows it
    assert page.stat().st_size > 0
    bad = Trajectory(
        traj.t, traj.q, traj.mode, traj.modes, traj.columns, traj.units, "s",
        (ev(PICK, "pick", "P9"), ev(PLACE, "place", "P9")),
    )  # fmt: skip
    bad_file = bad.save(tmp_path / "bad.json")
    other = tmp_path / "w.html"
    r = cellplan("view", "ur5_cell", "--trajectory", str(bad_file), "-o", str(other))
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "--trajectory" in r.stderr and "P9" in r.stderr
    assert not other.exists()

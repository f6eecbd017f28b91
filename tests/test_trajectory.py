"""Trajectory files: exact round trips (hypothesis), clear errors, combining and sampling."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from cellplan.errors import PersistenceError
from cellplan.trajectory import Event, Trajectory

finite = st.floats(
    allow_nan=False, allow_infinity=False, width=64, min_value=-1e300, max_value=1e300
)
text = st.text(alphabet=st.characters(blacklist_characters="|\n\r\x00", codec="utf-8"), max_size=12)


@st.composite
def trajectories(draw):
    n = draw(st.integers(1, 30))
    dim = draw(st.integers(1, 5))
    t = np.sort(draw(arrays(np.float64, n, elements=finite)))
    q = draw(arrays(np.float64, (n, dim), elements=finite))
    modes = tuple(draw(st.lists(text, min_size=1, max_size=4, unique=True)))
    mode = draw(arrays(np.int64, n, elements=st.integers(0, len(modes) - 1)))
    columns = tuple(f"c{i}" for i in range(dim))
    units = tuple(draw(st.sampled_from(["workcell", "rad"])) for _ in range(dim))
    kinds = st.text(alphabet="abcdefgh_", min_size=1, max_size=8)
    events = draw(
        st.lists(st.builds(Event, st.integers(0, n - 1), kinds, text, text, text, text), max_size=6)
    )
    events.sort(key=lambda e: e.index)
    extra = {}
    if draw(st.booleans()):
        extra["stage_duration"] = draw(st.floats(0, 10))
    if draw(st.booleans()):
        extra["qd"] = draw(arrays(np.float64, (n, dim), elements=finite))
        extra["qdd"] = draw(arrays(np.float64, (n, dim), elements=finite))
    if draw(st.booleans()):
        extra["velocity_limits"] = tuple(draw(st.lists(st.floats(1e-3, 1e3), min_size=dim,
                                                       max_size=dim)))  # fmt: skip
    return Trajectory(
        t, q, mode, modes, columns, units, "stage", tuple(events), {"seed": 3}, **extra
    )


@given(trajectories(), st.sampled_from([".csv", ".json", ".npz"]))
def test_every_format_round_trips_exactly(tmp_path_factory, traj, suffix):
    path = tmp_path_factory.mktemp("t") / f"traj{suffix}"
    traj.save(path)
    back = Trajectory.load(path)
    assert back == traj
    assert back.mode_names == traj.mode_names


def _line():
    t = np.arange(5.0)
    q = np.stack([t, 2 * t], axis=1)
    mode = np.array([0, 0, 1, 1, 1])
    return Trajectory(
        t,
        q,
        mode,
        ("idle", "busy"),
        ("x", "y"),
        ("workcell", "workcell"),
        events=(Event.from_text(2, "pick", "P1 at S1"),),
    )


def test_csv_is_readable_by_a_plain_csv_reader(tmp_path):
    import csv

    path = _line().save(tmp_path / "a.csv")
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# cellplan-trajectory 2 ")
    rows = list(csv.DictReader(lines[1:]))
    event = {"kind": "pick", "part": "P1", "region": "S1", "target": "", "detail": "P1 at S1"}
    assert rows[2] == {
        "t": "2.0",
        "seconds": "0.4",  # y moves 2 per stage: 0.2 s at the default 10 units/s
        "mode": "busy",
        "x": "2.0",
        "y": "4.0",
        "events": json.dumps([event], separators=(",", ":")),
    }


@pytest.mark.parametrize(
    "change",
    [
        {"t": np.array([0.0, 2.0, 1.0, 3.0, 4.0])},
        {"mode": np.array([0, 0, 2, 0, 0])},
        {"columns": ("x",)},
        {"units": ("workcell",)},
        {"q": np.full((5, 2), np.nan)},
        {"events": (Event(9, "pick"),)},
        {"columns": ("t", "y")},
    ],
)
def test_inconsistent_trajectories_are_refused(change):
    base = _line()
    fields = dict(
        t=base.t,
        q=base.q,
        mode=base.mode,
        modes=base.modes,
        columns=base.columns,
        units=base.units,
        events=base.events,
    )
    fields.update(change)
    with pytest.raises(ValueError, match="invalid trajectory"):
        Trajectory(**fields)


def _broken_npz(kind: str) -> bytes:
    """A trajectory .npz written by numpy, then broken: ``truncated`` (cut in half) or
    ``header`` (the header member's .npy header left without its closing brace)."""
    buffer = io.BytesIO()
    np.savez(buffer, header=np.array("{}"), t=np.arange(3.0))
    raw = buffer.getvalue()
    if kind == "truncated":
        return raw[: len(raw) // 2]
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(raw)) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = bytearray(src.read(info))
            if info.filename == "header.npy":  # read first
                data[data.index(b"}")] = ord(" ")
            dst.writestr(info.filename, bytes(data))
    return out.getvalue()


@pytest.mark.parametrize("kind", ["truncated", "header"])
def test_broken_npz_files_give_one_line(tmp_path, kind):
    path = tmp_path / "a.npz"
    path.write_bytes(_broken_npz(kind))
    with pytest.raises(PersistenceError) as err:
        Trajectory.load(path)
    assert len(err.value.problems) == 1
    assert err.value.problems[0].field == str(path)


@pytest.mark.parametrize(
    ("name", "content"),
    [
        ("a.csv", "t,mode\n1,2\n"),
        ("a.json", "[1, 2]"),
        ("a.json", json.dumps({"format": "cellplan-trajectory", "version": 99})),
        ("a.npz", "not a zip"),
        ("a.txt", "x"),
    ],
)
def test_bad_files_give_one_line(tmp_path, name, content):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(PersistenceError) as err:
        Trajectory.load(path)
    assert len(err.value.problems) == 1
    assert err.value.problems[0].field == str(path)


def test_concatenate_continues_time_and_merges_modes():
    a = _line()
    both = Trajectory.concatenate([a, a])
    assert len(both) == 10
    assert both.t[5] == a.t[-1]
    assert np.all(np.diff(both.t) >= 0)
    assert both.modes == ("idle", "busy")
    assert [e.index for e in both.events] == [2, 7]


def test_sample_interpolates_linearly():
    a = _line()
    assert np.allclose(a.sample([0.5, 10.0]), [[0.5, 1.0], [4.0, 8.0]])


def test_plot_draws_a_figure(tmp_path):
    path = _line().plot(tmp_path / "traj.png")
    assert path.stat().st_size > 1000


@given(trajectories())
def test_repr_is_one_short_line_without_arrays(traj):
    text = repr(traj)
    assert text.startswith(f"Trajectory({len(traj)} samples x {traj.dim} columns [")
    assert f"{len(traj.events)} events" in text and f"t in {traj.time_unit}" in text
    assert "\n" not in text and "array" not in text and len(text) < 200


def test_repr_png_is_the_plot():
    assert _line()._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"


# --- version 2: seconds, names, typed events, periodic columns ---------------------------------


def test_seconds_follow_the_timing_law():
    a = _line()
    # per stage x moves 1, y 2: the slower axis (y at 10 units/s) takes 0.2 s
    assert np.allclose(a.seconds, 0.2 * np.arange(5))
    b = Trajectory(a.t, a.q, a.mode, a.modes, a.columns, a.units, stage_duration=0.5)
    assert np.allclose(b.seconds, 0.5 * a.t)
    c = Trajectory(a.t, a.q, a.mode, a.modes, a.columns, a.units, velocity_limits=(1.0, 4.0))
    assert np.allclose(c.seconds, np.arange(5.0))  # x: 1 unit at 1 unit/s


def test_event_fields_are_typed_and_written_in_every_format(tmp_path):
    a = _line()
    (pick,) = a.events
    assert (pick.kind, pick.part, pick.region) == ("pick", "P1", "S1")
    assert a.event_time(pick) == (2.0, a.seconds[2])
    data = json.loads(a.save(tmp_path / "a.json").read_text())
    assert data["events"] == [
        {**pick.fields(), "index": 2, "t": 2.0, "seconds": float(a.seconds[2])}
    ]
    for suffix in (".csv", ".npz"):
        assert Trajectory.load(a.save(tmp_path / f"a{suffix}")).events == (pick,)


@pytest.mark.parametrize(
    ("kind", "detail", "fields"),
    [
        ("request", "P1 from S1 to D2", ("P1", "S1", "D2")),
        ("place", "P2 at D1", ("P2", "D1", "")),
        ("fmp_failed", "P2 at S1, then NR", ("P2", "S1", "")),
        ("source_change", "S1 to S2", ("", "S1", "S2")),
        ("grasp", "disc 3", ("disc 3", "", "")),
        ("switch", "disc 1 -> disc 2", ("disc 2", "", "")),
        ("arrive", "g1", ("", "g1", "")),
        ("escape", "k=4", ("", "", "")),
    ],
)
def test_event_text_of_the_planners_is_read_into_fields(kind, detail, fields):
    e = Event.from_text(3, kind, detail)
    assert (e.part, e.region, e.target) == fields
    assert e.detail == detail


def _v1_files(tmp_path):
    """The same trajectory as a version-1 CSV, JSON and NPZ file (as cellplan 0.1 wrote)."""
    header = {
        "format": "cellplan-trajectory",
        "version": 1,
        "time_unit": "stage",
        "columns": ["x", "theta"],
        "units": ["workcell", "rad"],
        "modes": ["NR"],
        "meta": {"seed": 1},
    }
    csv_text = (
        f"# cellplan-trajectory 1 {json.dumps(header)}\n"
        "t,mode,x,theta,events\n"
        "0.0,NR,1.0,0.0,request:P1 from S1 to D1\n"
        "1.0,NR,2.0,0.5,pick:P1 at S1|escape\n"
    )
    events = [
        {"index": 0, "kind": "request", "detail": "P1 from S1 to D1"},
        {"index": 1, "kind": "pick", "detail": "P1 at S1"},
        {"index": 1, "kind": "escape", "detail": ""},
    ]
    body = {"t": [0.0, 1.0], "q": [[1.0, 0.0], [2.0, 0.5]], "mode": [0, 0]}
    (tmp_path / "v1.csv").write_text(csv_text)
    (tmp_path / "v1.json").write_text(json.dumps({**header, **body, "events": events}))
    np.savez(
        tmp_path / "v1.npz",
        header=np.array(json.dumps(header)),
        t=np.array(body["t"]),
        q=np.array(body["q"]),
        mode=np.array(body["mode"]),
        event_index=np.array([e["index"] for e in events]),
        event_kind=np.array([e["kind"] for e in events]),
        event_detail=np.array([e["detail"] for e in events]),
    )
    return [tmp_path / f"v1.{s}" for s in ("csv", "json", "npz")]


def test_version_1_files_still_load(tmp_path):
    loaded = [Trajectory.load(p) for p in _v1_files(tmp_path)]
    assert loaded[0] == loaded[1] == loaded[2]
    traj = loaded[0]
    assert traj.events[0] == Event(0, "request", "P1 from S1 to D1", "P1", "S1", "D1")
    assert traj.events[1].part == "P1" and traj.events[2].kind == "escape"
    # seconds at the default speeds: x 1 unit at 10/s, theta 0.5 rad at pi/2 rad/s
    assert traj.seconds[1] == pytest.approx(max(0.1, 0.5 / (np.pi / 2)))
    # and saved again, it is a version-2 file that round-trips
    assert Trajectory.load(traj.save(tmp_path / "v2.csv")) == traj


def test_a_newer_version_is_refused_in_one_line(tmp_path):
    path = tmp_path / "a.json"
    data = _line().to_dict()
    data["version"] = 3
    path.write_text(json.dumps(data))
    with pytest.raises(PersistenceError) as err:
        Trajectory.load(path)
    assert len(err.value.problems) == 1
    assert "version 3; this cellplan reads versions 1 and 2" in str(err.value)


def _circle_walk(steps):
    """A walk on the circle: unwrapped positions and the same wrapped to (-pi, pi]."""
    q = np.concatenate([[0.0], np.cumsum(steps)])
    wrapped = np.angle(np.exp(1j * q))  # (-pi, pi]
    return q, wrapped


@given(st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=60))
def test_periodic_columns_are_unwrapped_to_the_motion_made(steps):
    q, wrapped = _circle_walk(np.asarray(steps))
    n = len(q)
    traj = Trajectory(
        np.arange(n, dtype=float),
        np.stack([wrapped, np.linspace(0, 1, n)], axis=1),
        np.zeros(n, dtype=np.int64),
        ("m",),
        ("q1", "q2"),
        ("rad", "rad"),
        periodic=(True, False),
    )
    # consecutive samples differ by the step actually made (each under half a turn)
    assert np.allclose(np.diff(traj.q[:, 0]), steps, atol=1e-9)
    assert np.allclose(np.angle(np.exp(1j * traj.q[:, 0])), wrapped, atol=1e-9)
    assert np.array_equal(traj.q[:, 1], np.linspace(0, 1, n))  # not periodic: untouched


def test_sample_follows_the_motion_across_the_half_turn():
    # the case: q1 goes 3.1416 -> -2.967 (a 10 degree step across +-pi)
    wrapped = np.array([np.pi - 0.3, np.pi, -np.pi + 0.1745, -np.pi + 0.35])
    traj = Trajectory(
        np.arange(4.0), wrapped[:, None], np.zeros(4, np.int64), ("m",), ("q1",), ("rad",),
        periodic=(True,),
    )  # fmt: skip
    assert np.max(np.abs(np.diff(traj.q[:, 0]))) < 0.31  # no 6.11 rad jump
    mid = traj.sample([1.5])[0, 0]
    assert mid == pytest.approx(np.pi + 0.1745 / 2)  # about 3.23, not about 0.09


# --- planner outputs: continuous joints, seconds, names, typed events --------------------------

#: The issue's case: a 3-link arm whose first joint turns without limit (periodic); the
#: source and destination lie either side of the -x axis, so the arm turns through +-180.
ARM_UNLIMITED = """\
cellplan: 1
name: arm-unlimited
description: A 3-link arm whose first joint is unlimited; it serves the regions round the back.
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 100, ymax: 100}
  obstacles: {}
robot:
  type: arm
  base: [50, 50]
  links:
    - {length: 20, width: 3}
    - {length: 15, width: 2}
    - {length: 8, width: 2}
  joint_limits: [[-180, 180], [-30, 30], [-30, 30]]
  start: [90, 0, 0]
parts:
  P1: {shape: {type: disc, center: [2, 0], radius: 1.5}}
sources:
  S1: {components: [{type: box, min: [8, 60], max: [24, 78]}]}
destinations:
  D1: {components: [{type: box, min: [8, 22], max: [24, 40]}]}
strategy:
  speed: 8.0
  arrival: {probability: 0.2}
  fine_motion: {time: 1.0}
  cells: [36, 12, 12]
"""

ROTATING_TINY = """\
cellplan: 1
name: rotating-tiny
description: strategies_tiny with a robot that turns.
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 30, ymax: 30}
  obstacles:
    middle: {type: box, min: [12, 12], max: [18, 16]}
robot:
  type: rotating
  shape: {type: box, min: [-1, -1], max: [1, 1]}
  start: [15, 8, 90]
  speed: [5, 5, 180]
parts:
  P1: {shape: {type: box, min: [-2, -0.5], max: [2, 0.5]}}
sources:
  S1: {components: [{type: box, min: [2, 2], max: [6, 5]}]}
  S2: {components: [{type: box, min: [24, 2], max: [28, 5]}]}
destinations:
  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}
strategy:
  speed: 2.5
  turn_speed: 45
  arrival: {probability: 0.1}
  fine_motion: {time: 1.5}
  cells: [12, 12, 8]
"""


def _strategy_run(tmp_path_factory, text, stages=150):
    """``(strategy, simulated run)`` of a scenario text (or a bundled name)."""
    import cellplan
    from cellplan.strategies.sim.simulate import simulate_result

    if "\n" in text:
        path = tmp_path_factory.mktemp("sc") / "scenario.yaml"
        path.write_text(text)
        text = str(path)
    setup = cellplan.load(text)
    strategy = cellplan.plan(setup, "strategies", sample_stages=20).solution
    res = simulate_result(strategy, stages, 0, cell=setup.workcell, robot_spec=setup.scenario.robot)
    assert res.trajectory is not None
    return strategy, res


def _step_bound(mdp):
    """The strategy's own largest step per axis: its actions' displacements (a step along
    a robot-frame heading may move either workcell axis by its whole length)."""
    step = np.abs(np.asarray(mdp.disp, float)).reshape(-1, len(mdp.shape))
    if mdp.heading_axis >= 0:
        planar = np.linalg.norm(step[:, :2], axis=1)
        step[:, 0] = step[:, 1] = planar
    return step.max(axis=0)


@pytest.fixture(scope="module")
def arm_run(tmp_path_factory):
    return _strategy_run(tmp_path_factory, ARM_UNLIMITED)


def _check_strategy_trajectory(res):
    traj = res.trajectory
    sim = res.solution
    periodic = np.asarray(traj.periodic)
    # the motion made: unwrapped samples equal the simulation's up to whole turns
    turns = (traj.q - sim.q)[:, periodic] / (2 * np.pi)
    assert np.allclose(turns, np.round(turns), atol=1e-9)
    assert np.array_equal(traj.q[:, ~periodic], sim.q[:, ~periodic])
    return traj


def test_the_arm_with_an_unlimited_joint_has_no_jump(arm_run):
    strategy, res = arm_run
    traj = res.trajectory
    assert traj.columns == ("q1", "q2", "q3") and traj.periodic == (True, False, False)
    assert traj.units == ("rad", "rad", "rad")
    wrapped = np.asarray(res.solution.q)[:, 0]
    jumps = np.flatnonzero(np.abs(np.diff(wrapped)) > np.pi)
    assert len(jumps) > 0  # the run does cross +-180 degrees
    _check_strategy_trajectory(res)
    bound = _step_bound(strategy.mdp)
    assert np.all(np.abs(np.diff(traj.q, axis=0)) <= bound + 1e-9)
    # sample across the crossing: on the motion (near +-pi), never the long way round
    k = int(jumps[0])
    mid = traj.sample([traj.t[k] + 0.5])[0, 0]
    assert mid == pytest.approx((traj.q[k, 0] + traj.q[k + 1, 0]) / 2)
    assert abs(abs(np.angle(np.exp(1j * mid))) - np.pi) < bound[0]


def test_every_robot_kind_steps_within_the_planners_bound(tmp_path_factory, arm_run):
    import cellplan

    # translating and rotating robots, and the planar arm: strategies' sample runs
    runs = [
        _strategy_run(tmp_path_factory, "strategies_tiny", 100),
        _strategy_run(tmp_path_factory, ROTATING_TINY, 100),
        arm_run,
    ]
    for strategy, res in runs:
        traj = _check_strategy_trajectory(res)
        bound = _step_bound(strategy.mdp)
        assert np.all(np.abs(np.diff(traj.q, axis=0)) <= bound + 1e-9)
    rot = runs[1][1].trajectory
    assert rot.periodic == (False, False, True)
    # the rotating scenario states its speeds (degrees/s in the file, rad/s in code)
    assert rot.velocity_limits == pytest.approx((5.0, 5.0, np.pi))
    # a point robot and a URDF arm: the adaptive planner's paths; every step is the
    # robot's own difference between the samples (the short way round on periodic axes)
    for name in ("adaptive_fig3", "adaptive_ur5"):
        setup = cellplan.load(name)
        traj = cellplan.plan(setup, "adaptive", tasks=2).trajectory
        robot = setup.workcell.robot
        assert traj.columns == tuple(robot.axis_names)
        assert traj.periodic == tuple(robot.periodic)
        steps = np.diff(traj.q, axis=0)
        assert np.allclose(steps, robot.difference(traj.q[:-1], traj.q[1:]), atol=1e-12)


def test_planner_outputs_carry_seconds_names_and_typed_events(arm_run):
    import cellplan

    strategy, res = arm_run
    traj = res.trajectory
    # strategies: seconds = stage x stage duration, the longest step at the robot's speed
    bound = _step_bound(strategy.mdp)
    assert traj.stage_duration == pytest.approx(np.max(bound / traj.velocity_limits))
    assert np.allclose(traj.seconds, traj.t * traj.stage_duration)
    (request, *_) = traj.events_of("request")
    assert (request.part, request.region, request.target) == ("P1", "S1", "D1")
    # assembly: path-length time plus seconds; grasp events name their disc
    seq = cellplan.plan(cellplan.load("discs_swap"), "assembly.sequential").trajectory
    assert seq.time_unit == "path" and seq.seconds[-1] > 0
    assert np.all(np.diff(seq.seconds) >= 0)
    assert all(e.part.startswith("disc ") for e in seq.events_of("grasp"))
    # a URDF arm: its joint names and its URDF's velocity limits
    ur5 = cellplan.plan(cellplan.load("adaptive_ur5"), "adaptive", tasks=1).trajectory
    assert ur5.columns[0] == "shoulder_pan_joint"
    assert ur5.velocity_limits[0] == pytest.approx(3.15)
    assert [e.region for e in ur5.events_of("task")] == [e.detail for e in ur5.events_of("task")]


@settings(max_examples=50)
@given(
    st.lists(st.floats(-50, 50), min_size=1, max_size=20),
    st.sampled_from([".csv", ".json", ".npz"]),
)
def test_periodic_trajectories_round_trip_exactly(tmp_path_factory, values, suffix):
    n = len(values)
    q = np.stack([np.asarray(values), np.linspace(0.0, 1.0, n)], axis=1)
    traj = Trajectory(
        np.arange(n, dtype=float), q, np.zeros(n, np.int64), ("m",), ("theta", "x"),
        ("rad", "workcell"), periodic=(True, False),
    )  # fmt: skip
    path = traj.save(tmp_path_factory.mktemp("p") / f"traj{suffix}")
    assert Trajectory.load(path) == traj


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("  speed: [5, 5]", "robot: speed needs one value per axis (3), got 2"),
        ("  speed: [5, 5, 180]\n  acceleration: [1, -1, 1]", "robot.acceleration[1]"),
        ("  speed: [5, .nan, 180]", "robot.speed[1]"),
    ],
)
def test_bad_robot_speeds_are_refused_in_one_line(line, message):
    from cellplan.errors import ScenarioError
    from cellplan.scenario import loads_scenario

    with pytest.raises(ScenarioError) as err:
        loads_scenario(ROTATING_TINY.replace("  speed: [5, 5, 180]", line))
    assert len(err.value.problems) == 1
    assert message in str(err.value)


def test_mode_names_is_an_attribute_that_slices():
    traj = Trajectory(
        t=np.array([0.0, 1.0, 2.0]),
        q=np.zeros((3, 1)),
        mode=np.array([0, 1, 1]),
        modes=("NR", "W"),
        columns=("x",),
        units=("workcell",),
    )
    assert traj.mode_names[:2] == ["NR", "W"]
    assert traj.mode_names == ["NR", "W", "W"]

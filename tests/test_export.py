"""ROS 2 export: JointTrajectory YAML and a rosbag2 (MCAP) read back equal with rosbags."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from cellplan import export
from cellplan.trajectory import Event, Trajectory


def _arm(retimed: bool = True) -> Trajectory:
    """A 3-joint motion with a stop (pick) in the middle, retimed or on the stage clock."""
    q = np.array([[0.0, 0.0, 0.0], [0.5, 0.2, 0.0], [0.5, 0.2, 0.0], [1.0, -0.3, 0.4]])
    traj = Trajectory(
        np.arange(4.0),
        q,
        np.zeros(4, dtype=np.int64),
        ("m",),
        ("shoulder", "elbow", "wrist"),
        ("rad",) * 3,
        events=(Event.from_text(2, "pick", "P1 at S1"),),
        stage_duration=0.5,
        velocity_limits=(1.0, 1.0, 2.0),
        acceleration_limits=(2.0, 2.0, 4.0),
    )
    return traj.retime() if retimed else traj


def _seconds(d) -> float:
    return d["sec"] + d["nanosec"] * 1e-9


@pytest.mark.parametrize("retimed", [True, False])
def test_yaml_reads_back_equal(tmp_path, retimed):
    traj = _arm(retimed)
    path = traj.to_ros2(tmp_path / "traj.yaml")
    data = yaml.safe_load(path.read_text())
    assert data == traj.to_ros2()
    assert data["joint_names"] == ["shoulder", "elbow", "wrist"]
    points = data["points"]
    qd, qdd = traj.velocities()
    assert len(points) == len(traj)  # seconds increase at every sample here
    for i, p in enumerate(points):
        assert p["positions"] == traj.q[i].tolist()
        assert p["velocities"] == qd[i].tolist()
        assert p["accelerations"] == qdd[i].tolist()
        assert abs(_seconds(p["time_from_start"]) - traj.seconds[i]) <= 1e-9
        assert 0 <= p["time_from_start"]["nanosec"] < 1_000_000_000


def test_bag_reads_back_equal_with_rosbags(tmp_path):
    traj = _arm()
    path = traj.to_ros2(tmp_path / "bag", "ros2-bag", frame_id="base_link")
    store = get_typestore(Stores.ROS2_HUMBLE)
    messages: dict[str, list] = {}
    with Reader(path) as reader:
        assert reader.connections[0].msgtype == "trajectory_msgs/msg/JointTrajectory"
        for conn, stamp, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            messages.setdefault(conn.topic, []).append((stamp, msg))
    (_, jt), *rest = messages[export.TRAJECTORY_TOPIC]
    assert not rest
    assert list(jt.joint_names) == list(traj.columns)
    assert jt.header.frame_id == "base_link"
    assert len(jt.points) == len(traj)
    for i, p in enumerate(jt.points):
        assert np.array_equal(p.positions, traj.q[i])
        assert np.array_equal(p.velocities, traj.qd[i])
        assert np.array_equal(p.accelerations, traj.qdd[i])
        assert (
            abs(p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 - traj.seconds[i]) < 1e-9
        )
    states = messages[export.STATES_TOPIC]
    assert len(states) == len(traj)
    for (stamp, js), sec, q in zip(states, traj.seconds, traj.q, strict=True):
        assert abs(stamp * 1e-9 - sec) < 1e-9
        assert js.header.stamp.sec * 10**9 + js.header.stamp.nanosec == stamp
        assert list(js.name) == list(traj.columns)
        assert np.array_equal(js.position, q)
    # and the module's own reader agrees
    jt2, states2 = export.read_ros2_bag(path)
    assert len(jt2.points) == len(jt.points) and len(states2) == len(states)


def test_an_existing_bag_is_never_replaced(tmp_path):
    (tmp_path / "bag").mkdir()
    with pytest.raises(export.ArgumentError, match="never replaced"):
        _arm().to_ros2(tmp_path / "bag", "ros2-bag")
    assert list((tmp_path / "bag").iterdir()) == []
    assert [p.name for p in tmp_path.iterdir()] == ["bag"]  # no staging folder left


def test_samples_at_the_same_time_are_left_out():
    # a path-length trajectory standing still: two samples at one time
    q = np.array([[0.0], [0.0], [1.0]])
    traj = Trajectory(np.zeros(3), q, np.zeros(3, np.int64), ("m",), ("j",), ("rad",), "path")
    points = traj.to_ros2()["points"]
    times = [_seconds(p["time_from_start"]) for p in points]
    assert len(points) == 2 and times[0] < times[1]


def test_cli_exports_every_format(cellplan, tmp_path):
    src = _arm(retimed=False).save(tmp_path / "traj.csv")
    r = cellplan("export", str(src), "-o", str(tmp_path / "a.yaml"), "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["format"] == "ros2-yaml" and info["retimed"] is False
    assert len(yaml.safe_load((tmp_path / "a.yaml").read_text())["points"]) == 4
    r = cellplan("export", str(src), "-f", "ros2-bag", "-o", str(tmp_path / "b"), "--retime")
    assert r.returncode == 0, r.stderr
    jt, _ = export.read_ros2_bag(tmp_path / "b")
    assert np.all(np.abs(np.asarray([p.velocities for p in jt.points])) <= [1.0, 1.0, 2.0])
    r = cellplan("export", str(src), "-f", "csv", "-o", str(tmp_path / "c.csv"))
    assert r.returncode == 0, r.stderr
    assert Trajectory.load(tmp_path / "c.csv") == Trajectory.load(src)


def test_cli_limits_are_in_degrees_for_angles(cellplan, tmp_path):
    src = _arm(retimed=False).save(tmp_path / "traj.json")
    r = cellplan(
        "export", str(src), "-o", str(tmp_path / "a.yaml"), "--velocity-limits", "45",
        "--acceleration-limits", "90,90,90",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    points = yaml.safe_load((tmp_path / "a.yaml").read_text())["points"]
    speeds = np.abs([p["velocities"] for p in points])
    assert speeds.max() <= np.radians(45) * (1 + 1e-6)
    assert speeds.max() >= np.radians(45) * 0.9  # it does reach the top speed


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["-f", "ros2-yml"], "--format: unknown format 'ros2-yml' (did you mean 'ros2-yaml'?)"),
        (["--velocity-limits", "0,1,1"], "--velocity-limits: every limit must be a positive"),
        (["--velocity-limits", "1,nan,1"], "--velocity-limits: every limit must be a positive"),
        (["--acceleration-limits", "1,2"], "--acceleration-limits: expected 3 values"),
        (["--velocity-limits", "fast"], "--velocity-limits: expected comma-separated numbers"),
    ],
)
def test_cli_bad_input_is_one_line(cellplan, tmp_path, args, message):
    src = _arm(retimed=False).save(tmp_path / "traj.csv")
    r = cellplan("export", str(src), "-o", str(tmp_path / "out.yaml"), *args)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0
    assert message in r.stderr
    assert not (tmp_path / "out.yaml").exists()


def test_cli_never_overwrites_its_input(cellplan, tmp_path):
    src = _arm(retimed=False).save(tmp_path / "traj.csv")
    before = src.read_bytes()
    r = cellplan("export", str(src), "-f", "csv", "-o", str(src))
    assert r.returncode == 2 and "TRAJ" in r.stderr
    assert src.read_bytes() == before


def test_version_ends_with_a_newline(cellplan):
    r = cellplan("--version")
    assert r.returncode == 0
    assert r.stdout.startswith("cellplan ") and r.stdout.endswith("\n")

"""A trajectory for ROS 2 controllers and tools, without a ROS installation.

* :func:`joint_trajectory` -- a ``trajectory_msgs/msg/JointTrajectory`` as a plain dict in
  the layout ``ros2 topic pub`` reads (joint names; points with positions, velocities,
  accelerations and ``time_from_start`` as ``sec`` and ``nanosec``);
  :func:`write_ros2_yaml` writes it as YAML.
* :func:`write_ros2_bag` -- a rosbag2 folder (MCAP storage) written with ``rosbags``
  (pure Python): topic ``/joint_trajectory`` holds the JointTrajectory once, at the
  start, and ``/joint_states`` one ``sensor_msgs/msg/JointState`` per sample, stamped
  at the sample's time (``start_ns`` + its seconds).
* :func:`read_ros2_yaml`, :func:`read_ros2_bag` read them back (tests, users).

Positions are in code units (radians for revolute joints, the workcell's unit for the
others, metres for URDF arms), as ROS expects. Velocities and accelerations are the
trajectory's (``qd``, ``qdd``, set by retiming), else finite differences over its seconds.
Samples at the same time as the one before (a path that stands still) are left out:
``time_from_start`` must increase.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from cellplan.errors import ArgumentError, Problem
from cellplan.fileio import write_text

if TYPE_CHECKING:
    from cellplan.trajectory import Trajectory

#: The formats of :func:`export`.
FORMATS = ("ros2-yaml", "ros2-bag", "csv")
#: Topics of the bag.
TRAJECTORY_TOPIC = "/joint_trajectory"
STATES_TOPIC = "/joint_states"
#: ROS 2 distribution whose message definitions the bag uses.
ROS_DISTRO = "humble"
NS = 1_000_000_000
JOINT_STATE = "sensor_msgs/msg/JointState"


def duration(seconds: float) -> dict[str, int]:
    """``builtin_interfaces/msg/Duration`` of ``seconds`` (rounded to the nanosecond)."""
    total = int(round(float(seconds) * NS))
    return {"sec": total // NS, "nanosec": total % NS}


def _points(traj: Trajectory) -> tuple[Any, Any, Any, Any]:
    """``(seconds, q, qd, qdd)`` of the samples a ROS message carries."""
    sec = np.asarray(traj.seconds, dtype=float)
    qd, qdd = traj.velocities()
    keep = np.concatenate([[True], np.diff(sec) > 0]) if len(sec) else np.zeros(0, bool)
    return sec[keep] - (sec[0] if len(sec) else 0.0), traj.q[keep], qd[keep], qdd[keep]


def joint_trajectory(traj: Trajectory, frame_id: str = "") -> dict[str, Any]:
    """The trajectory as a ``trajectory_msgs/msg/JointTrajectory`` dict (module docstring)."""
    sec, q, qd, qdd = _points(traj)
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": frame_id},
        "joint_names": list(traj.columns),
        "points": [
            {
                "positions": [float(v) for v in q[i]],
                "velocities": [float(v) for v in qd[i]],
                "accelerations": [float(v) for v in qdd[i]],
                "effort": [],
                "time_from_start": duration(sec[i]),
            }
            for i in range(len(sec))
        ],
    }


def write_ros2_yaml(traj: Trajectory, path: str | Path, frame_id: str = "") -> Path:
    """Write :func:`joint_trajectory` as YAML (atomically); returns the path.

    ``ros2 topic pub /joint_trajectory_controller/joint_trajectory
    trajectory_msgs/msg/JointTrajectory "$(cat FILE)"`` sends it.
    """
    text = yaml.safe_dump(joint_trajectory(traj, frame_id), sort_keys=False)
    return write_text(Path(path), text)


def read_ros2_yaml(path: str | Path) -> dict[str, Any]:
    """Read a file written by :func:`write_ros2_yaml` as a dict."""
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    if not isinstance(data, Mapping) or "points" not in data:
        raise ValueError(f"{path}: not a JointTrajectory")
    return dict(data)


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _messages(traj: Trajectory, frame_id: str, start_ns: int, store: Any) -> tuple[Any, list[Any]]:
    """The JointTrajectory message and the JointState messages (with their stamps)."""
    types = store.types
    Time = types["builtin_interfaces/msg/Time"]
    Duration = types["builtin_interfaces/msg/Duration"]
    Header = types["std_msgs/msg/Header"]
    Point = types["trajectory_msgs/msg/JointTrajectoryPoint"]
    JT = types["trajectory_msgs/msg/JointTrajectory"]
    JS = types["sensor_msgs/msg/JointState"]
    data = joint_trajectory(traj, frame_id)
    stamp = Time(sec=start_ns // NS, nanosec=start_ns % NS)
    points = [
        Point(
            positions=np.asarray(p["positions"], dtype=np.float64),
            velocities=np.asarray(p["velocities"], dtype=np.float64),
            accelerations=np.asarray(p["accelerations"], dtype=np.float64),
            effort=np.zeros(0, dtype=np.float64),
            time_from_start=Duration(**p["time_from_start"]),
        )
        for p in data["points"]
    ]
    jt = JT(header=Header(stamp=stamp, frame_id=frame_id), joint_names=data["joint_names"],
            points=points)  # fmt: skip
    states = []
    for p in data["points"]:
        ns = start_ns + p["time_from_start"]["sec"] * NS + p["time_from_start"]["nanosec"]
        msg = JS(
            header=Header(stamp=Time(sec=ns // NS, nanosec=ns % NS), frame_id=frame_id),
            name=data["joint_names"],
            position=np.asarray(p["positions"], dtype=np.float64),
            velocity=np.asarray(p["velocities"], dtype=np.float64),
            effort=np.zeros(0, dtype=np.float64),
        )
        states.append((ns, msg))
    return jt, states


def write_ros2_bag(
    traj: Trajectory, path: str | Path, frame_id: str = "", start_ns: int = 0
) -> Path:
    """Write a rosbag2 folder (MCAP storage) at ``path``; see the module docstring.

    The bag is written beside ``path`` and renamed into place, so a failure leaves
    nothing behind. ``path`` must not exist (a bag is a folder: it is never replaced).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    target = Path(path)
    if target.exists() or target.is_symlink():
        raise ArgumentError([Problem(str(target), "exists; a bag folder is never replaced")])
    store = _typestore()
    jt, states = _messages(traj, frame_id, int(start_ns), store)
    parent = target.parent if str(target.parent) else Path(".")
    staging = Path(tempfile.mkdtemp(prefix=".cellplan-bag-", dir=parent))
    try:
        bag = staging / target.name
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            c_jt = writer.add_connection(TRAJECTORY_TOPIC, jt.__msgtype__, typestore=store)
            c_js = writer.add_connection(
                STATES_TOPIC, "sensor_msgs/msg/JointState", typestore=store
            )
            writer.write(c_jt, int(start_ns), store.serialize_cdr(jt, jt.__msgtype__))
            for ns, msg in states:
                writer.write(c_js, ns, store.serialize_cdr(msg, msg.__msgtype__))
        os.rename(bag, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def read_ros2_bag(path: str | Path) -> tuple[Any, list[tuple[int, Any]]]:
    """Read a bag written by :func:`write_ros2_bag`: the JointTrajectory message and the
    ``(timestamp_ns, JointState)`` messages, decoded with ``rosbags``."""
    from rosbags.rosbag2 import Reader

    store = _typestore()
    jt = None
    states: list[tuple[int, Any]] = []
    with Reader(Path(path)) as reader:
        for conn, stamp, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == TRAJECTORY_TOPIC:
                jt = msg
            elif conn.topic == STATES_TOPIC:
                states.append((int(stamp), msg))
    if jt is None:
        raise ValueError(f"{path}: no {TRAJECTORY_TOPIC} message")
    return jt, states


def suggest(name: str, choices: Sequence[str]) -> str:
    """`` (did you mean X?)`` for the closest of ``choices``, or ``""``."""
    import difflib

    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""


def check_format(fmt: str) -> str:
    """``fmt`` when it is one of :data:`FORMATS`, else an :class:`ArgumentError`."""
    if fmt not in FORMATS:
        raise ArgumentError(
            [Problem("--format", f"unknown format {fmt!r}{suggest(fmt, FORMATS)}; "
                     f"choose one of {', '.join(FORMATS)}")]
        )  # fmt: skip
    return fmt


def export(traj: Trajectory, fmt: str, path: str | Path, frame_id: str = "") -> Path:
    """Write ``traj`` in ``fmt`` (:data:`FORMATS`) at ``path``; returns the path."""
    check_format(fmt)
    if fmt == "ros2-yaml":
        return write_ros2_yaml(traj, path, frame_id)
    if fmt == "ros2-bag":
        return write_ros2_bag(traj, path, frame_id)
    return write_text(Path(path), traj.to_csv_text())

"""A 3-D workcell and a motion of its arm as a :class:`~cellplan.view3d.Scene3D`.

:func:`cell_scene` gathers what :mod:`cellplan.view3d` draws: the obstacles, the
sources and destinations (translucent), the arm's collision meshes posed along the
configurations, and the carried part on the tool. ``cellplan show`` draws its first
frame as a PNG; ``cellplan view`` writes the interactive page.

:func:`held_from_events` reads the part held at each sample from a trajectory's typed
events (``pick`` ... ``place``/``reject``); ``cellplan view TRAJ`` and the viewer of
``cellplan assemble --algorithm robot`` both draw the held part from it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from cellplan import arm as arms
from cellplan.plots import COLORS
from cellplan.trajectory import Event
from cellplan.validity import FloatArray
from cellplan.view3d import MeshItem, Scene3D
from cellplan.workcell3d import Workcell3D

__all__ = ["HOLD_ENDS", "HOLD_STARTS", "cell_scene", "held_from_events"]

_RESOLUTION = 32
"""Sides of a drawn cylinder, capsule or sphere."""


HOLD_STARTS = ("pick",)
"""Event kinds after which the tool holds the event's ``part``."""
HOLD_ENDS = ("place", "reject")
"""Event kinds after which the tool no longer holds the event's ``part`` (put down at a
destination, or at a reject region)."""


def held_from_events(events: Iterable[Event], samples: int) -> list[str | None]:
    """The part held at each of ``samples`` samples, from typed events.

    A ``pick`` of part ``P`` at sample ``i`` and the next ``place`` (or ``reject``) of
    ``P`` at sample ``j`` hold ``P`` on samples ``i`` to ``j``, both included: at the pick
    and at the place the tool is at the part. Events are taken in the trajectory's order,
    so where a place and the next pick share a sample, the picked part is held there. A
    pick never put down holds its part to the end; a place with no pick before it, when
    it is the trajectory's first hold event, holds its part from sample 0 (a trajectory
    cut while carrying). Any other event (``fmp_failed``, ``request``, ``task`` ...)
    changes nothing.

    Parameters
    ----------
    events
        The trajectory's events (:attr:`cellplan.trajectory.Trajectory.events`).
    samples
        The trajectory's sample count.

    Returns
    -------
    list of str or None
        One entry per sample: the held part's name, or ``None`` when the tool is empty.
    """
    held: list[str | None] = [None] * samples
    current: str | None = None
    since = 0
    first = True
    for event in sorted(events, key=lambda e: e.index):  # stable: same-sample order kept
        if event.kind in HOLD_STARTS and event.part:
            if current is not None:  # picked again without a place: the earlier hold ends
                held[since : event.index] = [current] * (event.index - since)
            current, since, first = event.part, event.index, False
        elif event.kind in HOLD_ENDS and event.part:
            if current == event.part:
                held[since : event.index + 1] = [current] * (event.index + 1 - since)
            elif current is None and first:
                held[: event.index + 1] = [event.part] * (event.index + 1)
            current, first = None, False
    if current is not None:
        held[since:] = [current] * (samples - since)
    return held


def _rgb(name: str) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb

    return tuple(float(c) for c in to_rgb(COLORS[name]))  # type: ignore[return-value]


def cell_scene(
    cell: Workcell3D,
    q: FloatArray | None = None,
    times: Sequence[float] | FloatArray | None = None,
    carrying: Sequence[str | None] | str | None = None,
    title: str = "",
    time_label: str = "t (s)",
) -> Scene3D:
    """The cell with its arm at ``q`` (``(T, dim)``; default: the start configuration).

    Parameters
    ----------
    cell
        The 3-D workcell.
    q
        Configurations, one per frame (radians).
    times
        One per frame, increasing (default: 0, 1, 2 ...).
    carrying
        The part held at each frame (one name for all frames, or one per frame; ``None``
        holds nothing; :func:`held_from_events` reads it from a trajectory). A held part
        is drawn on the tool; before its first hold it stands where that hold begins,
        and after a hold it stays where the hold ended (where it was put down).
    title, time_label
        The picture's title and what ``times`` measure.
    """
    qs = cell.configurations(cell.robot.start if q is None else q)
    frames = len(qs)
    t = np.arange(frames, dtype=float) if times is None else np.asarray(times, dtype=float)
    held = [carrying] * frames if carrying is None or isinstance(carrying, str) else list(carrying)
    items: list[MeshItem] = []
    poses: list[FloatArray] = []  # (T, 4, 4) per item
    still = np.broadcast_to(np.eye(4), (frames, 4, 4))

    def add(item: MeshItem, pose: FloatArray) -> None:
        items.append(item)
        poses.append(np.broadcast_to(pose, (frames, 4, 4)))

    for name, solid in cell.obstacles.items():
        v, f = solid.triangles(_RESOLUTION)
        add(MeshItem(f"obstacle/{name}", v, f, _rgb("obstacle"), 1.0, "obstacle"), still)
    for role, regions in (("source", cell.sources), ("destination", cell.destinations)):
        for name, region in regions.items():
            for i, solid in enumerate(region.components):
                v, f = solid.triangles(_RESOLUTION)
                add(MeshItem(f"{role}/{name}.{i}", v, f, _rgb(role), 0.35, role), still)
    frame_poses = arms.forward(cell.robot.arm, qs)
    for k, mesh in enumerate(arms.link_meshes(cell.robot.arm)):
        if mesh.frame < 0:
            pose = cell.robot.arm.base @ mesh.placement
        else:
            pose = frame_poses[:, mesh.frame] @ mesh.placement
        label = f"robot/{mesh.link}.{k}"
        add(MeshItem(label, mesh.vertices, mesh.faces, _rgb("robot"), 1.0, "robot"), pose)
    tool = arms.tool_pose(cell.robot.arm, qs)
    for name, part in cell.parts.items():
        shown = np.array([h == name for h in held])
        if not shown.any():
            continue
        v, f = part.solid.triangles(_RESOLUTION)
        # A part not held at a frame stays on the tool pose of the last frame holding it
        # (where it was put down), and before its first hold on that hold's first frame
        # (where it is picked up): the viewer has no visibility per frame.
        frame = np.arange(frames)
        last = np.maximum.accumulate(np.where(shown, frame, -1))
        last[last < 0] = int(np.argmax(shown))
        pose = tool[last]
        add(MeshItem(f"part/{name}", v, f, _rgb("part"), 1.0, "part"), pose)
    return Scene3D(
        title=title or cell.name or "workcell",
        bounds=(cell.lo, cell.hi),
        items=tuple(items),
        poses=np.stack(poses, axis=1),
        times=t,
        time_label=time_label,
        path=tool[:, :3, 3] if frames > 1 else None,
    )

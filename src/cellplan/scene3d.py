"""A 3-D workcell and a motion of its arm as a :class:`~cellplan.view3d.Scene3D`.

:func:`cell_scene` gathers what :mod:`cellplan.view3d` draws: the obstacles, the
sources and destinations (translucent), the arm's collision meshes posed along the
configurations, and the carried part on the tool. ``cellplan show`` draws its first
frame as a PNG; ``cellplan view`` writes the interactive page.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellplan import arm as arms
from cellplan.plots import COLORS
from cellplan.validity import FloatArray
from cellplan.view3d import MeshItem, Scene3D
from cellplan.workcell3d import Workcell3D

__all__ = ["cell_scene"]

_RESOLUTION = 32
"""Sides of a drawn cylinder, capsule or sphere."""


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
        holds nothing).
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
        # A part not held at a frame is drawn on the tool of the first frame holding it:
        # the viewer has no visibility per frame, and this keeps it out of the way.
        first = int(np.argmax(shown))
        pose = np.where(shown[:, None, None], tool, tool[first])
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

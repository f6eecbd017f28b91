"""Object-attached subgoals (Chen, Section 2.3): a tool pose relative to an object."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tag:
    """An object-attached subgoal: tool pose in the frame of ``obj`` (``None``: the world).

    In a planar cell ``rel`` is ``(x, y, theta)`` and ``branch`` the elbow branch; in a
    3-D cell ``rel`` is the tool position ``(x, y, z)`` relative to the object's offset,
    ``branch`` is ``None``, and ``rot`` the tool's world orientation (a row-major 3x3
    rotation) for named goals, ``None`` for a vertex (its configuration keeps it).
    """

    obj: str | None
    rel: tuple[float, float, float]
    branch: int | None
    rot: tuple[float, ...] | None = None

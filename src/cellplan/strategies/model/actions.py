"""Action sets of the strategies paper: equation (5) and its variants of Section V.

Stay and FMP are part of every action set and are handled by the solver itself; this
module gives the motion actions as C-space displacements per stage:

* translating (or point) robot: K evenly spaced headings, a step of ``speed * dt``
  (equation (5), problems 1, 2 and 4);
* rotating robot: turn in place by ``+-turn_speed * dt`` or move along its axis, forward
  or backward, by ``speed * dt`` (problem 3); the translation is in the robot frame;
* planar arm: one joint by ``+-speed * dt`` degrees (problems 5 and 6), the joint limits
  being the grid bounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cellplan import units


@dataclass(frozen=True)
class ActionSet:
    """Motion actions of one speed class.

    Attributes
    ----------
    disp
        ``(A, dim)`` displacement per action (robot frame on the first two axes when
        ``heading_axis >= 0``).
    heading_axis
        Index of the orientation coordinate for robot-frame actions, or -1.
    labels
        A short name per action, for plots and logs.
    noise_prob
        ``(J,)`` probabilities of the noisy outcomes of every move (Section VI-4); one
        outcome (``[1.0]``) when motion is exact. With ``J > 1`` the rows of ``disp`` after
        the ``A`` commanded moves are the outcomes: row ``A + a J + j`` is where move ``a``
        lands in outcome ``j``.
    """

    disp: np.ndarray
    heading_axis: int
    labels: tuple[str, ...]
    noise_prob: np.ndarray = field(default_factory=lambda: np.ones(1))

    @property
    def commanded(self) -> int:
        """``A``, the number of commanded moves (one label each)."""
        return len(self.labels)


def with_noise(acts: ActionSet, offsets: np.ndarray, prob: np.ndarray, frame: str) -> ActionSet:
    """The action set with noisy outcomes appended (Section VI-4, rows ``A + a J + j``).

    ``offsets`` is ``(J, 2)`` ``[along, across]`` each move (``frame="motion"``, translating
    robots) or ``(J, dim)`` along the C-space axes in code units (``frame="world"``; for
    robot-frame moves, in the robot's frame like the moves themselves).
    """
    disp = acts.disp
    A, dim = disp.shape
    J = len(prob)
    out = np.empty((A, J, dim))
    for a in range(A):
        if frame == "motion":
            length = float(np.hypot(disp[a, 0], disp[a, 1]))
            u = disp[a, :2] / length
            n = np.array([-u[1], u[0]])
            out[a] = disp[a] + offsets[:, :1] * u + offsets[:, 1:2] * n
        else:
            out[a] = disp[a] + offsets
    rows = np.concatenate([disp, out.reshape(A * J, dim)])
    return ActionSet(np.ascontiguousarray(rows), acts.heading_axis, acts.labels, prob.copy())


def action_set(
    robot_type: str,
    dim: int,
    *,
    speed: float,
    stage_time: float,
    headings: int = 16,
    turn_speed_deg: float | None = None,
    factor: float = 1.0,
) -> ActionSet:
    """The motion actions for a robot kind, scaled by ``factor`` (speed while carrying).

    Parameters
    ----------
    robot_type
        ``point``, ``translating``, ``rotating`` or ``arm``.
    dim
        C-space dimension.
    speed
        Translation per unit time (workspace units), or degrees per unit time for arms.
    stage_time
        The stage length Delta t.
    headings
        K, for translating robots.
    turn_speed_deg
        Degrees per unit time, for the rotating robot.
    factor
        Speed multiplier (the part being carried).
    """
    step = speed * stage_time * factor
    if robot_type in ("point", "translating"):
        ang = 2.0 * math.pi * np.arange(headings) / headings
        disp = np.stack([step * np.cos(ang), step * np.sin(ang)], axis=1)
        labels = tuple(f"heading {units.degrees(float(a)):g}" for a in ang)
        return ActionSet(np.ascontiguousarray(disp), -1, labels)
    if robot_type == "rotating":
        if turn_speed_deg is None:
            raise ValueError("a rotating robot needs a turn speed")
        dth = units.radians(turn_speed_deg) * stage_time * factor
        disp = np.array(
            [[step, 0.0, 0.0], [-step, 0.0, 0.0], [0.0, 0.0, dth], [0.0, 0.0, -dth]], dtype=float
        )
        return ActionSet(disp, 2, ("forward", "backward", "turn left", "turn right"))
    if robot_type == "arm":
        dq = units.radians(step)  # arm speeds are degrees per unit time
        disp = np.zeros((2 * dim, dim))
        names: list[str] = []
        for j in range(dim):
            disp[2 * j, j] = dq
            disp[2 * j + 1, j] = -dq
            names += [f"joint {j + 1} +", f"joint {j + 1} -"]
        return ActionSet(disp, -1, tuple(names))
    raise ValueError(f"unknown robot type {robot_type!r}")

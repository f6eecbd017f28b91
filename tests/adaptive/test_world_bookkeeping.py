"""The bookkeeping the planar and 3-D worlds share (:class:`~.worldbase.ChangingWorld`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]

from cellplan.adaptive.section import MoveObject, RemoveObject, RotateObject
from cellplan.adaptive.world import World
from cellplan.adaptive.worldbase import ChangingWorld
from cellplan.errors import ArgumentError
from cellplan.scenario import loads_scenario


def _world() -> World:
    return World(loads_scenario(POINT_SCENARIO), resolution=0.1)


def test_every_change_starts_a_generation_and_names_what_moved() -> None:
    world = _world()
    assert isinstance(world, ChangingWorld)
    moved = world.apply(MoveObject(type="move_object", after_task=0, object="A", by=[1.0, 0.5]))
    assert moved == {"A"} and world.gen == 1
    assert world.objects["A"].pose == (1.0, 0.5, 0.0)
    turned = world.apply(
        RotateObject(type="rotate_object", after_task=0, object="A", degrees=90.0, about=[0, 0])
    )
    assert turned == {"A"} and world.gen == 2
    x, y, theta = world.objects["A"].pose  # (1, 0.5) turned a quarter about the origin
    assert np.allclose((x, y, theta), (-0.5, 1.0, math.pi / 2))
    assert world.apply(RemoveObject(type="remove_object", after_task=0, object="A")) == set()
    assert "A" not in world.objects and world.gen == 3


def test_hits_and_limits_come_from_the_shared_code() -> None:
    world = _world()
    assert world.hits(np.array([5.0, 3.0])) == ["A"]
    assert world.hits(np.array([3.95, 3.0])) == []
    assert world.hits(np.array([3.95, 3.0]), margin=0.1) == ["A"]
    assert not world.is_free_exact(np.array([[5.0, 3.0]]))[0]
    with pytest.raises(ArgumentError, match="outside the joint limits"):
        world.check_free(np.array([11.0, 3.0]), "q")
    with pytest.raises(ArgumentError, match="collides with obstacle 'A'"):
        world.check_free(np.array([5.0, 3.0]), "q")


def test_a_pose_or_shape_argument_is_checked_before_the_world_changes() -> None:
    world = _world()
    with pytest.raises(ArgumentError, match="three finite numbers"):
        world.set_pose("A", (1.0, math.nan, 0.0))
    with pytest.raises(ArgumentError) as err:
        world.shape({"type": "box", "min": [0.0, 0.0]})
    assert err.value.problems[0].field == "shape"
    assert world.gen == 0 and world.objects["A"].pose == (0.0, 0.0, 0.0)

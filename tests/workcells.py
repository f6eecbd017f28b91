"""Workcells shared by the foundation tests."""

from __future__ import annotations

from cellplan.workcell import Workcell, load_workcell


def rotating_cell() -> Workcell:
    return load_workcell("rotating_bar")[1]

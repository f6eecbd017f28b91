"""Cost accounting: every collision check, charged to the routine that made it.

The paper measures planning cost by the number of robot-to-obstacle distance
evaluations (Section 4). Here one collision check of one configuration is one
unit of cost, charged to the innermost active category: ``reach`` (the search
of planner R), ``trace`` (edge verification in T), ``solve`` (Solve, in S or in
T step 2), ``abstract`` (Abstract), ``cut`` (corner cutting, Section 2.6),
``repair`` (Repair of A1/A2 and object-attached updates) and ``baseline`` (the
Solve-only reference run).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field

STICKY = ("repair", "baseline")
CATEGORIES = ("reach", "trace", "solve", "abstract", "cut", "repair", "baseline")


@dataclass
class CheckCounter:
    """Counts of configuration checks per category, with a stack of active categories."""

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(CATEGORIES, 0))
    _stack: list[str] = field(default_factory=lambda: ["reach"])

    @contextlib.contextmanager
    def charge(self, category: str) -> Iterator[None]:
        """Charge the checks made inside the ``with`` block to ``category``."""
        if category not in self.counts:
            raise ValueError(f"unknown cost category {category!r}")
        self._stack.append(category)
        try:
            yield
        finally:
            self._stack.pop()

    def add(self, n: int) -> None:
        """Record ``n`` checks: to ``repair``/``baseline`` if active, else the innermost category.

        Repair (A1, A2) and the baseline run other routines (T, Solve) inside;
        their checks belong to the phase that made them necessary.
        """
        for sticky in STICKY:
            if sticky in self._stack:
                self.counts[sticky] += int(n)
                return
        self.counts[self._stack[-1]] += int(n)

    @property
    def total(self) -> int:
        """All checks except the baseline's."""
        return sum(v for k, v in self.counts.items() if k != "baseline")

    def snapshot(self) -> dict[str, int]:
        """A copy of the counts."""
        return dict(self.counts)

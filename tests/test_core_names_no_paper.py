"""The core names no paper package: packages register themselves (issue 11's rule).

Only the registration list (:data:`cellplan.registry.BUILTIN_PACKAGES`) may name them.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "cellplan"
CORE = [
    "__main__.py",
    "api.py",
    "cli.py",
    "cliutil.py",
    "core.py",
    "demo.py",
    "experiments.py",
    "registry.py",
    "report.py",
    "reproduce_cli.py",
    "scenario.py",
    "scheduler.py",
    "setup.py",
    "summary.py",
    "trajectory.py",
]
PACKAGE_REFERENCE = re.compile(
    r"cellplan\.(strategies|adaptive|assembly)\b|[\"'`](strategies|adaptive|assembly)[\"'`.]"
)


@pytest.mark.parametrize("name", [n for n in CORE if (SRC / n).is_file()])
def test_core_module_names_no_package(name):
    text = (SRC / name).read_text(encoding="utf-8")
    if name == "registry.py":
        start = text.index("BUILTIN_PACKAGES: tuple[str, ...] = (")
        text = text[:start] + text[text.index(")", start) :]
    hits = [m.group(0) for m in PACKAGE_REFERENCE.finditer(text)]
    assert hits == []

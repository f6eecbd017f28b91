"""Smoke test of ``benchmarks/bench_arms.py``: its quick run prints every figure and finds
no configuration or segment that the sphere checks call free and the meshes call colliding.
No wall time is asserted."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]

KEYS = (
    "load at start:",
    "sphere check (collides):",
    "sphere check, per config:",
    "mesh loop (exact_collides):",
    "ratio sphere / mesh:",
    "goal >= 100,000 /s per core:",
    "conservatism:",
    "unsafe (sphere-free, mesh-hit):",
    "largest clearance:",
    "segments |dq| = 0.1 rad:",
    "segments |dq| = 0.5 rad:",
    "certified, batched:",
    "certified, one call each:",
    "mesh, same samples:",
    "mesh, one call each:",
    "ratio certified / mesh:",
    "unsafe (cert-free, mesh-hit):",
    "bitmap (free_bitmap):",
    "bitmap memory:",
    "bitmap per cell:",
    "centres, no margin (clearance):",
    "what the box margin costs:",
    "load at end:",
)


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "bench_arms", ROOT / "benchmarks" / "bench_arms.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def test_quick_run_prints_every_figure(capsys: pytest.CaptureFixture[str]) -> None:
    results = _bench().main(["--quick"])
    out = capsys.readouterr().out
    missing = [k for k in KEYS if k not in out]
    assert not missing, f"missing from the printout: {missing}\n{out}"
    assert results["unsafe"] == 0
    assert results["unsafe_0.1"] == 0 and results["unsafe_0.5"] == 0
    assert results["rate"] > 0 and results["mesh_rate"] > 0
    assert 0.0 <= results["free"] <= 1.0
    assert results["peak_bytes"] > 0 and results["estimate_bytes"] > 0

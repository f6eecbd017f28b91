"""cellplan solve / simulate / plot end to end on a tiny scenario, and their errors."""

from __future__ import annotations

import json

import pytest
from strategies_helpers import TINY


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY.replace("CELLS", "16"))
    return path


def test_solve_simulate_plot(cellplan, scenario, tmp_path):
    npz = tmp_path / "s.npz"
    r = cellplan("solve", str(scenario), "-o", str(npz))
    assert r.returncode == 0, r.stderr
    assert "gain g =" in r.stdout and npz.exists()
    out = tmp_path / "sim"
    r = cellplan(
        "simulate",
        str(scenario),
        "--strategy",
        str(npz),
        "--stages",
        "120",
        "--seed",
        "3",
        "-o",
        str(out),
    )
    assert r.returncode == 0, r.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["metrics"]["stages"] == 120
    assert (out / "simulation.gif").stat().st_size > 0
    assert (out / "frames.png").exists() and (out / "frame_001.png").exists()
    fig = tmp_path / "w.png"
    r = cellplan("plot", str(scenario), "--strategy", str(npz), "--mode", "1,1,1,W", "-o", str(fig))
    assert r.returncode == 0, r.stderr
    assert fig.stat().st_size > 0


def test_unconverged_solve_saves_nothing(cellplan, scenario, tmp_path):
    text = scenario.read_text() + "  solver: {method: general, max_sweeps: 2}\n"
    scenario.write_text(text)
    npz = tmp_path / "s.npz"
    r = cellplan("solve", str(scenario), "-o", str(npz))
    assert r.returncode == 2
    assert "did not converge" in r.stderr and not npz.exists()


def test_bad_arguments_exit_2(cellplan, scenario, tmp_path):
    r = cellplan("solve", str(scenario), "-o", str(tmp_path / "s.txt"))
    assert r.returncode == 2 and "--output" in r.stderr
    npz = tmp_path / "s.npz"
    assert cellplan("solve", str(scenario), "-o", str(npz)).returncode == 0
    r = cellplan("simulate", str(scenario), "--strategy", str(npz), "--stages", "0")
    assert r.returncode == 2 and "--stages" in r.stderr
    r = cellplan(
        "plot",
        str(scenario),
        "--strategy",
        str(npz),
        "--mode",
        "7,7,7,W",
        "-o",
        str(tmp_path / "x.png"),
    )
    assert r.returncode == 2 and "--mode" in r.stderr
    r = cellplan("plot", "strategies_p1", "--strategy", str(npz), "-o", str(tmp_path / "x.png"))
    assert r.returncode == 2 and "different scenario" in r.stderr


def test_no_snap_solve_records_the_transition_law(cellplan, scenario, tmp_path):
    import numpy as np

    npz = tmp_path / "strict.npz"
    r = cellplan("solve", str(scenario), "--no-snap", "-o", str(npz))
    assert r.returncode == 0, r.stderr
    with np.load(npz) as data:
        meta = json.loads(str(data["meta"]))
    assert meta["transitions"] == "no-snap"

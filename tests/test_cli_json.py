"""``--json`` on every command: one JSON object on stdout whose numbers keep their types.

The test iterates over the commands the app registers, so a new command without
``--json`` fails here until it is given one (or listed in :data:`WITHOUT_JSON` with the
reason).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import typer

from cellplan.cli import app
from cellplan.core import Result, Status, check_stats

WITHOUT_JSON: dict[str, str] = {}


def commands() -> dict[str, object]:
    return dict(typer.main.get_command(app).commands)  # type: ignore[attr-defined]


def takes_json(command: object) -> bool:
    return any("--json" in p.opts for p in command.params)  # type: ignore[attr-defined]


def test_every_command_takes_json_but_the_listed_ones():
    lacking = {name for name, cmd in commands().items() if not takes_json(cmd)}
    assert lacking == set(WITHOUT_JSON)


@pytest.fixture
def trajectory_file(tmp_path) -> Path:
    from cellplan.trajectory import Trajectory

    traj = Trajectory(
        t=np.arange(3.0),
        q=np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]]),
        mode=np.zeros(3, dtype=np.int64),
        modes=("NR",),
        columns=("x", "y"),
        units=("m", "m"),
        time_unit="s",
    )
    path = tmp_path / "traj.csv"
    traj.save(path)
    return path


@pytest.fixture
def strategy_file(cellplan, tmp_path) -> Path:
    path = tmp_path / "s.npz"
    r = cellplan("solve", "strategies_tiny", "-o", str(path))
    assert r.returncode == 0, r.stderr
    return path


def arguments(name: str, tmp: Path, trajectory: Path, strategy: Path) -> list[str]:
    """Cheap arguments for each command (the demo and reproduce sweeps are stubbed)."""
    cheap = {
        "schema": [],
        "scenarios": [],
        "planners": [],
        "validate": ["discs_swap"],
        "show": ["discs_swap", "-o", str(tmp / "cell.png")],
        "view": ["panda_shelf", "-o", str(tmp / "cell.html")],
        "cspace": ["strategies_tiny", "--cells", "12,12", "-o", str(tmp / "c.png")],
        "export": [str(trajectory), "-o", str(tmp / "t.yaml")],
        "demo": ["-o", str(tmp / "demo")],
        "reproduce": ["assembly", "-o", str(tmp / "rep")],
        "solve": ["strategies_tiny", "-o", str(tmp / "again.npz")],
        "simulate": [
            "strategies_tiny",
            "--strategy",
            str(strategy),
            "--stages",
            "3",
            "--no-gif",
            "-o",
            str(tmp / "sim"),
        ],
        "adapt": ["adaptive_fig3", "--tasks", "1", "--no-baseline", "-o", str(tmp / "ad")],
        "assemble": ["discs_swap", "--frames", "2", "-o", str(tmp / "as")],
        "plot": ["strategies_tiny", "--strategy", str(strategy), "-o", str(tmp / "nr.png")],
    }
    return cheap[name]


@pytest.fixture
def stubbed_sweeps(monkeypatch, tmp_path):
    """``demo`` and ``reproduce`` without their minutes-long sweeps: the command's own
    code (arguments, output, JSON) runs, the sweep is a stand-in."""
    import cellplan.demo
    import cellplan.reproduce_cli

    def run_demo(output, console=None, serial=False, showcase=True):
        Path(output).mkdir(parents=True, exist_ok=True)
        return Path(output) / "index.html"

    def reproduce_sweep(papers, outdir, **given):
        sweep = SimpleNamespace(n_runs=4, n_failed=0, n_broken=0, lost="")
        return Path(outdir) / "index.html", sweep

    monkeypatch.setattr(cellplan.demo, "run_demo", run_demo)
    monkeypatch.setattr(cellplan.reproduce_cli, "reproduce_sweep", reproduce_sweep)


def test_every_command_prints_one_json_object(
    cellplan, tmp_path, trajectory_file, strategy_file, stubbed_sweeps
):
    seen = {}
    for name, cmd in sorted(commands().items()):
        if not takes_json(cmd):
            continue
        r = cellplan(name, *arguments(name, tmp_path, trajectory_file, strategy_file), "--json")
        assert r.returncode == 0, (name, r.stderr)
        lines = r.stdout.strip().splitlines()
        assert len(lines) == 1, (name, r.stdout[:300])
        payload = json.loads(lines[0])
        assert isinstance(payload, dict), name
        seen[name] = payload
    assert set(seen) == set(commands()) - set(WITHOUT_JSON)
    assert seen["reproduce"]["runs"] == 4 and seen["reproduce"]["status"] == "written"
    assert isinstance(seen["cspace"]["free_fraction"], float)
    assert seen["cspace"]["cells"] == [12, 12]
    assert seen["export"]["samples"] == 3 and seen["export"]["retimed"] is False
    assert {"name", "sections", "robot"} <= set(seen["scenarios"]["scenarios"][0])
    assert seen["schema"]["title"] == "Scenario"


def test_validate_json_has_machine_keys_and_typed_values(cellplan):
    r = cellplan("validate", "strategies_tiny", "--json")
    assert r.returncode == 0, r.stderr
    payload = json.loads(r.stdout)
    summary = payload["summary"]
    assert summary["dimension"] == 2 and isinstance(summary["dimension"], int)
    assert isinstance(summary["free_fraction"], float) and 0 < summary["free_fraction"] < 1
    assert isinstance(summary["parts"], list) and summary["parts"]
    assert all(isinstance(n, int) for n in summary["sources"].values())
    assert summary["sections"] == ["strategy"]
    assert payload["labels"]["dimension"] == "C-space dimension"
    # every key is a machine key; the package's legacy {label: text} lines are slugged
    assert all(k == k.lower() and " " not in k for k in summary)
    assert "assembly_modes" in summary


def test_text_and_json_validate_say_the_same_things(cellplan):
    text = cellplan("validate", "strategies_tiny")
    payload = json.loads(cellplan("validate", "strategies_tiny", "--json").stdout)
    labels = [line.split(":", 1)[0].strip() for line in text.stdout.splitlines()]
    assert labels == list(payload["labels"].values())


def test_stats_keep_int_and_bool_types_in_json():
    result = Result(
        Status.SOLVED,
        "ok",
        stats={"requests": 8, "rk4": True, "seconds": 0.5, "n": np.int64(3), "bad": np.nan},
    )
    stats = result.summary()["stats"]
    assert stats == {"requests": 8, "rk4": True, "seconds": 0.5, "n": 3, "bad": None}
    assert type(stats["requests"]) is int and type(stats["rk4"]) is bool
    assert type(stats["n"]) is int
    assert json.loads(json.dumps(stats))["requests"] == 8  # not 8.0


def test_check_stats_accepts_counts_and_flags_and_refuses_the_rest():
    assert check_stats({"n": 3, "ok": True, "t": 0.25}) == []
    bad = check_stats({"nan": float("nan"), "text": "x", "np": np.int64(1)})  # type: ignore[dict-item]
    assert len(bad) == 3


def test_reproduce_json_says_failed_runs_with_status_1(cellplan, monkeypatch, tmp_path):
    from cellplan import reproduce_cli

    def reproduce_sweep(papers, outdir, **given):
        sweep = SimpleNamespace(n_runs=5, n_failed=2, n_broken=0, lost="")
        return Path(outdir) / "index.html", sweep

    monkeypatch.setattr(reproduce_cli, "reproduce_sweep", reproduce_sweep)
    r = cellplan("reproduce", "assembly", "-o", str(tmp_path / "rep"), "--json")
    assert r.returncode == 1
    (line,) = r.stdout.strip().splitlines()
    payload = json.loads(line)
    assert payload["status"] == "failed" and payload["failed_runs"] == 2
    assert payload["runs"] == 5 and "2 of 5 runs failed" in payload["message"]
    assert "2 of 5 runs failed" in r.stderr

"""``cellplan assemble`` draws only when asked (issue 34: drawing must not dominate a
planning command; docs/benchmarks.md "Drawing in assemble")."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

from cellplan.cli import app

runner = CliRunner()

PICTURES = {"sequence.png", "assembly.gif"}


def test_by_default_assemble_writes_the_plan_and_never_loads_matplotlib(tmp_path: Path) -> None:
    out = tmp_path / "o"
    code = (
        "import sys\n"
        "from cellplan.cli import app\n"
        "try:\n"
        f"    app(['assemble', 'discs_swap', '-o', {str(out)!r}, '--json'], "
        "standalone_mode=False)\n"
        "except SystemExit as exc:\n"
        "    assert not exc.code, exc.code\n"
        "print('MPL', 'matplotlib' in sys.modules)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert r.returncode == 0, r.stderr
    payload, flag = r.stdout.strip().splitlines()
    assert flag == "MPL False"
    assert set(json.loads(payload)["outputs"]) == {"trajectory", "metrics"}
    assert {p.name for p in out.iterdir()} == {"trajectory.csv", "metrics.json"}


def test_pictures_flag_draws_the_sequence_and_the_gif(tmp_path: Path) -> None:
    res = runner.invoke(
        app, ["assemble", "discs_swap", "--pictures", "--gif-size", "240", "-o", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    assert PICTURES <= {p.name for p in tmp_path.iterdir()}
    assert (tmp_path / "assembly.gif").read_bytes()[:3] == b"GIF"
    from PIL import Image, ImageSequence

    with Image.open(tmp_path / "assembly.gif") as gif:
        assert gif.size[0] == 240
        assert sum(1 for _ in ImageSequence.Iterator(gif)) > 1


def test_a_gif_option_asks_for_the_pictures(tmp_path: Path) -> None:
    res = runner.invoke(
        app, ["assemble", "discs_swap", "--frames", "2", "-o", str(tmp_path), "--json"]
    )
    assert res.exit_code == 0, res.output
    assert set(json.loads(res.stdout)["outputs"]) == {
        "sequence",
        "animation",
        "trajectory",
        "metrics",
    }


def test_bad_frames_are_refused_with_or_without_pictures(cellplan, tmp_path: Path) -> None:
    for extra in ([], ["--pictures"]):
        r = cellplan("assemble", "discs_swap", "--frames", "1", *extra, "-o", str(tmp_path / "x"))
        assert r.returncode == 2
        assert "--frames" in r.stderr
        assert not (tmp_path / "x").exists()

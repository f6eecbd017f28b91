"""The command line: summaries, pictures, and one-line errors with exit status 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def test_console_script_runs_as_a_process():
    r = subprocess.run(
        [sys.executable, "-m", "cellplan.cli", "validate", "nope"], capture_output=True, text=True
    )
    assert (
        r.returncode == 2
        and "Traceback" not in r.stderr
        and "nope: no such bundled scenario" in r.stderr
    )


def test_validate_prints_a_summary(cellplan):
    r = cellplan("validate", "strategies_p1")
    assert r.returncode == 0, r.stderr
    assert "assembly modes: 17" in r.stdout
    assert "C-space dimension: 2" in r.stdout
    assert "free fraction" in r.stdout


def test_schema_is_json(cellplan):
    r = cellplan("schema")
    assert r.returncode == 0
    assert json.loads(r.stdout)["title"] == "Scenario"


def test_show_and_cspace_write_pictures(cellplan, tmp_path):
    r = cellplan("show", "strategies_p6", "-o", str(tmp_path / "cell.png"))
    assert r.returncode == 0, r.stderr
    r = cellplan(
        "cspace",
        "strategies_p6",
        "--cells",
        "16,16,8",
        "--slice",
        "3",
        "-o",
        str(tmp_path / "c.png"),
    )
    assert r.returncode == 0, r.stderr
    for name in ("cell.png", "c.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "c.png",
        "cell.png",
    ]  # no temporary leftovers


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["validate", "no_such_file.yaml"], "no_such_file.yaml: no such file"),
        (["validate", "no_such_scenario"], "no_such_scenario: no such bundled scenario"),
        (["cspace", "strategies_p1", "--carrying", "P9"], "--carrying: unknown part 'P9'"),
        (
            ["cspace", "strategies_p1", "--cells", "10,x"],
            "--cells: expected comma-separated integers",
        ),
        (
            ["cspace", "strategies_p1", "--cells", "10,10,10"],
            "--cells: needs 2 values for this robot, got 3",
        ),
        (["show", "strategies_p1", "-o", "picture.bmp"], "--output: unsupported image type '.bmp'"),
        (["validate", "strategies_p1", "--bogus"], "No such option: --bogus"),
    ],
)
def test_bad_arguments_give_one_line_and_status_2(cellplan, args, message, tmp_path):
    r = cellplan(*args, cwd=tmp_path)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    usage = ("Usage:", "Try ")  # click's usage hint around an unknown-option error
    errors = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith(usage)]
    assert len(errors) == 1 and message in errors[0]


def test_bad_scenario_lists_every_problem(cellplan, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "cellplan: 1\nworkcell:\n  bounds: {xmax: 10, ymax: 10}\n  obstacles:\n"
        "    w: {type: box, min: [4, 0], max: [6, 6]}\n"
        "robot: {type: point, start: [5, 3]}\n"
        "parts: {P: {shape: {type: box, min: [0, 0], max: [1, 1]}, mass: 2}}\n"
    )
    r = cellplan("validate", str(bad))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "parts.P.mass: unknown key" in r.stderr
    bad.write_text(bad.read_text().replace(", mass: 2", ""))
    r = cellplan("validate", str(bad))
    assert r.returncode == 2
    assert "robot.start: configuration (5, 3) collides with obstacle 'w'" in r.stderr


def test_validate_summarises_a_disc_scenario(cellplan):
    r = cellplan("validate", "discs_seven")
    assert r.returncode == 0, r.stderr
    assert "discs: 7 generated" in r.stdout
    assert "C-space dimension" not in r.stdout  # no robot in a pure disc problem


def test_version_and_short_help(cellplan):
    from cellplan import __version__

    r = cellplan("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"cellplan {__version__}"
    r = cellplan("validate", "-h")
    assert r.returncode == 0 and "--json" in r.stdout


def test_command_list_is_whole_at_80_columns(cellplan, monkeypatch):
    """Each command's line in ``cellplan --help`` is its own sentence, never cut with "..."."""
    from cellplan.cliutil import SHORT_HELP_WIDTH

    monkeypatch.setenv("COLUMNS", "80")
    r = cellplan("--help")
    assert r.returncode == 0
    listed = r.stdout.split("Commands:")[1].strip().splitlines()
    names = [line.split()[0] for line in listed]
    assert {"solve", "adapt", "assemble", "reproduce", "export"} <= set(names)
    assert [line for line in listed if "..." in line or "``" in line] == []
    width = max(map(len, names))
    assert [
        n for n, line in zip(names, listed, strict=True) if len(line) > width + 4 + SHORT_HELP_WIDTH
    ] == []


def test_validate_json_is_one_object_on_stdout(cellplan):
    r = cellplan("validate", "discs_seven", "--json")
    assert r.returncode == 0, r.stderr
    payload = json.loads(r.stdout)
    assert payload["status"] == "valid" and payload["summary"]["sections"] == ["discs"]
    assert len(r.stdout.strip().splitlines()) == 1


def test_a_bug_exits_70_with_one_line(cellplan, monkeypatch):
    import cellplan.summary as summary

    def broken(setup, progress=None):
        raise KeyError("oops")

    monkeypatch.setattr(summary, "facts", broken)
    r = cellplan("validate", "strategies_tiny")
    assert r.returncode == 70
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "internal error" in lines[0] and "KeyError" in lines[0]
    assert "Traceback" not in r.stderr


def test_summaries_are_not_wrapped_when_piped():
    r = subprocess.run(
        [sys.executable, "-m", "cellplan.cli", "validate", "strategies_p1"],
        capture_output=True,
        text=True,
        env={**__import__("os").environ, "COLUMNS": "40"},
    )
    assert r.returncode == 0
    line = next(x for x in r.stdout.splitlines() if "free fraction" in x)
    assert "conservative)" in line


def test_output_paths_that_cannot_be_written_are_one_line(cellplan, tmp_path):
    folder = tmp_path / "cell.png"
    folder.mkdir()
    r = cellplan("show", "strategies_tiny", "-o", str(folder))
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: --output: {folder} is a folder; give a file name"
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = cellplan("show", "strategies_tiny", "-o", str(blocker / "cell.png"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert str(blocker) in r.stderr


def test_cspace_slice_out_of_range_is_one_line(cellplan, tmp_path):
    r = cellplan("cspace", "strategies_p3", "--slice", "-1", "-o", str(tmp_path / "c.png"))
    assert r.returncode == 2
    assert r.stderr.strip().startswith("error: --slice: must be in [0, ")
    assert not (tmp_path / "c.png").exists()


@pytest.mark.parametrize("name", ["discs_seven", "adaptive_fig3", "strategies_tiny"])
def test_show_draws_every_kind_of_scenario(cellplan, tmp_path, name):
    out = tmp_path / f"{name}.png"
    r = cellplan("show", name, "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 10_000


def test_validate_refuses_a_cspace_grid_that_cannot_fit_naming_the_field(cellplan, tmp_path):
    import yaml

    from cellplan.registry import resolve_scenario_path

    data = yaml.safe_load(resolve_scenario_path("rotating_bar").read_text())
    data.setdefault("cspace", {})["cells"] = [4096, 4096, 4096]
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(data))
    r = cellplan("validate", str(path))
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: cspace.cells 4096,4096,4096: needs about "), lines
    assert "for the C-space bitmap; this machine has " in lines[0]


def test_3d_cells_validate_show_and_view(cellplan, tmp_path):
    """The README's 3-D commands: validate, show (a PNG in metres), view (one offline
    page); a C-space picture of a six-joint arm and a view of a 2-D cell are refused."""
    r = cellplan("validate", "ur5_cell")
    assert r.returncode == 0, r.stderr
    assert "collision geometry: spheres" in r.stdout
    assert "reachable (components): bin_a 1/1, bin_b 1/1, fixture 1/1" in r.stdout
    png = tmp_path / "cell.png"
    r = cellplan("show", "ur5_cell", "-o", str(png), "--view", "front")
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = tmp_path / "cell.html"
    r = cellplan("view", "panda_shelf", "-o", str(page))
    assert r.returncode == 0, r.stderr
    html = page.read_text()
    assert "<script" in html and 'src="http' not in html
    r = cellplan("cspace", "ur5_cell", "-o", str(tmp_path / "c.png"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "2 or 3 axes" in r.stderr
    r = cellplan("view", "strategies_p1", "-o", str(tmp_path / "p1.html"))
    assert r.returncode == 2 and "3-D cells" in r.stderr
    assert not (tmp_path / "p1.html").exists() and not (tmp_path / "c.png").exists()

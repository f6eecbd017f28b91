"""Hand-made hostile inputs that once crashed, hung or printed a traceback (issue 16).

Each is kept as an explicit case: in-process where the worst outcome is an exception,
in a subprocess with a timeout where it was a segmentation fault or a hang.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from fuzz_harness import bad_lines, run_cli

from cellplan import scenario as scenario_module
from cellplan.registry import resolve_scenario_path

TINY = resolve_scenario_path("strategies_tiny").read_text(encoding="utf-8")
SWAP = resolve_scenario_path("discs_swap").read_text(encoding="utf-8")
P5 = resolve_scenario_path("strategies_p5").read_text(encoding="utf-8")


def write(tmp: Path, text: str | bytes, name: str = "s.yaml") -> Path:
    path = tmp / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
    return path


def assert_bad_input(args: list[str], *where: str, options: bool = False) -> str:
    """Exit 2, every line naming a field, option or one of ``where``; returns stderr."""
    r = run_cli(args)
    assert r.code == 2, r.describe()
    bad = bad_lines(r.stderr, files=[*where, *args[1:]], options=options)
    assert not bad, r.describe()
    return r.stderr


BAD_FILES = {
    "latin-1": (TINY + "# caf\u00e9\n").encode("latin-1"),
    "utf-16": TINY.encode("utf-16"),
    "binary": bytes(range(256)) * 4,
    "nul byte": TINY.replace("strategies-tiny", "a\x00b").encode(),
    "deep nesting": ("cellplan: 1\nx: " + "[" * 2000 + "]" * 2000 + "\n").encode(),
    "list as a key": TINY.replace("  middle:", "  [a, b]:").encode(),
    "unhashable key": b"cellplan: 1\n? {a: 1}\n: 2\n",
    "duplicate key": (TINY + "workcell: {}\n").encode(),
    "python tag": TINY.replace(
        "speed: 2.5", "speed: !!python/object/apply:os.system [ls]"
    ).encode(),
    "unknown alias": (TINY + "extra: *nowhere\n").encode(),
    "recursive alias": (TINY + "extra: &r [*r]\n").encode(),
    "markup in a key": TINY.replace("  middle:", "  '[/x]':").encode(),
    "bounds 1e308": TINY.replace("xmax: 30", "xmax: 1e308").encode(),
    "coordinate 1e30": TINY.replace("max: [18, 16]", "max: [1e30, 16]").encode(),
    "max_sweeps 1e21": TINY.replace("actions:", "solver: {max_sweeps: 1e21}\n  actions:").encode(),
    "speed nan": TINY.replace("speed: 2.5", "speed: .nan").encode(),
    "cells 0": TINY.replace("cells: [12, 12]", "cells: [0, 12]").encode(),
    "disc radius 1e308": SWAP.replace("radius: 1", "radius: 1e308", 1).encode(),
    "5000 copies of a component": TINY.replace(
        "D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}",
        "D1: {components: [&c {type: box, min: [13, 25], max: [17, 28]}" + ", *c" * 5000 + "]}",
    ).encode(),
    "900 overlapping components": TINY.replace(
        "D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}",
        "D1: {components: [&c {type: box, min: [13, 25], max: [17, 28]}" + ", *c" * 900 + "]}",
    ).encode(),
    "null key": TINY.replace("  middle:", "  null:").encode(),
    "true key": TINY.replace("robot:", "true: 1\nrobot:").encode(),
    # reached GEOS through the region enclosure test (exit 70) once validate built the model
    "arm link width 3e300": P5.replace(
        "{length: 25, width: 3}", "{length: 25, width: 3e300}"
    ).encode(),
    "empty file": b"",
    "a list": b"- 1\n- 2\n",
    # PyYAML's scalar constructors raised plain Python errors (exit 70); the first was
    # found by the slow fuzzer in a description tagged !!timestamp
    "bad timestamp": TINY.replace("name: strategies-tiny", "name: !!timestamp ''").encode(),
    "bad int": TINY.replace("speed: 2.5", "speed: !!int abc").encode(),
    "bad bool": TINY.replace("speed: 2.5", "speed: !!bool maybe").encode(),
    "empty float": TINY.replace("speed: 2.5", "speed: !!float ''").encode(),
    "impossible date": TINY.replace("name: strategies-tiny", "name: 2001-02-30").encode(),
    "5000-digit int": TINY.replace("speed: 2.5", "speed: " + "9" * 5000).encode(),
    # each source is an obstacle for every other: 5,000 copies kept validate busy > 5 min
    "5000 copies of a source": TINY.replace(
        "  S2: {components: [{type: box, min: [24, 2], max: [28, 5]}]}\n",
        "  S2: &s2 {components: [{type: box, min: [24, 2], max: [28, 5]}]}\n"
        + "".join(f"  S{i}: *s2\n" for i in range(3, 5003)),
    ).encode(),
    "1001 requests": TINY.replace(
        "speed: 2.5",
        "speed: 2.5\n  requests: ["
        + ", ".join(["{part: P1, source: S1, destination: D1}"] * 1001)
        + "]",
    ).encode(),
    # an infinite move per stage became garbage integers in the stencil tables
    "stage_time 1e300": TINY.replace("speed: 2.5", "speed: 2.5\n  stage_time: 1e300").encode(),
    # validate ran the C-space rasters for minutes (the rasters grow with the part)
    "part longer than the workcell": P5.replace(
        "P1: {shape: {type: box, min: [0, -2.5], max: [5, 2.5]}}",
        "P1: {shape: {type: box, min: [0, -2000], max: [5, 2.5]}}",
    ).encode(),
}


@pytest.mark.parametrize("content", BAD_FILES.values(), ids=BAD_FILES.keys())
def test_hostile_scenario_files(content: bytes, tmp_path: Path) -> None:
    path = write(tmp_path, content)
    assert_bad_input(["validate", str(path)], str(path))


def test_billion_laughs_is_refused_before_validation(tmp_path: Path) -> None:
    laughs = ["l0: &l0 [x, x, x, x, x, x, x, x, x, x]"]
    laughs += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10)}]" for i in range(1, 9)]
    path = write(tmp_path, "cellplan: 1\n" + "\n".join(laughs) + "\n")
    err = assert_bad_input(["validate", str(path)], str(path))
    assert "aliases (*name) expand to more than" in err


def test_too_many_values_stop_the_parser(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(scenario_module, "MAX_YAML_NODES", 1000)
    path = write(tmp_path, "cellplan: 1\nx: [" + ", ".join(["1"] * 2000) + "]\n")
    err = assert_bad_input(["validate", str(path)], str(path))
    assert "more than 1,000 values" in err


def test_many_problems_are_capped_with_a_count(tmp_path: Path) -> None:
    start = ", ".join(["x"] * 250)
    text = TINY.replace(
        "robot:\n  type: translating",
        f"robot:\n  type: arm\n  links: [{{length: 1, width: 1}}]\n  start: [{start}]\n  _t: 1",
    ).split("\n  shape: {type: box, min: [-1, -1]")[0]
    path = write(tmp_path, text + "\n")
    err = assert_bad_input(["validate", str(path)], str(path))
    lines = err.splitlines()
    assert len(lines) == 101 and lines[-1].endswith("more problems not shown")


@pytest.mark.parametrize("name", ["$x^$", "$\\foo$", "[/x] [bold]", "50% {0} \\$"])
def test_show_draws_names_as_plain_text(name: str, tmp_path: Path) -> None:
    text = TINY.replace("name: strategies-tiny", f"name: {json.dumps(name)}")
    path = write(tmp_path, text)
    r = run_cli(["show", str(path), "-o", str(tmp_path / "w.png")])
    assert r.code == 0, r.describe()
    assert (tmp_path / "w.png").is_file()


OPTION_CASES = {
    "radius inf": (["assemble", "--random", "3", "--radius", "inf"], "--radius"),
    "log10-beta nan": (["assemble", "--random", "3", "--log10-beta", "nan"], "--log10-beta"),
    "radius 1e308": (["assemble", "--random", "3", "--radius", "1e308"], "--radius"),
    "radius 1e-300": (["assemble", "--random", "3", "--radius", "1e-300"], "--radius"),
    "fill 1e-300": (["assemble", "--random", "3", "--fill", "1e-300"], "--fill"),
    "fill 5e-324": (["assemble", "--random", "3", "--fill", "5e-324"], "--fill"),
    "frames 1e22": (["assemble", "discs_swap", "--frames", str(10**22)], "--frames"),
    "cspace slice -1": (["cspace", "strategies_tiny", "--slice", "-1"], "--slice"),
    "cspace cells empty": (["cspace", "strategies_tiny", "--cells", ""], "--cells"),
    "seed text": (["simulate", "strategies_tiny", "--strategy", "x.npz", "--seed", "a"], "--seed"),
    "unknown option": (["validate", "strategies_tiny", "--bogus"], "--bogus"),
    "missing argument": (["validate"], "SCENARIO"),
    "empty scenario": (["validate", ""], "SCENARIO"),
    "reproduce --only empty": (["reproduce", "--only", ""], "--only"),
    "output is a folder": (["show", "strategies_tiny", "-o", "."], "--output"),
    "markup in a path": (["show", "strategies_tiny", "-o", "[/x]/a.bmp"], "--output"),
}


@pytest.mark.parametrize(("args", "option"), OPTION_CASES.values(), ids=OPTION_CASES.keys())
def test_hostile_options(args: list[str], option: str, tmp_path: Path) -> None:
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        err = assert_bad_input(args, options=True)
    finally:
        os.chdir(cwd)
    assert err.splitlines()[0].startswith(f"error: {option}: "), err
    assert not any(p.name != "x.npz" for p in tmp_path.iterdir()), "left output behind"


def test_output_inside_a_file_is_refused_before_work(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    for args in (
        ["show", "strategies_tiny", "-o", str(blocker / "w.png")],
        ["demo", "-o", str(blocker / "out")],
        ["assemble", "--random", "2", "-o", str(blocker / "out")],
        ["adapt", "adaptive_fig3", "--db", str(blocker / "x.sqlite")],
    ):
        err = assert_bad_input(args, options=True)
        assert "is a file, not a folder" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


def test_start_within_tolerance_is_a_finished_run(tmp_path: Path) -> None:
    r = run_cli(["assemble", "discs_swap", "--tolerance", "1e308", "--frames", "2", "-o",
                 str(tmp_path / "out")])  # fmt: skip
    assert r.code == 0, r.describe()


# --- in a separate process: what once crashed the interpreter or hung ------------------------

CRASH_PRONE = {
    "coordinate 1e30": TINY.replace("max: [18, 16]", "max: [1e30, 16]"),
    "bounds 1e308": TINY.replace("xmax: 30", "xmax: 1e308"),
    "deep nesting 100k": "cellplan: 1\nx: " + "[" * 100_000 + "]" * 100_000 + "\n",
    "billion laughs": "cellplan: 1\n"
    + "".join(
        f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10) if i else 'x, x, x, x, x, x, x, x'}]\n"
        for i in range(9)
    ),
}


CRASH_CASES = [(name, "validate") for name in CRASH_PRONE] + [
    ("bounds 1e308", "show"),  # hung in shapely
    ("coordinate 1e30", "show"),
]


@pytest.mark.parametrize(("case", "command"), CRASH_CASES)
def test_crash_prone_files_exit_2_in_a_real_process(
    case: str, command: str, tmp_path: Path
) -> None:
    path = write(tmp_path, CRASH_PRONE[case])
    args = [sys.executable, "-m", "cellplan.cli", command, str(path)]
    if command == "show":
        args += ["-o", str(tmp_path / "w.png")]
    r = subprocess.run(args, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert not bad_lines(r.stderr, files=[str(path)]), r.stderr[-2000:]
    assert not (tmp_path / "w.png").exists()

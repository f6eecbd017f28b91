"""Bad 3-D scenario input through the command line: one line per problem, naming the field.

Each case edits a bundled scenario (``ur5_cell``, ``panda_shelf``, or a 2-D one), writes it
with any file it refers to (tests/data/bad3d) into a fresh folder, and runs
``cellplan validate FILE`` and ``cellplan show FILE -o out.png`` in-process, capturing
stderr at the file-descriptor level (so that a C++ library writing to stderr is seen).
Each must exit 2 with one ``error: FIELD: message`` line per problem, print no traceback,
and write nothing (no image, no other file).

Cases marked ``xfail(strict=True)`` are the project rule's known violations: each test
states the right behaviour, and starts to pass (failing the strict mark) once fixed.
"""

from __future__ import annotations

import copy
import json
import shutil
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml

from cellplan import budget, solids
from cellplan.cli import main
from cellplan.registry import resolve_scenario_path, scenario_names
from cellplan.scenario3d import is_3d

DATA = Path(__file__).parent / "data" / "bad3d"
SCENARIOS_3D = ("ur5_cell", "panda_shelf")


@dataclass
class Ran:
    """Exit status and fd-level output of one in-process command."""

    code: int
    stdout: str
    stderr: str

    def describe(self) -> str:
        return f"exit {self.code}\nstdout:\n{self.stdout[-1500:]}\nstderr:\n{self.stderr[-3000:]}"


@pytest.fixture
def cli(capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> Callable[..., Ran]:
    """Run ``cellplan *args`` as the console script does; output captured at the fd level.

    An exception escaping ``main`` (which would be a traceback) becomes exit -1 with the
    traceback as its stderr, so the checks below report it like any other failure.
    """

    def run(*args: str) -> Ran:
        capfd.readouterr()
        monkeypatch.setattr(sys, "argv", ["cellplan", *args])
        code = 0
        tb = ""
        try:
            main()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except Exception:
            code, tb = -1, traceback.format_exc()
        out = capfd.readouterr()
        return Ran(code, out.out, out.err + tb)

    return run


def bundled(name: str) -> dict[str, Any]:
    return yaml.safe_load(resolve_scenario_path(name).read_text(encoding="utf-8"))


_BASES = {name: bundled(name) for name in (*SCENARIOS_3D, "strategies_tiny", "rotating_bar")}


def base(name: str) -> dict[str, Any]:
    return copy.deepcopy(_BASES[name])


# --- the edits ----------------------------------------------------------------------------------


def ur5_with(**robot: Any) -> dict[str, Any]:
    d = base("ur5_cell")
    d["robot"].update(robot)
    return d


def with_obstacle(name: str, solid: dict[str, Any], scenario: str = "ur5_cell") -> dict[str, Any]:
    d = base(scenario)
    obstacles = dict(d["workcell"].get("obstacles") or {})
    obstacles[name] = solid
    d["workcell"]["obstacles"] = obstacles
    return d


def scan(path: str) -> dict[str, Any]:
    """A mesh obstacle above the table, clear of the UR5 at its start."""
    return {"type": "mesh", "path": path, "scale": [0.1] * 3, "pose": {"xyz": [0.5, 0.5, 1.2]}}


def urdf_missing_mesh() -> dict[str, Any]:
    d = ur5_with(urdf="missing_mesh.urdf", start=[0])
    del d["robot"]["tool"]
    return d


def panda_joints(joints: list[str]) -> dict[str, Any]:
    d = base("panda_shelf")
    d["robot"]["joints"] = joints
    return d


def panda_joint4_locked(value: float) -> dict[str, Any]:
    """Panda with joint 4 locked (not active) at ``value`` degrees."""
    d = base("panda_shelf")
    r = d["robot"]
    r["joints"] = [j for j in r["joints"] if j != "panda_joint4"]
    r["locked"]["panda_joint4"] = value
    r["start"] = [0, -45, 0, 0, 90, 45]
    return d


def panda_start(index: int, value: float) -> dict[str, Any]:
    d = base("panda_shelf")
    d["robot"]["start"][index] = value
    return d


def edit(name: str, path: str, value: Any) -> dict[str, Any]:
    """Bundled scenario ``name`` with the value at dotted ``path`` replaced."""
    d = base(name)
    node = d
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    node[int(keys[-1]) if isinstance(node, list) else keys[-1]] = value
    return d


def with_part(scenario: str, shape: dict[str, Any]) -> dict[str, Any]:
    d = base(scenario)
    d["parts"][next(iter(d["parts"]))]["shape"] = shape
    return d


def urdf_robot_in(scenario: str) -> dict[str, Any]:
    d = base(scenario)
    d["robot"] = {"type": "urdf", "urdf": "ur5", "start": [0, -90, 90, -90, -90, 0]}
    return d


# --- the cases ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One bad input: the scenario data, the files it needs, what the answer must be."""

    id: str
    data: Callable[[], dict[str, Any]]
    fields: tuple[str, ...]
    """the field each line must name, in order (one line per problem)"""
    needle: str = ""
    """text every line's message must hold"""
    files: tuple[str, ...] = ()
    """files of tests/data/bad3d copied next to the scenario"""
    xfail: str = ""
    env: dict[str, str] = field(default_factory=dict)


LONG_NAME = "x" * 300
"""A file name longer than NAME_MAX (255) but within the schema's 4096 characters."""

SOLID_BOX_2D = {"type": "box", "min": [0.4, 0.4], "max": [0.5, 0.5]}

CASES = [
    Case(
        "urdf-not-xml",
        lambda: ur5_with(urdf="broken.urdf"),
        ("robot.urdf",),
        "not valid XML",
        files=("broken.urdf",),
    ),
    Case(
        "urdf-xml-but-no-robot",
        lambda: ur5_with(urdf="no_links.urdf"),
        ("robot.urdf",),
        "URDF",
        files=("no_links.urdf",),
    ),
    Case(
        "urdf-path-name-too-long",
        lambda: ur5_with(urdf=LONG_NAME + ".urdf"),
        ("robot.urdf",),
    ),
    Case(
        "srdf-path-name-too-long",
        lambda: ur5_with(srdf=LONG_NAME + ".srdf"),
        ("robot.srdf",),
    ),
    Case(
        "urdf-mesh-missing",
        urdf_missing_mesh,
        ("robot.urdf",),
        "missing.stl",
        files=("missing_mesh.urdf",),
    ),
    Case(
        "mesh-obstacle-missing",
        lambda: with_obstacle("scan", scan("nowhere.stl")),
        ("workcell.obstacles.scan.path",),
        "nowhere.stl",
    ),
    Case(
        "mesh-path-name-too-long",
        lambda: with_obstacle("scan", scan(LONG_NAME + ".stl")),
        ("workcell.obstacles.scan.path",),
    ),
    Case(
        "mesh-flat-stl",
        lambda: with_obstacle("scan", scan("flat.stl")),
        ("workcell.obstacles.scan.path",),
        "no volume",
        files=("flat.stl",),
    ),
    Case(
        "mesh-flat-obj",
        lambda: with_obstacle("scan", scan("flat.obj")),
        ("workcell.obstacles.scan.path",),
        "no volume",
        files=("flat.obj",),
    ),
    Case(
        "joints-unknown",
        lambda: panda_joints(["panda_joint1", "panda_joint2", "panda_joint33"]),
        ("robot.joints[2]",),
        "panda_joint33",
    ),
    Case("tool-unknown", lambda: ur5_with(tool="gripper"), ("robot.tool",), "gripper"),
    Case(
        "locked-unknown-joint",
        lambda: edit("panda_shelf", "robot.locked.panda_finger_joint3", 0.01),
        ("robot.locked.panda_finger_joint3",),
        "no such movable joint",
    ),
    Case(
        "locked-outside-limits",
        lambda: panda_joint4_locked(10),
        ("robot.locked.panda_joint4",),
        "outside",
    ),
    Case(
        "start-outside-limits",
        lambda: panda_start(3, 10),
        ("robot.start[3]",),
        "panda_joint4 = 10 is outside its limits [-176",
    ),
    Case(
        "start-wrong-count",
        lambda: ur5_with(start=[0, -90, 90, -90, -90]),
        ("robot.start",),
        "has 5 values; the robot has 6 active joints",
    ),
    Case(
        "base-inside-obstacle",
        lambda: with_obstacle(
            "crate", {"type": "box", "size": [0.4, 0.4, 0.3], "pose": {"xyz": [0, 0, 0.9]}}
        ),
        ("robot.base",),
        "inside obstacle 'crate'",
    ),
    Case(
        "start-collides",
        lambda: ur5_with(start=[0, 60, 0, 0, 0, 0]),
        ("robot.start",),
        "collides with obstacle 'table'",
    ),
    Case(
        "2d-box-obstacle-in-3d",
        lambda: with_obstacle("wall", SOLID_BOX_2D),
        ("workcell.obstacles.wall",),
        "2-D",
    ),
    Case(
        "2d-disc-obstacle-in-3d",
        lambda: with_obstacle("disc", {"type": "disc", "center": [0, 0], "radius": 0.1}),
        ("workcell.obstacles.disc",),
        "2-D shape in a 3-D workcell",
    ),
    Case(
        "2d-disc-part-in-3d",
        lambda: with_part("ur5_cell", {"type": "disc", "center": [0, 0], "radius": 0.02}),
        ("parts.P1.shape",),
        "2-D shape in a 3-D workcell",
    ),
    Case(
        # The scenario fuzzer: a part box 2.5e-19 m thick was refused under the field
        # "vertices" of the sphere cover, which names nothing in the file.
        "flat-part-in-3d",
        lambda: with_part("ur5_cell", {"type": "box", "size": [0.05, 0.05, 2.5e-19]}),
        ("parts.P1.shape",),
        "no volume",
    ),
    Case(
        "2d-box-source-in-3d",
        lambda: edit("ur5_cell", "sources.bin_a.components", [SOLID_BOX_2D]),
        ("sources.bin_a.components[0]",),
        "2-D shape in a 3-D workcell",
    ),
    Case(
        "solid-obstacle-in-2d",
        lambda: with_obstacle(
            "cube",
            {"type": "box", "size": [1, 1, 1], "pose": {"xyz": [5, 5, 0]}},
            "strategies_tiny",
        ),
        ("workcell.obstacles.cube",),
        "solid in a 2-D workcell",
    ),
    Case(
        "cylinder-obstacle-in-2d",
        lambda: with_obstacle(
            "can", {"type": "cylinder", "radius": 1, "length": 2}, "rotating_bar"
        ),
        ("workcell.obstacles.can",),
        "solid in a 2-D workcell",
    ),
    Case(
        "solid-part-in-2d",
        lambda: with_part("strategies_tiny", {"type": "box", "size": [1, 1, 1]}),
        ("parts.P1.shape",),
        "solid in a 2-D workcell",
    ),
    Case(
        "version-1-with-3d-bounds",
        lambda: edit("ur5_cell", "cellplan", 1),
        ("cellplan",),
        "needs 'cellplan: 2'",
    ),
    Case(
        "urdf-robot-in-2d",
        lambda: urdf_robot_in("rotating_bar"),
        ("robot.type",),
        "needs a 3-D workcell",
    ),
    Case(
        "urdf-robot-in-2d-with-strategy",
        lambda: urdf_robot_in("strategies_tiny"),
        ("robot.type",),
        "needs a 3-D workcell",
    ),
    Case(
        "solid-unknown-key",
        lambda: edit("ur5_cell", "workcell.obstacles.table.colour", "red"),
        ("workcell.obstacles.table.colour",),
        "unknown key",
    ),
    Case(
        "pose-unknown-key",
        lambda: edit("ur5_cell", "workcell.obstacles.table.pose.xyzw", [0, 0, 0, 1]),
        ("workcell.obstacles.table.pose.xyzw",),
        "did you mean 'xyz'",
    ),
    Case(
        "pose-two-numbers",
        lambda: edit("ur5_cell", "workcell.obstacles.table.pose.xyz", [0.25, 0.0]),
        ("workcell.obstacles.table.pose.xyz",),
    ),
    Case(
        "pose-four-numbers",
        lambda: edit("ur5_cell", "workcell.obstacles.table.pose.xyz", [0.25, 0.0, 0.7, 1]),
        ("workcell.obstacles.table.pose.xyz",),
        "has 4 items",
    ),
    Case(
        "size-negative",
        lambda: edit("ur5_cell", "workcell.obstacles.table.size", [1.6, -1.4, 0.05]),
        ("workcell.obstacles.table.size[1]",),
        "greater than 0",
    ),
    Case(
        "radius-negative",
        lambda: edit("ur5_cell", "workcell.obstacles.pillar.radius", -0.05),
        ("workcell.obstacles.pillar.radius",),
        "greater than 0",
    ),
    Case(
        "rpy-beyond-360",
        lambda: edit("ur5_cell", "workcell.obstacles.table.pose.rpy", [0, 0, 400]),
        ("workcell.obstacles.table.pose.rpy[2]",),
        "360",
    ),
    Case(
        "base-rpy-beyond-minus-360",
        lambda: edit("ur5_cell", "robot.base.rpy", [-400, 0, 0]),
        ("robot.base.rpy[0]",),
        "-360",
    ),
]

COMMANDS = ("validate", "show")


def write_case(case: Case, folder: Path) -> Path:
    for name in case.files:
        shutil.copy(DATA / name, folder / name)
    path = folder / "scenario.yaml"
    path.write_text(yaml.safe_dump(case.data(), sort_keys=False), encoding="utf-8")
    return path


def listing(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_size for p in folder.rglob("*")}


def run_bad(cli: Callable[..., Ran], command: str, path: Path) -> Ran:
    """Run ``command`` on ``path``; check it wrote nothing and printed no traceback."""
    folder = path.parent
    before = listing(folder)
    image = folder / "out.png"
    args = [command, str(path)] + (["-o", str(image)] if command == "show" else [])
    r = cli(*args)
    assert "Traceback" not in r.stdout + r.stderr, r.describe()
    assert not image.exists(), r.describe()
    assert listing(folder) == before, r.describe()
    return r


def split_line(line: str) -> tuple[str, str]:
    """``error: FIELD: message`` -> ``(FIELD, message)``."""
    assert line.startswith("error: "), line
    where, sep, message = line[len("error: ") :].partition(": ")
    assert sep and message.strip(), line
    return where, message


def check_answer(r: Ran, fields: tuple[str, ...], needle: str = "") -> list[str]:
    """Exit 2, one ``error: FIELD: message`` line per expected field; the messages."""
    assert r.code == 2, r.describe()
    lines = r.stderr.splitlines()
    assert all(line.startswith("error: ") for line in lines), r.describe()
    named = [split_line(line) for line in lines]
    assert [f for f, _ in named] == list(fields), r.describe()
    assert all(needle in m for _, m in named), r.describe()
    return [m for _, m in named]


def params() -> list[Any]:
    out = []
    for case in CASES:
        marks = [pytest.mark.xfail(strict=True, reason=case.xfail)] if case.xfail else []
        for command in COMMANDS:
            out.append(pytest.param(case, command, id=f"{case.id}-{command}", marks=marks))
    return out


@pytest.mark.parametrize(("case", "command"), params())
def test_bad_3d_input_is_one_line_per_problem(
    case: Case, command: str, cli: Callable[..., Ran], tmp_path: Path
) -> None:
    path = write_case(case, tmp_path)
    check_answer(run_bad(cli, command, path), case.fields, case.needle)


@pytest.mark.parametrize("command", COMMANDS)
def test_mesh_too_large_for_the_memory_left(
    command: str, cli: Callable[..., Ran], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # 2 MB of OBJ text is taken for about 100,000 triangles (100 MB to load); allow 20 MB
    # more than this process holds. The mesh itself (a tetrahedron) loads without a limit.
    big = tmp_path / "big.obj"
    tetra = (DATA / "tetra.obj").read_text(encoding="utf-8")
    big.write_text(tetra + ("# padding " + "x" * 89 + "\n") * 20_000, encoding="utf-8")
    vertices, faces = solids.load_mesh(big, field="control")
    assert len(vertices) == 4 and len(faces) == 4
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(with_obstacle("scan", scan("big.obj"))), encoding="utf-8")
    monkeypatch.setenv(budget.LIMIT_VARIABLE, str(budget.resident_memory() + 20 * 10**6))
    r = run_bad(cli, command, path)
    (message,) = check_answer(r, ("workcell.obstacles.scan.path",), "needs about")
    assert "to load mesh" in message and "big.obj" in message


# --- messages that name the field but say the wrong thing ----------------------------------------


def test_locked_outside_limits_speaks_the_files_units(
    cli: Callable[..., Ran], tmp_path: Path
) -> None:
    case = next(c for c in CASES if c.id == "locked-outside-limits")
    (message,) = check_answer(run_bad(cli, "validate", write_case(case, tmp_path)), case.fields)
    assert "10" in message and "-176" in message and "radian" not in message, message


def test_pose_with_two_numbers_says_three_are_needed(
    cli: Callable[..., Ran], tmp_path: Path
) -> None:
    case = next(c for c in CASES if c.id == "pose-two-numbers")
    (message,) = check_answer(run_bad(cli, "validate", write_case(case, tmp_path)), case.fields)
    assert "missing" not in message and "3" in message, message


def test_long_urdf_name_is_a_scenario_error_through_the_api(tmp_path: Path) -> None:
    import cellplan
    from cellplan.errors import ScenarioError

    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(ur5_with(urdf=LONG_NAME + ".urdf")), encoding="utf-8")
    with pytest.raises(ScenarioError) as err:
        cellplan.load(path).workcell  # noqa: B018 - built on first access
    assert [p.field for p in err.value.problems] == ["robot.urdf"]


@pytest.mark.parametrize(
    ("data", "field"),
    [
        pytest.param(
            lambda: with_part("ur5_cell", {"size": [0.04, 0.04, 0.06]}),
            "parts.P1.shape",
            id="solid-without-type",
        ),
        pytest.param(
            lambda: with_obstacle("crate", {"size": [0.1, 0.1, 0.1], "pose": {}}),
            "workcell.obstacles.crate",
            id="obstacle-without-type",
        ),
        pytest.param(lambda: ur5_with(joints=[]), "robot.joints", id="joints-empty"),
        pytest.param(lambda: ur5_with(start=[]), "robot.start", id="start-empty"),
        pytest.param(lambda: ur5_with(urdf="x" * 4097), "robot.urdf", id="urdf-path-4097"),
    ],
)
def test_messages_are_cellplans_own_words(
    data: Callable[[], dict[str, Any]], field: str, cli: Callable[..., Ran], tmp_path: Path
) -> None:
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data()), encoding="utf-8")
    (message,) = check_answer(run_bad(cli, "validate", path), (field,))
    for jargon in ("discriminator", "should have", "after validation", "Input should"):
        assert jargon not in message, message


# --- valid 3-D input that must not crash ---------------------------------------------------------


def check_clean(r: Ran) -> None:
    """Exit 0, or 2 with ``error: FIELD: message`` lines; never 70 nor a traceback."""
    assert r.code in (0, 2), r.describe()
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.describe()
    if r.code == 2:
        for line in r.stderr.splitlines():
            split_line(line)


def one_joint_panda() -> dict[str, Any]:
    d = panda_joints(["panda_joint1"])
    d["robot"]["start"] = [0]
    return d


def ur5_cell_without_robot() -> dict[str, Any]:
    d = base("ur5_cell")
    for key in ("robot", "parts", "sources", "destinations"):
        del d[key]
    return d


def test_validate_a_one_joint_arm(cli: Callable[..., Ran], tmp_path: Path) -> None:
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(one_joint_panda()), encoding="utf-8")
    check_clean(cli("validate", str(path)))


def test_show_a_3d_cell_without_robot(cli: Callable[..., Ran], tmp_path: Path) -> None:
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(ur5_cell_without_robot()), encoding="utf-8")
    assert cli("validate", str(path)).code == 0
    image = tmp_path / "out.png"
    r = cli("show", str(path), "-o", str(image))
    check_clean(r)
    assert image.is_file() == (r.code == 0), r.describe()


# --- what must keep working ---------------------------------------------------------------------

# 2-D by the raw file, independently of the loader: bounds without a z range.
TWO_D = [n for n in scenario_names() if "zmin" not in bundled(n)["workcell"]["bounds"]]
SLOW_TO_SUMMARISE = {
    "strategies_noise",
    "strategies_p2",
    "strategies_p3",
    "strategies_p5",
    "strategies_p6",
}
"""2-D scenarios whose ``validate`` summary takes over a second each (strategies models)."""


def test_every_2d_bundled_scenario_still_loads_as_2d() -> None:
    import cellplan

    for name in TWO_D:
        setup = cellplan.load(name)
        assert not is_3d(setup.scenario), name
        if setup.scenario.robot is not None:
            assert setup.workcell.dimension == 2, name


@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=[pytest.mark.slow] if n in SLOW_TO_SUMMARISE else []) for n in TWO_D],
)
def test_every_2d_bundled_scenario_still_validates(name: str, cli: Callable[..., Ran]) -> None:
    r = cli("validate", name)
    assert r.code == 0 and r.stderr == "", r.describe()
    shown = bundled(name).get("name") or name
    assert f"scenario: {shown}" in r.stdout, r.describe()


def test_schema_describes_2d_and_3d(cli: Callable[..., Ran]) -> None:
    r = cli("schema")
    assert r.code == 0 and r.stderr == "", r.describe()
    schema = json.loads(r.stdout)
    text = json.dumps(schema)
    for word in ("zmin", "zmax", "urdf", "capsule", "cylinder", "mesh", "rpy", "polygon", "disc"):
        assert f'"{word}"' in text, word

"""Fuzzing 3-D scenarios (format 2): mutated ``ur5_cell`` and ``panda_shelf``.

Each case applies one to three mutations aimed at what 3-D files add: solids and poses
(negative, zero, NaN, infinite, huge or boolean sizes and angles, two or four numbers
where three belong, unknown keys, a 2-D shape or another solid kind), the URDF robot
(unknown joint, frame and locked names, another bundled robot, start values outside the
limits or of the wrong count, empty lists, a subset of its own joints), file paths
(missing, a folder, a device, a name too long, a broken, flat or non-URDF file, hostile
text), the bounds (``zmin`` dropped or above ``zmax``), whole sections dropped (a cell
without a robot) and the format version; besides the generic ones (a key dropped, renamed
or retyped, a line duplicated). Each mutant is written next to copies of tests/data/bad3d,
then:

* ``cellplan validate`` (in-process, :func:`fuzz_harness.run_cli`, with the process's
  stderr file descriptor captured too, so a C++ library's message counts) must exit 0
  (stderr empty but for ``note:`` lines) or 2 (every line ``error: FIELD: message``),
  never 70 nor a traceback nor a hang, and write nothing;
* ``cellplan.load(path).workcell`` (the model, without the summary ``validate`` adds)
  must succeed or raise :class:`~cellplan.errors.CellplanError` whose problems each name a
  field; nothing else.

The default run is a few seeded cases per scenario; the ``slow`` run tries
``CELLPLAN_FUZZ_3D_EXAMPLES`` per scenario and records its counts in
``$CELLPLAN_FUZZ_COUNTS`` like the others:

    CELLPLAN_FUZZ_3D_EXAMPLES=300 pytest -m slow tests/fuzz/test_fuzz_3d.py

The slow run finds the bugs tests/test_scenario3d_input.py marks as expected failures
(a file name over 255 characters, a URDF urdfdom rejects, a one-joint arm, ``show``
without a robot) until they are fixed.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import tempfile
import traceback
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from fuzz_harness import FailureLog, Outcome, bad_lines, fuzz_settings, run_cli
from fuzz_mutations import EXTREME_NUMBERS, HOSTILE_NAMES, VALUES
from hypothesis import given
from hypothesis import strategies as st

import cellplan
from cellplan.errors import CellplanError
from cellplan.registry import resolve_scenario_path
from cellplan.scenario import Scenario

SCENARIOS_3D = ["ur5_cell", "panda_shelf"]
FAST_VALIDATE = 10
FAST_MODEL = 40
FAST_SHOW = 4
SLOW_EXAMPLES = int(os.environ.get("CELLPLAN_FUZZ_3D_EXAMPLES", "300"))

DATA = Path(__file__).parent.parent / "data" / "bad3d"
FIXTURES = [
    "broken.urdf",
    "no_links.urdf",
    "missing_mesh.urdf",
    "flat.stl",
    "flat.obj",
    "tetra.obj",
]

# --- vocabularies -------------------------------------------------------------------------------

NUMBERS: list[Any] = [
    *EXTREME_NUMBERS,
    361,
    -361,
    359.999,
    -0.001,
    1e-12,
    0.0,
    2.5,
    -2.5,
    1e4,
]
NUMBER_TEXTS = ["1", "nan", "inf", "-inf", "1e400", "0x10", "1_000", "", "1,5", "one"]
UR5_JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]
JOINT_NAMES = [
    "shoulder_pan_joint",
    "elbow_joint",
    "wrist_3_joint",
    "panda_joint1",
    "panda_joint4",
    "panda_joint8",
    "panda_finger_joint1",
    "panda_finger_joint2",
    "panda_hand_joint",
    "joint1",
    "world_joint",
]
FRAME_NAMES = [
    "tool0",
    "panda_hand",
    "panda_link8",
    "base_link",
    "base",
    "world",
    "universe",
    "ee_link",
    "panda_leftfinger",
    "shoulder_pan_joint",
]
URDF_NAMES = ["ur5", "panda", "UR5", "ur10", "ur5 ", "panda.urdf", "example-robot-data"]
BAD_PATHS = [
    "nowhere.stl",
    "nowhere.urdf",
    ".",
    "..",
    "/",
    "/dev/null",
    "/dev/zero",
    "/proc/self/mem",
    "fixtures",
    "a\x00b",
    "~/x.stl",
    "http://example.com/x.stl",
    "package://ur5_description/x.stl",
    "x" * 4097,
    "x" * 300 + ".stl",
    "broken.urdf",
    "no_links.urdf",
    "missing_mesh.urdf",
    "flat.stl",
    "flat.obj",
    "tetra.obj",
    "TETRA.OBJ",
    "tetra",
    " tetra.obj",
]
SOLIDS: list[dict[str, Any]] = [
    {"type": "box", "size": [0.1, 0.1, 0.1], "pose": {"xyz": [0.5, 0.5, 1.2]}},
    {"type": "cylinder", "radius": 0.05, "length": 0.2, "pose": {"xyz": [0.5, -0.5, 1.2]}},
    {"type": "sphere", "radius": 0.05, "pose": {"xyz": [-0.5, 0.5, 1.2]}},
    {"type": "capsule", "radius": 0.03, "length": 0.1, "pose": {"xyz": [0.5, 0.5, 0.2]}},
    {"type": "mesh", "path": "tetra.obj", "scale": [0.1] * 3, "pose": {"xyz": [0.5, 0.5, 1.2]}},
    {"type": "box", "size": [0.1, 0.1, 0.1], "pose": {"xyz": [0.5, 0.5, 1.2], "rpy": [30, 45, 60]}},
    {"type": "box", "min": [0, 0], "max": [0.1, 0.1]},
    {"type": "disc", "center": [0, 0], "radius": 0.1},
    {"type": "polygon", "points": [[0, 0], [0.1, 0], [0, 0.1]]},
    {"type": "cylinder", "radius": 0.05},
    {"type": "box", "size": [0.1, 0.1, 0.1], "pose": [0.5, 0.5, 1.2]},
    {"type": "torus", "radius": 0.1, "pose": {"xyz": [0.5, 0.5, 1.2]}},
]
KEYS = st.one_of(
    st.sampled_from(
        [
            *("type", "size", "radius", "length", "pose", "xyz", "rpy", "path", "scale"),
            *("urdf", "srdf", "base", "tool", "joints", "locked", "start", "zmin", "zmax"),
        ]
    ),
    st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=8),
    st.integers(-3, 3),
    st.booleans(),
    st.none(),
)

# --- tree helpers -------------------------------------------------------------------------------


def bundled_text(name: str) -> str:
    return resolve_scenario_path(name).read_text(encoding="utf-8")


def tree_paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += tree_paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += tree_paths(v, (*prefix, i))
    return out


def get(node: Any, path: tuple[Any, ...]) -> Any:
    for p in path:
        node = node[p]
    return node


def put(root: Any, path: tuple[Any, ...], value: Any) -> Any:
    if not path:
        return value
    get(root, path[:-1])[path[-1]] = value
    return root


def robot_of(data: Any) -> dict[str, Any] | None:
    robot = data.get("robot") if isinstance(data, dict) else None
    return robot if isinstance(robot, dict) else None


def solid_slots(data: Any) -> list[tuple[Any, ...]]:
    """Where a solid may go: obstacles (new or existing), part shapes, region components."""
    if not isinstance(data, dict):
        return []
    slots: list[tuple[Any, ...]] = []
    cell = data.get("workcell")
    if isinstance(cell, dict) and isinstance(cell.get("obstacles"), dict):
        slots += [("workcell", "obstacles", n) for n in [*cell["obstacles"], "extra"]]
    parts = data.get("parts")
    if isinstance(parts, dict):
        slots += [("parts", n, "shape") for n, part in parts.items() if isinstance(part, dict)]
    for section in ("sources", "destinations"):
        regions = data.get(section)
        if isinstance(regions, dict):
            for name, region in regions.items():
                comps = region.get("components") if isinstance(region, dict) else None
                if isinstance(comps, list):
                    slots += [(section, name, "components", i) for i in range(len(comps))]
    return slots


# --- mutations ----------------------------------------------------------------------------------

KINDS = [
    "number",
    "number",
    "negate",
    "bool",
    "number-text",
    "drop",
    "rename",
    "retype",
    "empty",
    "length",
    "name",
    "name",
    "path",
    "path",
    "solid",
    "solid",
    "bounds",
    "version",
    "robot",
    "robot",
    "sections",
    "many",
]


@st.composite
def mutation_3d(draw: st.DrawFn, data: Any) -> Any:
    """One mutation of the parsed tree (modified in place and returned)."""
    paths = tree_paths(data)
    numeric = [p for p in paths if isinstance(get(data, p), int | float)]
    dicts = [p for p in paths if isinstance(get(data, p), dict) and get(data, p)]
    lists = [p for p in paths if isinstance(get(data, p), list)]
    robot = robot_of(data)
    kind = draw(st.sampled_from(KINDS))

    if kind in ("number", "negate", "bool", "number-text") and numeric:
        path = draw(st.sampled_from(numeric))
        old = get(data, path)
        if kind == "number":
            new: Any = draw(st.one_of(st.sampled_from(NUMBERS), st.floats(), st.integers()))
        elif kind == "negate":
            new = -old if draw(st.booleans()) else old * draw(st.sampled_from([0, -1e6, 1e6]))
        elif kind == "bool":
            new = draw(st.booleans())
        else:
            new = draw(st.sampled_from(NUMBER_TEXTS))
        return put(data, path, new)
    if kind in ("drop", "rename") and dicts:
        node = get(data, draw(st.sampled_from(dicts)))
        key = draw(st.sampled_from(list(node)))
        value = node.pop(key)
        if kind == "rename":
            node[draw(KEYS)] = value
        return data
    if kind == "empty" and (dicts or lists):
        path = draw(st.sampled_from(dicts + lists))
        return put(data, path, type(get(data, path))())
    if kind == "length" and lists:
        node = get(data, draw(st.sampled_from(lists)))
        if node and draw(st.booleans()):
            node.pop()
        else:
            node.append(draw(st.sampled_from([*node[-1:], 0, 0.5, "x", None, [1, 2, 3]])))
        return data
    if kind == "name" and robot is not None:
        target = draw(st.sampled_from(["joints", "tool", "locked", "urdf", "type", "solid-type"]))
        if target == "joints":
            joints = robot.get("joints")
            joints = list(joints) if isinstance(joints, list) else []
            names = st.sampled_from(JOINT_NAMES + HOSTILE_NAMES)
            if joints and draw(st.booleans()):
                joints[draw(st.integers(0, len(joints) - 1))] = draw(names)
            else:
                joints = draw(st.lists(names, min_size=0, max_size=8))
            robot["joints"] = joints
        elif target == "tool":
            robot["tool"] = draw(st.sampled_from(FRAME_NAMES + HOSTILE_NAMES))
        elif target == "locked":
            locked = robot.get("locked")
            locked = dict(locked) if isinstance(locked, dict) else {}
            locked[draw(st.sampled_from(JOINT_NAMES + HOSTILE_NAMES))] = draw(
                st.sampled_from([0, 0.03, -90, 10, 400, math.nan, True, "x"])
            )
            robot["locked"] = locked
        elif target == "urdf":
            robot["urdf"] = draw(st.sampled_from(URDF_NAMES + HOSTILE_NAMES))
        elif target == "type":
            robot["type"] = draw(st.sampled_from(["arm", "point", "translating", "URDF", "sdf"]))
        else:
            slots = solid_slots(data)
            if slots:
                slot = draw(st.sampled_from(slots))
                shape = get(data, slot) if slot[-1] != "extra" else None
                if isinstance(shape, dict):
                    shape["type"] = draw(
                        st.sampled_from(["box", "cylinder", "sphere", "capsule", "mesh", "disc"])
                    )
        return data
    if kind == "path":
        where = draw(st.sampled_from(["urdf", "srdf", "mesh"]))
        bad = draw(st.sampled_from(BAD_PATHS))
        if where in ("urdf", "srdf") and robot is not None:
            robot[where] = bad
        else:
            slots = solid_slots(data)
            if slots:
                solid = {"type": "mesh", "path": bad, "pose": {"xyz": [0.5, 0.5, 1.2]}}
                put(data, draw(st.sampled_from(slots)), solid)
        return data
    if kind == "solid":
        slots = solid_slots(data)
        if slots:
            solid = yaml.safe_load(yaml.safe_dump(draw(st.sampled_from(SOLIDS))))
            if draw(st.booleans()):  # and damage it
                solid = draw(mutation_3d(solid))
            put(data, draw(st.sampled_from(slots)), solid)
        return data
    if kind == "bounds":
        cell = data.get("workcell") if isinstance(data, dict) else None
        bounds = cell.get("bounds") if isinstance(cell, dict) else None
        if isinstance(bounds, dict):
            how = draw(st.sampled_from(["drop-zmin", "drop-zmax", "swap", "equal", "flat"]))
            if how.startswith("drop-"):
                bounds.pop(how[5:], None)
            elif how == "swap":
                bounds["zmin"], bounds["zmax"] = bounds.get("zmax"), bounds.get("zmin")
            elif how == "equal":
                bounds["zmax"] = bounds.get("zmin")
            else:
                bounds["zmax"] = 0.1
        return data
    if kind == "version" and isinstance(data, dict):
        data["cellplan"] = draw(st.sampled_from([1, 3, 0, "2", 2.0, True, None, [2]]))
        return data
    if kind == "robot" and robot is not None:
        field = draw(
            st.sampled_from(
                ["start", "base", "subset", "subset", "srdf", "joints", "locked", "tool"]
            )
        )
        start = robot.get("start")
        if field == "subset" and isinstance(start, list) and start:
            # some of the robot's own joints, in order, with their start values: valid
            # unless the rest, now locked at 0 or their nearest limit, collide
            own = robot.get("joints") if isinstance(robot.get("joints"), list) else UR5_JOINTS
            count = min(len(own), len(start))
            keep = sorted(draw(st.sets(st.integers(0, count - 1), min_size=1, max_size=count)))
            robot["joints"] = [own[i] for i in keep]
            robot["start"] = [start[i] for i in keep]
        elif field == "start":
            robot["start"] = draw(
                st.lists(st.sampled_from([0, -90, 90, 180, -180, 400, 1e9, math.inf]), max_size=9)
            )
        elif field == "base":
            robot["base"] = draw(
                st.sampled_from(
                    [
                        {"xyz": [0, 0, 0.9]},
                        {"xyz": [0.5, 0.05, 0.9]},
                        {"xyz": [5, 5, 5]},
                        {"xyz": [0, 0, 0.755], "rpy": [180, 0, 0]},
                        {"rpy": [0, 90]},
                        [0, 0, 0],
                        {},
                        None,
                    ]
                )
            )
        else:
            robot.pop(field, None)
        return data
    if kind == "sections" and isinstance(data, dict):
        drop = draw(
            st.sampled_from(
                [
                    ("robot", "parts", "sources", "destinations"),
                    ("parts", "sources", "destinations"),
                    ("sources", "destinations"),
                    ("parts",),
                    ("robot",),
                    ("workcell",),
                ]
            )
        )
        for key in drop:
            data.pop(key, None)
        return data
    if kind == "many":
        cell = data.get("workcell") if isinstance(data, dict) else None
        obstacles = cell.get("obstacles") if isinstance(cell, dict) else None
        if isinstance(obstacles, dict) and obstacles:
            key = draw(st.sampled_from(list(obstacles)))
            for i in range(draw(st.sampled_from([50, 500]))):
                obstacles[f"{key}_{i}"] = obstacles[key]
        return data
    # retype (also the fallback when the chosen kind has nothing to act on)
    path = draw(st.sampled_from(paths))
    return put(data, path, draw(VALUES))


def dump(data: Any) -> str:
    try:
        return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=10**6)
    except (yaml.YAMLError, RecursionError, TypeError):
        return yaml.safe_dump({"cellplan": 2}, sort_keys=False)


@st.composite
def mutated_3d(draw: st.DrawFn, name: str) -> bytes:
    """The bytes of a mutated copy of bundled 3-D scenario ``name``."""
    data = yaml.safe_load(bundled_text(name))
    for _ in range(draw(st.sampled_from([1, 1, 1, 2, 2, 3]))):  # mostly one: deeper checks
        data = draw(mutation_3d(data))
    text = dump(data)
    if draw(st.integers(0, 7)) == 0:  # a key given twice (YAML allows it; cellplan must not)
        lines = text.splitlines(keepends=True)
        keyed = [i for i, line in enumerate(lines) if ":" in line]
        if keyed:
            at = draw(st.sampled_from(keyed))
            lines.insert(at, lines[at])
        text = "".join(lines)
    return text.encode("utf-8", "surrogatepass")


# --- running one mutant -------------------------------------------------------------------------

QUIET_WARNINGS = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)


@contextlib.contextmanager
def everything_on_stderr() -> Iterator[list[str]]:
    """Collect what would reach the terminal's stderr besides ``sys.stderr``: writes to
    file descriptor 2 (a C++ library's messages) and the warnings Python would print."""
    found: list[str] = []
    saved = os.dup(2)
    with tempfile.TemporaryFile() as native, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        os.dup2(native.fileno(), 2)
        try:
            yield found
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            native.seek(0)
            text = native.read().decode("utf-8", "replace")
            found += text.splitlines()
            found += [
                f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})"
                for w in caught
                if not issubclass(w.category, QUIET_WARNINGS)
            ]


def top_keys(content: bytes) -> set[str]:
    """The schema's top-level keys and the file's own (where it still parses)."""
    keys = set(Scenario.model_fields)
    try:
        data = yaml.safe_load(content)
    except Exception:  # PyYAML raises plain Python errors on some bad values
        return keys
    if not isinstance(data, dict):
        return keys
    words = {None: "null", True: "true", False: "false"}
    return keys | {words[k] if k is None or isinstance(k, bool) else str(k) for k in data}


def listing(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_size for p in folder.rglob("*")}


def run_mutant(name: str, content: bytes, work: Path, command: str = "validate") -> Outcome:
    """Write the mutant, run ``cellplan COMMAND`` on it, check the answer."""
    path = work / f"{name}.yaml"
    path.write_bytes(content)
    image = work / "shown.png"
    image.unlink(missing_ok=True)
    before = listing(work)
    args = [command, str(path)] + (["-o", str(image)] if command == "show" else [])
    with everything_on_stderr() as extra:
        r = run_cli(args)
    if extra:
        r = Outcome(r.args, r.code, r.stdout, r.stderr + "".join(f"{x}\n" for x in extra))
    case = f"{r.describe()}\nmutant:\n{content.decode('utf-8', 'replace')[:3000]}"
    assert r.code in (0, 2), case
    assert "Traceback" not in r.stdout + r.stderr, case
    if r.code == 2:
        bad = bad_lines(r.stderr, files=[str(path)], roots=top_keys(content))
        assert not bad, f"lines not naming a field: {bad[:5]}\n{case}"
        assert listing(work) == before, f"wrote {set(listing(work)) - set(before)}\n{case}"
    else:
        noise = [line for line in r.stderr.splitlines() if not line.startswith("note: ")]
        assert not noise, case
        after = listing(work)
        if command == "show":
            assert image.is_file(), case
            after.pop(image.name, None)
        assert after == before, f"wrote {set(after) - set(before)}\n{case}"
    return r


def build_mutant(name: str, content: bytes, work: Path) -> None:
    """``cellplan.load(path).workcell``: a model, or one named problem per mistake."""
    path = work / f"{name}-model.yaml"
    path.write_bytes(content)
    case = f"mutant:\n{content.decode('utf-8', 'replace')[:3000]}"
    with everything_on_stderr() as extra:
        try:
            cellplan.load(path).workcell  # noqa: B018 - built on first access
        except CellplanError as exc:
            lines = "".join(f"error: {p}\n" for p in exc.problems)
            assert exc.problems, case
            assert all(p.field and p.message.strip() for p in exc.problems), f"{lines}{case}"
            bad = bad_lines(lines, files=[str(path)], roots=top_keys(content))
            assert not bad, f"problems not naming a field: {bad[:5]}\n{case}"
        except Exception:  # a bug: fail this case (the slow runs log it and go on)
            raise AssertionError(f"{traceback.format_exc()[-3000:]}\n{case}") from None
    assert not extra, f"printed on stderr: {extra[:5]}\n{case}"


# --- the tests ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("fuzz-3d")
    for name in FIXTURES:
        shutil.copy(DATA / name, folder / name)
    (folder / "fixtures").mkdir()
    return folder


@pytest.fixture
def in_work(work: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Run from the work folder, so a stray relative write is seen there."""
    monkeypatch.chdir(work)
    return work


@pytest.mark.parametrize("name", SCENARIOS_3D)
def test_validate_mutated_3d_scenarios(name: str, in_work: Path) -> None:
    @fuzz_settings(FAST_VALIDATE)
    @given(content=mutated_3d(name))
    def check(content: bytes) -> None:
        run_mutant(name, content, in_work)

    check()


@pytest.mark.parametrize("name", SCENARIOS_3D)
def test_model_of_mutated_3d_scenarios(name: str, in_work: Path) -> None:
    @fuzz_settings(FAST_MODEL)
    @given(content=mutated_3d(name))
    def check(content: bytes) -> None:
        build_mutant(name, content, in_work)

    check()


def test_show_mutated_3d_scenarios(in_work: Path) -> None:
    @fuzz_settings(FAST_SHOW)
    @given(content=mutated_3d("ur5_cell"))
    def check(content: bytes) -> None:
        run_mutant("ur5_cell", content, in_work, "show")

    check()


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS_3D)
def test_validate_mutated_3d_scenarios_hundreds(name: str, in_work: Path) -> None:
    log = FailureLog("scenario-3d", name)

    @fuzz_settings(SLOW_EXAMPLES)
    @given(content=mutated_3d(name))
    def check(content: bytes) -> None:
        log.check(lambda: run_mutant(name, content, in_work), content)

    check()
    log.finish()


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS_3D)
def test_model_of_mutated_3d_scenarios_hundreds(name: str, in_work: Path) -> None:
    log = FailureLog("model-3d", name)

    @fuzz_settings(SLOW_EXAMPLES)
    @given(content=mutated_3d(name))
    def check(content: bytes) -> None:
        log.check(lambda: build_mutant(name, content, in_work), content)

    check()
    log.finish()


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENARIOS_3D)
def test_show_mutated_3d_scenarios_dozens(name: str, in_work: Path) -> None:
    log = FailureLog("show-3d", name)

    @fuzz_settings(max(1, SLOW_EXAMPLES // 8))
    @given(content=mutated_3d(name))
    def check(content: bytes) -> None:
        log.check(lambda: run_mutant(name, content, in_work, "show"), content)

    check()
    log.finish()

"""Scenario files: schema, validation messages, round trips."""

from __future__ import annotations

import json

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from cellplan.errors import ScenarioError
from cellplan.registry import resolve_scenario_path, scenario_names
from cellplan.scenario import dump_scenario, json_schema, load_scenario, loads_scenario, parse_yaml

BASE = """
cellplan: 1
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 50, ymax: 40}
  obstacles:
    wall: {type: box, min: [20, 0], max: [24, 20]}
robot: {type: translating, shape: {type: box, min: [-1, -1], max: [1, 1]}, start: [5, 5]}
parts:
  P1: {shape: {type: box, min: [-2, -1], max: [2, 1]}}
sources:
  S1: {components: [{type: box, min: [2, 30], max: [8, 36]}]}
destinations:
  D1: {components: [{type: box, min: [40, 30], max: [46, 36]}]}
"""


def problems(text: str) -> list[str]:
    with pytest.raises(ScenarioError) as err:
        loads_scenario(text)
    return [str(p) for p in err.value.problems]


def edit(path: str, value) -> str:
    data = yaml.safe_load(BASE)
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    node[keys[-1]] = value
    return yaml.safe_dump(data)


def test_base_is_valid():
    sc = loads_scenario(BASE)
    assert sc.robot.type == "translating" and list(sc.parts) == ["P1"]


@pytest.mark.parametrize("name", scenario_names())
def test_bundled_scenarios_round_trip(name):
    sc = load_scenario(name)
    assert loads_scenario(dump_scenario(sc)) == sc
    assert loads_scenario(dump_scenario(sc)).digest() == sc.digest()


boxes = st.tuples(st.floats(0, 40), st.floats(0, 30), st.floats(1, 9), st.floats(1, 9)).map(
    lambda t: {"type": "box", "min": [t[0], t[1]], "max": [t[0] + t[2], t[1] + t[3]]}
)


@st.composite
def scenarios(draw):
    robot = draw(
        st.one_of(
            st.fixed_dictionaries(
                {"type": st.just("point"), "start": st.tuples(st.floats(0, 50), st.floats(0, 40))}
            ),
            st.fixed_dictionaries(
                {
                    "type": st.just("rotating"),
                    "shape": boxes,
                    "start": st.tuples(st.floats(0, 50), st.floats(0, 40), st.floats(-179, 180)),
                }
            ),
            st.fixed_dictionaries(
                {
                    "type": st.just("arm"),
                    "base": st.tuples(st.floats(10, 40), st.floats(10, 30)),
                    "links": st.lists(
                        st.fixed_dictionaries(
                            {"length": st.floats(1, 10), "width": st.floats(0.1, 2)}
                        ),
                        min_size=2,
                        max_size=3,
                    ),
                    "start": st.just([0.0, 0.0, 0.0]),
                }
            ).map(lambda r: {**r, "start": r["start"][: len(r["links"])]}),
        )
    )
    names = draw(st.lists(st.sampled_from(["A", "B", "C", "wall", "x1"]), unique=True, max_size=4))
    return {
        "cellplan": 1,
        "name": draw(st.text(max_size=10)),
        "workcell": {
            "bounds": {"xmin": 0, "ymin": 0, "xmax": 50, "ymax": 40},
            "obstacles": {n: draw(boxes) for n in names},
        },
        "robot": robot,
        "parts": {"P": {"shape": draw(boxes)}},
    }


@given(data=scenarios())
def test_schema_round_trip_is_identity(data):
    sc = loads_scenario(yaml.safe_dump(data))
    again = loads_scenario(dump_scenario(sc))
    assert again == sc
    assert loads_scenario(dump_scenario(again)) == again


def test_yaml_syntax_error_has_line_and_column():
    (msg,) = problems("cellplan: 1\nworkcell: {bounds: [1, 2\n")
    assert msg.startswith("<string>:") and "YAML syntax" in msg
    line, col = msg.split(":")[1:3]
    assert int(line) >= 2 and int(col) >= 1


def test_duplicate_keys_are_rejected():
    (msg,) = problems(BASE + "parts: {}\n")
    assert "duplicate key 'parts'" in msg


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        (
            "workcell.obstacles.wall.colour",
            "red",
            "workcell.obstacles.wall.colour: unknown key (allowed: type, min, max)",
        ),
        ("robot.startt", [1, 1], "robot.startt: unknown key; did you mean 'start'?"),
        ("robot.start", [1, "x"], "robot.start[1]: expected a number (got 'x')"),
        (
            "workcell.bounds",
            [0, 1],
            "workcell.bounds: expected a mapping with xmin, ymin, xmax, ymax (got a list)",
        ),
        ("robot.type", "pont", "robot: unknown type 'pont'; 'type' must be one of 'point', "),
        (
            "workcell.obstacles.wall",
            {"type": "polygon", "points": [[0, 0], [4, 4], [4, 0], [0, 4]]},
            "workcell.obstacles.wall: polygon is self-intersecting",
        ),
        (
            "workcell.obstacles.wall",
            {"type": "polygon", "points": [[0, 0], [1, 1], [2, 2]]},
            "workcell.obstacles.wall: polygon is degenerate (zero area)",
        ),
        (
            "sources.S1.components",
            [{"type": "box", "min": [45, 30], "max": [55, 36]}],
            "sources.S1.components[0]: lies outside the workcell bounds",
        ),
        (
            "workcell.obstacles.wall",
            {"type": "disc", "center": [1, 1], "radius": -2},
            "workcell.obstacles.wall.radius: must be greater than 0 (got -2)",
        ),
        ("cellplan", 3, "cellplan: unsupported format version 3; this cellplan reads 1 and 2"),
    ],
)
def test_each_problem_is_one_line_naming_the_field(path, value, expected):
    found = problems(edit(path, value))
    assert any(p.startswith(expected) for p in found), found
    assert not any("Input should" in p or "instance of" in p for p in found)


def bundled(name: str) -> dict:
    return yaml.safe_load(resolve_scenario_path(name).read_text())


@pytest.mark.parametrize(
    ("name", "change", "expected"),
    [
        (
            "adaptive_fig3",
            lambda d: d["adaptive"].__setitem__("changes", [{"at": 1}]),
            "adaptive.changes[0]: needs a 'type', one of 'add_object', 'remove_object', "
            "'move_object', 'rotate_object', 'add_goal', 'remove_goal'",
        ),
        (
            "adaptive_fig3",
            lambda d: d["adaptive"].__setitem__("changes", [{"type": "add"}]),
            "adaptive.changes[0]: unknown type 'add'; 'type' must be one of 'add_object', ",
        ),
        (
            "ur5_cell",
            lambda d: d["workcell"]["obstacles"]["table"].__setitem__("type", "cube"),
            "workcell.obstacles.table: unknown type 'cube'; 'type' must be one of ",
        ),
        (
            "ur5_cell",
            lambda d: d["workcell"]["obstacles"]["table"].pop("type"),
            "workcell.obstacles.table: needs a 'type', one of ",
        ),
        (
            "strategies_tiny",
            lambda d: d["robot"].pop("type"),
            "robot: needs a 'type', one of 'point', 'translating', 'rotating', 'arm', 'urdf'",
        ),
        (
            "strategies_tiny",
            lambda d: d["workcell"]["obstacles"]["middle"].pop("type"),
            "workcell.obstacles.middle: needs a 'type', one of 'polygon', 'box', 'disc'",
        ),
    ],
)
def test_a_missing_or_unknown_type_lists_the_types_that_exist(name, change, expected):
    """A discriminated union's error names the field and the ``type`` values it accepts,
    never pydantic's "Unable to extract tag using discriminator"."""
    data = bundled(name)
    change(data)
    found = problems(yaml.safe_dump(data))
    assert any(p.startswith(expected) for p in found), found
    assert not any("discriminator" in p or "Input tag" in p for p in found), found


def test_a_3d_solid_lists_the_solids_not_the_planar_shapes():
    data = bundled("ur5_cell")
    data["workcell"]["obstacles"]["table"]["type"] = "cube"
    (line,) = [p for p in problems(yaml.safe_dump(data)) if p.startswith("workcell.obstacles")]
    assert "'cylinder'" in line and "'polygon'" not in line


def test_every_problem_is_reported_at_once():
    data = yaml.safe_load(BASE)
    data["robot"]["colour"] = "red"
    data["workcell"]["bounds"]["xmax"] = "wide"
    data["parts"]["P1"]["shape"]["type"] = "blob"
    msgs = problems(yaml.safe_dump(data))
    assert len(msgs) == 3
    assert any(m.startswith("robot.colour") for m in msgs)
    assert any(m.startswith("workcell.bounds.xmax") for m in msgs)
    assert any(m.startswith("parts.P1.shape") for m in msgs)


def test_arm_joint_limits_and_start_are_checked():
    arm = {
        "type": "arm",
        "links": [{"length": 5, "width": 1}] * 2,
        "start": [0, 200],
        "joint_limits": [[-190, 90], [10, 0]],
    }
    msgs = problems(edit("robot", arm))
    assert "robot.joint_limits[0]: limit -190.0 deg is outside [-180, 180]" in msgs
    assert "robot.joint_limits[1]: lower limit 10.0 is not below upper limit 0.0" in msgs
    assert "robot.start[1]: joint angle 200.0 deg is outside (-180, 180]" in msgs


def test_names_must_be_unique_across_sections():
    data = yaml.safe_load(BASE)
    data["destinations"]["S1"] = data["destinations"].pop("D1")
    assert "destinations.S1: name already used in sources" in problems(yaml.safe_dump(data))


def test_overlapping_components_are_rejected():
    comps = [
        {"type": "box", "min": [2, 30], "max": [8, 36]},
        {"type": "box", "min": [5, 31], "max": [9, 35]},
    ]
    assert (
        "sources.S1.components[1]: overlaps components[0]; components must be disjoint"
        in problems(edit("sources.S1.components", comps))
    )


def test_json_schema_describes_every_section():
    schema = json_schema()
    json.dumps(schema)
    for key in (
        "workcell",
        "robot",
        "parts",
        "sources",
        "destinations",
        "strategy",
        "adaptive",
        "discs",
    ):
        assert key in schema["properties"]


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"\xff\xfe\x00c\x00e", "is not UTF-8 text"),
        ("cellplan: 1\nname: caf\u00e9\n".encode("latin-1"), "is not UTF-8 text"),
        (b"[" * 3000 + b"]" * 3000, "YAML nested too deeply"),
        (b"cellplan: 1\n? [1, 2]\n: 3\n", "a mapping key must be a plain name"),
    ],
)
def test_hostile_files_are_one_line(tmp_path, content, expected):
    path = tmp_path / "bad.yaml"
    path.write_bytes(content)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    (problem,) = err.value.problems
    assert expected in problem.message


def test_huge_files_are_refused_before_reading(tmp_path, monkeypatch):
    import cellplan.scenario as scenario_module

    monkeypatch.setattr(scenario_module, "MAX_FILE_BYTES", 100)
    path = tmp_path / "big.yaml"
    path.write_text("cellplan: 1\n" + "# padding\n" * 20)
    with pytest.raises(ScenarioError, match="scenario files are limited"):
        load_scenario(path)


def test_schema_describes_every_field():
    schema = json_schema()
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$id"].startswith("urn:cellplan:scenario:")
    assert "cellplan schema" not in schema["description"]
    models = {"Scenario": schema, **schema["$defs"]}
    undocumented = [
        f"{model}.{prop}"
        for model, body in models.items()
        for prop, spec in body.get("properties", {}).items()
        if not spec.get("description")
    ]
    assert undocumented == []
    cells = schema["$defs"]["StrategySection"]["properties"]["cells"]["description"]
    assert "128 x 128" in cells


def test_a_bad_character_is_located_in_characters_not_bytes():
    # libyaml reports a byte offset; the two-byte "é" before it must not shift the column.
    with pytest.raises(ScenarioError) as err:
        parse_yaml("cellplan: 1\nname: caf\u00e9 \x07\n", "f.yaml")
    (problem,) = err.value.problems
    assert problem.field == "f.yaml:2:12"
    assert "U+0007" in problem.message


def test_nesting_is_refused_before_composing():
    import cellplan.scenario as scenario_module

    deep = "[" * (scenario_module.MAX_YAML_DEPTH + 1) + "]" * (scenario_module.MAX_YAML_DEPTH + 1)
    with pytest.raises(ScenarioError, match="nested too deeply"):
        parse_yaml(deep, "f.yaml")
    ok = "[" * scenario_module.MAX_YAML_DEPTH + "]" * scenario_module.MAX_YAML_DEPTH
    assert parse_yaml(ok, "f.yaml") is not None


# --- issue 36: strict numbers, merge keys -----------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("xmax: 50", "xmax: true", "workcell.bounds.xmax"),
        ("min: [20, 0]", "min: [20, false]", "workcell.obstacles.wall.min[1]"),
        ("start: [5, 5]", "start: [true, 5]", "robot.start[0]"),
    ],
)
def test_a_boolean_is_not_a_number(old, new, field):
    assert problems(BASE.replace(old, new)) == [f"{field}: expected a number, not true or false"]


@pytest.mark.parametrize("version", ["true", "1.0", "'1'"])
def test_format_version_is_the_integer_1(version):
    (line,) = problems(BASE.replace("cellplan: 1", f"cellplan: {version}"))
    assert line.startswith("cellplan: unsupported format version")


def test_every_section_refuses_booleans_as_numbers():
    """The check lives in StrictModel, so package sections get it too (not per field)."""
    tiny = resolve_scenario_path("strategies_tiny").read_text(encoding="utf-8")
    for old, new in [("speed: 2.5", "speed: true"), ("cells: [12, 12]", "cells: [12, true]")]:
        (line,) = problems(tiny.replace(old, new))
        assert line.endswith("expected a number, not true or false")


MERGED = """
cellplan: 1
box: &box {type: box, min: [2, 30], max: [8, 36]}
workcell:
  bounds: {xmin: 0, ymin: 0, xmax: 50, ymax: 40}
  obstacles:
    wall: {<<: *box, min: [20, 0], max: [24, 20]}
robot: {type: translating, shape: {<<: *box, min: [-1, -1], max: [1, 1]}, start: [5, 5]}
parts:
  P1: {shape: {<<: [{min: [-2, -1]}, *box], max: [2, 1]}}
sources:
  S1: {components: [*box]}
destinations:
  D1: {components: [{<<: *box, min: [40, 30], max: [46, 36]}]}
"""


def test_merge_keys_load_equal_to_the_expanded_file():
    data = parse_yaml(MERGED)
    del data["box"]  # the anchor's holder is not a scenario key
    assert data == parse_yaml(BASE)
    # explicit keys override merged ones; of several merged mappings the first wins
    assert data["parts"]["P1"]["shape"] == {"type": "box", "min": [-2, -1], "max": [2, 1]}


def test_merged_keys_may_be_overridden_but_explicit_ones_not_repeated():
    assert parse_yaml("b: &b {x: 1}\nm: {<<: *b, x: 2}\n")["m"] == {"x": 2}
    with pytest.raises(ScenarioError, match="duplicate key 'x'"):
        parse_yaml("b: &b {x: 1}\nm: {<<: *b, x: 2, x: 3}\n")
    with pytest.raises(ScenarioError, match="duplicate key '<<'"):
        parse_yaml("b: &b {x: 1}\nm: {<<: *b, <<: *b}\n")


@pytest.mark.parametrize("value", ["3", "[1, 2]", "[{x: 1}, text]", "null"])
def test_a_merge_of_something_else_than_mappings_is_one_line_naming_it(value):
    with pytest.raises(ScenarioError) as err:
        parse_yaml(f"m: {{<<: {value}}}\n")
    (problem,) = err.value.problems
    assert "merge key (<<)" in problem.message and "\n" not in str(problem)


def test_merge_limits_hold():
    with pytest.raises(ScenarioError, match="into itself"):
        parse_yaml("m: &r {<<: *r}\n")
    chain = ["a0: &a0 {k0: 1}"] + [
        f"a{i}: &a{i} {{<<: *a{i - 1}, k{i}: 1}}" for i in range(1, 2000)
    ]
    with pytest.raises(ScenarioError, match="expand to more than"):
        parse_yaml("\n".join(chain))

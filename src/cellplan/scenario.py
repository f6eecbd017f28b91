"""Scenario files: load, validate, dump, and describe (JSON Schema).

A scenario is a versioned YAML file (``cellplan: 1``). The core sections
(``workcell``, ``robot``, ``parts``, ``sources``, ``destinations``, ``cspace``)
are defined here in :class:`ScenarioBase`; each registered package
(:func:`cellplan.registry.packages`) contributes one optional section, and
:class:`Scenario` is built from the base and those sections when this module is
first imported. Loading a file imports only the section models, never planner code.

Validation happens in three layers, each reporting *every* problem it finds as
one line naming the field:

1. YAML syntax (with line and column) and duplicate keys;
2. the schema (types, unknown keys, ranges, polygon simplicity), by pydantic;
3. cross-references (names used before being defined, dimensions, joint limits,
   regions inside the bounds), by :func:`check_references` and each section's
   ``check(scenario)`` method.

Geometric consistency that needs collision checks (a start configuration in
collision, say) is checked when the model is built, in
:meth:`cellplan.workcell.Workcell.from_scenario`.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import math
import re
import types
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union, get_args, get_origin

import numpy as np
import shapely
import yaml
from pydantic import (
    BaseModel,
    Discriminator,
    Field,
    SerializerFunctionWrapHandler,
    Tag,
    ValidationError,
    create_model,
    model_serializer,
)

from cellplan.errors import Problem, ScenarioError
from cellplan.scenario3d import (
    UNION_CHOOSERS,
    UNION_TAGS,
    AnyShape,
    RobotMotion,
    UrdfRobotSpec,
    Workcell3DSpec,
    check_references_3d,
    is_3d,
    planar,
    planar_workcell,
    shape_dimension,
    workcell_dimension,
)
from cellplan.schema import (
    NAME_PATTERN,
    Bounds,
    Cells,
    Coord,
    Length,
    Name,
    Shape,
    StrictModel,
    Vec2,
)

# ``Scenario`` itself is left out of ``__all__``: it is built when this module is imported
# (ScenarioBase plus the registered sections), so its documentation is ScenarioBase's.
__all__ = [
    "MAX_FILE_BYTES",
    "MAX_NAMED",
    "MAX_YAML_NODES",
    "SCHEMA_ID",
    "SCHEMA_VERSION",
    "ArmRobotSpec",
    "CSpaceSpec",
    "LinkSpec",
    "PartSpec",
    "PointRobotSpec",
    "RegionSpec",
    "RobotSpec",
    "RotatingRobotSpec",
    "ScenarioBase",
    "TranslatingRobotSpec",
    "WorkcellSpec",
    "build_scenario_model",
    "check_references",
    "dump_scenario",
    "format_location",
    "json_schema",
    "load_scenario",
    "loads_scenario",
    "parse_yaml",
    "problems_from_validation",
    "robot_dimension",
    "scenario_from_data",
    "section_keys",
]

SCHEMA_VERSION = 2
"""The format version cellplan writes. Version 2 added 3-D cells and URDF robots
(:mod:`cellplan.scenario3d`); every version-1 file reads unchanged."""
SCHEMA_VERSIONS = (1, 2)
"""The format versions cellplan reads."""

MAX_FILE_BYTES = 10_000_000
"""Largest scenario file read; a workcell description is kilobytes, so more is a mistake."""


# --- core sections ---------------------------------------------------------------------------


class WorkcellSpec(StrictModel):
    """Rectangular bounds and named static obstacles."""

    bounds: Bounds = Field(
        description="the rectangle the robot stays in (workcell units)",
        examples=[{"xmin": 0, "ymin": 0, "xmax": 100, "ymax": 100}],
    )
    obstacles: dict[Name, AnyShape] = Field(
        default_factory=dict,
        max_length=100_000,
        description="static obstacles by name (box, polygon or disc, workcell units)",
        examples=[{"wall": {"type": "box", "min": [20, 0], "max": [24, 20]}}],
    )

    @property
    def planar_obstacles(self) -> dict[str, Shape]:
        """The obstacles typed as 2-D shapes (validation keeps solids out of 2-D cells)."""
        return {name: planar(shape) for name, shape in self.obstacles.items()}


class PointRobotSpec(RobotMotion):
    """A point robot; C = R^2."""

    type: Literal["point"] = Field(description="robot kind")
    start: Vec2 = Field(description="start position (workcell units)", examples=[[15, 8]])


class TranslatingRobotSpec(RobotMotion):
    """A rigid body that translates only; C = R^2. ``shape`` is in the robot frame."""

    type: Literal["translating"] = Field(description="robot kind")
    shape: Shape = Field(
        description="the body in its own frame (workcell units)",
        examples=[{"type": "box", "min": [-1, -1], "max": [1, 1]}],
    )
    start: Vec2 = Field(description="start position of the frame origin", examples=[[15, 8]])


class RotatingRobotSpec(RobotMotion):
    """A rigid body that translates and rotates; C = R^2 x S^1.

    ``start`` is ``(x, y, theta)`` with theta in degrees. The robot's axis of
    orientation (the direction it moves along in problem 3 of the strategies
    paper) is the +x axis of its frame.
    """

    type: Literal["rotating"] = Field(description="robot kind")
    shape: Shape = Field(
        description="the body in its own frame (workcell units); its axis is +x",
        examples=[{"type": "box", "min": [-3, -0.5], "max": [3, 0.5]}],
    )
    start: tuple[Coord, Coord, float] = Field(
        description="start (x, y, theta): position in workcell units, theta in degrees",
        examples=[[20, 10, 90]],
    )


class LinkSpec(StrictModel):
    """One link of a planar arm: a rectangle from its joint, ``length`` long, ``width`` wide;
    or a capsule, that rectangle with round end caps (discs of diameter ``width`` centred
    on the link's two joints)."""

    length: Length
    """joint-to-joint length (workcell units)"""
    width: Length
    """link width, the caps' diameter for capsules (workcell units)"""
    shape: Literal["rectangle", "capsule"] = "rectangle"
    """rectangle, or capsule (round end caps)"""

    @model_serializer(mode="wrap")
    def _omit_default_shape(self, handler: SerializerFunctionWrapHandler) -> Any:
        # A rectangle link dumps as before the shape field existed, so digests of
        # existing scenarios (saved strategies, experience databases) do not change.
        data = handler(self)
        if isinstance(data, dict) and data.get("shape") == "rectangle":
            data.pop("shape")
        return data


#: Most links of an arm: a C-space grid over more axes has at least 2^100 cells, beyond
#: any memory, and its estimates need integers past a float's range (issue 36).
MAX_LINKS = 100


class ArmRobotSpec(RobotMotion):
    """A planar n-link revolute chain; C = the joint angles.

    Angles are in degrees. Joint i is measured relative to link i-1 (joint 1 from
    the world +x axis). ``joint_limits`` default to the full circle (-180, 180],
    making that joint periodic. ``end_effector_orientation``, when given, holds
    the gripper frame at that fixed world orientation (problem 5 of the
    strategies paper); otherwise the gripper frame follows the last link.
    """

    type: Literal["arm"]
    """robot kind"""
    base: Vec2 = (0.0, 0.0)
    """position of joint 1 (workcell units)"""
    links: list[LinkSpec] = Field(min_length=1, max_length=MAX_LINKS)
    """the links, from the base"""
    joint_limits: list[tuple[float, float]] | None = None
    """per joint (lower, upper) in degrees (default: full turn, periodic)"""
    end_effector_orientation: float | None = None
    """hold the gripper at this world orientation, degrees (problem 5)"""
    start: list[float]
    """start joint angles, degrees"""


RobotSpec = Annotated[
    PointRobotSpec | TranslatingRobotSpec | RotatingRobotSpec | ArmRobotSpec | UrdfRobotSpec,
    Field(discriminator="type"),
]


class PartSpec(StrictModel):
    """A part's shape in the gripper frame; while carried it moves rigidly with the gripper."""

    shape: AnyShape = Field(
        description="the part in the gripper frame (workcell units; a solid in a 3-D cell)",
        examples=[{"type": "box", "min": [-2, -0.5], "max": [2, 0.5]}],
    )


class RegionSpec(StrictModel):
    """A source or destination: one or more disjoint components."""

    components: list[AnyShape] = Field(
        min_length=1,
        max_length=1000,
        description="disjoint shapes (workcell units; solids in a 3-D cell); a part may be "
        "picked or placed at any",
        examples=[[{"type": "box", "min": [2, 2], "max": [6, 5]}]],
    )


class CSpaceSpec(StrictModel):
    """Default configuration-space resolution (cells per axis) for bitmaps and reports."""

    cells: list[Cells] | None = Field(
        default=None,
        description="cells per C-space axis (default: 128 x 128 point and translating robots, "
        "64 x 64 x 32 rotating, 64 per arm joint)",
        examples=[[100, 100]],
    )


# --- the scenario ----------------------------------------------------------------------------


MAX_NAMED = 100
"""Most parts, most sources and most destinations a scenario may name. The paper's
problems use at most 6, 4 and 4; each source is an obstacle in every other source's free
space (equations (1)-(2)), so checking a file costs the square of the number of sources
(5,000 copies of a source kept ``validate`` busy for over 5 minutes; 100 take 4 s)."""


class ScenarioBase(StrictModel):
    """A cellplan scenario: a workcell, what moves in it, and each planner's settings.

    Lengths are in the workcell's own unit; angles are in degrees. The registered
    packages' sections (``strategy:``, ``adaptive:``, ``discs:`` ...) are added as
    optional fields by :func:`build_scenario_model`.
    """

    cellplan: Literal[1, 2] = Field(
        description="scenario format version (2 for 3-D cells)", examples=[2]
    )
    name: str = Field(default="", max_length=200, description="short name", examples=["my-cell"])
    description: str = Field(
        default="", max_length=10_000, description="what the scenario shows (free text)"
    )
    workcell: Annotated[
        Annotated[WorkcellSpec, Tag("2d")] | Annotated[Workcell3DSpec, Tag("3d")],
        Discriminator(workcell_dimension),
    ] = Field(description="bounds and static obstacles (3-D when the bounds name zmin, zmax)")
    robot: RobotSpec | None = Field(
        default=None,
        description="the robot: point, translating, rotating, a planar arm, or a URDF arm "
        "in a 3-D cell (angles in degrees); none for disc assembly",
    )
    parts: dict[Name, PartSpec] = Field(
        default_factory=dict,
        max_length=MAX_NAMED,
        description="parts by name, in the gripper frame",
    )
    sources: dict[Name, RegionSpec] = Field(
        default_factory=dict,
        max_length=MAX_NAMED,
        description="regions where parts are picked up, by name",
    )
    destinations: dict[Name, RegionSpec] = Field(
        default_factory=dict,
        max_length=MAX_NAMED,
        description="regions where parts are delivered, by name",
    )
    cspace: CSpaceSpec = Field(
        default_factory=CSpaceSpec,
        description="configuration-space resolution of bitmaps",
    )

    if TYPE_CHECKING:
        # Package sections are fields of the built model; to the type checker they are Any.
        def __getattr__(self, name: str) -> Any: ...

    def digest(self) -> str:
        """SHA-256 of the canonical JSON form; identifies a scenario in saved artefacts."""
        canonical = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()

    def section_names(self) -> list[str]:
        """Names of the package sections present in this scenario."""
        return [n for n in section_keys() if getattr(self, n, None) is not None]


def section_keys() -> list[str]:
    """Keys of the registered packages' scenario sections, in registry order."""
    from cellplan.registry import sections

    return list(sections())


def build_scenario_model() -> type[ScenarioBase]:
    """:class:`ScenarioBase` plus one optional field per registered package section."""
    from cellplan.registry import packages

    fields: dict[str, Any] = {}
    for pkg in packages().values():
        if pkg.section is not None and pkg.section_model is not None:
            fields[pkg.section] = (
                pkg.section_model | None,
                Field(default=None, description=f"{pkg.name}: {pkg.title}"),
            )
    return create_model("Scenario", __base__=ScenarioBase, __doc__=ScenarioBase.__doc__, **fields)


if TYPE_CHECKING:
    Scenario = ScenarioBase
else:
    Scenario = build_scenario_model()


# --- loading ---------------------------------------------------------------------------------


MAX_YAML_NODES = 1_000_000
"""Most YAML values (scalars, lists, mappings, aliases) a scenario file may hold, and most
values its aliases may expand to: a bound on the work of validating any file."""


MAX_YAML_DEPTH = 64
"""Deepest nesting of lists and mappings a scenario file may have (a scenario needs about 8);
it keeps the composer's recursion, in C or in Python, far from any stack limit."""

# libyaml's parser and composer are about 3x faster than the pure-Python ones on large
# files (60,000 obstacles: 40 s of a 59 s validate were the Python scanner); construction,
# where the checks below live, is Python in both.
_BaseLoader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


_MERGE_TAG = "tag:yaml.org,2002:merge"
_MERGE_VALUE = "a merge key (<<) takes a mapping (*name) or a list of mappings"
#: A mapping's entries by constructed key: (key node, value node).
_Pairs = dict[Any, tuple[yaml.Node, yaml.Node]]


class _UniqueKeyLoader(_BaseLoader):
    """Safe loader that rejects duplicate mapping keys instead of keeping the last one,
    and expands merge keys (``<<``) within the same limits as aliases.

    :func:`parse_yaml` first counts the file's values and depth on the event stream (see
    :func:`_check_size`), so composing never starts on a file beyond the limits.
    """

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        # Each mapping's entries with its merges expanded, by node (nodes never change),
        # and how many entries all expansions made: a chain of merges could otherwise
        # build far more than MAX_YAML_NODES entries before the size check sees them.
        self.merged: dict[int, _Pairs] = {}
        self.merged_entries = 0


_TOO_DEEP = f"YAML nested too deeply (more than {MAX_YAML_DEPTH} levels)"
_OPEN = (yaml.MappingStartEvent, yaml.SequenceStartEvent)
_CLOSE = (yaml.MappingEndEvent, yaml.SequenceEndEvent)
_VALUE = (yaml.ScalarEvent, yaml.AliasEvent, *_OPEN)


def _check_size(text: str, source: str) -> None:
    """Refuse a file past :data:`MAX_YAML_NODES` values or :data:`MAX_YAML_DEPTH` levels.

    The event stream is produced one event at a time without recursion, so this bounds
    the work and memory of any file before a node tree is built.
    """
    nodes = depth = 0
    for event in yaml.parse(text, Loader=_UniqueKeyLoader):
        reason = ""
        if isinstance(event, _VALUE):
            nodes += 1
            if nodes > MAX_YAML_NODES:
                reason = f"more than {MAX_YAML_NODES:,} values; a scenario holds far fewer"
        if isinstance(event, _OPEN):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                reason = _TOO_DEEP
        elif isinstance(event, _CLOSE):
            depth -= 1
        if reason:
            mark = event.start_mark
            where = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark else source
            raise ScenarioError([Problem(where, reason)])


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> Any:
    """A mapping whose keys are plain names, each written once, with merge keys expanded.

    A merge key (``<<: *base`` or ``<<: [*a, *b]``, YAML 1.1) copies the keys of the
    mappings it names, as YAML specifies: a key written in the mapping itself overrides
    a merged one, and of several merged mappings the first that has a key wins. Only keys
    written twice in one mapping (``<<`` included) are duplicates; overriding a merged key
    is the point of merging. The nodes are never changed, so an anchor merged in one place
    reads the same everywhere else.
    """
    pairs = _merged_pairs(loader, node, deep, ())
    return {key: loader.construct_object(value, deep=deep) for key, (_, value) in pairs.items()}


def _merged_pairs(
    loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool, open_nodes: tuple[int, ...]
) -> _Pairs:
    """``node``'s entries by constructed key, merges expanded (once per node, each level
    holding one entry per distinct key however often its sources are repeated)."""
    if id(node) in loader.merged:
        return loader.merged[id(node)]
    if id(node) in open_nodes:
        raise yaml.constructor.ConstructorError(
            None, None, "a merge key (<<) merges a mapping into itself", node.start_mark
        )
    explicit: _Pairs = {}
    merge_key: yaml.Node | None = None
    sources: list[yaml.MappingNode] = []
    for key_node, value_node in node.value:
        if key_node.tag == _MERGE_TAG:
            if merge_key is not None:
                raise yaml.constructor.ConstructorError(
                    None, None, "duplicate key '<<'", key_node.start_mark
                )
            merge_key = key_node
            items = value_node.value if isinstance(value_node, yaml.SequenceNode) else [value_node]
            for item in items:
                if not isinstance(item, yaml.MappingNode):
                    raise yaml.constructor.ConstructorError(
                        None, None, f"{_MERGE_VALUE}, not a {item.id}", item.start_mark
                    )
                sources.append(item)
            continue
        key = loader.construct_object(key_node, deep=deep)
        if not isinstance(key, str | int | float | bool) and key is not None:
            raise yaml.constructor.ConstructorError(
                None,
                None,
                "a mapping key must be a plain name, not a list or mapping",
                key_node.start_mark,
            )
        if key in explicit:
            mark = key_node.start_mark
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", mark)
        explicit[key] = (key_node, value_node)
    if not sources:
        return explicit
    pairs: _Pairs = {}
    # Later sources first, so that earlier ones (then the explicit keys) overwrite them.
    for source in reversed(sources):
        pairs.update(_merged_pairs(loader, source, deep, (*open_nodes, id(node))))
    pairs.update(explicit)
    loader.merged_entries += len(pairs)
    if loader.merged_entries > MAX_YAML_NODES:
        raise yaml.constructor.ConstructorError(
            None,
            None,
            f"its merge keys (<<) expand to more than {MAX_YAML_NODES:,} values",
            merge_key.start_mark if merge_key is not None else node.start_mark,
        )
    loader.merged[id(node)] = pairs
    return pairs


_UniqueKeyLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
    _construct_mapping,
)


def _strict_scalar(construct: Any) -> Any:
    """A scalar constructor whose bad values are YAML errors with a position.

    PyYAML's own raise whatever Python raises: ``!!int abc`` a ValueError, ``!!bool
    maybe`` a KeyError, ``!!timestamp 2001-13-45`` a ValueError, ``!!timestamp ''`` an
    AttributeError.
    """

    def strict(loader: _UniqueKeyLoader, node: yaml.Node) -> Any:
        try:
            return construct(loader, node)
        except yaml.YAMLError:
            raise
        except (ValueError, TypeError, AttributeError, KeyError, IndexError, OverflowError):
            value = _one_line(node.value)
            shown = value if len(value) <= 40 else value[:37] + "..."
            tag = node.tag.rsplit(":", 1)[-1]
            reason = f"{shown!r} is not a valid !!{tag} value"
            raise yaml.constructor.ConstructorError(None, None, reason, node.start_mark) from None

    return strict


for _kind in ("null", "bool", "int", "float", "binary", "timestamp", "str"):
    _tag = f"tag:yaml.org,2002:{_kind}"
    _UniqueKeyLoader.add_constructor(_tag, _strict_scalar(_UniqueKeyLoader.yaml_constructors[_tag]))


def parse_yaml(text: str, source: str = "<string>") -> Any:
    """Parse YAML safely; syntax errors become a :class:`ScenarioError` with line and column."""
    try:
        text.encode()
    except UnicodeEncodeError as exc:  # a str with lone surrogates (never read from a file)
        raise ScenarioError(
            [Problem(source, f"is not valid Unicode text ({exc.reason})")]
        ) from None
    try:
        _check_size(text, source)
        data = yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark else source
        problem = _one_line(exc.problem or exc)
        # libyaml >= 0.2.6 (PyYAML 6.0.4's wheels) stops at its own depth limit while
        # scanning ahead, before _check_size sees the events; say it the same way.
        if "maximum nesting depth" in problem:
            problem = _TOO_DEEP
        else:
            problem = f"YAML syntax: {problem}"
        raise ScenarioError([Problem(where, problem)]) from None
    except yaml.reader.ReaderError as exc:
        position = exc.position
        if _BaseLoader is not yaml.SafeLoader:  # libyaml counts UTF-8 bytes
            position = len(text.encode()[:position].decode(errors="ignore"))
        line = text.count("\n", 0, position) + 1
        column = position - (text.rfind("\n", 0, position) + 1) + 1
        code = exc.character if isinstance(exc.character, int) else ord(exc.character)
        raise ScenarioError(
            [
                Problem(
                    f"{source}:{line}:{column}",
                    f"YAML syntax: character U+{code:04X} is not allowed in YAML text",
                )
            ]
        ) from None
    except yaml.YAMLError as exc:
        raise ScenarioError([Problem(source, f"YAML syntax: {_one_line(exc)}")]) from None
    except RecursionError:
        raise ScenarioError([Problem(source, "YAML nested too deeply")]) from None
    if _expanded_size(data, {}) > MAX_YAML_NODES:
        # Aliases share one parsed node, but validation walks every use of it.
        raise ScenarioError(
            [
                Problem(
                    source,
                    f"its aliases (*name) expand to more than {MAX_YAML_NODES:,} values",
                )
            ]
        )
    return data


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _expanded_size(node: Any, memo: dict[int, int]) -> int:
    """Values in ``node`` with every alias expanded (shared nodes counted once per use).

    Capped just above :data:`MAX_YAML_NODES`, and recursive structures (which the safe
    loader refuses) would be counted as their first visit.
    """
    if not isinstance(node, dict | list):
        return 1
    key = id(node)
    if key in memo:
        return memo[key]
    memo[key] = 1  # a back-reference while counting (recursive data) counts as one
    total = 1
    for child in node.values() if isinstance(node, dict) else node:
        total += _expanded_size(child, memo)
        if total > MAX_YAML_NODES:
            break
    memo[key] = total
    return total


def format_location(loc: Iterable[Any], data: Any) -> str:
    """Turn a pydantic error location into ``a.b[0].c``, dropping union tags.

    Discriminated unions add the tag (``translating``) to the location although it
    is not a key of the input; walking the input data tells the two apart.
    """
    parts: list[str] = []
    node = data
    loc = list(loc)
    for pos, item in enumerate(loc):
        if item == "[key]":
            continue  # the key itself is wrong; the path already ends with it
        if isinstance(node, dict) and node.get("type") == item and pos + 1 < len(loc):
            continue  # a union's tag, even where a key has the same name (robot.urdf)
        same = _keys_matching(node, item) if isinstance(node, dict) else []
        if same:
            # pydantic reports a key true as 1 and a key null as 'None': name it as written
            written = next((k for k in same if type(k) is type(item)), same[0])
            parts.append(_key_text(written))
            node = node[written]
        elif isinstance(node, list) and isinstance(item, int) and 0 <= item < len(node):
            parts.append(f"[{item}]")
            node = node[item]
        elif isinstance(node, dict | list):
            # A tag of a union, or a missing key (then it is the field that is missing).
            if isinstance(item, str) and not _is_union_tag(item, node):
                parts.append(item)
                node = None
        elif not (isinstance(item, str) and _is_union_tag(item, node)):
            parts.append(str(item))
    return ".".join(parts).replace(".[", "[")


def _keys_matching(node: dict[Any, Any], item: Any) -> list[Any]:
    """The keys of ``node`` that a location item stands for (``'None'`` for a null key)."""
    same = [k for k in node if k == item]
    return same or [k for k in node if not isinstance(k, str) and str(k) == item]


def _key_text(key: Any) -> str:
    """A mapping key as a path segment: as written when it is a plain name (``null``,
    ``true`` for YAML's), quoted (``['a b']``) otherwise, so the path stays one token."""
    if key is None:
        text = "null"
    elif isinstance(key, bool):
        text = "true" if key else "false"
    else:
        text = str(key)
    return text if re.fullmatch(r"[A-Za-z0-9_.\-]+", text) else f"[{text!r}]"


def _is_union_tag(item: str, node: Any) -> bool:
    """Whether a location item names a union member rather than a key: a shape's ``type``,
    a validator wrapper, a member type (``list[RequestSpec]``, ``literal['all']``) or a
    model class (``RandomTasks``; every field name is lower case)."""
    return (
        (isinstance(node, dict) and node.get("type") == item)
        or item in {"function-after", "function-before", "tagged-union", *UNION_TAGS}
        or "[" in item
        or (item[:1].isupper() and item.isidentifier())
    )


def problems_from_validation(
    exc: ValidationError, data: Any, root: type[BaseModel] | None = None
) -> list[Problem]:
    """One :class:`Problem` per pydantic error, with readable field paths and messages.

    Messages say what is expected in the file's terms (``expected a mapping with xmin,
    ymin, xmax, ymax``), never pydantic's class names; an unknown key gets a "did you
    mean" when a close name is allowed there.
    """
    root = Scenario if root is None else root
    errors = exc.errors(include_url=False)
    fields = [format_location(err["loc"], data) for err in errors]
    # In a union such as 'all' | [requests], the member the value's type chose says what
    # is wrong; the literal member's "must be 'all'" would only add noise.
    chosen = {f for f, err in zip(fields, errors, strict=True) if err["type"] != "literal_error"}
    problems = []
    for field, err in zip(fields, errors, strict=True):
        if (
            err["type"] == "literal_error"
            and not isinstance(err.get("input"), str)
            and any(f == field or f.startswith((field + ".", field + "[")) for f in chosen)
        ):
            continue
        problems.append(Problem(field, _message(err, data, root)))
    return list(dict.fromkeys(problems))  # both members of a union may say the same


_EXPECTED = {
    "list_type": "expected a list",
    "tuple_type": "expected a list",
    "float_type": "expected a number",
    "float_parsing": "expected a number",
    "int_type": "expected a whole number",
    "int_parsing": "expected a whole number",
    "int_from_float": "expected a whole number",
    "string_type": "expected text",
    "bool_type": "expected true or false",
    "bool_parsing": "expected true or false",
    "finite_number": "expected a finite number",
    "missing": "missing (required)",
    "invalid_key": "a key must be text",
}


def _message(err: Any, data: Any, root: type[BaseModel]) -> str:
    kind, msg, loc = err["type"], err["msg"], tuple(err["loc"])
    if kind == "extra_forbidden":
        model = _model_at(loc[:-1], data, root)
        allowed = list(model.model_fields) if model is not None else []
        close = difflib.get_close_matches(str(loc[-1]), allowed, n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        return f"unknown key{hint}" + (f" (allowed: {', '.join(allowed)})" if allowed else "")
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        model = _model_at(loc, data, root)
        if model is not None:
            return f"expected a mapping with {', '.join(model.model_fields)}{_got(err)}"
        return f"expected a mapping{_got(err)}"
    if kind == "string_pattern_mismatch" and err.get("ctx", {}).get("pattern") == NAME_PATTERN:
        return f"a name may hold only letters, digits, '_', '.' and '-'{_got(err)}"
    if kind == "missing" and loc and isinstance(loc[-1], int):
        given = err.get("input")
        count = f"{len(given)} value(s)" if isinstance(given, list | tuple) else "too few values"
        return f"has {count}; at least {loc[-1] + 1} are needed"
    if kind == "union_tag_not_found":
        tags = _tags(_annotation_at(loc, data, root), _node_at(loc, data))
        if tags:
            return f"needs a 'type', one of {', '.join(repr(t) for t in tags)}"
        return "needs a 'type'"
    if kind == "too_short":
        ctx = err.get("ctx", {})
        return f"needs at least {ctx.get('min_length')} item(s), got {ctx.get('actual_length')}"
    if kind == "string_too_long":
        ctx = err.get("ctx", {})
        n = len(err["input"]) if isinstance(err.get("input"), str) else "more"
        return f"has {n} characters; at most {ctx.get('max_length')} allowed"
    if kind == "union_tag_invalid":
        ctx = err.get("ctx", {})
        tags = _tags(_annotation_at(loc, data, root), _node_at(loc, data))
        expected = ", ".join(repr(t) for t in tags) if tags else ctx.get("expected_tags")
        return f"unknown type {ctx.get('tag')!r}; 'type' must be one of {expected}"
    if kind == "too_long":
        ctx = err.get("ctx", {})
        n = ctx.get("actual_length")
        if n is None and hasattr(err.get("input"), "__len__"):
            n = len(err["input"])  # pydantic leaves it out for mappings
        return f"has {n:,} items; at most {ctx.get('max_length'):,} allowed"
    if kind in _EXPECTED:
        return _EXPECTED[kind] + ("" if kind == "missing" else _got(err))
    for prefix in ("Value error, ", "Assertion failed, "):
        msg = msg.removeprefix(prefix)
    if msg.startswith("Input should be "):
        msg = "must be " + msg[len("Input should be ") :] + _got(err)
    return msg


def _got(err: Any) -> str:
    value = err.get("input")
    if isinstance(value, dict):
        return " (got a mapping)"
    if isinstance(value, list):
        return " (got a list)"
    text = repr(value)
    return f" (got {text[:40]}{'...' if len(text) > 40 else ''})"


def _model_at(loc: tuple[Any, ...], data: Any, root: type[BaseModel]) -> type[BaseModel] | None:
    """The pydantic model that validates the node at ``loc`` of ``data`` (None if unclear)."""
    tp = _resolve(_annotation_at(loc, data, root), _node_at(loc, data))
    return tp if isinstance(tp, type) and issubclass(tp, BaseModel) else None


def _node_at(loc: tuple[Any, ...], data: Any) -> Any:
    """The input node at ``loc`` (union tags in the location skipped; None if absent)."""
    node = data
    for item in loc:
        if isinstance(node, dict) and item in node:
            node = node[item]
        elif isinstance(node, list) and isinstance(item, int) and 0 <= item < len(node):
            node = node[item]
        elif not (isinstance(item, str) and _is_union_tag(item, node)):
            return None
    return node


def _tags(tp: Any, node: Any) -> list[str]:
    """The ``type`` values a (discriminated) union accepts at a node, in declaration order:
    where a 2-D/3-D chooser picks a member first, the chosen member's only."""
    while get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    if get_origin(tp) in (Union, types.UnionType):
        chosen = _chosen_member(tp, node)
        if chosen is not None:
            return _tags(chosen, node)
        found = [t for a in get_args(tp) for t in _tags(a, node)]
        return list(dict.fromkeys(found))
    if isinstance(tp, type) and issubclass(tp, BaseModel) and "type" in tp.model_fields:
        return [str(v) for v in get_args(tp.model_fields["type"].annotation)]
    return []


def _annotation_at(loc: tuple[Any, ...], data: Any, root: type[BaseModel]) -> Any:
    """The annotation (unresolved: a union stays a union) that validates the node at
    ``loc`` of ``data``; None if unclear."""
    tp: Any = root
    node = data
    for pos, item in enumerate(loc):
        if isinstance(item, str) and item in UNION_TAGS:
            tp = _member_tagged(tp, item)  # a 2-D/3-D union's member, named in the location
            continue
        tp = _resolve(tp, node)
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            # A tag that is also a key (robot.urdf) is the tag unless there is more to walk.
            tag = (
                isinstance(node, dict)
                and node.get("type") == item
                and (pos + 1 < len(loc) or not isinstance(node.get(item), dict | list))
            )
            if tag or item not in tp.model_fields:
                if isinstance(node, dict) and (
                    node.get("type") == item or "-" in str(item) or item in UNION_TAGS
                ):
                    continue  # a union tag pydantic puts in the location
                return None
            tp = tp.model_fields[item].annotation
            node = node.get(item) if isinstance(node, dict) else None
        elif get_origin(tp) is dict:
            tp = get_args(tp)[1]
            node = node.get(item) if isinstance(node, dict) else None
        elif get_origin(tp) in (list, tuple):
            tp = get_args(tp)[0]
            ok = isinstance(node, list) and isinstance(item, int) and 0 <= item < len(node)
            node = node[item] if ok else None
        else:
            return None
    return tp


def _member_tagged(tp: Any, tag: str) -> Any:
    """The member of a union of ``Tag``-annotated members whose tag is ``tag`` (``tp``
    itself when it has none)."""
    return _tagged_members(tp).get(tag, tp)


def _tagged_members(tp: Any) -> dict[str, Any]:
    """``{tag: member}`` of a union whose members carry a pydantic ``Tag`` (the 2-D/3-D
    unions; ``Annotated`` unwrapped first); empty for anything else."""
    while get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    if get_origin(tp) not in (Union, types.UnionType):
        return {}
    return {
        m.tag: a
        for a in get_args(tp)
        if get_origin(a) is Annotated
        for m in get_args(a)[1:]
        if isinstance(m, Tag)
    }


def _chosen_member(tp: Any, node: Any) -> Any:
    """The member of a tagged union that its chooser (:data:`UNION_CHOOSERS`, 2-D or 3-D)
    picks for ``node``; None where ``tp`` has no chooser."""
    tagged = _tagged_members(tp)
    choose = UNION_CHOOSERS.get(frozenset(tagged)) if tagged else None
    return None if choose is None else tagged[choose(node)]


def _resolve(tp: Any, node: Any) -> Any:
    """Unwrap ``Annotated`` and ``Optional``; pick a union member by the node's ``type``,
    or by a callable discriminator (2-D or 3-D) when the union has one."""
    while get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    chosen = _chosen_member(tp, node)
    if chosen is not None:
        return _resolve(chosen, node)
    if get_origin(tp) in (Union, types.UnionType):
        members = [a for a in get_args(tp) if a is not type(None)]
        members = [_resolve(a, node) for a in members]
        models = [m for m in members if isinstance(m, type) and issubclass(m, BaseModel)]
        if len(members) == 1:
            return members[0]
        if len(models) == 1:
            return models[0]
        tag = node.get("type") if isinstance(node, dict) else None
        for m in models:
            field = m.model_fields.get("type")
            if field is not None and tag in get_args(field.annotation):
                return m
        return None
    return tp


def scenario_from_data(data: Any, source: str = "<data>", folder: Path | None = None) -> Scenario:
    """Validate already-parsed data (a dict) into a :class:`Scenario`.

    ``folder`` is where relative paths (meshes, URDFs) are found: the scenario file's
    folder; ``None`` for text with no file, whose files are then checked when the
    model is built.
    """
    if not isinstance(data, dict):
        raise ScenarioError([Problem(source, "a scenario must be a YAML mapping")])
    if "cellplan" not in data:
        raise ScenarioError(
            [Problem("cellplan", f"missing format version (write 'cellplan: {SCHEMA_VERSION}')")]
        )
    # A boolean equals 1 in Python, and 1.0 too: the version is an integer, exactly.
    if type(data["cellplan"]) is not int or data["cellplan"] not in SCHEMA_VERSIONS:
        raise ScenarioError(
            [
                Problem(
                    "cellplan",
                    f"unsupported format version {data['cellplan']!r}; "
                    f"this cellplan reads {' and '.join(map(str, SCHEMA_VERSIONS))}",
                )
            ]
        )
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(problems_from_validation(exc, data)) from None
    problems = check_references(scenario, folder)
    from cellplan.registry import packages

    kind = "3d" if is_3d(scenario) else "2d"
    owners = {p.section: p for p in packages().values() if p.section is not None}
    robot = scenario.robot
    if robot is not None and (robot.type == "urdf") != (kind == "3d"):
        # A robot of the other kind of workcell (reported above): the sections' checks
        # read the robot and would only add lines that follow from that one mistake.
        raise ScenarioError(problems)
    for name in scenario.section_names():
        section = getattr(scenario, name)
        owner = owners.get(name)
        if owner is not None and kind not in owner.workcells:
            problems.append(
                Problem(
                    name,
                    f"the {owner.name} planners work in {' and '.join(owner.workcells)} "
                    f"workcells; this one is {kind}",
                )
            )
            continue
        check: Callable[[Scenario], list[Problem]] | None = getattr(section, "check", None)
        if check is not None:
            problems.extend(check(scenario))
    if problems:
        raise ScenarioError(problems)
    return scenario


def load_scenario(path: str | Path) -> Scenario:
    """Read, parse and validate a scenario file (or a bundled scenario's name).

    Raises
    ------
    ScenarioError
        With one problem per mistake found; nothing is built from a bad file.
    """
    from cellplan.registry import resolve_scenario_path

    resolved = resolve_scenario_path(path)
    try:
        size = resolved.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ScenarioError(
                [
                    Problem(
                        str(path),
                        f"is {size / 1e6:.1f} MB; scenario files are limited to "
                        f"{MAX_FILE_BYTES / 1e6:.0f} MB",
                    )
                ]
            )
        raw = resolved.read_bytes()
    except OSError as exc:
        raise ScenarioError([Problem(str(path), f"cannot read: {exc.strerror or exc}")]) from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ScenarioError(
            [
                Problem(
                    str(path),
                    f"is not UTF-8 text (invalid byte at offset {exc.start}); save it as UTF-8",
                )
            ]
        ) from None
    data = parse_yaml(text, source=str(resolved))
    return scenario_from_data(data, source=str(resolved), folder=resolved.parent)


def loads_scenario(text: str) -> Scenario:
    """Parse and validate scenario YAML text."""
    return scenario_from_data(parse_yaml(text), source="<string>")


def dump_scenario(scenario: Scenario) -> str:
    """The scenario as YAML; ``loads_scenario(dump_scenario(s)) == s``."""
    data = scenario.model_dump(mode="json", exclude_none=True)
    return yaml.safe_dump(data, sort_keys=False)


SCHEMA_ID = f"urn:cellplan:scenario:{SCHEMA_VERSION}"
"""The ``$id`` of the scenario schema (a URN: the schema is published by ``cellplan schema``)."""


def json_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of scenario files, with ``$schema`` and ``$id``."""
    body = Scenario.model_json_schema()
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": SCHEMA_ID,
        **body,
    }


# --- cross-reference checks ------------------------------------------------------------------


def _unique_names(sc: Scenario) -> list[Problem]:
    """Obstacles, sources and destinations share one name space."""
    problems: list[Problem] = []
    names: dict[str, str] = {}
    for section, entries in (
        ("workcell.obstacles", sc.workcell.obstacles),
        ("sources", sc.sources),
        ("destinations", sc.destinations),
    ):
        for name in entries:
            if name in names:
                problems.append(Problem(f"{section}.{name}", f"name already used in {names[name]}"))
            names[name] = section
    return problems


def _only_planar(sc: Scenario) -> list[Problem]:
    """A 2-D scenario holds no solid and no URDF robot."""
    problems: list[Problem] = []
    shapes = [(f"parts.{n}.shape", p.shape) for n, p in sc.parts.items()]
    shapes += [(f"workcell.obstacles.{n}", o) for n, o in sc.workcell.obstacles.items()]
    for section, regions in (("sources", sc.sources), ("destinations", sc.destinations)):
        for name, region in regions.items():
            shapes += [
                (f"{section}.{name}.components[{i}]", c) for i, c in enumerate(region.components)
            ]
    for field, shape in shapes:
        if shape_dimension(shape) == "solid":
            problems.append(
                Problem(
                    field, "is a solid in a 2-D workcell; a 3-D cell's bounds name zmin and zmax"
                )
            )
    if sc.robot is not None and sc.robot.type == "urdf":
        problems.append(
            Problem("robot.type", "a URDF robot needs a 3-D workcell (bounds with zmin and zmax)")
        )
    return problems


def robot_dimension(robot: Any) -> int:
    """Dimension of the robot's configuration space."""
    if robot.type in ("point", "translating"):
        return 2
    if robot.type == "rotating":
        return 3
    if robot.type == "urdf":
        return len(robot.start)
    return len(robot.links)


def check_references(sc: Scenario, folder: Path | None = None) -> list[Problem]:
    """Consistency checks that span fields; returns every problem found.

    A 3-D scenario has its own (:func:`cellplan.scenario3d.check_references_3d`);
    ``folder`` is where its relative paths are found.
    """
    if is_3d(sc):
        return _unique_names(sc) + check_references_3d(sc, folder)
    problems = _only_planar(sc)
    if problems:
        return _unique_names(sc) + problems
    problems = _unique_names(sc)
    bounds = planar_workcell(sc).bounds.to_shapely()
    for section, regions in (("sources", sc.sources), ("destinations", sc.destinations)):
        for name, region in regions.items():
            geoms = [planar(c).to_shapely() for c in region.components]
            for i, g in enumerate(geoms):
                if not bounds.covers(g):
                    problems.append(
                        Problem(
                            f"{section}.{name}.components[{i}]", "lies outside the workcell bounds"
                        )
                    )
            # One line per overlapping component, naming the first one it overlaps; the
            # tree keeps this near-linear for regions of many components.
            tree = shapely.STRtree(geoms)
            first: dict[int, int] = {}
            for i, j in zip(*tree.query(geoms, predicate="intersects"), strict=True):
                if j < i and (i not in first or j < first[i]):
                    first[int(i)] = int(j)
            for i, j in sorted(first.items()):
                problems.append(
                    Problem(
                        f"{section}.{name}.components[{i}]",
                        f"overlaps components[{j}]; components must be disjoint",
                    )
                )
    for name, shape in planar_workcell(sc).obstacles.items():
        if not bounds.intersects(planar(shape).to_shapely()):
            problems.append(
                Problem(f"workcell.obstacles.{name}", "lies entirely outside the workcell bounds")
            )

    robot = sc.robot
    if robot is not None:
        dim = robot_dimension(robot)
        if robot.type == "arm":
            n = len(robot.links)
            if len(robot.start) != n:
                problems.append(
                    Problem(
                        "robot.start", f"has {len(robot.start)} joint angles; the arm has {n} links"
                    )
                )
            if robot.joint_limits is not None:
                if len(robot.joint_limits) != n:
                    problems.append(
                        Problem(
                            "robot.joint_limits",
                            f"has {len(robot.joint_limits)} entries; the arm has {n} links",
                        )
                    )
                for i, (lo, hi) in enumerate(robot.joint_limits):
                    for v in (lo, hi):
                        if not -180.0 <= v <= 180.0:
                            problems.append(
                                Problem(
                                    f"robot.joint_limits[{i}]",
                                    f"limit {v} deg is outside [-180, 180]",
                                )
                            )
                    if not lo < hi:
                        problems.append(
                            Problem(
                                f"robot.joint_limits[{i}]",
                                f"lower limit {lo} is not below upper limit {hi}",
                            )
                        )
                if len(robot.joint_limits) == n and len(robot.start) == n:
                    for i, (q, (lo, hi)) in enumerate(
                        zip(robot.start, robot.joint_limits, strict=True)
                    ):
                        if not lo <= q <= hi:
                            problems.append(
                                Problem(
                                    f"robot.start[{i}]",
                                    f"joint angle {q} deg is outside its limits [{lo}, {hi}]",
                                )
                            )
            for i, q in enumerate(robot.start):
                if not -180.0 < q <= 180.0:
                    problems.append(
                        Problem(f"robot.start[{i}]", f"joint angle {q} deg is outside (-180, 180]")
                    )
            if (
                robot.end_effector_orientation is not None
                and not -180.0 < robot.end_effector_orientation <= 180.0
            ):
                problems.append(
                    Problem("robot.end_effector_orientation", "must be in (-180, 180] degrees")
                )
        elif robot.type == "rotating" and not -180.0 < robot.start[2] <= 180.0:
            problems.append(
                Problem("robot.start", f"orientation {robot.start[2]} deg is outside (-180, 180]")
            )
        if sc.cspace.cells is not None and len(sc.cspace.cells) != dim:
            problems.append(
                Problem(
                    "cspace.cells",
                    f"has {len(sc.cspace.cells)} entries; the robot's C-space has dimension {dim}",
                )
            )
    elif sc.parts or sc.sources or sc.destinations:
        problems.append(Problem("robot", "parts, sources and destinations need a robot"))

    # A part reaching further from the gripper than the workcell's diagonal can never be
    # carried inside the bounds, and the C-space rasters would grow with its size (a part
    # 209 units long in a 100-unit cell ran the rotating robot's bitmap for minutes).
    b = planar_workcell(sc).bounds
    diagonal = math.hypot(b.xmax - b.xmin, b.ymax - b.ymin)
    for name, part in sc.parts.items():
        coords = shapely.get_coordinates(planar(part.shape).to_shapely())
        reach = float(np.max(np.hypot(coords[:, 0], coords[:, 1]))) if len(coords) else 0.0
        if reach > diagonal:
            problems.append(
                Problem(
                    f"parts.{name}.shape",
                    f"reaches {reach:.4g} from the gripper, beyond the workcell's diagonal "
                    f"({diagonal:.4g}); it could never be carried inside the bounds",
                )
            )
    return problems

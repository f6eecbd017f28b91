"""Hypothesis strategies that mutate scenario files.

:func:`mutated_scenario` starts from a bundled scenario's text and applies one to three
mutations, each on the parsed data (delete, duplicate, retype or rename a key; extreme,
NaN, infinite, negative or tiny numbers; empty and huge lists; hostile object names) or
on the text itself (non-UTF-8 bytes, a byte order mark, truncation, duplicated lines,
deep nesting, YAML anchors and aliases, tags, a list used as a key, control characters).
The result is the bytes of a file for ``cellplan validate``.
"""

from __future__ import annotations

import math
from typing import Any

import yaml
from hypothesis import strategies as st

from cellplan.registry import resolve_scenario_path, scenario_names

SCENARIOS = scenario_names()

#: Numbers that have broken number-handling code somewhere: bounds of float64 and int64,
#: values that overflow when squared or converted to int, subnormals, signed zeros.
EXTREME_NUMBERS: list[Any] = [
    0,
    -0.0,
    -1,
    -5,
    1,
    0.5,
    1e-300,
    5e-324,
    -1e-300,
    1e-9,
    1e6,
    1e6 + 1,
    -1e6 - 1,
    1e7,
    1e15,
    1e21,
    1e30,
    -1e30,
    1e154,
    1e308,
    -1e308,
    math.inf,
    -math.inf,
    math.nan,
    2**31,
    2**53 + 1,
    2**63,
    -(2**63) - 1,
    2**64,
    10**30,
    10**400,
    4096,
    4097,
    65536,
    360,
    -180,
    180.0000001,
    720,
]

#: Object names matplotlib or rich could misread (math text, markup), and odd Unicode.
HOSTILE_NAMES = [
    "$x^$",
    "$\\foo$",
    "$",
    "[/x]",
    "[bold]x",
    "[red]",
    "%s%d",
    "{0}",
    "a\u0301",
    "\u202e",
    "名前",
    "x" * 300,
    "",
    " ",
    "a.b",
    "-",
    "..",
    "\\",
    "<script>",
]

SCALARS = st.one_of(
    st.sampled_from(EXTREME_NUMBERS),
    st.integers(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
    st.sampled_from(HOSTILE_NAMES),
    st.booleans(),
    st.none(),
)
#: Keys the mutations write: short names of the characters field paths use, plus
#: non-text keys (YAML allows numbers, booleans and null as keys).
KEYS = st.one_of(
    st.text(alphabet="abcdefghijklmnopqrstuvwxyzXYZ_-0123456789", min_size=1, max_size=12),
    st.sampled_from(["type", "min", "max", "start", "shape", "points", "cells", "name"]),
    st.integers(-5, 5),
    st.booleans(),
    st.none(),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(KEYS, inner, max_size=3)),
    max_leaves=8,
)


def bundled_text(name: str) -> str:
    return resolve_scenario_path(name).read_text(encoding="utf-8")


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every path in the tree (the root is ``()``)."""
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


def _get(node: Any, path: tuple[Any, ...]) -> Any:
    for p in path:
        node = node[p]
    return node


def _set(root: Any, path: tuple[Any, ...], value: Any) -> Any:
    if not path:
        return value
    _get(root, path[:-1])[path[-1]] = value
    return root


@st.composite
def data_mutation(draw: st.DrawFn, data: Any) -> Any:
    """One mutation of the parsed tree (the tree is modified and returned)."""
    paths = _paths(data)
    numeric = [p for p in paths if isinstance(_get(data, p), int | float)]
    containers = [p for p in paths if isinstance(_get(data, p), dict | list) and _get(data, p)]
    kind = draw(
        st.sampled_from(
            [
                "number",
                "number",
                "number",
                "delete",
                "duplicate",
                "retype",
                "rename",
                "empty",
                "huge",
                "name",
                "scale",
            ]
        )
    )
    if kind in ("number", "scale") and numeric:
        path = draw(st.sampled_from(numeric))
        old = _get(data, path)
        if kind == "scale":
            new = old * draw(st.sampled_from([-1, 0, 1e-9, 1e3, 1e6, 1e12, 1e300]))
        else:
            new = draw(st.one_of(st.sampled_from(EXTREME_NUMBERS), st.floats(), st.integers()))
        return _set(data, path, new)
    if kind in ("delete", "duplicate", "rename", "empty", "huge") and containers:
        path = draw(st.sampled_from(containers))
        node = _get(data, path)
        if kind == "empty":
            return _set(data, path, type(node)())
        keys = list(node) if isinstance(node, dict) else list(range(len(node)))
        key = draw(st.sampled_from(keys))
        if kind == "delete":
            del node[key]
        elif kind == "duplicate":
            if isinstance(node, list):
                node.insert(key, node[key])
            else:
                node[draw(KEYS)] = node[key]
        elif kind == "rename" and isinstance(node, dict):
            value = node.pop(key)
            node[draw(KEYS)] = value
        elif kind == "huge":
            count = draw(st.sampled_from([100, 1000, 5000]))
            if isinstance(node, list):
                node.extend([node[key]] * count)
            else:
                for i in range(count):
                    node[f"{key}_{i}"] = node[key]
        return data
    if kind == "name":
        dicts = [p for p in paths if isinstance(_get(data, p), dict) and _get(data, p)]
        path = draw(st.sampled_from(dicts)) if dicts else ()
        node = _get(data, path)
        if isinstance(node, dict) and node:  # the whole file may have been emptied
            key = draw(st.sampled_from(list(node)))
            node[draw(st.sampled_from(HOSTILE_NAMES))] = node.pop(key)
        return data
    # retype (also the fallback when the chosen kind has nothing to act on)
    path = draw(st.sampled_from(paths))
    return _set(data, path, draw(VALUES))


def _dump(data: Any) -> str:
    try:
        return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=10**6)
    except (yaml.YAMLError, RecursionError, TypeError):
        return yaml.safe_dump({"cellplan": 1}, sort_keys=False)


TAGS = [
    "!!python/object/apply:os.system ['echo pwned']",
    "!!python/name:os.system",
    "!!binary aGVsbG8=",
    "!!timestamp 2001-12-14",
    "!!set {a, b}",
    "!!omap [{a: 1}, {b: 2}]",
    "!!float 'nan'",
    "!!int '0x7fffffffffffffffffff'",
    "!custom 3",
    "!<tag:yaml.org,2002:str> 5",
    "!!str",
    "!!null ''",
]

STANDARD_TAGS = ["null", "bool", "int", "float", "timestamp", "binary", "str"]


@st.composite
def text_mutation(draw: st.DrawFn, text: str) -> bytes:
    """One mutation of the file's text; returns the bytes to write."""
    lines = text.splitlines(keepends=True) or ["\n"]
    at = draw(st.integers(0, max(0, len(lines) - 1)))
    kind = draw(
        st.sampled_from(
            [
                "latin1",
                "utf16",
                "bytes",
                "bom",
                "truncate",
                "dupline",
                "deep",
                "anchor",
                "tag",
                "listkey",
                "control",
                "tabs",
                "merge",
            ]
        )
    )
    if kind == "latin1":
        return (text[: draw(st.integers(0, len(text)))] + "é ñ ü" + text).encode(
            "latin-1", "replace"
        )
    if kind == "utf16":
        return text.encode(draw(st.sampled_from(["utf-16", "utf-16-le", "utf-32"])))
    if kind == "bytes":
        raw = bytearray(text.encode())
        pos = draw(st.integers(0, len(raw)))
        raw[pos:pos] = draw(st.binary(min_size=1, max_size=8))
        return bytes(raw)
    if kind == "bom":
        return b"\xef\xbb\xbf" + text.encode()
    if kind == "truncate":
        return text.encode()[: draw(st.integers(0, len(text.encode())))]
    if kind == "dupline":
        lines.insert(at, lines[at])
    elif kind == "deep":
        depth = draw(st.sampled_from([50, 500, 3000, 20_000]))
        opener, closer = draw(st.sampled_from([("[", "]"), ("{a: ", "}")]))
        lines.append(f"deep: {opener * depth}1{closer * depth}\n")
    elif kind == "anchor":
        # a value anchored and aliased elsewhere, or an alias of nothing, or a recursive one
        variant = draw(st.integers(0, 3))
        if variant == 0:
            lines.append("extra: &a [1, 2]\nextra2: *a\n")
        elif variant == 1:
            lines.append("extra: *nowhere\n")
        elif variant == 2:
            lines.append("extra: &r [*r]\n")
        else:
            laughs = ["l0: &l0 [x, x, x, x, x, x, x, x, x, x]\n"]
            laughs += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10)}]\n" for i in range(1, 8)]
            lines += laughs
    elif kind == "tag":
        line = lines[at]
        if ":" in line and not line.rstrip().endswith(":"):
            head, _, value = line.partition(":")
            if draw(st.booleans()):
                lines[at] = f"{head}: {draw(st.sampled_from(TAGS))}\n"
            else:  # a standard tag on the value that is there (!!int abc, !!timestamp 3)
                lines[at] = f"{head}: !!{draw(st.sampled_from(STANDARD_TAGS))} {value.strip()}\n"
        else:
            lines.append(f"extra: {draw(st.sampled_from(TAGS))}\n")
    elif kind == "listkey":
        line = lines[at]
        stripped = line.lstrip()
        indent = line[: len(line) - len(stripped)]
        key, sep, rest = stripped.partition(":")
        if sep and key and not key.startswith(("-", "#")):
            lines[at] = f"{indent}[{key}, 1]:{rest}"
        else:
            lines.append("? [a, b]\n: 1\n")
    elif kind == "control":
        ch = draw(st.sampled_from(["\x00", "\x07", "\x1b[31m", "\ufeff", "\u2028", "\x85"]))
        lines[at] = lines[at][:-1] + ch + "\n" if lines[at].endswith("\n") else lines[at] + ch
    elif kind == "tabs":
        lines[at] = "\t" + lines[at]
    else:  # merge keys
        lines.append("base: &b {x: 1}\nmerged: {<<: *b, y: 2}\n")
    return "".join(lines).encode("utf-8", "surrogatepass")


@st.composite
def mutated_scenario(draw: st.DrawFn, name: str) -> bytes:
    """The bytes of a mutated copy of bundled scenario ``name``."""
    text = bundled_text(name)
    rounds = draw(st.integers(1, 3))
    text_level = draw(st.integers(0, 3)) == 0
    data = yaml.safe_load(text)
    for _ in range(rounds if not text_level else rounds - 1):
        data = draw(data_mutation(data))
    text = _dump(data) if data is not None else text
    if text_level:
        return draw(text_mutation(text))
    return text.encode("utf-8", "surrogatepass")

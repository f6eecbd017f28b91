"""Control characters from the input never reach the terminal (issue 36).

A scenario's name, a key or a path printed raw let ``ESC ] 0;...`` set the terminal's
title, ``ESC [2J`` clear the screen and ``ESC [31m`` change the colour. Everything printed
from user input goes through :func:`cellplan.errors.printable`.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cellplan.errors import printable
from cellplan.registry import resolve_scenario_path

TINY = resolve_scenario_path("strategies_tiny").read_text(encoding="utf-8")
# YAML double-quoted escapes: \e is ESC, \a BEL, \x9b the one-character CSI (C1).
HOSTILE = r"\e]0;pwned\a\e[2J\e[31mred\x9b1m\x7f"


def no_control_bytes(text: str) -> None:
    assert "\x1b" not in text
    assert "\x9b" not in text
    assert "\x07" not in text


def test_printable_escapes_c0_del_and_c1_only():
    assert printable("a\x1b[31mb") == r"a\x1b[31mb"
    assert printable("\x00\x07\t\n\x7f") == r"\x00\x07\x09\x0a\x7f"
    assert printable("\x9b\x85") == r"\u009b\u0085"
    assert printable("café ✓ [bold]x[/]") == "café ✓ [bold]x[/]"


def test_validate_escapes_the_scenario_name(cellplan, tmp_path: Path):
    path = tmp_path / "s.yaml"
    path.write_text(TINY.replace("name: strategies-tiny", f'name: "{HOSTILE}"'))
    r = cellplan("validate", str(path))
    assert r.returncode == 0, r.stderr
    no_control_bytes(r.stdout + r.stderr)
    assert r"\x1b]0;pwned\x07\x1b[2J\x1b[31mred\u009b1m\x7f" in r.stdout


def test_show_escapes_the_output_path(cellplan, tmp_path: Path):
    out = tmp_path / "a\x1b[2Jb.png"
    r = cellplan("show", "strategies_tiny", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert out.exists()
    no_control_bytes(r.stdout + r.stderr)
    assert r"a\x1b[2Jb.png" in r.stdout


@pytest.mark.parametrize("command", ["validate", "show"])
def test_an_error_naming_a_hostile_key_or_path_is_escaped(cellplan, tmp_path: Path, command):
    path = tmp_path / "s.yaml"
    path.write_text(TINY.replace("    middle:", f'    "{HOSTILE}":'))
    r = cellplan(
        command, str(path), *(["-o", str(tmp_path / "x.png")] if command == "show" else [])
    )
    assert r.returncode == 2
    assert r.stderr.startswith("error: workcell.obstacles")
    no_control_bytes(r.stdout + r.stderr)
    r = cellplan(command, str(tmp_path / "\x1b]0;title\x07missing.yaml"))
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1
    no_control_bytes(r.stdout + r.stderr)

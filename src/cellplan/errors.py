"""User-facing errors.

Every mistake a user can make (a bad scenario file, a bad argument, a database
made for another robot) raises a :class:`CellplanError` carrying one
:class:`Problem` per mistake. The CLI prints one line per problem, naming the
field, and exits with status 2; nothing else is caught, so a genuine bug still
shows its traceback.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

# C0 controls (tab and newline included), DEL, and C1 controls (U+0080-U+009F; a terminal
# may read U+009B alone as ESC [).
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """``text`` with every control character shown as an escape (``\\x1b``, ``\\u009b``).

    Everything cellplan prints that may hold user input (a scenario's name, a key, a path,
    an error line) goes through this, so the input cannot set the terminal's title, clear
    the screen or change its colours, nor break a line in two.
    """
    return _CONTROL.sub(_escape, text)


def _escape(match: re.Match[str]) -> str:
    code = ord(match.group())
    return f"\\x{code:02x}" if code < 0x80 else f"\\u{code:04x}"


@dataclass(frozen=True)
class Problem:
    """One thing wrong with the input.

    Parameters
    ----------
    field
        Dotted path of the offending field (``robot.start``,
        ``sources.S1.components[0]``), or an argument name such as ``--k``.
        Empty when the problem concerns the whole input.
    message
        What is wrong, in one line.
    """

    field: str
    message: str

    def __str__(self) -> str:
        return f"{self.field}: {self.message}" if self.field else self.message


class CellplanError(Exception):
    """An input problem the user can fix; carries one or more :class:`Problem`."""

    def __init__(self, problems: Iterable[Problem] | str, field: str = "") -> None:
        if isinstance(problems, str):
            problems = [Problem(field, problems)]
        self.problems: tuple[Problem, ...] = tuple(problems)
        if not self.problems:
            raise ValueError("CellplanError needs at least one problem")
        super().__init__("\n".join(str(p) for p in self.problems))


class ScenarioError(CellplanError):
    """The scenario file or the model built from it is invalid."""


class ArgumentError(CellplanError):
    """A command-line or API argument is invalid."""


class PersistenceError(CellplanError):
    """A saved artefact (strategy file, experience database, cache entry) is unusable."""


class Interrupted(Exception):
    """A command stopped by Ctrl-C that has more to say than ``interrupted`` (what is
    kept, how to resume). The CLI prints its message as one line and exits 130. Not a
    ``KeyboardInterrupt``: the command-line parser would turn that into a bare status."""


def raise_if(problems: list[Problem], error: type[CellplanError] = ScenarioError) -> None:
    """Raise ``error`` with all collected problems, if there are any."""
    if problems:
        raise error(problems)

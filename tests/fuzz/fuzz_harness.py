"""Run the ``cellplan`` command line in-process for the fuzzing tests, and check its output.

:func:`run_cli` calls :func:`cellplan.cli.main` exactly as the console script does (the
same exit-status mapping, including the top-level catch that turns a bug into exit 70),
with stdout and stderr captured and a time limit per call. :func:`bad_lines` is the
check every exit-2 answer must pass: each stderr line is one problem that names a field,
an option or a file.
"""

from __future__ import annotations

import ast
import contextlib
import io
import os
import re
import signal
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

from hypothesis import HealthCheck, Phase, settings

from cellplan.cli import main

#: Seconds one in-process command may take before the fuzzer calls it a hang.
HANG_SECONDS = float(os.environ.get("CELLPLAN_FUZZ_HANG_SECONDS", "60"))


class Hang(BaseException):
    """Raised in the test when a command overran :data:`HANG_SECONDS` (a BaseException, so
    the command's own ``except Exception`` cannot swallow it)."""


@dataclass
class Outcome:
    """Exit status and captured output of one in-process command."""

    args: tuple[str, ...]
    code: int
    stdout: str
    stderr: str

    def describe(self) -> str:
        return f"cellplan {' '.join(self.args)} -> exit {self.code}\nstderr:\n{self.stderr[:3000]}"


@contextlib.contextmanager
def _time_limit(seconds: float) -> Iterator[None]:
    if seconds <= 0 or not hasattr(signal, "SIGALRM"):
        yield
        return

    def on_alarm(signum: int, frame: object) -> None:
        raise Hang(f"over {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def run_cli(args: Sequence[str], timeout: float = HANG_SECONDS) -> Outcome:
    """Run ``cellplan *args`` in this process; an exception escaping ``main`` propagates."""
    saved = sys.argv
    sys.argv = ["cellplan", *args]
    out, err = io.StringIO(), io.StringIO()
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            with _time_limit(timeout):
                try:
                    main()
                except SystemExit as exc:
                    code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.argv = saved
    return Outcome(tuple(args), code, out.getvalue(), err.getvalue())


# A field path: dotted keys and [index] parts, with keys that are not plain names quoted
# (``sources.S1.components[0].min``, ``workcell.obstacles['a b']``).
_PLAIN = r"[A-Za-z0-9_.\-]+"
_QUOTED = r"\[(?:'(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\")\]"
# a field path, optionally followed by the request it is about (strategy.requests <P1,S1,D1>)
# or by the value it holds (strategy.cells 64,64,30: needs about 53 GB ...)
_ABOUT = r"(?: <[\w.,\-]+>| [\w.,+\-]+)?"
FIELD_RE = re.compile(rf"(?P<root>{_PLAIN}|{_QUOTED})(?:\.{_PLAIN}|\[\d+\]|{_QUOTED})*{_ABOUT}")
# a long option, a short one (click reads "-9..." as one), an argument, the program
OPTION_RE = re.compile(rf"(?:--[a-z][a-z0-9\-]*|-[a-z0-9]|[A-Z][A-Z_]*|cellplan){_ABOUT}")
MORE_RE = re.compile(r"error: \d+ more problems? not shown")


def _root_keys(root: str) -> list[str]:
    """What the first key of a field path may be, unquoted (``['a b']`` -> ``a b``;
    ``a.b`` -> ``a`` or ``a.b``, since keys may hold dots)."""
    if root.startswith("["):
        return [str(ast.literal_eval(root[1:-1]))]
    parts = root.split(".")
    return [".".join(parts[: i + 1]) for i in range(len(parts))]


def bad_lines(
    stderr: str,
    files: Sequence[str] = (),
    roots: Iterable[str] | None = None,
    options: bool = False,
) -> list[str]:
    """The stderr lines that are not one problem naming a field, option or file.

    A good line is ``error: WHERE: message`` with a message, where WHERE is a file named
    in ``files`` (optionally with ``:line:col``); or a field path whose first key is one
    of ``roots`` (the file's top-level keys and the schema's, when given); or, with
    ``options``, a command-line option (``--radius``) or argument (``SCENARIO``). The
    last line may say how many more problems were left out. Tracebacks, pydantic dumps,
    blank answers and lines without a place are bad.
    """
    lines = stderr.splitlines()
    if not lines:
        return ["(no error line at all)"]
    allowed_roots = None if roots is None else set(roots)
    bad = []
    file_re = re.compile("|".join(rf"{re.escape(f)}(?::\d+:\d+)?" for f in files) or "(?!)")
    for i, line in enumerate(lines):
        if i == len(lines) - 1 and i > 0 and MORE_RE.fullmatch(line):
            continue
        if not line.startswith("error: "):
            bad.append(line)
            continue
        rest = line[len("error: ") :]
        ok = False
        for where_re in (file_re, OPTION_RE if options else None, FIELD_RE):
            if where_re is None:
                continue
            for m in where_re.finditer(rest):
                if m.start() != 0:
                    break
                tail = rest[m.end() :]
                if not (tail.startswith(": ") and tail[2:].strip()):
                    continue
                if where_re is FIELD_RE and allowed_roots is not None:
                    if not allowed_roots.intersection(_root_keys(m.group("root"))):
                        continue
                ok = True
                break
            if ok:
                break
        if not ok:
            bad.append(line)
    return bad


def record(kind: str, name: str, cases: int, failures: int = 0) -> None:
    """Append how many cases a fuzz test tried to ``$CELLPLAN_FUZZ_COUNTS`` (JSON lines),
    when set: the figures docs/reliability.md reports."""
    target = os.environ.get("CELLPLAN_FUZZ_COUNTS")
    if target:
        import json

        with open(target, "a", encoding="utf-8") as f:
            row = {"kind": kind, "name": name, "cases": cases, "failures": failures}
            f.write(json.dumps(row) + "\n")


class FailureLog:
    """The slow runs' way of failing: every failing case is written down and the run goes
    on, so one run gives both the number of cases tried and the number of failures; the
    test fails at the end if there was any. Cases go to ``$CELLPLAN_FUZZ_FAILURES`` (a
    folder) when set."""

    def __init__(self, kind: str, name: str) -> None:
        self.kind, self.name, self.tried, self.failed = kind, name, 0, []

    def check(self, case: Callable[[], None], content: bytes | str = b"") -> None:
        self.tried += 1
        try:
            case()
        except (AssertionError, Hang) as exc:
            self.failed.append(f"{type(exc).__name__}: {str(exc)[:2000]}")
            folder = os.environ.get("CELLPLAN_FUZZ_FAILURES")
            if folder:
                os.makedirs(folder, exist_ok=True)
                stem = f"{folder}/{self.kind}-{self.name.replace(' ', '_')}-{len(self.failed)}"
                with open(stem + ".txt", "w", encoding="utf-8") as f:
                    f.write(self.failed[-1])
                data = content.encode() if isinstance(content, str) else content
                with open(stem + ".case", "wb") as f:
                    f.write(data)

    def finish(self) -> None:
        record(self.kind, self.name, self.tried, len(self.failed))
        assert not self.failed, (
            f"{len(self.failed)} of {self.tried} failed; first: {self.failed[0]}"
        )


def fuzz_settings(examples: int) -> settings:
    """Fixed seed, no example database: the same cases on every machine and run."""
    return settings(
        max_examples=examples,
        derandomize=True,
        database=None,
        deadline=None,
        # no shrinking or explaining: a failing case is printed as drawn, and the
        # tracer of the explain phase would slow every call tenfold
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
    )

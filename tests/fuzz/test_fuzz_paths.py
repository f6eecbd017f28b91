"""Fuzzing the paths every command reads and writes (issue 36).

Each case gives one command a hostile path in one role (its scenario, ``--strategy``,
``--db`` or ``-o``): a symbolic link to a regular file, to a victim file outside the
output, to ``/dev/null``, ``/dev/zero`` or a folder, a dangling link, a FIFO, a folder, a
hard link, a file inside a file, the longest legal name and one byte over, an output that
is one of the inputs (by the same name, a link or a hard link), a folder holding links
or FIFOs at the names the command writes, a read-only file system and a full one. The
command must:

* exit 0, 1 or 2 (never 70, never a traceback, never hang), each exit-2 line naming an
  option, the argument or a path;
* leave every file outside its output as it was (the victim, the inputs, ``/dev/null``),
  and, when it exits 2, leave everything as it was, its output too.

The default run tries a few cases per command with a fixed seed; the slow run tries
``CELLPLAN_FUZZ_PATH_EXAMPLES`` per command:

    CELLPLAN_FUZZ_PATH_EXAMPLES=1500 pytest -m slow tests/fuzz/test_fuzz_paths.py
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import stat
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from fuzz_harness import FailureLog, bad_lines, fuzz_settings, run_cli
from hypothesis import given
from hypothesis import strategies as st

from cellplan.fileio import name_max
from cellplan.registry import scenario_path

FAST_EXAMPLES = 6
SLOW_EXAMPLES = int(os.environ.get("CELLPLAN_FUZZ_PATH_EXAMPLES", "1500"))

#: What a hostile path may be, per role. Inputs are read; outputs are written.
INPUT_KINDS = [
    "link-to-input",
    "link-to-dev-zero",
    "link-to-dev-null",
    "dangling-link",
    "fifo",
    "folder",
    "missing",
    "inside-a-file",
    "hard-link",
    "longest-name",
]
FILE_OUTPUT_KINDS = [
    "absent",
    "regular",
    "link-to-victim",
    "hard-link-to-victim",
    "link-to-dev-null",
    "link-to-folder",
    "dangling-link",
    "fifo",
    "folder",
    "inside-a-file",
    "longest-name",
    "name-over-limit",
    "is-the-input",
    "link-to-the-input",
    "hard-link-to-the-input",
    "read-only-fs",
    "full-disk",
]
FOLDER_OUTPUT_KINDS = [
    "absent",
    "existing",
    "is-a-file",
    "inside-a-file",
    "link-to-folder",
    "holds-link-to-victim",
    "holds-fifo",
    "holds-folder",
    "holds-the-input",
    "name-over-limit",
    "read-only-fs",
    "full-disk",
]


@dataclass(frozen=True)
class Command:
    """One command: how to build its line from its inputs and output."""

    name: str
    inputs: tuple[str, ...]  # roles read: SCENARIO, FILE, --strategy, --db
    output: str  # "file:.png", "file:.npz" or "folder"
    line: Callable[[dict[str, Path], Path], list[str]]


COMMANDS = [
    Command("validate", ("SCENARIO",), "", lambda i, o: ["validate", str(i["SCENARIO"])]),
    Command(
        "show", ("SCENARIO",), "file:.png", lambda i, o: ["show", str(i["SCENARIO"]), "-o", str(o)]
    ),
    Command(
        "cspace",
        ("SCENARIO",),
        "file:.png",
        lambda i, o: ["cspace", str(i["SCENARIO"]), "-o", str(o)],
    ),
    Command(
        "solve",
        ("SCENARIO",),
        "file:.npz",
        lambda i, o: ["solve", str(i["SCENARIO"]), "-o", str(o)],
    ),
    Command(
        "plot",
        ("SCENARIO", "--strategy"),
        "file:.png",
        lambda i, o: ["plot", str(i["SCENARIO"]), "--strategy", str(i["--strategy"]), "-o", str(o)],
    ),
    Command(
        "simulate",
        ("SCENARIO", "--strategy"),
        "folder",
        lambda i, o: [
            "simulate",
            str(i["SCENARIO"]),
            "--strategy",
            str(i["--strategy"]),
            "--stages",
            "30",
            "--no-gif",
            "-o",
            str(o),
        ],
    ),
    Command(
        "assemble",
        ("FILE",),
        "folder",
        lambda i, o: ["assemble", str(i["FILE"]), "--frames", "2", "-o", str(o)],
    ),
    Command(
        "adapt",
        ("SCENARIO", "--db"),
        "folder",
        lambda i, o: [
            "adapt",
            str(i["SCENARIO"]),
            "--tasks",
            "1",
            "--no-baseline",
            "--db",
            str(i["--db"]),
            "-o",
            str(o),
        ],
    ),
]

#: Names the folder commands write (a link or FIFO planted at one must not be followed).
WRITTEN = {"simulate": "metrics.json", "assemble": "metrics.json", "adapt": "summary.json"}
SCENARIOS = {"simulate": "strategies_tiny", "plot": "strategies_tiny", "assemble": "discs_swap"}


def _mount(target: Path, options: str) -> bool:
    target.mkdir()
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)], capture_output=True
    )
    return made.returncode == 0


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Path | None]]:
    """A strategy file, and (as root) a read-only and a full file system, for every case."""
    base = tmp_path_factory.mktemp("paths")
    strategy = base / "tiny.npz"
    assert run_cli(["solve", "strategies_tiny", "-o", str(strategy)]).code == 0
    mounts: dict[str, Path | None] = {"strategy": strategy}
    for key, options in (("read-only-fs", "size=64k,ro"), ("full-disk", "size=64k")):
        mounts[key] = base / key if _mount(base / key, options) else None
    if mounts["full-disk"] is not None:
        with contextlib.suppress(OSError):  # fill it: every later write fails
            with open(mounts["full-disk"] / "filler", "wb") as fh:
                fh.write(b"\0" * (1 << 20))
    yield mounts
    for key in ("read-only-fs", "full-disk"):
        if mounts[key] is not None:
            subprocess.run(["umount", str(mounts[key])], check=False)


def _snapshot(root: Path, skip: Path | None) -> dict[str, tuple[int, int, str]]:
    """Every entry under ``root`` (but ``skip``): its type, size and content hash."""
    seen: dict[str, tuple[int, int, str]] = {}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            if skip is not None and (path == skip or skip in path.parents):
                continue
            st_ = os.lstat(path)
            digest = ""
            if stat.S_ISREG(st_.st_mode):
                digest = hashlib.sha256(path.read_bytes()).hexdigest()
            elif stat.S_ISLNK(st_.st_mode):
                digest = os.readlink(path)
            seen[str(path.relative_to(root))] = (stat.S_IFMT(st_.st_mode), st_.st_size, digest)
    return seen


def _long_name(folder: Path, suffix: str, over: int = 0) -> Path:
    limit = name_max(folder)
    return folder / ("n" * (limit - len(suffix) + over) + suffix)


def _hostile_input(kind: str, good: Path, sandbox: Path) -> Path:
    """The path given for an input whose good file is ``good``."""
    path = sandbox / f"in-{kind}{good.suffix}"
    if kind == "link-to-input":
        path.symlink_to(good)
    elif kind == "link-to-dev-zero":
        path.symlink_to("/dev/zero")
    elif kind == "link-to-dev-null":
        path.symlink_to("/dev/null")
    elif kind == "dangling-link":
        path.symlink_to(sandbox / "nowhere")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    elif kind == "missing":
        path = sandbox / "no" / "such" / good.name
    elif kind == "inside-a-file":
        path = good / "x"
    elif kind == "hard-link":
        os.link(good, path)
    elif kind == "longest-name":
        path = _long_name(sandbox, good.suffix)
        shutil.copy(good, path)
    return path


def _hostile_output(
    kind: str,
    command: Command,
    inputs: dict[str, Path],
    sandbox: Path,
    world: dict[str, Path | None],
) -> Path | None:
    """The ``-o`` path, or None where the case needs a file system this machine lacks."""
    out = sandbox / "out"
    victim = sandbox / "victim.txt"
    suffix = command.output.partition(":")[2]
    target = out / f"result{suffix}" if suffix else out / "folder"
    if kind in ("read-only-fs", "full-disk"):
        fs = world[kind]
        return None if fs is None else fs / target.name
    out.mkdir()
    first = next(iter(inputs.values()))
    if kind == "absent":
        return target
    if kind in ("regular",):
        target.write_bytes(b"old contents")
    elif kind == "link-to-victim":
        target.symlink_to(victim)
    elif kind == "hard-link-to-victim":
        os.link(victim, target)
    elif kind == "link-to-dev-null":
        target.symlink_to("/dev/null")
    elif kind == "link-to-folder":
        (sandbox / "elsewhere").mkdir()
        target.symlink_to(sandbox / "elsewhere")
    elif kind == "dangling-link":
        target.symlink_to(sandbox / "nowhere")
    elif kind in ("fifo",):
        os.mkfifo(target)
    elif kind in ("folder", "existing"):
        target.mkdir()
    elif kind == "is-a-file":
        target.write_bytes(b"a file")
    elif kind == "inside-a-file":
        target = victim / target.name
    elif kind == "longest-name":
        target = _long_name(out, suffix)
    elif kind == "name-over-limit":
        target = _long_name(out, suffix, over=1)
    elif kind == "is-the-input":
        target = first
    elif kind == "link-to-the-input":
        target.symlink_to(first)
    elif kind == "hard-link-to-the-input":
        os.link(first, target)
    elif kind.startswith("holds-"):
        target.mkdir()
        planted = target / WRITTEN[command.name]
        if kind == "holds-link-to-victim":
            planted.symlink_to(victim)
        elif kind == "holds-fifo":
            os.mkfifo(planted)
        elif kind == "holds-folder":
            planted.mkdir()
        else:  # holds-the-input: an input file under a name the command writes
            shutil.copy(first, planted)
            key = next(iter(inputs))
            inputs[key] = planted
    return target


def _good_inputs(command: Command, sandbox: Path, world: dict[str, Path | None]) -> dict[str, Path]:
    (sandbox / "in").mkdir()
    found: dict[str, Path] = {}
    for role in command.inputs:
        if role in ("SCENARIO", "FILE"):
            name = SCENARIOS.get(command.name, "strategies_tiny")
            if command.name == "adapt":
                name = "adaptive_fig4"
            found[role] = sandbox / "in" / f"{name}.yaml"
            shutil.copy(scenario_path(name), found[role])
        elif role == "--strategy":
            strategy = world["strategy"]
            assert strategy is not None
            found[role] = sandbox / "in" / "q.npz"
            shutil.copy(strategy, found[role])
        elif role == "--db":
            found[role] = sandbox / "in" / "exp.sqlite"  # created by the run
    return found


def _form(path: Path, form: str) -> Path:
    """``path`` as given on the line: absolute, relative to the working folder, or with a
    ``..`` detour (aliases must be seen through all three)."""
    if form == "relative":
        return Path(os.path.relpath(path))
    if form == "detour":
        return path.parent / ".." / path.parent.name / path.name
    return path


def _within(entry: str, written: list[str]) -> bool:
    """Whether a changed entry belongs to a written path: the path itself, what is inside
    it or beside it under its name (``exp.sqlite-wal``, ``exp.sqlite.lock``), or a
    folder created to hold it (``new`` for ``new/exp.sqlite``)."""
    return any(
        entry == a or entry.startswith((a + "/", a + ".", a + "-")) or a.startswith(entry + "/")
        for a in written
    )


def _case(
    command: Command, kinds: dict[str, str], form: str, world: dict[str, Path | None]
) -> None:
    base = Path(tempfile.mkdtemp(prefix="fz-"))
    sandbox = base / "s"
    sandbox.mkdir()
    try:
        victim = sandbox / "victim.txt"
        victim.write_text("precious\n", encoding="utf-8")
        inputs = _good_inputs(command, sandbox, world)
        output = _hostile_output(kinds.get("-o", "absent"), command, inputs, sandbox, world)
        if output is None:
            return  # no such file system here (not root): nothing to try
        for role in command.inputs:
            kind = kinds.get(role, "good")
            if kind == "good":
                continue
            if role == "--db":  # created by the run: the hostile file is beside it
                if kind == "missing":
                    inputs[role] = sandbox / "new" / "exp.sqlite"
                elif kind == "hard-link":
                    inputs[role] = _hostile_input("link-to-input", victim, sandbox)
                else:
                    inputs[role] = _hostile_input(kind, victim, sandbox)
            else:
                inputs[role] = _hostile_input(kind, inputs[role], sandbox)
        null_before = os.stat("/dev/null")
        before = _snapshot(sandbox, None)
        given = {role: _form(path, form) for role, path in inputs.items()}
        outcome = run_cli(command.line(given, _form(output, form)))
        description = f"{kinds} {form}: {outcome.describe()}"
        assert outcome.code in (0, 1, 2), description
        assert "Traceback" not in outcome.stderr, description
        null_after = os.stat("/dev/null")
        assert stat.S_ISCHR(null_after.st_mode) and null_after.st_ino == null_before.st_ino
        assert victim.read_text(encoding="utf-8") == "precious\n", description
        after = _snapshot(sandbox, None)
        changed = {k for k in set(before) | set(after) if before.get(k) != after.get(k)}
        if outcome.code == 2:
            named = [str(p) for p in (*given.values(), _form(output, form), sandbox)]
            assert not bad_lines(outcome.stderr, files=named, options=True), description
            late = ("error: --output:", "error: output:")
            if "--db" in inputs and any(t in outcome.stderr for t in late):
                # adapt commits each task to its database as it goes; outputs that fail
                # to write after the run leave those tasks there, to resume from.
                db = os.path.relpath(os.path.realpath(inputs["--db"]), sandbox.resolve())
                changed = {k for k in changed if not _within(k, [db])}
            assert not changed, f"exit 2 changed {sorted(changed)}: {description}"
        else:
            written = [output, *([inputs["--db"]] if "--db" in inputs else [])]
            allowed = [
                str(Path(os.path.realpath(p)).relative_to(os.path.realpath(sandbox)))
                for p in written
                if Path(os.path.realpath(sandbox)) in Path(os.path.realpath(p)).parents
            ]
            outside = {k for k in changed if not _within(k, allowed)}
            assert not outside, f"changed outside the output: {sorted(outside)}; {description}"
    finally:
        shutil.rmtree(base, ignore_errors=True)
        for key in ("read-only-fs", "full-disk"):
            fs = world.get(key)
            if fs is not None:
                for entry in fs.iterdir():
                    if entry.name != "filler":
                        if entry.is_dir() and not entry.is_symlink():
                            shutil.rmtree(entry, ignore_errors=True)
                        else:
                            entry.unlink()


def _kinds(command: Command) -> st.SearchStrategy[dict[str, str]]:
    """A kind for every role at once: most inputs good, the output often hostile."""
    roles = {role: st.sampled_from(["good", "good", *INPUT_KINDS]) for role in command.inputs}
    if command.output == "folder":
        roles["-o"] = st.sampled_from(FOLDER_OUTPUT_KINDS)
    elif command.output:
        roles["-o"] = st.sampled_from(FILE_OUTPUT_KINDS)
    return st.fixed_dictionaries(roles)


def _fuzz(command: Command, examples: int, world: dict[str, Path | None], log: FailureLog) -> None:
    @fuzz_settings(examples)
    @given(_kinds(command), st.sampled_from(["absolute", "relative", "detour"]))
    def run(kinds: dict[str, str], form: str) -> None:
        log.check(lambda: _case(command, kinds, form, world), f"{command.name} {kinds} {form}")

    run()


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c.name)
def test_hostile_paths(command: Command, world: dict[str, Path | None]) -> None:
    log = FailureLog("paths", command.name)
    _fuzz(command, FAST_EXAMPLES, world, log)
    log.finish()


@pytest.mark.slow
@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c.name)
def test_hostile_paths_thousands(command: Command, world: dict[str, Path | None]) -> None:
    log = FailureLog("paths", command.name)
    _fuzz(command, SLOW_EXAMPLES, world, log)
    log.finish()

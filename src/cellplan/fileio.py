"""Files cellplan reads and writes: atomic outputs, staged output folders, checked inputs.

Outputs. A file is written to a temporary name in the same folder, then renamed onto
its target (:func:`atomic_path`), so an interrupted run never leaves a half-written
file behind: the target either keeps its old content or gets the complete new one. A
command that fills a folder writes every file into a temporary folder beside it and
moves them in only when all are written (:func:`staged_folder`): a full disk or an
error half-way leaves the target folder as it was.

Only regular files are ever replaced. A target that is a symbolic link, a device, a
pipe or a socket is refused (:func:`check_replaceable`): renaming onto ``/dev/null``
as root replaces the machine's ``/dev/null``, and writing through a link writes
wherever it points. New files are created with ``O_EXCL`` (``mkstemp``), so a name
never follows a link planted beside the target.

The rename alone protects against the process dying (a crash, ``kill -9``): the
operating system still writes the file out. It does not protect against the
machine losing power or the kernel crashing before the data reached the disk,
when the renamed file can come back empty or the rename itself can be lost.
``durable=True`` closes that gap for files whose loss would lose work (cache
entries of finished runs): the temporary file is flushed to disk (``fsync``)
before the rename and the folder after it, at the cost of a disk round trip.

Inputs. :func:`open_input` opens a file the user named and refuses anything but a
regular file before a byte is read: a link to ``/dev/zero`` or ``/dev/urandom``
would otherwise be read without end, and a FIFO would block.
"""

from __future__ import annotations

import contextlib
import fnmatch
import glob
import json
import math
import os
import shutil
import stat
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

from cellplan.errors import ArgumentError, PersistenceError, Problem

#: Longest file name most file systems take (``NAME_MAX``), when the system cannot say.
DEFAULT_NAME_MAX = 255


def name_max(folder: str | os.PathLike[str]) -> int:
    """The longest file name the file system of ``folder`` (or its nearest existing
    ancestor) accepts."""
    path = Path(folder).absolute()
    for candidate in (path, *path.parents):
        if candidate.is_dir():
            with contextlib.suppress(OSError, ValueError):
                return int(os.pathconf(candidate, "PC_NAME_MAX"))
            break
    return DEFAULT_NAME_MAX


def kind_of(mode: int) -> str:
    """What a non-regular file is, in words (for messages)."""
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a pipe (FIFO)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def check_replaceable(target: str | os.PathLike[str], field: str | None = None) -> Path:
    """Refuse ``target`` unless it is absent or a regular file (never followed if a link).

    Parameters
    ----------
    target
        A file cellplan is about to create or replace.
    field
        What names the target in the error (an option such as ``--db``); the path
        itself when None.

    Raises
    ------
    ArgumentError
        One line: the target is a link, a folder, a device, a FIFO or a socket, or its
        name is longer than the file system allows.
    """
    target = Path(target)
    where = str(target) if field is None else field
    limit = name_max(target.parent)
    if len(os.fsencode(target.name)) > limit:
        raise ArgumentError(
            f"the file name is {len(os.fsencode(target.name))} bytes; this file system takes "
            f"at most {limit}",
            where,
        )
    try:
        st = os.lstat(target)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise ArgumentError(f"cannot use {target} ({exc.strerror or exc})", where) from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        what = kind_of(st.st_mode)
        hint = (
            "give a file name"
            if stat.S_ISDIR(st.st_mode)
            else "cellplan replaces only regular files"
        )
        raise ArgumentError(f"{target} is {what}; {hint}", where)
    return target


def fsync_path(path: str | os.PathLike[str]) -> None:
    """Flush a file's or a folder's contents to disk (``fsync``; a folder: its entries)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str], durable: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    The temporary file keeps the target's suffix so that writers which infer the
    format from the extension (matplotlib, numpy) behave the same. ``durable``:
    ``fsync`` the file before the rename and the folder after it (see the module
    docstring).

    Raises
    ------
    ArgumentError
        ``target`` exists and is not a regular file (:func:`check_replaceable`), checked
        before anything is written and again just before the rename.
    """
    target = Path(target)
    check_replaceable(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    # O_EXCL (mkstemp's own flag) never follows a link planted at the temporary name.
    # The name is short and independent of the target's stem (".XXXXXXXX.tmp.png"), so
    # a legal long target name still gets a legal temporary name; the suffix is kept for
    # writers that read the format from it.
    fd, tmp_name = tempfile.mkstemp(
        prefix=".",
        suffix=".tmp" + (target.suffix if len(target.suffix) <= 16 else ""),
        dir=target.parent,
    )
    os.close(fd)
    tmp = Path(tmp_name)
    # mkstemp creates the file private (0600); give it the usual permissions.
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o666 & ~umask)
    try:
        yield tmp
        if durable:
            fsync_path(tmp)
        check_replaceable(target)  # the writer may have run long: look again
        os.replace(tmp, target)
        if durable:
            fsync_path(target.parent)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def staged_folder(
    target: str | os.PathLike[str],
    keep: Mapping[str, str | os.PathLike[str]] | None = None,
    option: str = "--output",
) -> Iterator[Path]:
    """Yield an empty temporary folder; on success move its files into ``target``.

    A command writes all its outputs into the yielded folder. Only when the block ends
    without an exception are they moved into ``target`` (created if missing), each by
    one rename, so an error half-way (a full disk, a bug, Ctrl-C) leaves ``target`` as
    it was: no half-written file, no folder that was not there before.

    Parameters
    ----------
    target
        The output folder.
    keep
        Files that must not be replaced (``field -> path``: the command's inputs). A
        staged file that would land on one of them is refused before anything is moved
        (:func:`check_distinct` refuses the same before any work; this is the last
        line of defence for names known only at the end).
    option
        What names ``target`` in errors.

    Raises
    ------
    ArgumentError
        A staged file would replace an input, or a file in ``target`` it would replace
        is not a regular file.
    """
    target = Path(target)
    parent = target.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".cellplan-", suffix=".staging", dir=parent))
    try:
        yield stage
        moves = [
            (path, target / path.relative_to(stage))
            for path in sorted(stage.rglob("*"))
            if not path.is_dir()
        ]
        guarded = {field: Path(p) for field, p in (keep or {}).items()}
        for _, dest in moves:
            check_replaceable(dest, option)
            for field, path in guarded.items():
                if same_file(dest, path):
                    raise ArgumentError(
                        f"{dest} is the input given as {field}; writing it would destroy it",
                        option,
                    )
        target.mkdir(parents=True, exist_ok=True)
        for src, dest in moves:
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dest)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name one file: the same inode (hard links, links followed), or,
    where either is missing, the same resolved path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def check_distinct(
    outputs: Iterable[tuple[str, str | os.PathLike[str]]],
    inputs: Mapping[str, str | os.PathLike[str]],
) -> None:
    """Refuse, before any work, an output file that is one of the inputs.

    Parameters
    ----------
    outputs
        ``(option, file)`` pairs the command will write (a folder output lists each
        file it writes there under the folder's option). A name may be a pattern
        (``frame_*.png``) for files numbered at run time.
    inputs
        ``option -> file`` the command reads or updates (scenario, strategy, database).

    Raises
    ------
    ArgumentError
        One line per collision, naming the output option and the input it would destroy.
    """
    problems = [
        Problem(option, f"{out} is the input given as {field}; writing it would destroy it")
        for option, out in outputs
        for field, inp in inputs.items()
        if _lands_on(Path(out), Path(inp))
    ]
    if problems:
        raise ArgumentError(list(dict.fromkeys(problems)))


def _lands_on(out: Path, inp: Path) -> bool:
    if not glob.has_magic(out.name):
        return same_file(out, inp)
    real = Path(os.path.realpath(inp))  # a link into the folder lands where it points
    return fnmatch.fnmatchcase(real.name, out.name) and same_file(out.parent, real.parent)


def open_input(path: str | os.PathLike[str], field: str | None = None) -> IO[bytes]:
    """Open a file the user named for reading, refusing anything but a regular file.

    Links are followed (a link to a scenario file is fine), but what they lead to must
    be a regular file: devices (``/dev/zero``), FIFOs and sockets are refused before a
    byte is read. The file is opened non-blocking first so a FIFO cannot hang the
    check, then switched back to blocking reads.

    Raises
    ------
    PersistenceError
        One line naming ``field`` (the path when None): missing, a folder, not a
        regular file, or unreadable.
    """
    where = str(path) if field is None else field
    named = "" if field is None else f"{path} "  # the path leads the line when it is the field
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise PersistenceError(f"{named}no such file".strip(), where) from None
    except IsADirectoryError:
        raise PersistenceError(f"{named}is a folder, not a file", where) from None
    except OSError as exc:
        raise PersistenceError(f"{named}cannot be read ({exc.strerror or exc})", where) from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise PersistenceError(
                f"{named}is {kind_of(mode)}, not a regular file; give a file", where
            )
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def write_text(target: str | os.PathLike[str], text: str, durable: bool = False) -> Path:
    """Write ``text`` to ``target`` atomically and return the target path.

    ``durable``: flushed to disk before it is renamed into place (:func:`atomic_path`).
    """
    with atomic_path(target, durable) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(target)


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON's null), numpy
    scalars and arrays as Python numbers and lists, and paths as strings.

    RFC 8259 has no NaN or Infinity: ``jq`` and ``JSON.parse`` reject files holding
    them, so every JSON cellplan writes goes through this.
    """
    if hasattr(value, "tolist") and not isinstance(value, str):
        value = value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


def dumps_json(data: Any, indent: int | None = None) -> str:
    """``data`` as strict JSON text (:func:`json_safe`; never NaN or Infinity)."""
    return json.dumps(json_safe(data), indent=indent, allow_nan=False)


def write_json(target: str | os.PathLike[str], data: Any) -> Path:
    """Write ``data`` as indented, strict JSON (:func:`dumps_json`) to ``target`` atomically."""
    return write_text(target, dumps_json(data, indent=2) + "\n")

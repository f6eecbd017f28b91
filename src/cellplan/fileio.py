"""Atomic output files: write to a temporary name in the same folder, then rename.

An interrupted run therefore never leaves a half-written file behind: the
target either keeps its old content or gets the complete new one.

The rename alone protects against the process dying (a crash, ``kill -9``): the
operating system still writes the file out. It does not protect against the
machine losing power or the kernel crashing before the data reached the disk,
when the renamed file can come back empty or the rename itself can be lost.
``durable=True`` closes that gap for files whose loss would lose work (cache
entries of finished runs): the temporary file is flushed to disk (``fsync``)
before the rename and the folder after it, at the cost of a disk round trip.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any


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
    """
    target = Path(target)
    if target.is_dir():
        # Checked first so the error names the target, not the temporary file.
        raise IsADirectoryError(21, "is a folder; give a file name", str(target))
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent
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
        os.replace(tmp, target)
        if durable:
            fsync_path(target.parent)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text(target: str | os.PathLike[str], text: str, durable: bool = False) -> Path:
    """Write ``text`` to ``target`` atomically and return the target path.

    ``durable``: flushed to disk before it is renamed into place (:func:`atomic_path`).
    """
    with atomic_path(target, durable) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(target)


def write_json(target: str | os.PathLike[str], data: Any) -> Path:
    """Write ``data`` as indented JSON to ``target`` atomically."""
    return write_text(target, json.dumps(data, indent=2, sort_keys=False, default=_jsonable) + "\n")


def _jsonable(value: Any) -> Any:
    # numpy scalars and arrays appear in metrics; everything else is a bug.
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")

"""Reading ``.npz`` archives against a declared format, before any array reaches a kernel.

A format is a mapping ``name -> ArraySpec``: the dtype, the shape as expressions in named
sizes (``("M", "N")``, ``("M + 1",)``, ``("K", "A", "T", "2 ** d")``), and the range of
the values (bounds that are expressions too, whether NaN or infinities may appear).
:func:`read_arrays` checks, in this order and naming the file and the array in every
message:

1. the archive: a readable zip of ``<name>.npy`` members, no member missing or unknown;
2. each member's ``.npy`` header *before its data is read*: the exact dtype (never an
   object dtype: no pickles), C order, the shape against the expressions (a size met for
   the first time is taken from the file, within its declared limit), and the memory the
   whole archive will take against the memory available;
3. the data: the exact byte count, the CRC of the zip member (a bit flip is caught),
   booleans stored as 0 or 1, NaN and infinities only where allowed, every value within
   its bounds.

Anything wrong raises :class:`~cellplan.errors.PersistenceError` with one problem.
"""

from __future__ import annotations

import ast
import math
import operator
import tokenize
import zipfile
import zlib
from collections.abc import Callable, Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from cellplan import budget
from cellplan.errors import PersistenceError, Problem
from cellplan.fileio import open_input


@dataclass(frozen=True)
class ArraySpec:
    """One array of a file format.

    Attributes
    ----------
    dtype
        The numpy dtype (``"int64"``, ``"float64"``, ``"bool"``), or ``"str"`` for a
        0-d unicode string of at most ``max_chars`` characters.
    shape
        One expression per axis in the named sizes: an integer, a name, or ``+ - * **``
        of those. A bare name not yet known is read from the file.
    low, high
        Inclusive bounds of the values (expressions, or None).
    nan, inf
        Whether NaN, or infinities (within the bounds), may appear.
    doc
        What the array holds (for the documentation).
    """

    dtype: str
    shape: tuple[str, ...] = ()
    low: str | None = None
    high: str | None = None
    nan: bool = False
    inf: bool = False
    max_chars: int = 1_000_000
    doc: str = ""


_OPS: dict[type, Callable[[int, int], int]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Pow: operator.pow,
}
Fail = Callable[[str, str], PersistenceError]


def evaluate(expr: str, sizes: Mapping[str, int]) -> int:
    """Value of a size expression (KeyError for an unknown name)."""

    def ev(node: ast.AST) -> int:
        if isinstance(node, ast.Constant) and isinstance(node.value, int):
            return int(node.value)
        if isinstance(node, ast.Name):
            return int(sizes[node.id])
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            return int(_OPS[type(node.op)](ev(node.left), ev(node.right)))
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return -ev(node.operand)
        raise ValueError(f"unsupported size expression {expr!r}")

    return ev(ast.parse(expr, mode="eval").body)


def read_arrays(
    path: str | Path,
    specs: Mapping[str, ArraySpec],
    sizes: MutableMapping[str, int],
    limits: Mapping[str, tuple[int, int]] | None = None,
    *,
    first: tuple[str, ...] = (),
    after_first: Callable[[dict[str, np.ndarray], MutableMapping[str, int]], None] | None = None,
    what: str = "a .npz archive",
    working: Callable[[Mapping[str, int]], int] | None = None,
) -> dict[str, np.ndarray]:
    """Read and check every array of ``path`` against ``specs``.

    Parameters
    ----------
    sizes
        The sizes known beforehand (from metadata); sizes read from the file are added.
    limits
        ``name -> (lo, hi)`` for the sizes read from the file.
    first, after_first
        Arrays to read before the others, and a callable ``f(arrays, sizes)`` run after
        them (to bind sizes from their contents, e.g. metadata in a string array).
    what
        The kind of file, for messages (``not a strategy file (...)``).
    working
        Bytes the caller needs beside the arrays (its checks' temporaries), from the
        sizes; counted with the arrays' bytes against the memory available.
    """
    where = str(path)
    limits = {} if limits is None else limits  # the caller may fill it after the first arrays

    def fail(field: str, message: str) -> PersistenceError:
        return PersistenceError([Problem(where, f"{field}: {message}" if field else message)])

    # A device or FIFO (a link to /dev/zero, say) is refused before zipfile reads it
    # without end; the archive then reads the regular file it was.
    open_input(path).close()
    try:
        archive = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise PersistenceError([Problem(where, "no such file")]) from None
    except IsADirectoryError:
        raise PersistenceError([Problem(where, "is a folder, not a file")]) from None
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise fail("", f"not {what} ({_short(exc)})") from None
    out: dict[str, np.ndarray] = {}
    with archive:
        members: dict[str, zipfile.ZipInfo] = {}
        for info in archive.infolist():
            name = info.filename
            if not name.endswith(".npy") or name[:-4] in members:
                raise fail(name, "unexpected member of the archive")
            # numpy writes stored or deflated members, never encrypted ones; a flipped
            # flag bit or method would make zipfile raise RuntimeError/NotImplementedError.
            if info.flag_bits & 0x1:
                raise fail(name, "encrypted member (not written by numpy; a damaged file?)")
            if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise fail(name, f"unsupported compression method {info.compress_type}")
            members[name[:-4]] = info
        missing = [n for n in specs if n not in members]
        if missing:
            raise fail(missing[0], f"missing array (not {what}, or a damaged one)")
        unknown = sorted(set(members) - set(specs))
        if unknown:
            raise fail(unknown[0], "unexpected array (not part of this file format)")
        order = [*first, *(n for n in specs if n not in first)]
        # What the zip directory claims, before any member is opened.
        budget.require(sum(members[n].file_size for n in order), where, "to read")
        headers: dict[str, tuple[tuple[int, ...], np.dtype]] = {}

        def attempt(name: str, read_data: bool) -> None:
            spec = specs[name]
            try:
                with archive.open(members[name]) as fh:
                    shape, dtype = _read_header(
                        fh, name, spec, sizes, limits, fail, members[name].file_size
                    )
                    headers[name] = (shape, dtype)
                    if read_data:
                        out[name] = _read_data(fh, name, spec, shape, dtype, sizes, fail)
            except PersistenceError:
                raise
            except (
                zipfile.BadZipFile,
                zlib.error,
                EOFError,
                OSError,
                ValueError,
                RuntimeError,
                NotImplementedError,
                # numpy tokenizes a .npy header before it parses it: an unbalanced bracket
                # (one flipped bit) raises these, not ValueError.
                tokenize.TokenError,
                SyntaxError,
            ) as exc:
                raise fail(name, f"unreadable ({_short(exc)})") from None

        for name in first:
            attempt(name, True)
        if first and after_first is not None:
            after_first(out, sizes)
        rest = [n for n in order if n not in first]
        # Every header before any data: the sizes the file declares are checked against
        # their limits and the memory they need against the memory available while only
        # a few hundred bytes of each member have been inflated (a small file of deflated
        # zeros may declare gigabytes).
        for name in rest:
            attempt(name, False)
        declared = sum(_nbytes(*headers[n]) for n in rest)
        need = declared + (working(sizes) if working is not None else 0)
        budget.require(need, where, "to read")
        for name in rest:
            attempt(name, True)
    return out


def _short(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:120] or type(exc).__name__


def _read_header(
    fh: IO[bytes],
    name: str,
    spec: ArraySpec,
    sizes: MutableMapping[str, int],
    limits: Mapping[str, tuple[int, int]],
    fail: Fail,
    stored: int,
) -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype a member's ``.npy`` header declares, checked against ``spec``
    and the sizes (a size met for the first time is bound here), before any data."""
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version == (1, 0):
        shape, fortran, dtype = fmt.read_array_header_1_0(fh)
    elif version in ((2, 0), (3, 0)):
        shape, fortran, dtype = fmt.read_array_header_2_0(fh)
    else:
        raise fail(name, f"unsupported .npy version {version}")
    if dtype.hasobject:
        raise fail(name, "holds Python objects (pickles are never loaded)")
    if fortran:
        raise fail(name, "stored in Fortran order (expected C order)")
    if spec.dtype == "str":
        if dtype.kind != "U" or shape != () or dtype.itemsize // 4 > spec.max_chars:
            raise fail(name, f"expected a text of at most {spec.max_chars} characters")
    elif dtype != np.dtype(spec.dtype):
        raise fail(name, f"dtype {dtype.str} (expected {np.dtype(spec.dtype).name})")
    if len(shape) != len(spec.shape):
        raise fail(name, f"shape {shape} (expected {len(spec.shape)} axes: {spec.shape})")
    for axis, (expr, n) in enumerate(zip(spec.shape, shape, strict=True)):
        if expr.isidentifier() and expr not in sizes:
            lo, hi = limits.get(expr, (0, 2**31))
            if not lo <= n <= hi:
                raise fail(name, f"axis {axis} ({expr}) is {n}, expected {lo} to {hi}")
            sizes[expr] = n
        expected = evaluate(expr, sizes)
        if n != expected:
            raise fail(name, f"shape {shape}, expected axis {axis} ({expr}) to be {expected}")
    if _nbytes(shape, dtype) > stored:
        raise fail(name, "data size does not match its header (truncated or padded)")
    return shape, dtype


def _nbytes(shape: tuple[int, ...], dtype: np.dtype) -> int:
    """Bytes of an array (Python integers: a declared shape cannot wrap round)."""
    return math.prod(shape) * dtype.itemsize


def _read_data(
    fh: IO[bytes],
    name: str,
    spec: ArraySpec,
    shape: tuple[int, ...],
    dtype: np.dtype,
    sizes: Mapping[str, int],
    fail: Fail,
) -> np.ndarray:
    """The data after a checked header: exactly its byte count, values within ``spec``."""
    nbytes = _nbytes(shape, dtype)
    arr = np.empty(shape, dtype)
    view = arr.reshape(-1).view(np.uint8)
    got = fh.readinto(view.data) if nbytes else 0  # type: ignore[attr-defined]
    if got != nbytes or fh.read(1):
        raise fail(name, "data size does not match its header (truncated or padded)")
    _check_values(arr, name, spec, sizes, fail)
    return arr


def _check_values(
    arr: np.ndarray, name: str, spec: ArraySpec, sizes: Mapping[str, int], fail: Fail
) -> None:
    if spec.dtype == "str" or arr.size == 0:
        return
    if arr.dtype == np.bool_:
        if arr.view(np.uint8).max() > 1:
            raise fail(name, "booleans other than 0 and 1")
        return
    values = arr
    if arr.dtype.kind == "f":
        if not spec.nan and np.isnan(arr).any():
            raise fail(name, "contains NaN")
        if not spec.inf and np.isinf(arr).any():
            raise fail(name, "contains infinite values")
        values = arr[~np.isnan(arr)]
        if values.size == 0:
            return
    lo = evaluate(spec.low, sizes) if spec.low is not None else None
    hi = evaluate(spec.high, sizes) if spec.high is not None else None
    if lo is not None and values.min() < lo:
        raise fail(name, f"value {values.min()} below {lo} (expected {lo} to {spec.high})")
    if hi is not None and values.max() > hi:
        raise fail(name, f"value {values.max()} above {hi} (expected {spec.low} to {hi})")

"""Hostile strategy files: every crafted file is refused with one line, or is safe to use.

Crafted from a real solved file (the bundled ``strategies_tiny``): corrupt and truncated
bytes, dropped and added arrays, wrong dtypes and shapes, out-of-range indices, NaN and
infinities, metadata with missing keys, wrong types and broken JSON, plain ``.npy``
files, pickled object arrays. In-process through :meth:`Strategy.load` (then a short
simulation of anything accepted), and, for the cases that once crashed the interpreter
with SIGSEGV, in a subprocess that must exit 2. The ``slow`` variant runs 1,000 crafted
files through ``cellplan simulate`` and ``cellplan plot``.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cellplan.api import load
from cellplan.errors import CellplanError, PersistenceError
from cellplan.setup import Setup
from cellplan.strategies.policy.fileformat import ARRAYS
from cellplan.strategies.policy.strategy import Strategy, solve_scenario
from cellplan.strategies.sim.simulate import simulate_result

SCENARIO = "strategies_tiny"


def solved_file(source: str | Setup, folder: Path) -> tuple:
    """A solved strategy file of a bundled scenario (or a setup): (setup, path, arrays, meta)."""
    setup = load(source) if isinstance(source, str) else source
    strategy, _ = solve_scenario(setup.scenario, setup.workcell)
    path = strategy.save(folder / "base.npz")
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))
    return setup, path, arrays, meta


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A solved strategy file of the bundled tiny scenario."""
    return solved_file(SCENARIO, tmp_path_factory.mktemp("base"))


INT_FIELDS = [n for n, s in ARRAYS.items() if s.dtype == "int64"]
FLOAT_FIELDS = [n for n, s in ARRAYS.items() if s.dtype == "float64"]
INDEX_VALUES = [-1, -2, -(2**63), 2**62, 2**31, 10**9, 144, 145, 5, 6, 8, 63, 64]
FLOAT_VALUES = [np.nan, np.inf, -np.inf, 1e308, -1e308, -1.0, 2.0, 1e-300, 0.0, 1e30]
META_VALUES = ["x", "", 1, -1, 0, 1.5, None, [], {}, [1, 2], True, 1e308, 10**30, "NaN"]
KINDS = [
    "truncate",
    "flip",
    "bytes",
    "drop",
    "add",
    "dtype",
    "shape",
    "index",
    "float",
    "meta_drop",
    "meta_type",
    "meta_nested",
    "meta_text",
    "npy",
    "pickle",
]


def _write(path: Path, arrays: dict, meta: object, compressed: bool) -> Path:
    payload = dict(arrays)
    if meta is not None:
        payload["meta"] = np.array(meta if isinstance(meta, str) else json.dumps(meta))
    with open(path, "wb") as fh:
        (np.savez_compressed if compressed else np.savez)(fh, **payload)
    return path


def craft(data, base, folder: Path) -> tuple[str, Path]:
    """One crafted file (kind, path), drawn with hypothesis ``data``."""
    _, good, arrays, meta = base
    arrays = {k: v.copy() for k, v in arrays.items()}
    meta = json.loads(json.dumps(meta))
    kind = data.draw(st.sampled_from(KINDS), label="kind")
    path = folder / f"{kind}.npz"
    compressed = data.draw(st.booleans(), label="compressed")
    raw = good.read_bytes()
    if kind == "truncate":
        cut = data.draw(st.integers(0, len(raw) - 1), label="cut")
        path.write_bytes(raw[:cut])
        return kind, path
    if kind == "flip":
        where = data.draw(st.integers(0, len(raw) - 1), label="byte")
        bit = data.draw(st.integers(0, 7), label="bit")
        flipped = bytearray(raw)
        flipped[where] ^= 1 << bit
        path.write_bytes(bytes(flipped))
        return kind, path
    if kind == "bytes":
        path.write_bytes(data.draw(st.binary(max_size=300), label="bytes"))
        return kind, path
    if kind == "npy":
        arr = np.arange(data.draw(st.integers(0, 50), label="n"), dtype=float)
        np.save(path.with_suffix(".npy"), arr)
        path = path.with_suffix(".npy")
        return kind, path
    if kind == "pickle":
        name = data.draw(st.sampled_from([*arrays, "extra"]), label="name")
        arrays[name] = np.array([{"a": 1}, None], dtype=object)
        with open(path, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)
        return kind, path
    name = data.draw(st.sampled_from(sorted(arrays)), label="array")
    if kind == "drop":
        if data.draw(st.booleans(), label="drop meta"):
            return kind, _write(path, arrays, None, compressed)
        del arrays[name]
    elif kind == "add":
        arrays[data.draw(st.sampled_from(["extra", "values2", "x"]), label="new")] = np.zeros(3)
    elif kind == "dtype":
        dtype = data.draw(
            st.sampled_from(["float32", "int32", "float64", "int64", "bool", "uint8", ">i8"]),
            label="dtype",
        )
        with np.errstate(invalid="ignore"):  # NaN values cast to integers: the mutation
            arrays[name] = arrays[name].astype(dtype)
    elif kind == "shape":
        a = arrays[name]
        how = data.draw(st.sampled_from(["axis", "shorter", "longer", "scalar", "empty"]))
        if how == "axis":
            a = a[None]
        elif how == "shorter" and a.ndim:
            a = a[:-1]
        elif how == "longer" and a.ndim:
            a = np.concatenate([a, a[:1]])
        elif how == "scalar":
            a = a.reshape(-1)[:1].reshape(()) if a.size else np.zeros((), a.dtype)
        else:
            a = a.reshape(-1)[:0]
        arrays[name] = a
    elif kind == "index":
        name = data.draw(st.sampled_from(INT_FIELDS), label="int array")
        a = arrays[name].reshape(-1)
        i = data.draw(st.integers(0, a.size - 1), label="index")
        a[i] = data.draw(
            st.sampled_from(INDEX_VALUES) | st.integers(-(2**63), 2**63 - 1), label="value"
        )
    elif kind == "float":
        name = data.draw(st.sampled_from(FLOAT_FIELDS), label="float array")
        a = arrays[name].reshape(-1)
        i = data.draw(st.integers(0, a.size - 1), label="index")
        a[i] = data.draw(st.sampled_from(FLOAT_VALUES) | st.floats(), label="value")
    elif kind == "meta_drop":
        del meta[data.draw(st.sampled_from(sorted(meta)), label="key")]
    elif kind == "meta_type":
        key = data.draw(st.sampled_from(sorted(meta)), label="key")
        meta[key] = data.draw(st.sampled_from(META_VALUES), label="value")
    elif kind == "meta_nested":
        target = data.draw(
            st.sampled_from(["grid.shape", "grid.lower", "grid.periodic", "modes", "labels"])
        )
        value = data.draw(st.sampled_from([*META_VALUES, 10**9, 2, -5]), label="value")
        outer, _, inner = target.partition(".")
        seq = meta[outer][inner] if inner else meta[outer]
        how = data.draw(st.sampled_from(["set", "append", "pop"]), label="how")
        if how == "set" and seq:
            seq[0] = value
        elif how == "append":
            seq.append(value)
        elif seq:
            seq.pop()
    elif kind == "meta_text":
        text = json.dumps(meta)
        choice = data.draw(st.sampled_from(["cut", "text", "list", "deep"]), label="how")
        if choice == "cut":
            text = text[: data.draw(st.integers(0, len(text) - 1))]
        elif choice == "text":
            text = data.draw(st.text(max_size=40), label="text")
        elif choice == "list":
            text = "[1, 2, 3]"
        else:
            text = "[" * 5000 + "]" * 5000
        return kind, _write(path, arrays, text, compressed)
    return kind, _write(path, arrays, meta, compressed)


def check_load(path: Path, setup) -> str:
    """``refused`` (one clean line naming the file) or ``accepted`` (and usable)."""
    try:
        strategy = Strategy.load(path, setup.scenario)
    except PersistenceError as exc:
        assert len(exc.problems) == 1, exc
        line = str(exc)
        assert "\n" not in line and line.startswith(str(path)), line
        return "refused"
    strategy.attach(setup.workcell)
    try:
        simulate_result(strategy, 20, 0, cell=setup.workcell)
    except CellplanError as exc:  # e.g. a recorded start outside the domain: a clean refusal
        assert all("\n" not in str(p) for p in exc.problems)
    return "accepted"


@settings(
    max_examples=40,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_crafted_files_are_refused_cleanly_or_usable(data, base, tmp_path):
    _, path = craft(data, base, tmp_path)
    check_load(path, base[0])


def test_the_untouched_file_loads(base):
    setup, path, _, _ = base
    assert check_load(path, setup) == "accepted"


@pytest.mark.parametrize(
    ("field", "index", "value", "words"),
    [
        ("coff", 0, 10**9, "coff: differs"),
        ("vcls", 1, 99, "vcls: value 99 above"),
        ("branch_layer", 0, 10**6, "branch_layer: value"),
        ("branch_ptr", 1, -(2**40), "branch_ptr: value"),
        ("fmp_next", 0, 7, "fmp_next"),
        ("interior", 0, True, "interior: differs"),
        ("nact", 0, 63, "nact: value"),
        ("shape", 0, 10**6, "shape: value"),
    ],
)
def test_out_of_range_indices_are_named(base, tmp_path, field, index, value, words):
    assert_refused(base, tmp_path, lambda a: a[field].reshape(-1).__setitem__(index, value), words)


def assert_refused(base: tuple, folder: Path, change: Any, words: str) -> None:
    """``change`` (a function of the arrays) makes the file refused with a line matching
    ``words``."""
    setup, _, arrays, meta = base
    arrays = {k: v.copy() for k, v in arrays.items()}
    change(arrays)
    path = _write(folder / "bad.npz", arrays, meta, True)
    with pytest.raises(PersistenceError, match=words):
        Strategy.load(path, setup.scenario)


def test_a_cell_count_past_int64_is_refused(base, tmp_path):
    """4096^6 cells wrap round to 0 in int64: the count is taken in Python integers."""
    _, _, arrays, meta = base
    meta = json.loads(json.dumps(meta))
    meta["grid"] = {"shape": [4096] * 6, "lower": [0.0] * 6, "upper": [1.0] * 6}
    meta["grid"]["periodic"] = [False] * 6
    for key in ("home", "start", "axes"):
        meta.pop(key, None)
    path = _write(tmp_path / "big.npz", arrays, meta, True)
    with pytest.raises(PersistenceError, match=r"meta.grid.shape: 4.72e\+21 cells"):
        Strategy.load(path)


def test_a_pickle_is_never_loaded(base, tmp_path):
    setup, _, arrays, meta = base
    arrays = dict(arrays, values=np.array([object()], dtype=object))
    path = tmp_path / "p.npz"
    with open(path, "wb") as fh:
        np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)
    with pytest.raises(PersistenceError, match="pickles are never loaded"):
        Strategy.load(path, setup.scenario)


def test_a_member_header_that_does_not_tokenize_is_named(base, tmp_path):
    # A flipped bit that unbalances a bracket in a member's .npy header made numpy's header
    # tokenizer raise tokenize.TokenError, which reached the user as exit 70 (found by the
    # slow crafted-file run). The header here is written by hand, its dict left open.
    setup, _, arrays, meta = base
    path = tmp_path / "open.npz"
    with open(path, "wb") as fh:
        np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)
    with zipfile.ZipFile(path) as src:
        members = {i.filename: src.read(i) for i in src.infolist()}
    raw = bytearray(members["values.npy"])
    end = raw.index(b"}")
    raw[end] = ord(" ")  # "{'descr': ... 'shape': (M, N), " and no closing brace
    members["values.npy"] = bytes(raw)
    with zipfile.ZipFile(path, "w") as dst:
        for name, data in members.items():
            dst.writestr(name, data)
    with pytest.raises(PersistenceError, match="values: unreadable"):
        Strategy.load(path, setup.scenario)


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [
        ("flag_bits", 0x1, "encrypted member"),
        ("compress_type", zipfile.ZIP_BZIP2, "unsupported compression method"),
    ],
)
def test_an_encrypted_or_foreign_member_is_named(base, tmp_path, field, value, words):
    # One flipped bit in a member's header used to reach zipfile's RuntimeError (exit 70).
    # The headers are edited in place: zipfile will not write an encrypted member.
    setup, good, _, _ = base
    raw = bytearray(good.read_bytes())
    # (signature, offset of the flags; the method follows at +2)
    for signature, offset in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        at = raw.index(signature) + offset + (2 if field == "compress_type" else 0)
        old = int.from_bytes(raw[at : at + 2], "little")
        new = old | value if field == "flag_bits" else value
        raw[at : at + 2] = new.to_bytes(2, "little")
    path = tmp_path / "odd.npz"
    path.write_bytes(bytes(raw))
    with zipfile.ZipFile(path) as check:  # the edit reached the header zipfile reads
        assert getattr(check.infolist()[0], field) & value == value
    with pytest.raises(PersistenceError, match=words):
        Strategy.load(path, setup.scenario)


def test_a_zip_bomb_header_is_refused_before_reading(base, tmp_path, monkeypatch):
    """An array whose header declares more memory than there is: refused, not allocated."""
    setup, good, _, _ = base
    path = tmp_path / "big.npz"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if info.filename != "values.npy":
                dst.writestr(info.filename, src.read(info))
        buf = io.BytesIO()
        np.save(buf, np.zeros(10**6))  # 8 MB, compresses to almost nothing
        dst.writestr("values.npy", buf.getvalue())
    monkeypatch.setenv("CELLPLAN_MEMORY_LIMIT", "1MB")
    with pytest.raises(CellplanError, match=r"needs about 8\.[0-9] MB to read; this machine has"):
        Strategy.load(path, setup.scenario)


SEGFAULT_CASES = {  # crafted arrays that crashed `simulate` and `plot` before the checks
    "coff": ("coff", 10**9),
    "vcls": ("vcls", 10**6),
    "branch_layer": ("branch_layer", 10**6),
    "interior": ("interior", True),
}


@pytest.mark.parametrize("case", sorted(SEGFAULT_CASES))
@pytest.mark.parametrize("command", ["simulate", "plot"])
def test_segfault_cases_exit_2_in_a_subprocess(base, tmp_path, case, command):
    _, _, arrays, meta = base
    field, value = SEGFAULT_CASES[case]
    arrays = {k: v.copy() for k, v in arrays.items()}
    flat = arrays[field].reshape(-1)
    if field == "interior":
        flat[:] = True  # every cell claims its stencils stay inside: border cells overflow
    else:
        flat[:] = value
    path = _write(tmp_path / "bad.npz", arrays, meta, True)
    extra = ["--stages", "20", "--no-gif"] if command == "simulate" else []
    out = tmp_path / ("run" if command == "simulate" else "x.png")
    args = [command, SCENARIO, "--strategy", str(path), "-o", str(out), *extra]
    proc = subprocess.run(
        [sys.executable, "-m", "cellplan.cli", *args],
        capture_output=True,
        text=True,
        env={**os.environ, "CELLPLAN_DEBUG": ""},
        timeout=300,
    )
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and field in lines[0], proc.stderr
    assert not out.exists()


SLOW_EXAMPLES = int(os.environ.get("CELLPLAN_FUZZ_STRATEGIES", "1000"))
COUNTS: dict[str, int] = {}


@pytest.mark.slow
@settings(
    max_examples=SLOW_EXAMPLES,
    derandomize=True,
    deadline=None,
    database=None,
    suppress_health_check=list(HealthCheck),
)
@given(data=st.data())
def test_slow_crafted_files_through_simulate_and_plot(data, base, cellplan, tmp_path_factory):
    folder = tmp_path_factory.mktemp("crafted")
    kind, path = craft(data, base, folder)
    for command in ("simulate", "plot"):
        out = folder / ("run" if command == "simulate" else "x.png")
        extra = ["--stages", "20", "--no-gif"] if command == "simulate" else []
        r = cellplan(command, SCENARIO, "--strategy", str(path), "-o", str(out), *extra)
        assert r.returncode in (0, 1, 2), (kind, r)
        if r.returncode == 2:
            lines = r.stderr.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith("error: "), (kind, r.stderr)
            assert not out.exists()
        key = f"{command} exit {r.returncode}"
        COUNTS[key] = COUNTS.get(key, 0) + 1
    COUNTS["files"] = COUNTS.get("files", 0) + 1
    COUNTS[f"kind {kind}"] = COUNTS.get(f"kind {kind}", 0) + 1


@pytest.mark.slow
def test_slow_report_counts():
    """Print the figures of the slow run (run after it: ``-s`` shows them)."""
    if not COUNTS:
        pytest.skip("run together with test_slow_crafted_files_through_simulate_and_plot")
    print("\ncrafted strategy files:", json.dumps(COUNTS, sort_keys=True), time.strftime("%H:%M"))
    assert COUNTS["files"] >= min(SLOW_EXAMPLES, 1000)


def test_sizes_read_from_the_file_are_held_to_their_limits(base, tmp_path):
    # The limits of SIZE_LIMITS (K <= M move classes here) are filled in after the
    # metadata is read; they were once dropped (an empty dict replaced by a new one).
    setup, _, arrays, meta = base
    arrays = {k: v.copy() for k, v in arrays.items()}
    M = len(meta["modes"])
    arrays["free"] = np.ones((M + 1, arrays["free"].shape[1]), bool)
    path = _write(tmp_path / "bad.npz", arrays, meta, True)
    with pytest.raises(
        PersistenceError, match=rf"free: axis 0 \(K\) is {M + 1}, expected 1 to {M}"
    ):
        Strategy.load(path, setup.scenario)

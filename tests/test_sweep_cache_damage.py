"""Damaged runner-cache entries that defeated the parser (issue 36): each one recomputed.

200,000 ``[`` made ``json.loads`` raise ``RecursionError``, which ``RunCache.get`` did not
catch, so one such entry aborted the whole ``reproduce`` sweep with exit 70.
"""

from __future__ import annotations

import io
import json
from dataclasses import replace
from pathlib import Path

import pytest
from rich.console import Console

import fake_sweep_experiments as fake
from cellplan import experiments as ex
from cellplan.core import RunSpec

DAMAGE = {
    "200,000 [": "[" * 200_000,
    "200,000 {": '{"a":' * 200_000,
    "nested 900 deep, then valid": '{"format": ' + "[" * 900 + "]" * 900 + "}",
    "1e400 (infinity)": None,  # filled from a real entry below
    "a 100,000-digit integer": None,
    "not UTF-8": b"\xff\xfe{".decode("latin-1"),
    "over the size limit": " " * (ex.MAX_ENTRY_BYTES + 1) + "{}",
}


def entries_of(folder: Path) -> list[Path]:
    return sorted((folder / "cache" / "fake.grid").rglob("*.json"))


@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_every_damaged_entry_is_recomputed(tmp_path: Path, damage: str) -> None:
    original = ex.run_sweep([fake.grid()], 2, False, tmp_path, serial=True, progress=False)
    entry = entries_of(tmp_path)[0]
    text = DAMAGE[damage]
    good = json.loads(entry.read_text())
    if damage.startswith("1e400"):
        good["row"]["area"] = "INF"
        text = json.dumps(good).replace('"INF"', "1e400")
    elif damage.startswith("a 100,000"):
        good["row"]["hits"] = "BIG"
        text = json.dumps(good).replace('"BIG"', "7" * 100_000)
    assert text is not None
    entry.write_bytes(text.encode("latin-1") if damage == "not UTF-8" else text.encode())

    calls: list[RunSpec] = []

    def run(spec: RunSpec) -> dict[str, object]:
        calls.append(spec)
        return fake.grid_run(spec)

    log = io.StringIO()
    again = ex.run_sweep(
        [replace(fake.grid(), run=run)],
        2,
        False,
        tmp_path,
        serial=True,
        progress=False,
        console=Console(file=log, width=400),
    )
    assert again.runs[0].n_recomputed_corrupt == 1
    assert log.getvalue().count("recomputing") == 1
    assert len(calls) == 1 + 2  # the damaged entry, and the two runs that always fail
    rows = [{k: v for k, v in r.items() if k != "run_wall_s"} for r in again.runs[0].rows]
    assert rows == [
        {k: v for k, v in r.items() if k != "run_wall_s"} for r in original.runs[0].rows
    ]
    # rewritten, and trusted again: a third sweep runs only the two failing runs
    calls.clear()
    ex.run_sweep([replace(fake.grid(), run=run)], 2, False, tmp_path, serial=True, progress=False)
    assert len(calls) == 2

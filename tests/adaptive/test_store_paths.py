"""The experience database and ``adapt``'s outputs against hostile paths (issue 36).

A database path that is a device or a FIFO is refused, never replaced; the lock's sidecar
is never followed through a link; one database reached through a symbolic link or a hard
link has one lock; a database without its content checksum is refused; and an output
that would land on the database or the scenario is refused before any work.
"""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from adaptive_scenarios import POINT_SCENARIO  # type: ignore[import-not-found]

from cellplan.adaptive.commands import OUTPUT_FILES, write_outputs
from cellplan.adaptive.store import ExperienceStore
from cellplan.api import load, plan
from cellplan.errors import PersistenceError
from cellplan.scenario import Scenario, loads_scenario

HERE = Path(__file__).parent


def _cellplan(*args: str, **kw: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cellplan.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
        **kw,
    )


@pytest.fixture(scope="module")
def sc() -> Scenario:
    return loads_scenario(POINT_SCENARIO)


@pytest.fixture
def scenario_file(tmp_path: Path) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(POINT_SCENARIO, encoding="utf-8")
    return path


# --- paths that are not files ------------------------------------------------------------------


def test_a_link_to_dev_null_is_refused_and_dev_null_kept(sc: Scenario, tmp_path: Path) -> None:
    before = os.stat("/dev/null")
    link = tmp_path / "null.sqlite"
    link.symlink_to("/dev/null")
    with pytest.raises(PersistenceError, match="is a device"):
        ExperienceStore(link, sc)
    after = os.stat("/dev/null")
    assert (after.st_ino, after.st_mode) == (before.st_ino, before.st_mode)
    assert not Path("/dev/null.lock").exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="mknod needs root (CI runs as root)")
def test_a_device_node_given_as_db_stays_a_device(scenario_file: Path, tmp_path: Path) -> None:
    node = tmp_path / "mynull"
    os.mknod(node, 0o666 | 0o020000, os.makedev(1, 3))  # a character device, as /dev/null
    r = _cellplan("adapt", str(scenario_file), "--db", str(node), "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"error: --db: {node} is a device; cellplan replaces only regular files"
    ]
    assert not node.is_file() and node.is_char_device()
    assert not (tmp_path / "out").exists()


def test_a_fifo_given_as_db_is_refused_without_blocking(
    scenario_file: Path, tmp_path: Path, sc: Scenario
) -> None:
    fifo = tmp_path / "pipe.sqlite"
    os.mkfifo(fifo)
    r = _cellplan("adapt", str(scenario_file), "--db", str(fifo), "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "pipe (FIFO)" in r.stderr
    with pytest.raises(PersistenceError, match="pipe"):
        ExperienceStore(fifo, sc)
    assert Path(fifo).is_fifo()


@pytest.mark.parametrize("kind", ["symlink", "fifo"])
def test_a_planted_lock_file_is_refused_and_its_target_untouched(
    kind: str, sc: Scenario, tmp_path: Path
) -> None:
    db = tmp_path / "exp.sqlite"
    lock = tmp_path / "exp.sqlite.lock"
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n", encoding="utf-8")
    if kind == "symlink":
        lock.symlink_to(victim.name)
    else:
        os.mkfifo(lock)
    with pytest.raises(PersistenceError, match=r"not a regular file|symbolic link"):
        ExperienceStore(db, sc)
    assert victim.read_text(encoding="utf-8") == "precious\n"
    assert not db.exists()


def test_a_database_name_too_long_for_its_sidecars_is_one_line(
    scenario_file: Path, tmp_path: Path
) -> None:
    db = tmp_path / ("d" * 250 + ".sqlite")[-250:]
    r = _cellplan("adapt", str(scenario_file), "--db", str(db), "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "too long" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


# --- one database, one lock, whatever its name -------------------------------------------------


@pytest.mark.parametrize("alias", ["symlink", "hardlink", "relative"])
def test_one_database_reached_by_two_names_has_one_lock(
    alias: str, sc: Scenario, tmp_path: Path
) -> None:
    real = tmp_path / "real.sqlite"
    ExperienceStore(real, sc).close()  # exists, with no run state yet
    other = tmp_path / "alias.sqlite"
    if alias == "symlink":
        other.symlink_to(real.name)
    elif alias == "hardlink":
        os.link(real, other)
    else:
        other = tmp_path / "sub" / ".." / "real.sqlite"
        (tmp_path / "sub").mkdir()
    with ExperienceStore(real, sc):
        with pytest.raises(PersistenceError, match="in use by"):
            ExperienceStore(other, sc)
    with ExperienceStore(other, sc):  # free again once the first closes
        with pytest.raises(PersistenceError, match="in use by"):
            ExperienceStore(real, sc)


def test_a_second_adapt_through_a_link_gets_the_in_use_line(
    scenario_file: Path, tmp_path: Path
) -> None:
    real = tmp_path / "real.sqlite"
    alias = tmp_path / "alias.sqlite"
    proc = subprocess.Popen(
        [sys.executable, str(HERE / "db_child.py"), "hold", str(real), str(scenario_file)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        os.link(real, alias)
        r = _cellplan("adapt", str(scenario_file), "--db", str(alias), "-o", str(tmp_path / "o"))
        assert r.returncode == 2
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "in use by" in lines[0], r.stderr
        assert not (tmp_path / "o").exists()
    finally:
        proc.kill()
        proc.wait()


# --- the checksum is not optional ---------------------------------------------------------------


def test_a_database_without_its_checksum_is_refused(sc: Scenario, tmp_path: Path) -> None:
    db = tmp_path / "exp.sqlite"
    ExperienceStore(db, sc).close()
    with sqlite3.connect(db) as conn:
        conn.execute("DELETE FROM meta WHERE key = 'digest'")
    conn.close()
    with pytest.raises(PersistenceError, match="no content checksum"):
        ExperienceStore(db, sc)


# --- outputs never land on inputs ---------------------------------------------------------------


@pytest.mark.parametrize("name", ["tasks.csv", "summary.json", "graph.graphml", "paths.csv"])
def test_an_output_that_is_the_database_is_refused_before_work(
    name: str, scenario_file: Path, tmp_path: Path
) -> None:
    out = tmp_path / "OUT"
    db = out / name
    r = _cellplan("adapt", str(scenario_file), "--db", str(db), "-o", str(out))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"error: --output: {db} is the input given as --db; writing it would destroy it"
    ]
    assert not out.exists()


def test_an_output_that_is_the_scenario_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "OUT"
    out.mkdir()
    scenario = out / "summary.json"  # JSON is YAML: a scenario file may be named so
    scenario.write_text(POINT_SCENARIO, encoding="utf-8")
    r = _cellplan("adapt", str(scenario), "-o", str(out))
    assert r.returncode == 2 and "given as SCENARIO" in r.stderr
    assert scenario.read_text(encoding="utf-8") == POINT_SCENARIO


def test_adapt_writes_only_the_files_it_declares(scenario_file: Path, tmp_path: Path) -> None:
    """The names checked against the inputs before work are every name written."""
    result = plan(load(str(scenario_file)), "adaptive", tasks=2)
    files = write_outputs(result, tmp_path / "out")
    written = {p.name for p in (tmp_path / "out").iterdir()}
    assert written == {p.name for p in files.values()}
    assert written <= set(OUTPUT_FILES)


def test_a_link_in_the_output_folder_is_not_written_through(
    scenario_file: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n", encoding="utf-8")
    (out / "summary.json").symlink_to(victim)
    r = _cellplan("adapt", str(scenario_file), "-o", str(out))
    assert r.returncode == 2
    assert "symbolic link" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert victim.read_text(encoding="utf-8") == "precious\n"
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]  # nothing moved in

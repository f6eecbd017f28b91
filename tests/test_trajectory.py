"""Trajectory files: exact round trips (hypothesis), clear errors, combining and sampling."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from cellplan.errors import PersistenceError
from cellplan.trajectory import Event, Trajectory

finite = st.floats(
    allow_nan=False, allow_infinity=False, width=64, min_value=-1e300, max_value=1e300
)
text = st.text(alphabet=st.characters(blacklist_characters="|\n\r\x00", codec="utf-8"), max_size=12)


@st.composite
def trajectories(draw):
    n = draw(st.integers(1, 30))
    dim = draw(st.integers(1, 5))
    t = np.sort(draw(arrays(np.float64, n, elements=finite)))
    q = draw(arrays(np.float64, (n, dim), elements=finite))
    modes = tuple(draw(st.lists(text, min_size=1, max_size=4, unique=True)))
    mode = draw(arrays(np.int64, n, elements=st.integers(0, len(modes) - 1)))
    columns = tuple(f"c{i}" for i in range(dim))
    units = tuple(draw(st.sampled_from(["workcell", "rad"])) for _ in range(dim))
    kinds = st.text(alphabet="abcdefgh_", min_size=1, max_size=8)
    events = draw(st.lists(st.builds(Event, st.integers(0, n - 1), kinds, text), max_size=6))
    events.sort(key=lambda e: e.index)
    return Trajectory(t, q, mode, modes, columns, units, "stage", tuple(events), {"seed": 3})


@given(trajectories(), st.sampled_from([".csv", ".json", ".npz"]))
def test_every_format_round_trips_exactly(tmp_path_factory, traj, suffix):
    path = tmp_path_factory.mktemp("t") / f"traj{suffix}"
    traj.save(path)
    back = Trajectory.load(path)
    assert back == traj
    assert back.mode_names() == traj.mode_names()


def _line():
    t = np.arange(5.0)
    q = np.stack([t, 2 * t], axis=1)
    mode = np.array([0, 0, 1, 1, 1])
    return Trajectory(
        t,
        q,
        mode,
        ("idle", "busy"),
        ("x", "y"),
        ("workcell", "workcell"),
        events=(Event(2, "pick", "P1"),),
    )


def test_csv_is_readable_by_a_plain_csv_reader(tmp_path):
    import csv

    path = _line().save(tmp_path / "a.csv")
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# cellplan-trajectory 1 ")
    rows = list(csv.DictReader(lines[1:]))
    assert rows[2] == {"t": "2.0", "mode": "busy", "x": "2.0", "y": "4.0", "events": "pick:P1"}


@pytest.mark.parametrize(
    "change",
    [
        {"t": np.array([0.0, 2.0, 1.0, 3.0, 4.0])},
        {"mode": np.array([0, 0, 2, 0, 0])},
        {"columns": ("x",)},
        {"units": ("workcell",)},
        {"q": np.full((5, 2), np.nan)},
        {"events": (Event(9, "pick"),)},
        {"columns": ("t", "y")},
    ],
)
def test_inconsistent_trajectories_are_refused(change):
    base = _line()
    fields = dict(
        t=base.t,
        q=base.q,
        mode=base.mode,
        modes=base.modes,
        columns=base.columns,
        units=base.units,
        events=base.events,
    )
    fields.update(change)
    with pytest.raises(ValueError, match="invalid trajectory"):
        Trajectory(**fields)


def _broken_npz(kind: str) -> bytes:
    """A trajectory .npz written by numpy, then broken: ``truncated`` (cut in half) or
    ``header`` (the header member's .npy header left without its closing brace)."""
    buffer = io.BytesIO()
    np.savez(buffer, header=np.array("{}"), t=np.arange(3.0))
    raw = buffer.getvalue()
    if kind == "truncated":
        return raw[: len(raw) // 2]
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(raw)) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = bytearray(src.read(info))
            if info.filename == "header.npy":  # read first
                data[data.index(b"}")] = ord(" ")
            dst.writestr(info.filename, bytes(data))
    return out.getvalue()


@pytest.mark.parametrize("kind", ["truncated", "header"])
def test_broken_npz_files_give_one_line(tmp_path, kind):
    path = tmp_path / "a.npz"
    path.write_bytes(_broken_npz(kind))
    with pytest.raises(PersistenceError) as err:
        Trajectory.load(path)
    assert len(err.value.problems) == 1
    assert err.value.problems[0].field == str(path)


@pytest.mark.parametrize(
    ("name", "content"),
    [
        ("a.csv", "t,mode\n1,2\n"),
        ("a.json", "[1, 2]"),
        ("a.json", json.dumps({"format": "cellplan-trajectory", "version": 99})),
        ("a.npz", "not a zip"),
        ("a.txt", "x"),
    ],
)
def test_bad_files_give_one_line(tmp_path, name, content):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(PersistenceError) as err:
        Trajectory.load(path)
    assert len(err.value.problems) == 1
    assert err.value.problems[0].field == str(path)


def test_concatenate_continues_time_and_merges_modes():
    a = _line()
    both = Trajectory.concatenate([a, a])
    assert len(both) == 10
    assert both.t[5] == a.t[-1]
    assert np.all(np.diff(both.t) >= 0)
    assert both.modes == ("idle", "busy")
    assert [e.index for e in both.events] == [2, 7]


def test_sample_interpolates_linearly():
    a = _line()
    assert np.allclose(a.sample([0.5, 10.0]), [[0.5, 1.0], [4.0, 8.0]])


def test_plot_draws_a_figure(tmp_path):
    path = _line().plot(tmp_path / "traj.png")
    assert path.stat().st_size > 1000

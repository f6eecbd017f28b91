"""Strategy files that lie, and the strategy section's numbers at the edges (issue 36).

A digest is not a proof: a strategy solved for another workcell, or with blocked cells
marked free, must be refused before any motion (exit 2, one line naming the file and
the array), and a run whose motion collides stops with status ``failed`` (exit 1).
"""

from __future__ import annotations

import json
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cellplan
import cellplan.errors
from cellplan.budget import format_bytes, resident_memory
from cellplan.errors import PersistenceError, ScenarioError
from cellplan.scenario import loads_scenario
from cellplan.strategies.policy.fileformat import MAX_MAGNITUDE, read_strategy
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.section import MAX_FMP_STAGES, MIN_ARRIVAL
from cellplan.strategies.sim.simulate import first_collision, simulate_result

TINY = Path(__file__).parents[2] / "scenarios" / "strategies_tiny.yaml"
OBSTACLE = "  obstacles:\n    middle: {type: box, min: [12, 12], max: [18, 16]}\n"


def _solve(text: str, path: Path) -> Path:
    result = cellplan.plan(cellplan.loads(text), "strategies", sample_stages=1)
    return result.solution.save(path)


def _rewrite(src: Path, dst: Path, **changes: np.ndarray) -> Path:
    """``src`` with some arrays (or ``meta``, a dict) replaced, written as numpy does."""
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for name, value in changes.items():
        arrays[name] = np.array(json.dumps(value)) if name == "meta" else value
    np.savez_compressed(dst, **arrays)
    return dst


def _meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        return json.loads(str(z["meta"]))


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The real strategy, (a) one solved without the obstacle under the real digest, and
    (b) the real one with the obstacle's cells marked free and live."""
    where = tmp_path_factory.mktemp("trust")
    text = TINY.read_text()
    assert OBSTACLE in text
    real = _solve(text, where / "real.npz")
    digest = cellplan.loads(text).scenario.digest()
    open_cell = _solve(text.replace(OBSTACLE, ""), where / "open.npz")
    meta = _meta(open_cell) | {"scenario_digest": digest}
    lie_a = _rewrite(open_cell, where / "lie_a.npz", meta=meta)
    with np.load(real, allow_pickle=False) as z:
        free, live, values, valid = z["free"], z["live"], z["values"], z["valid"]
        vcls, nact = z["vcls"], z["nact"]
    blocked = ~free[vcls[0]]
    free_b = free | blocked[None, :]
    live_b = live | blocked[None, :]
    values_b = np.where(live_b & ~live, np.nanmax(values), values)
    valid_b = np.where(blocked[None, :], (1 << nact[:, None]) - 1, valid)
    lie_b = _rewrite(
        real, where / "lie_b.npz", free=free_b, live=live_b, values=values_b, valid=valid_b
    )
    return {"real": real, "a": lie_a, "b": lie_b}


@pytest.mark.parametrize("which", ["a", "b"])
def test_lying_strategy_is_refused_by_simulate_and_plot(cellplan, files, tmp_path, which):
    for command in (
        ["simulate", "--no-gif", "-o", str(tmp_path / "sim")],
        ["plot", "-o", str(tmp_path / "p.png")],
    ):
        r = cellplan(command[0], str(TINY), "--strategy", str(files[which]), *command[1:])
        assert r.returncode == 2, r
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1, r.stderr
        assert str(files[which]) in lines[0]
        assert "free:" in lines[0]
        assert "does not match the scenario's geometry" in lines[0]
    assert not (tmp_path / "sim").exists()
    assert not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("which", ["a", "b"])
def test_lying_strategy_is_refused_by_the_api(files, which):
    setup = cellplan.load(str(TINY))
    with pytest.raises(PersistenceError, match=r"free: .* differ from the model"):
        Strategy.load(files[which], setup.scenario)
    with pytest.raises(PersistenceError, match=r"free: .* differ from the model"):
        read_strategy(files[which], setup.scenario, setup.workcell)


def test_the_real_strategy_loads_and_simulates(cellplan, files, tmp_path):
    r = cellplan(
        "simulate",
        str(TINY),
        "--strategy",
        str(files["real"]),
        "--no-gif",
        "-o",
        str(tmp_path / "s"),
    )
    assert r.returncode == 0, r
    assert "requests served" in r.stdout


@pytest.mark.parametrize("which", ["a", "b"])
def test_a_colliding_run_stops_failed(files, which):
    """Defence in depth: loaded without the scenario (no geometry check), the run is
    checked against the exact workcell and stops at the first collision."""
    setup = cellplan.load(str(TINY))
    cell = setup.workcell
    strat = Strategy.load(files[which]).attach(cell)
    result = simulate_result(strat, 401, 0, cell=cell)
    assert str(result.status) == "failed"
    assert "collides with the workcell" in result.message
    sim = result.solution
    stop = len(sim.actions)
    assert stop < 401
    assert cell.collides(sim.q[-1:], None, "none")[0] or first_collision(strat, sim, cell) == (
        stop,
        result.message.split("; the run stops")[0].split(": ", 1)[1],
    )


def test_a_real_run_never_collides(files):
    setup = cellplan.load(str(TINY))
    strat = Strategy.load(files["real"], setup.scenario).attach(setup.workcell)
    result = simulate_result(strat, 401, 0, cell=setup.workcell)
    assert first_collision(strat, result.solution, setup.workcell) is None
    assert str(result.status) == "solved"


# --- finite but extreme values in a strategy file ---------------------------------------


CASES = [(v, w) for v in (1e308, 1e200, MAX_MAGNITUDE * 10) for w in ("values", "cost")]


@settings(max_examples=7, deadline=None)
@given(case=st.sampled_from([*CASES, (1e60, "values")]))  # 1e60: far beyond S L / p
def test_extreme_values_are_refused(files, tmp_path_factory, case):
    scale, which = case
    where = tmp_path_factory.mktemp("extreme")
    with np.load(files["real"], allow_pickle=False) as z:
        arr = z[which].copy()
    if which == "values":
        arr[np.isfinite(arr)] = scale
    else:
        arr[arr > 0] = scale
    bad = _rewrite(files["real"], where / "x.npz", **{which: arr})
    with pytest.raises(PersistenceError, match=f"{which}: .*(above|outside)|meta.gain"):
        Strategy.load(bad)


def test_extreme_values_refused_by_plot_and_simulate(cellplan, files, tmp_path):
    with np.load(files["real"], allow_pickle=False) as z:
        values = np.where(np.isnan(z["values"]), np.nan, 1e308)
    bad = _rewrite(files["real"], tmp_path / "big.npz", values=values)
    for args in (
        ["plot", "-o", str(tmp_path / "p.png")],
        ["simulate", "--no-gif", "-o", str(tmp_path / "s")],
    ):
        r = cellplan(args[0], str(TINY), "--strategy", str(bad), *args[1:])
        assert r.returncode == 2, r
        assert len(r.stderr.strip().splitlines()) == 1 and "values:" in r.stderr


# --- an archive that declares gigabytes --------------------------------------------------


def _npy_header(shape: tuple[int, ...], descr: str) -> bytes:
    """A version 1.0 .npy header (as numpy writes it) for an array of ``shape``."""
    text = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape!r}, }}"
    pad = 64 - (10 + len(text) + 1) % 64
    body = (text + " " * pad + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(body)) + body


def test_declared_gigabytes_refused_before_inflating(files, tmp_path, monkeypatch):
    """The real file's arrays on a grid of 4096 x 4096 cells: the headers declare about
    2.3 GB while the file holds only the headers (each zip entry claims the size its header
    declares); the reader refuses it from the headers, before inflating any data."""
    meta = _meta(files["real"])
    n = 4096
    meta["grid"]["shape"] = [n, n]
    with np.load(files["real"], allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    cells = int(np.prod(arrays["shape"]))
    claims: dict[str, int] = {}
    path = tmp_path / "huge.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, arr in arrays.items():
            if name == "meta":
                zf.writestr("meta.npy", _npy_bytes(np.array(json.dumps(meta))))
            elif name == "shape":
                zf.writestr("shape.npy", _npy_bytes(np.array([n, n], np.int64)))
            elif cells in arr.shape:
                shape = tuple(n * n if s == cells else s for s in arr.shape)
                header = _npy_header(shape, arr.dtype.str)
                zf.writestr(f"{name}.npy", header)
                claims[f"{name}.npy"] = len(header) + int(np.prod(shape)) * arr.dtype.itemsize
            else:
                zf.writestr(f"{name}.npy", _npy_bytes(arr))
    _claim_sizes(path, claims)
    assert path.stat().st_size < 100_000
    assert sum(claims.values()) > 2e9
    setup = cellplan.load(str(TINY))
    # Room for what the zip directory claims, not for the checks and the rebuilt model
    # the headers imply (over 1 GB more): as under the 3.4 GB address-space limit.
    room = resident_memory() + sum(claims.values()) + 200_000_000
    monkeypatch.setenv("CELLPLAN_MEMORY_LIMIT", str(room))
    with pytest.raises(cellplan.errors.CellplanError, match=r"needs about .* to read"):
        Strategy.load(path, setup.scenario)


def _claim_sizes(path: Path, claims: dict[str, int]) -> None:
    """Patch the uncompressed size each central-directory entry claims."""
    data = bytearray(path.read_bytes())
    at = data.find(b"PK\x01\x02")
    while at >= 0:
        (length,) = struct.unpack_from("<H", data, at + 28)
        name = data[at + 46 : at + 46 + length].decode()
        if name in claims:
            struct.pack_into("<I", data, at + 24, claims[name])
        at = data.find(b"PK\x01\x02", at + 46)
    path.write_bytes(bytes(data))


def _npy_bytes(arr: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def test_format_bytes_never_overflows():
    assert format_bytes(10**400) == "10^400 B"
    assert format_bytes(2.4e6) == "2.4 MB"


# --- numbers the solver cannot work with, refused by validate -----------------------------


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("probability: 0.1", "probability: 0", "strategy.arrival.probability"),
        ("probability: 0.1", "probability: 5e-324", "strategy.arrival.probability"),
        ("probability: 0.1", "rate: 1e-300", "strategy.arrival.rate"),
        (
            "fine_motion: {time: 1.5}",
            "fine_motion: {time: 1e308, rate: 1e308}",
            "strategy.fine_motion",
        ),
        (
            "fine_motion: {time: 1.5}",
            "fine_motion: {time: 1.5, point: [15, 26], rate: 1e308}",
            "strategy.fine_motion",
        ),
        # a stage's loss (stage time x urgency) bounds the values a solve writes
        ("strategy:\n", "strategy:\n  stage_time: 1.0e+7\n", "strategy.stage_time"),
        ("strategy:\n", "strategy:\n  urgency: {P1: 1.0e+9}\n", "strategy.urgency.P1"),
    ],
)
def test_validate_refuses_what_solve_cannot_solve(cellplan, tmp_path, old, new, field):
    text = TINY.read_text()
    assert old in text
    path = tmp_path / "s.yaml"
    path.write_text(text.replace(old, new))
    for command in ("validate", "solve"):
        args = [command, str(path)] + (
            ["-o", str(tmp_path / "s.npz")] if command == "solve" else []
        )
        r = cellplan(*args)
        assert r.returncode == 2, r
        assert r.stderr.strip().splitlines()[0].startswith(f"error: {field}:"), r.stderr
    with pytest.raises(ScenarioError):
        loads_scenario(text.replace(old, new))


def test_bounds_at_their_edges_are_accepted():
    text = TINY.read_text()
    loads_scenario(text.replace("probability: 0.1", f"probability: {MIN_ARRIVAL * 1.01!r}"))
    loads_scenario(
        text.replace("fine_motion: {time: 1.5}", f"fine_motion: {{time: {MAX_FMP_STAGES}}}")
    )


def test_arm_links_are_bounded(cellplan, tmp_path):
    text = (Path(__file__).parents[2] / "scenarios" / "strategies_failures_arm.yaml").read_text()
    data = __import__("yaml").safe_load(text)
    data["robot"]["links"] = [{"length": 0.1, "width": 0.05}] * 170
    data["robot"].pop("joint_limits", None)
    data["robot"]["start"] = [0] * 170
    data["strategy"].pop("cells", None)
    path = tmp_path / "arm.yaml"
    path.write_text(__import__("yaml").safe_dump(data))
    r = cellplan("validate", str(path))
    assert r.returncode == 2, r
    assert r.stderr.startswith("error: robot.links:"), r.stderr

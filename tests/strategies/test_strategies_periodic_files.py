"""Strategy files, mode names, pictures and ``cellplan validate`` for time-varying models
(Section VI-1 of the strategies paper).

A time-varying model is the product (mode, phase) of the Section V model with the phase
of a period ``P``: the layer of mode ``m`` at phase ``t`` is ``t * M + m`` (``M`` modes a
phase), every stage leads to the next phase, and a region on a conveyor belt moves with
the phase. The file stores the period, each layer's phase and the belts' velocities
(version 4). The checks here: a solved file round-trips exactly (actions and values at
every layer) and a Section V file still loads as a stationary model; tampered periods,
phases, belts, branches and FMP successors are refused with one line naming the field;
crafted files are refused with one line or safe to query at every layer; layers are named
with a phase (``<P1,S1,D1,W>@3``, ``NR@5``, ``1,1,1,W@3`` or ``--phase``); the pictures
draw a belt region where it lies at the plotted phase; ``validate`` counts the layers.

The scenario is the tiny cell with source S1 on a belt (2 units per stage to the right,
period 6, requests in the first two stages of each period): 5 modes x 6 phases, 12 x 12.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from strategies_helpers import TINY
from test_strategies_fileformat import _write, craft, solved_file
from test_strategies_pending_files import _SameDigest, refused

from cellplan.api import loads
from cellplan.errors import PersistenceError
from cellplan.strategies.experiments.plots import plot_mode
from cellplan.strategies.policy.fileformat import VERSION, read_strategy
from cellplan.strategies.policy.strategy import Strategy, solve_scenario

PERIOD = 6
#: Modes of one phase: NR, two W and two C (requests <P1,S1,D1> and <P1,S2,D1>).
PER_PHASE = 5
M = PERIOD * PER_PHASE
VELOCITY = (2.0, 0.0)


def belt_text(
    period: int = PERIOD, velocity: tuple[float, float] = VELOCITY, cells: int = 12
) -> str:
    """The tiny cell with S1 on a belt and requests in the first two stages of a period."""
    profile = [1, 1] + [0] * (period - 2)
    return TINY.replace("CELLS", str(cells)) + (
        f"  period: {period}\n  arrival_profile: {profile}\n"
        f"  belts:\n    S1: {{velocity: [{velocity[0]}, {velocity[1]}]}}\n"
    )


@pytest.fixture(scope="module")
def tv_base(tmp_path_factory):
    """A solved strategy file of the time-varying tiny cell: (setup, path, arrays, meta)."""
    return solved_file(loads(belt_text()), tmp_path_factory.mktemp("tvbase"))


@pytest.fixture(scope="module")
def section_v_base(tmp_path_factory):
    """A solved strategy file of the stationary tiny cell (Section V)."""
    return solved_file("strategies_tiny", tmp_path_factory.mktemp("vbase"))


def centres(strat: Strategy, layer: int, every: int = 1) -> list[np.ndarray]:
    """The centres of the live cells of ``layer`` (every ``every``-th)."""
    mdp = strat.mdp
    cells = np.flatnonzero(mdp.live[layer])[::every]
    idx = np.array(np.unravel_index(cells, tuple(mdp.shape))).T
    return list(mdp.lower + (idx + 0.5) * mdp.spacing)


# --- round trip ---------------------------------------------------------------------------


def test_the_file_stores_the_period_the_phases_and_the_belts(tv_base):
    _, _, arrays, meta = tv_base
    assert meta["version"] == VERSION == 4
    assert meta["period"] == PERIOD and len(meta["modes"]) == M
    assert meta["phases"] == [t for t in range(PERIOD) for _ in range(PER_PHASE)]
    assert meta["belts"] == {"S1": list(VELOCITY)}
    for layer in range(M):
        assert meta["modes"][layer] == meta["modes"][layer % PER_PHASE]
    assert arrays["values"].shape == (M, 144) and arrays["tf"].shape == (M, 144)


def test_a_time_varying_strategy_round_trips_exactly(tv_base, tmp_path):
    setup, path, _, _ = tv_base
    fresh, _ = solve_scenario(setup.scenario, setup.workcell)
    loaded = Strategy.load(path, setup.scenario)
    again = Strategy.load(loaded.save(tmp_path / "again.npz"), setup.scenario)
    for strat in (loaded, again):
        mdp = strat.mdp
        assert (mdp.period, dict(mdp.belts)) == (PERIOD, {"S1": VELOCITY})
        assert mdp.modes == fresh.mdp.modes and mdp.modes_per_phase == PER_PHASE
        assert [m.phase for m in mdp.modes] == [layer // PER_PHASE for layer in range(M)]
        assert mdp.modes[PER_PHASE + 1].label == "<P1,S1,D1,W>@1"
        np.testing.assert_array_equal(strat.values, fresh.values)  # NaN off the live states
        for name in ("tf", "fmp_next", "cost", "live", "branch_ptr", "branch_layer", "vcls"):
            np.testing.assert_array_equal(getattr(mdp, name), getattr(fresh.mdp, name))
        assert not mdp.is_simple() and mdp.opt_ptr is None
        assert strat.gain == fresh.gain
    # The belt moves S1's pick region: its fields differ between phases.
    w = fresh.mdp.w_layer(0)
    assert not np.array_equal(fresh.mdp.tf[w], fresh.mdp.tf[fresh.mdp.layer(w, 3)])
    # The same action at every live cell centre of every layer.
    for layer in range(M):
        assert fresh.mdp.live[layer].any()
        for q in centres(fresh, layer):
            assert loaded.action(q, layer) == again.action(q, layer) == fresh.action(q, layer)


def test_a_stationary_file_stores_period_1_and_loads_as_before(section_v_base, tmp_path):
    setup, path, _, meta = section_v_base
    assert meta["period"] == 1 and meta["belts"] == {}
    assert meta["phases"] == [-1] * len(meta["modes"])
    strat = Strategy.load(path, setup.scenario)
    mdp = strat.mdp
    assert mdp.period == 1 and dict(mdp.belts) == {} and mdp.is_simple()
    assert all(m.phase == -1 for m in mdp.modes) and mdp.modes_per_phase == mdp.n_modes
    assert [m.label for m in mdp.modes] == [
        "NR",
        "<P1,S1,D1,W>",
        "<P1,S2,D1,W>",
        "<P1,S1,D1,C>",
        "<P1,S2,D1,C>",
    ]
    again = Strategy.load(strat.save(tmp_path / "again.npz"), setup.scenario)
    np.testing.assert_array_equal(again.values, strat.values)
    assert again.mdp.modes == strat.mdp.modes


# --- refusals ----------------------------------------------------------------------------


def _meta_set(key: str, value: Any) -> Any:
    return lambda meta: meta.__setitem__(key, value)


def _phase_set(i: int, value: int) -> Any:
    return lambda meta: meta["phases"].__setitem__(i, value)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (_meta_set("period", 0), r"meta.period: Input should be greater than or equal to 1"),
        (_meta_set("period", 1001), r"meta.period: Input should be less than or equal to 1000"),
        (_meta_set("period", "6"), r"meta.period: Input should be a valid integer"),
        (lambda meta: meta.pop("period"), r"meta.period: Field required"),
        (lambda meta: meta.pop("phases"), r"meta.phases: Field required"),
        (lambda meta: meta.pop("belts"), r"meta.belts: Field required"),
        (_meta_set("period", 4), rf"meta.period: 4 stages do not divide the {M} modes"),
        # 3 divides 30, but then a phase holds 10 layers: the phases say 5
        (_meta_set("period", 3), r"meta.phases.5: 1; expected 0 \(the layer of mode m at phase"),
        (_meta_set("period", 1), r"meta.phases.0: 0; expected -1 \(.*-1: no period\)"),
        (_phase_set(7, 2), r"meta.phases.7: 2; expected 1 \(the layer of mode m at phase t is"),
        (_phase_set(0, -1), r"meta.phases.0: -1; expected 0"),
        (_phase_set(3, -2), r"meta.phases.3: Input should be greater than or equal to -1"),
        (lambda meta: meta["phases"].pop(), rf"meta.phases: {M - 1} values; expected {M}"),
        # layer 7 (<P1,S2,D1,W>@1) becomes a second <P1,S1,D1,W>
        (
            lambda meta: meta["modes"].__setitem__(7, meta["modes"][1]),
            r"meta.modes.7: differs from mode 2, its copy at phase 0",
        ),
        # every phase holds NR, W, C in this order: swapping at phase 0 breaks the order
        (
            lambda meta: meta["modes"].__setitem__(
                slice(0, M), [meta["modes"][(i + 1) % PER_PHASE] for i in range(M)]
            ),
            r"meta.modes: expected NR, then the W modes",
        ),
        (
            _meta_set("belts", {"S9": [1.0, 0.0]}),
            r"meta.belts.S9: not a source or destination of the modes",
        ),
        (
            _meta_set("belts", {"S1": [1.0]}),
            r"meta.belts.S1: List should have at least 2 items",
        ),
        (
            _meta_set("belts", {"S1": [1.0, 0.0, 0.0]}),
            r"meta.belts.S1: List should have at most 2 items",
        ),
        (_meta_set("belts", {"S1": "fast"}), r"meta.belts.S1: Input should be a valid list"),
        (
            _meta_set("belts", {"S1": [float("nan"), 0.0]}),
            r"meta.belts.S1.0: Input should be a finite number",
        ),
        (
            _meta_set("belts", {"S1": [1e308, 0.0]}),
            r"meta.belts.S1: a velocity of 1e\+308 carries the region beyond any finite",
        ),
        (_meta_set("belts", []), r"meta.belts: Input should be a valid dictionary"),
        (_meta_set("version", 3), r"version 3 \(an older cellplan\); solve the scenario again"),
    ],
)
def test_tampered_periods_phases_and_belts_are_named(tv_base, tmp_path, change, words):
    refused(tv_base, tmp_path, words, meta_change=change)


def _layer_of(a: dict, layer: int) -> slice:
    return slice(int(a["branch_ptr"][layer]), int(a["branch_ptr"][layer + 1]))


def _branches_stay(a: dict) -> None:
    """The branches of NR@2 lead to phase 2 again instead of phase 3."""
    a["branch_layer"][_layer_of(a, 2 * PER_PHASE)] -= PER_PHASE


def _shift_one_fmp(a: dict) -> None:
    """The pick of <P1,S1,D1,W>@4 (and its outcome) lands one phase later than at the
    other phases: a model the scenario cannot produce."""
    layer = 4 * PER_PHASE + 1
    nxt = (int(a["fmp_next"][layer]) + PER_PHASE) % M
    a["fmp_next"][layer] = nxt
    a["out_layer"][int(a["out_ptr"][layer])] = nxt


def _fmp_to_a_w_layer(a: dict) -> None:
    layer = 2 * PER_PHASE + 1
    a["fmp_next"][layer] = 3 * PER_PHASE + 2
    a["out_layer"][int(a["out_ptr"][layer])] = 3 * PER_PHASE + 2


def _no_live_nr(a: dict) -> None:
    nr = np.arange(M) % PER_PHASE == 0
    a["live"][nr] = False
    a["values"][nr] = np.nan


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (_branches_stay, r"branch_layer: a branch that does not lead to the next phase"),
        (
            _shift_one_fmp,
            r"fmp_next: the FMP of a mode advances the phase by different stages at different",
        ),
        (_fmp_to_a_w_layer, r"fmp_next: the FMP successors do not follow the mode order"),
        # NR at phase 3 gets an FMP
        (
            lambda a: a["fmp_next"].__setitem__(3 * PER_PHASE, 1),
            r"fmp_next: the FMP successors do not follow the mode order",
        ),
        # NR@1 takes the first outcome of <P1,S1,D1,W>@0's successor
        (
            lambda a: a["out_ptr"].__setitem__(PER_PHASE + 1, a["out_ptr"][PER_PHASE + 1] + 1),
            r"out_ptr: NR has no FMP and every other mode has at least one outcome",
        ),
        # the pick of <P1,S2,D1,W>@3 leads to a C layer other than its fmp_next
        (
            lambda a: a["out_layer"].__setitem__(
                int(a["out_ptr"][3 * PER_PHASE + 2]), a["fmp_next"][3 * PER_PHASE + 2] - 1
            ),
            r"out_layer: the first outcome of a mode's FMP is not its fmp_next",
        ),
        (_no_live_nr, r"live: no live state in NR"),
        (
            lambda a: a.__setitem__("out_layer", a["out_layer"][: M - PERIOD - 1]),
            rf"out_layer: axis 0 \(G\) is {M - PERIOD - 1}, expected {M - PERIOD} to",
        ),
    ],
)
def test_tampered_phase_layouts_are_named(tv_base, tmp_path, change, words):
    refused(tv_base, tmp_path, words, arrays_change=change)


def test_the_same_fmp_shift_at_every_phase_is_a_valid_model(tv_base, tmp_path):
    """A pick that takes one stage more at every phase is a model the checks accept (a
    longer fine motion): the file loads and answers at every layer."""
    setup, _, arrays, meta = tv_base
    arrays = {k: v.copy() for k, v in arrays.items()}
    for t in range(PERIOD):
        layer = t * PER_PHASE + 1
        nxt = (int(arrays["fmp_next"][layer]) + PER_PHASE) % M
        arrays["fmp_next"][layer] = nxt
        arrays["out_layer"][int(arrays["out_ptr"][layer])] = nxt
    strat = Strategy.load(_write(tmp_path / "longer.npz", arrays, meta, True), setup.scenario)
    for layer in range(M):
        for q in centres(strat, layer, 7):
            strat.action(q, layer)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        (belt_text(period=5), r"meta.period: 6 stages, the scenario's period is 5"),
        (TINY.replace("CELLS", "12"), r"meta.period: 6 stages, the scenario's period is 1"),
        (
            belt_text(velocity=(1.0, 0.0)),
            r"meta.belts: \['S1'\] differ from the scenario's belts \['S1'\] or their velocities",
        ),
        (
            belt_text(velocity=(-2.0, 0.0)).replace("    S1: {velocity", "    S2: {velocity"),
            r"meta.belts: \['S1'\] differ from the scenario's belts \['S2'\]",
        ),
    ],
)
def test_another_period_or_belt_says_solve_again(tv_base, text, words):
    _, path, _, meta = tv_base
    other = loads(text).scenario
    with pytest.raises(PersistenceError, match=r"different scenario .*solve this scenario again"):
        read_strategy(path, other)
    with pytest.raises(PersistenceError, match=words + r".*solve this scenario again"):
        read_strategy(path, _SameDigest(other, meta["scenario_digest"]))


def test_a_stationary_file_against_a_time_varying_scenario_says_solve_again(section_v_base):
    _, path, _, meta = section_v_base
    other = loads(belt_text()).scenario
    with pytest.raises(
        PersistenceError, match=r"meta.period: 1 stages, the scenario's period is 6"
    ):
        read_strategy(path, _SameDigest(other, meta["scenario_digest"]))


def test_a_stationary_file_with_belts_or_a_period_is_refused(section_v_base, tmp_path):
    refused(
        section_v_base,
        tmp_path,
        r"meta.belts: a stationary model \(period 1\) has no belts",
        meta_change=_meta_set("belts", {"S1": [1.0, 0.0]}),
    )
    refused(
        section_v_base,
        tmp_path,
        r"meta.period: 2 stages do not divide the 5 modes",
        meta_change=_meta_set("period", 2),
    )


# --- crafted files -------------------------------------------------------------------------

#: Tamperings aimed at the phase layout (beside the generic ones of :func:`craft`).
PERIODIC_KINDS = ["period", "phase", "belt", "branch_phase", "fmp_phase", "generic"]


def craft_periodic(data: Any, base: tuple, folder: Path) -> tuple[str, Path]:
    """One crafted file: a generic tampering (:func:`craft`) or one of the phase layout."""
    # half of them generic: the layout checks must not hide the others
    kinds = PERIODIC_KINDS + ["generic"] * (len(PERIODIC_KINDS) - 2)
    kind = data.draw(st.sampled_from(kinds), label="periodic kind")
    if kind == "generic":
        return craft(data, base, folder)
    _, _, arrays, meta = base
    arrays = {k: v.copy() for k, v in arrays.items()}
    meta = json.loads(json.dumps(meta))
    if kind == "period":
        meta["period"] = data.draw(
            st.sampled_from([0, 1, 2, 3, 5, 6, 10, 15, 30, 60, 1000]) | st.integers(), label="T"
        )
    elif kind == "phase":
        i = data.draw(st.integers(0, M - 1), label="layer")
        meta["phases"][i] = data.draw(st.integers(-3, PERIOD + 2), label="phase")
    elif kind == "belt":
        name = data.draw(st.sampled_from(["S1", "S2", "D1", "", "X"]), label="belt")
        velocity = data.draw(st.lists(st.floats(), min_size=0, max_size=3), label="velocity")
        meta["belts"] = {name: velocity}
    elif kind == "branch_phase":
        # one branch, or every branch, moved to another phase of the same mode
        b = arrays["branch_layer"]
        shift = data.draw(st.integers(1, PERIOD - 1), label="shift") * PER_PHASE
        if data.draw(st.booleans(), label="all"):
            b[:] = (b + shift) % M
        else:
            i = data.draw(st.integers(0, len(b) - 1), label="branch")
            b[i] = (b[i] + shift) % M
    else:
        # the FMP of one layer, or of one mode at every phase, moved to another phase
        m = data.draw(st.integers(1, PER_PHASE - 1), label="mode")
        shift = data.draw(st.integers(1, PERIOD - 1), label="shift") * PER_PHASE
        every = data.draw(st.booleans(), label="every phase")
        phases = range(PERIOD) if every else [data.draw(st.integers(0, PERIOD - 1))]
        move_outcome = data.draw(st.booleans(), label="outcome too")
        for t in phases:
            layer = t * PER_PHASE + m
            nxt = (int(arrays["fmp_next"][layer]) + shift) % M
            arrays["fmp_next"][layer] = nxt
            if move_outcome:
                arrays["out_layer"][int(arrays["out_ptr"][layer])] = nxt
    path = _write(folder / f"{kind}.npz", arrays, meta, data.draw(st.booleans()))
    return kind, path


@settings(
    max_examples=250,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_crafted_time_varying_files_are_refused_cleanly_or_safe_to_query(data, tv_base, tmp_path):
    """Refused with one line naming the file, or every layer answers ``action`` at (a
    sample of) its live cell centres and names its modes without crashing."""
    kind, path = craft_periodic(data, tv_base, tmp_path)
    setup = tv_base[0]
    try:
        strat = Strategy.load(path, setup.scenario)
    except PersistenceError as exc:
        assert len(exc.problems) == 1 and "\n" not in str(exc), (kind, exc)
        assert str(exc).startswith(str(path)), (kind, exc)
        event(f"{kind}: refused")
        return
    event(f"{kind}: accepted")
    mdp = strat.mdp
    for layer in range(mdp.n_modes):
        for q in centres(strat, layer, 5):
            try:
                strat.action(q, layer)
            except ValueError:  # a state with no action: the documented refusal
                pass
        assert strat.mode_index(mdp.modes[layer].label) == layer


# --- mode names ------------------------------------------------------------------------------


def test_every_layer_is_named_by_its_label_or_with_a_phase(tv_base):
    setup, path, _, _ = tv_base
    strat = Strategy.load(path, setup.scenario)
    for layer, mode in enumerate(strat.modes):
        t, m = divmod(layer, PER_PHASE)
        assert mode.phase == t
        assert strat.mode_index(mode.label) == layer
        assert strat.mode_index(f" {mode.label.replace('@', ' @ ')} ") == layer
        plain = strat.modes[m].label.split("@")[0]
        assert strat.mode_index(plain, t) == layer == strat.mode_index(f"{plain}@{t}", t)
        assert strat.mode_index(plain) == m  # a plain name is phase 0
    assert strat.mode_index("NR@5") == 5 * PER_PHASE
    assert strat.mode_index("NR", 5) == 5 * PER_PHASE
    assert strat.mode_index("1,1,1,W@3") == 3 * PER_PHASE + 1
    assert strat.mode_index("1,2,1,C@3") == 3 * PER_PHASE + 4
    assert strat.mode_index("P1,S2,D1,W@0") == 2


@pytest.mark.parametrize(
    ("text", "phase", "words"),
    [
        ("NR@6", None, r"--mode: 6 is outside the period \(phases 0 to 5\)"),
        ("NR", 6, r"--phase: 6 is outside the period \(phases 0 to 5\)"),
        ("NR", -1, r"--phase: -1 is outside the period"),
        ("NR@-1", None, r"--mode: expected a phase number after '@', got 'NR@-1'"),
        ("NR@", None, r"--mode: expected a phase number after '@'"),
        ("1,1,1,W@x", None, r"--mode: expected a phase number after '@'"),
        ("NR@2", 3, r"--phase: 3 differs from the phase 2 of 'NR@2'"),
        ("P1,S9,D1,W@2", None, r"--mode: no mode 'P1,S9,D1,W' .*at phases 0 to 5"),
    ],
)
def test_a_wrong_phase_is_refused_naming_the_option(tv_base, text, phase, words):
    setup, path, _, _ = tv_base
    strat = Strategy.load(path, setup.scenario)
    with pytest.raises(PersistenceError, match=words) as caught:
        strat.mode_index(text, phase)
    assert len(caught.value.problems) == 1


def test_a_stationary_strategy_has_phase_0_only(section_v_base):
    setup, path, _, _ = section_v_base
    strat = Strategy.load(path, setup.scenario)
    assert strat.mode_index("NR@0") == 0 == strat.mode_index("NR", 0)
    assert strat.mode_index("<P1,S2,D1,C>@0") == 4 == strat.mode_index("1,2,1,C", 0)
    for text, phase, field in (("NR@1", None, "--mode"), ("NR", 2, "--phase")):
        with pytest.raises(PersistenceError, match=rf"{field}: \d: this strategy is stationary"):
            strat.mode_index(text, phase)


# --- the CLI, pictures and validate ---------------------------------------------------------


def test_plot_takes_a_phase_and_refuses_a_wrong_one_in_one_line(
    cellplan, tv_base, section_v_base, tmp_path
):
    _, path, _, _ = tv_base
    yaml = tmp_path / "belt.yaml"
    yaml.write_text(belt_text())
    out = tmp_path / "w3.png"
    args = ("--strategy", str(path), "--mode", "1,1,1,W", "--phase", "3", "-o", str(out))
    r = cellplan("plot", str(yaml), *args)
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 0
    for args, words in (
        (("--phase", "6"), "--phase: 6 is outside the period (phases 0 to 5)"),
        (("--mode", "NR@9"), "--mode: 9 is outside the period (phases 0 to 5)"),
        (("--mode", "NR@1", "--phase", "2"), "--phase: 2 differs from the phase 1 of 'NR@1'"),
    ):
        bad = tmp_path / "bad.png"
        r = cellplan("plot", str(yaml), "--strategy", str(path), *args, "-o", str(bad))
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and words in lines[0], r.stderr
        assert not bad.exists()
    # a stationary strategy: phase 0 only
    _, vpath, _, _ = section_v_base
    ok = tmp_path / "v.png"
    r = cellplan("plot", "strategies_tiny", "--strategy", str(vpath), "--phase", "0", "-o", str(ok))
    assert r.returncode == 0, r.stderr
    bad = tmp_path / "v1.png"
    r = cellplan(
        "plot", "strategies_tiny", "--strategy", str(vpath), "--phase", "1", "-o", str(bad)
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "--phase: 1: this strategy is stationary" in lines[0] and not bad.exists()


def _outline_x(fig: Any, name: str) -> list[float]:
    """The smallest x of the outlines with ``gid`` ``name`` on each panel of ``fig``."""
    xs = []
    for ax in fig.axes:
        for patch in ax.patches:
            if patch.get_gid() == name:
                xs.append(float(patch.get_path().vertices[:, 0].min()))
    return xs


def test_plot_mode_draws_the_belt_region_where_it_is_at_the_phase(tv_base, tmp_path, monkeypatch):
    """S1 rides the belt at 2 units a stage: at phase 4 its outline lies 8 units right of
    where it lies at phase 0 on both panels, S2 (no belt) stays, and the titles give the
    phase."""
    import cellplan.plots

    setup, path, _, _ = tv_base
    strat = Strategy.load(path, setup.scenario).attach(setup.workcell)
    figures: list[Any] = []
    save = cellplan.plots.save_figure
    monkeypatch.setattr(
        cellplan.plots, "save_figure", lambda fig, p, **kw: (figures.append(fig), save(fig, p))[1]
    )
    drawn = {}
    for t in (0, 4):
        layer = strat.mode_index("<P1,S1,D1,W>", t)
        plot_mode(strat, setup.workcell, layer, tmp_path / f"w{t}.png")
        fig = figures[-1]
        drawn[t] = (_outline_x(fig, "S1"), _outline_x(fig, "S2"))
        titles = [ax.get_title() for ax in fig.axes[:2]]
        assert all(f"<P1,S1,D1,W>, phase {t} of {PERIOD}" in x.replace("\n", " ") for x in titles)
    (s1_0, s2_0), (s1_4, s2_4) = drawn[0], drawn[4]
    assert len(s1_0) == len(s1_4) == 2 and s1_0 == [2.0, 2.0]  # S1 spans x 2 to 6
    assert s1_4 == pytest.approx([2.0 + 4 * VELOCITY[0]] * 2)
    assert s2_0 == s2_4 == [24.0, 24.0]
    assert _outline_x(figures[-1], "belt:S1") == [2.0, 2.0]  # the belt's track, each panel


def test_the_belt_track_spans_the_region_over_the_period(tv_base, section_v_base):
    """The track drawn for S1 runs from where a part comes in (x 2 to 6) to where the last
    phase leaves it, the region moved by (PERIOD - 1) stages of its belt."""
    from cellplan.plots import new_figure
    from cellplan.strategies.experiments.plots import draw_belts

    setup, path, _, _ = tv_base
    strat = Strategy.load(path, setup.scenario)
    _, axes = new_figure()
    draw_belts(axes[0, 0], strat, setup.workcell)
    (track,) = [p for p in axes[0, 0].patches if p.get_gid() == "belt:S1"]
    xs, ys = track.get_path().vertices.T
    assert xs.min() == pytest.approx(2.0)
    assert xs.max() == pytest.approx(6.0 + (PERIOD - 1) * VELOCITY[0])
    assert (ys.min(), ys.max()) == pytest.approx((2.0, 5.0))
    stationary = Strategy.load(section_v_base[1])
    _, axes = new_figure()
    draw_belts(axes[0, 0], stationary, setup.workcell)
    assert not axes[0, 0].patches  # nothing without a belt


def test_frames_and_gif_draw_the_belt_region_where_it_is_at_each_stage(
    tv_base, tmp_path, monkeypatch
):
    """A run through the phases: each frame and GIF picture draws the workcell with S1
    moved by its belt's offset at the stage's phase (S2, on no belt, never moves)."""
    import cellplan.plots
    from cellplan.strategies.experiments.plots import plot_frames, save_animation
    from cellplan.strategies.sim.simulate import Simulation

    setup, path, _, _ = tv_base
    strat = Strategy.load(path, setup.scenario)
    seen: list[tuple[float, float]] = []
    draw = cellplan.plots.draw_workcell

    def record(ax, cell, highlight=(), labels=True, offsets=None):
        seen.append((offsets or {}).get("S1", (0.0, 0.0)))
        assert "S2" not in (offsets or {})
        draw(ax, cell, highlight, labels, offsets)
        xs = [p.get_path().vertices[:, 0] for p in ax.patches]
        assert any(x.min() == pytest.approx(2.0 + seen[-1][0]) for x in xs)  # S1's left edge

    monkeypatch.setattr(cellplan.plots, "draw_workcell", record)
    layers = [
        strat.mode_index("NR", 3),
        strat.mode_index("1,1,1,W", 4),
        strat.mode_index("1,1,1,W@5"),
    ]
    q = np.array([[15.0, 8.0], [12.0, 8.0], [12.0, 6.0]])
    sim = Simulation(q, np.array(layers), np.zeros(2, np.int64), np.zeros(2))
    assert sim.segments() == [(0, 1), (1, 2), (2, 2)]  # each drawn at its last stage
    plot_frames(strat, setup.workcell, sim, tmp_path / "frames", each=True)
    assert seen == [(8.0, 0.0), (10.0, 0.0), (10.0, 0.0)] * 2  # the frames, then the grid
    seen.clear()
    save_animation(strat, setup.workcell, sim, tmp_path / "run.gif", max_frames=3)
    assert seen == [(6.0, 0.0), (8.0, 0.0), (10.0, 0.0)]


def test_validate_counts_the_layers_of_the_period(cellplan, tmp_path):
    path = tmp_path / "belt.yaml"
    path.write_text(belt_text())
    r = cellplan("validate", str(path))
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if "assembly modes:" in x)
    assert line.strip() == (
        f"assembly modes: {PER_PHASE} x {PERIOD} phases = {M} layers (Section VI-1: period "
        f"{PERIOD} stages, belt S1)"
    )


def test_validate_counts_the_layers_of_the_bundled_conveyor(cellplan):
    r = cellplan("validate", "strategies_conveyor")
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if "assembly modes:" in x)
    assert line.strip() == (
        "assembly modes: 7 x 20 phases = 140 layers (Section VI-1: period 20 stages, belt S1)"
    )

"""Strategy files, mode names, pictures and ``cellplan validate`` for simultaneous requests
(Section VI-2 of the strategies paper).

A model of simultaneous requests has FMP options (``opt_ptr``: which waiting request a
pick serves), ``tf`` and the FMP outcomes by option, and Q modes (the waiting requests and
the carried one). The checks here: a solved file round-trips exactly and a Section V file
still loads as a model without options; tampered option arrays and mode metadata are
refused with one line naming the array or field; Q modes are named on the command line by
their labels; the pictures draw them; ``validate`` says how many modes each
``max_pending`` gives.

The scenario is the tiny cell with a second destination and three request types and
``max_pending: 2``, so that the options (``O = 24``) and the modes (``M = 22``) differ in
number. The waiting requests of a mode are a multiset (two requests of one type may wait
at once); the numbers below come from the model (:func:`~.request_sets.mode_counts`,
:func:`~.pending.option_count`), and the modes are named by their labels, whose index in
the file is that of :func:`~.pending.pending_modes`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from strategies_helpers import TINY
from test_strategies_fileformat import _write, craft, solved_file

from cellplan.api import loads
from cellplan.errors import PersistenceError
from cellplan.strategies.experiments.plots import (
    carried_part,
    mode_regions,
    plot_frames,
    plot_mode,
    save_animation,
    wrap_title,
)
from cellplan.strategies.model.mdp import Mode
from cellplan.strategies.policy.fileformat import mode_of, read_strategy
from cellplan.strategies.policy.strategy import Strategy
from cellplan.strategies.section import mode_counts
from cellplan.strategies.sim.simulate import Simulation
from cellplan.strategies.variants.pending import option_count, pending_modes

REQUESTS = [("P1", "S1", "D1"), ("P1", "S2", "D1"), ("P1", "S1", "D2")]
#: The scenario's modes and FMP options (three request types, at most two open at once).
M = sum(mode_counts(len(REQUESTS), 2))
OPTIONS = option_count(len(REQUESTS), 2)


def label_of(q: tuple[int, ...], r: int) -> str:
    """The label of the mode ``(Q, r)`` of :func:`~.pending.pending_modes` (indices into
    ``REQUESTS``)."""
    if not q and r < 0:
        return "NR"
    carried = REQUESTS[r] if r >= 0 else ("", "", "")
    return Mode("Q", *carried, waiting=tuple(",".join(REQUESTS[i]) for i in q)).label


#: The modes' labels in file order.
LABELS = [label_of(q, r) for q, r in pending_modes(len(REQUESTS), 2)]
#: Modes the tamperings below use.
BOTH = LABELS.index("{P1,S1,D1; P1,S2,D1}")  # two types wait: two FMP options (picks)
TWICE = LABELS.index("{P1,S1,D1; P1,S1,D1}")  # one type waits twice: one FMP option
CARRYING = LABELS.index("{P1,S1,D1} + <P1,S1,D1>")


def pending_text(max_pending: int = 2, cells: int = 12) -> str:
    """The tiny cell with a destination D2 (top left) and three request types."""
    listed = ", ".join(f"{{part: {p}, source: {s}, destination: {d}}}" for p, s, d in REQUESTS)
    return (
        TINY.replace("CELLS", str(cells)).replace(
            "  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}",
            "  D1: {components: [{type: box, min: [13, 25], max: [17, 28]}]}\n"
            "  D2: {components: [{type: box, min: [2, 25], max: [6, 28]}]}",
        )
        + f"  max_pending: {max_pending}\n  requests: [{listed}]\n"
    )


@pytest.fixture(scope="module")
def pending_base(tmp_path_factory):
    """A solved strategy file of simultaneous requests: (setup, path, arrays, meta)."""
    return solved_file(loads(pending_text()), tmp_path_factory.mktemp("pbase"))


@pytest.fixture(scope="module")
def section_v_base(tmp_path_factory):
    return solved_file("strategies_tiny", tmp_path_factory.mktemp("vbase"))


def refused(
    base: tuple,
    folder: Path,
    words: str,
    arrays_change: Any = None,
    meta_change: Any = None,
    scenario: Any = "same",
) -> str:
    """The file with ``arrays_change``/``meta_change`` applied is refused with one line
    naming the file and matching ``words``; returns the line."""
    setup, _, arrays, meta = base
    arrays = {k: v.copy() for k, v in arrays.items()}
    meta = json.loads(json.dumps(meta))
    if arrays_change is not None:
        arrays_change(arrays)
    if meta_change is not None:
        meta_change(meta)
    path = _write(folder / "bad.npz", arrays, meta, True)
    with pytest.raises(PersistenceError, match=words) as caught:
        Strategy.load(path, setup.scenario if scenario == "same" else scenario)
    line = str(caught.value)
    assert len(caught.value.problems) == 1 and "\n" not in line
    assert line.startswith(str(path)), line
    return line


# --- round trip ---------------------------------------------------------------------------


def test_the_scenario_has_more_options_than_modes(pending_base):
    _, _, arrays, meta = pending_base
    # NR, 3 + 6 empty modes (multisets of 1 and 2 of the 3 types), 3 x (1 + 3) carrying
    assert M == len(pending_modes(3, 2)) == 1 + 3 + 6 + 12 == 22
    # one pick per waiting type: 3 single, 3 twice-one-type, 3 x 2 two-type; 12 deliveries
    assert OPTIONS == 3 + 3 + 3 * 2 + 12 == 24
    assert [mode_of(m).label for m in meta["modes"]] == LABELS
    assert arrays["tf"].shape[0] == OPTIONS
    assert arrays["opt_ptr"].shape == (M + 1,) and arrays["out_ptr"].shape == (OPTIONS + 1,)
    assert meta["version"] == 4


def test_a_pending_strategy_round_trips_exactly(pending_base, tmp_path):
    setup, path, _, _ = pending_base
    loaded = Strategy.load(path, setup.scenario)
    again = Strategy.load(loaded.save(tmp_path / "again.npz"), setup.scenario)
    from cellplan.strategies.policy.strategy import solve_scenario

    fresh, _ = solve_scenario(setup.scenario, setup.workcell)
    for strat in (loaded, again):
        mdp = strat.mdp
        assert not mdp.is_simple()
        assert mdp.opt_ptr is not None
        np.testing.assert_array_equal(mdp.opt_ptr, fresh.mdp.opt_ptr)
        np.testing.assert_array_equal(strat.values, fresh.values)  # NaN off the live states
        assert mdp.modes == fresh.mdp.modes
        assert [m.label for m in mdp.modes] == [m.label for m in fresh.mdp.modes]
        assert all(m.kind == "Q" for m in mdp.modes[1:])
        for name in ("tf", "fmp_next", "cost", "live", "branch_ptr", "branch_layer", "free"):
            np.testing.assert_array_equal(getattr(mdp, name), getattr(fresh.mdp, name))
        for mine, theirs in zip(mdp.fmp_outcomes(), fresh.mdp.fmp_outcomes(), strict=True):
            np.testing.assert_array_equal(mine, theirs)
        assert strat.gain == fresh.gain
    # The loaded strategy acts as the solved one at the live cell centres of every mode.
    mdp = fresh.mdp
    for m in range(mdp.n_modes):
        for c in np.flatnonzero(mdp.live[m])[::3]:
            q = mdp.lower + (np.array(np.unravel_index(c, tuple(mdp.shape))) + 0.5) * mdp.spacing
            assert loaded.action(q, m) == fresh.action(q, m)


def test_a_section_v_file_stores_the_identity_and_loads_without_options(section_v_base):
    setup, path, arrays, meta = section_v_base
    np.testing.assert_array_equal(arrays["opt_ptr"], np.arange(len(meta["modes"]) + 1))
    strat = Strategy.load(path, setup.scenario)
    assert strat.mdp.opt_ptr is None and strat.mdp.is_simple()
    assert strat.mdp.tf.shape[0] == strat.mdp.n_modes


# --- refusals ----------------------------------------------------------------------------


def _set(name: str, index: int, value: Any) -> Any:
    return lambda a: a[name].reshape(-1).__setitem__(index, value)


def _pick(a: dict, mode: int, option: int) -> int:
    """The index in ``out_layer`` of the first outcome of a mode's ``option``-th FMP option."""
    return int(a["out_ptr"][a["opt_ptr"][mode] + option])


def _set_pick(mode: int, option: int, value: Any) -> Any:
    """Sets the first outcome of a mode's ``option``-th FMP option (``value(a)``)."""
    return lambda a: a["out_layer"].__setitem__(_pick(a, mode, option), value(a))


def _pick_both_of_twice(a: dict) -> None:
    """The one pick of ``{P1,S1,D1; P1,S1,D1}`` leads to ``{} + <P1,S1,D1>``: both requests
    leave the queue, where the model leaves the other one waiting."""
    both_gone = LABELS.index("{} + <P1,S1,D1>")
    a["out_layer"][_pick(a, TWICE, 0)] = both_gone
    a["fmp_next"][TWICE] = both_gone


@pytest.mark.parametrize(
    ("change", "words"),
    [
        # the options of {P1,S1,D1; P1,S2,D1} start before those of the mode before it
        (
            lambda a: a["opt_ptr"].__setitem__(BOTH, a["opt_ptr"][BOTH - 1] - 1),
            r"opt_ptr: expected 0, non-decreasing, ending at the number",
        ),
        (_set("opt_ptr", -1, OPTIONS - 1), r"opt_ptr: expected 0, non-decreasing, ending at"),
        (_set("opt_ptr", 0, 1), r"opt_ptr: expected 0, non-decreasing"),
        (_set("opt_ptr", -1, OPTIONS + 1), rf"opt_ptr: value {OPTIONS + 1} above {OPTIONS}"),
        (_set("opt_ptr", 1, 1), r"opt_ptr: NR has no FMP option"),
        (_set("out_layer", 0, M), rf"out_layer: value {M} above {M - 1}"),
        (_set("out_layer", 0, -1), r"out_layer: value -1 below 0"),
        # the second pick of {P1,S1,D1; P1,S2,D1} (not its first: fmp_next) leads to NR
        (
            _set_pick(BOTH, 1, lambda a: 0),
            r"out_layer: mode \{P1,S1,D1; P1,S2,D1\} has an FMP outcome",
        ),
        # ... or picks the same request as the mode's first option
        (
            _set_pick(BOTH, 1, lambda a: a["out_layer"][_pick(a, BOTH, 0)]),
            r"out_layer: mode \{P1,S1,D1; P1,S2,D1\} has an FMP outcome the model cannot",
        ),
        # the pick of {P1,S1,D1; P1,S1,D1} takes both requests (fmp_next agrees with it)
        (
            _pick_both_of_twice,
            r"out_layer: mode \{P1,S1,D1; P1,S1,D1\} has an FMP outcome the model cannot",
        ),
        (_set("out_prob", 5, 0.5), r"out_prob: the outcomes of an FMP option do not sum to 1"),
        (_set("out_cost", 2, np.inf), r"out_cost: contains infinite values"),
        # fmp_next names the second pick of {P1,S1,D1; P1,S2,D1}, not its first
        (
            lambda a: a["fmp_next"].__setitem__(BOTH, a["out_layer"][_pick(a, BOTH, 1)]),
            r"fmp_next: not the first outcome of the mode's first FMP",
        ),
        (
            lambda a: a.__setitem__("out_ptr", a["out_ptr"][:20]),
            rf"out_ptr: shape \(20,\), expected axis 0 \(O \+ 1\) to be {OPTIONS + 1}",
        ),
        # fewer rows of tf (M - 1, the fewest FMP options a file may have) than options:
        # every header is checked before any data, so out_ptr's length is named first
        (
            lambda a: a.__setitem__("tf", a["tf"][: M - 1]),
            rf"out_ptr: shape \({OPTIONS + 1},\), expected axis 0 \(O \+ 1\) to be {M}",
        ),
    ],
)
def test_tampered_options_are_named(pending_base, tmp_path, change, words):
    refused(pending_base, tmp_path, words, arrays_change=change)


def _swap_requests(meta: dict) -> None:
    """Requests 1 and 2 change names everywhere: a valid model, not the scenario's."""
    a, b = ",".join(REQUESTS[0]), ",".join(REQUESTS[1])
    for m in meta["modes"][1:]:
        waiting = [{a: b, b: a}.get(w, w) for w in m[4:]]
        carried = {a: b, b: a}.get(",".join(m[1:4]), ",".join(m[1:4]))
        m[1:] = (carried.split(",") if m[1] else ["", "", ""]) + waiting


@pytest.mark.parametrize(
    ("change", "words"),
    [
        # a fourth request type, in one mode only
        (
            lambda meta: meta["modes"][BOTH].__setitem__(4, "P1,S2,D2"),
            rf"meta.modes: {M} modes; up to 2 open requests of 4 types make "
            rf"{sum(mode_counts(4, 2))}",
        ),
        (
            lambda meta: meta["modes"][BOTH].__setitem__(4, "P1;S1;D1"),
            rf"meta.modes.{BOTH}: waiting request 'P1;S1;D1' is not 'part,source,destination'",
        ),
        # a request type may wait twice, but a third time is a mode of max_pending 3
        (
            lambda meta: meta["modes"][TWICE].append("P1,S1,D1"),
            rf"meta.modes: {M} modes; up to 3 open requests of 3 types make "
            rf"{sum(mode_counts(3, 3))}",
        ),
        # {P1,S1,D1; P1,S2,D1} becomes a second {P1,S1,D1; P1,S1,D1}
        (
            lambda meta: meta["modes"][BOTH].__setitem__(5, "P1,S1,D1"),
            r"meta.modes: a Q mode appears twice",
        ),
        (
            lambda meta: meta["modes"][CARRYING].__setitem__(2, ""),
            rf"meta.modes.{CARRYING}: a Q mode names the part, source and destination it carries",
        ),
        (
            lambda meta: meta["modes"][2].__setitem__(4, meta["modes"][1][4]),
            r"meta.modes: a Q mode appears twice",
        ),
        (
            lambda meta: meta["modes"][1].__delitem__(4),
            r"meta.modes.1: a Q mode with no open request",
        ),
        (
            lambda meta: meta["modes"][0].__setitem__(0, "W"),
            r"meta.modes: expected NR, then the W modes",
        ),
        (lambda meta: meta.__setitem__("version", 2), r"version 2 \(an older cellplan\); solve"),
        (lambda meta: meta.__setitem__("version", 1), r"version 1 \(an older cellplan\); solve"),
    ],
)
def test_tampered_modes_are_named(pending_base, tmp_path, change, words):
    refused(pending_base, tmp_path, words, meta_change=change)


def test_renamed_requests_load_alone_but_not_with_the_scenario(pending_base, tmp_path):
    """Swapping two request types' names everywhere gives a valid model of simultaneous
    requests, not the scenario's: refused with it, accepted without it."""
    setup, _, arrays, meta = pending_base
    meta = json.loads(json.dumps(meta))
    _swap_requests(meta)
    path = _write(tmp_path / "swapped.npz", arrays, meta, True)
    strat = Strategy.load(path)
    assert strat.mode_index("{P1,S2,D1}") == 1  # the name the file now gives mode 1
    with pytest.raises(PersistenceError, match=rf"meta.modes: {M} modes that differ from the {M}"):
        Strategy.load(path, setup.scenario)


class _SameDigest:
    """A scenario that claims the file's digest (to reach the check after it)."""

    def __init__(self, scenario: Any, digest: str) -> None:
        self._scenario, self._digest = scenario, digest

    def digest(self) -> str:
        return self._digest

    def __getattr__(self, name: str) -> Any:
        return getattr(self._scenario, name)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        (
            pending_text(max_pending=3),
            rf"{M} modes that differ from the {sum(mode_counts(3, 3))} of the scenario's 3 "
            "requests with max_pending 3",
        ),
        (
            pending_text().replace(", {part: P1, source: S1, destination: D2}", ""),
            rf"{M} modes that differ from the {sum(mode_counts(2, 2))} of the scenario's 2 "
            "requests with max_pending 2",
        ),
        # a Section V scenario: one request at a time
        (
            TINY.replace("CELLS", "12"),
            rf"differ from the {sum(mode_counts(2, 1))} of the scenario's 2 requests with max",
        ),
    ],
)
def test_another_max_pending_or_request_list_says_solve_again(pending_base, text, words):
    _, path, _, meta = pending_base
    other = loads(text).scenario
    with pytest.raises(PersistenceError, match=r"different scenario .*solve this scenario again"):
        read_strategy(path, other)
    with pytest.raises(PersistenceError, match=words + r".*solve this scenario again"):
        read_strategy(path, _SameDigest(other, meta["scenario_digest"]))


def test_a_section_v_file_with_options_is_refused(section_v_base, tmp_path):
    words = r"opt_ptr: expected one FMP option per mode \(0, 1, ..., M\) in a model without"
    refused(section_v_base, tmp_path, words, _set("opt_ptr", 1, 0))
    line = refused(section_v_base, tmp_path, r"version 2 \(an older", None, _set_version(2))
    assert line.endswith("solve the scenario again to write version 4")


def _set_version(v: int) -> Any:
    return lambda meta: meta.__setitem__("version", v)


@settings(
    max_examples=80,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_crafted_pending_files_are_refused_cleanly_or_safe_to_query(data, pending_base, tmp_path):
    """Crafted files (as for Section V): refused with one line, or every mode answers
    ``action`` at every cell centre without crashing the kernels."""
    kind, path = craft(data, pending_base, tmp_path)
    setup = pending_base[0]
    try:
        strat = Strategy.load(path, setup.scenario)
    except PersistenceError as exc:
        assert len(exc.problems) == 1 and "\n" not in str(exc), (kind, exc)
        return
    mdp = strat.mdp
    for m in range(mdp.n_modes):
        for c in np.flatnonzero(mdp.live[m])[::5]:
            idx = np.array(np.unravel_index(c, tuple(mdp.shape)))
            strat.action(mdp.lower + (idx + 0.5) * mdp.spacing, m)


# --- mode names, pictures, validate ----------------------------------------------------------


def test_every_q_label_names_its_mode(pending_base):
    setup, path, _, _ = pending_base
    strat = Strategy.load(path, setup.scenario)
    for i, mode in enumerate(strat.modes):
        assert strat.mode_index(mode.label) == i
        assert strat.mode_index(f"  {mode.label}\t") == i
        assert strat.mode_index("".join(mode.label.split())) == i
        if len(mode.waiting) > 1:  # the waiting requests form a multiset: order is free
            turned = Mode("Q", mode.part, mode.source, mode.destination, waiting=mode.waiting[::-1])
            assert strat.mode_index(turned.label) == i
    assert strat.mode_index("{}") == 0 == strat.mode_index("NR")
    with pytest.raises(PersistenceError, match=r"no mode '\{P1,S9,D1\}' in this strategy"):
        strat.mode_index("{P1,S9,D1}")
    with pytest.raises(PersistenceError, match=rf"\({M} modes\)"):
        strat.mode_index("{P1,S1,D1} + <P1,S1,D9>")
    with pytest.raises(PersistenceError, match=r"expected a mode label such as"):
        strat.mode_index("{P1,S1,D1")
    with pytest.raises(PersistenceError, match=r"expected NR or a mode label such as"):
        strat.mode_index("P1,S1,D1")


def test_a_request_type_waiting_twice_round_trips_and_is_named(pending_base, tmp_path):
    """Two requests of one type may wait at once (the waiting requests are a multiset): the
    mode {P1,S1,D1; P1,S1,D1} is written with the request twice, read back as it was, and
    named by its label, apart from {P1,S1,D1}; its one FMP option picks one of the two."""
    setup, path, arrays, meta = pending_base
    twice = "{P1,S1,D1; P1,S1,D1}"
    assert meta["modes"][TWICE] == ["Q", "", "", "", "P1,S1,D1", "P1,S1,D1"]
    loaded = Strategy.load(path, setup.scenario)
    again_path = loaded.save(tmp_path / "again.npz")
    again = Strategy.load(again_path, setup.scenario)
    with np.load(again_path, allow_pickle=False) as data:
        assert json.loads(str(data["meta"]))["modes"] == meta["modes"]
        for name in ("opt_ptr", "out_ptr", "out_layer", "fmp_next", "live", "tf"):
            np.testing.assert_array_equal(data[name], arrays[name])
    for strat in (loaded, again):
        mode = strat.modes[TWICE]
        assert mode.waiting == ("P1,S1,D1", "P1,S1,D1") and mode.label == twice
        assert strat.mode_index(twice) == TWICE == strat.mode_index(" {P1,S1,D1;P1,S1,D1} ")
        assert strat.mode_index("{P1,S1,D1}") == LABELS.index("{P1,S1,D1}") != TWICE
        assert strat.mode_index("{P1,S1,D1} + <P1,S1,D1>") == CARRYING
        mdp = strat.mdp
        assert mdp.opt_ptr is not None
        assert mdp.opt_ptr[TWICE + 1] - mdp.opt_ptr[TWICE] == 1
        assert mdp.fmp_next[TWICE] == CARRYING  # one P1,S1,D1 carried, the other waits
        np.testing.assert_array_equal(strat.values[TWICE], loaded.values[TWICE])
    for label in ("{P1,S1,D1; P1,S1,D1; P1,S1,D1}", "{P1,S1,D1; P1,S1,D1} + <P1,S1,D1>"):
        with pytest.raises(PersistenceError, match=r"no mode '\{P1,S1,D1; P1,S1,D1"):
            loaded.mode_index(label)  # three open requests: more than max_pending


def test_plot_mode_draws_a_q_mode(cellplan, pending_base, tmp_path):
    _, path, _, _ = pending_base
    yaml = tmp_path / "pending.yaml"
    yaml.write_text(pending_text())
    out = tmp_path / "q.png"
    label = "{P1,S2,D1} + <P1,S1,D2>"
    r = cellplan("plot", str(yaml), "--strategy", str(path), "--mode", f" {label} ", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 0
    bad = tmp_path / "bad.png"
    r = cellplan("plot", str(yaml), "--strategy", str(path), "--mode", "{P1,S9,D1}", "-o", str(bad))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--mode" in lines[0] and "no mode '{P1,S9,D1}'" in lines[0]
    assert not bad.exists()


@pytest.mark.parametrize("code", [-2, -4, -5])
def test_plot_mode_marks_every_fmp_option_as_fmp(pending_base, tmp_path, monkeypatch, code):
    """A policy that picks (FMP option 0, 1 or 2: codes -2, -4, -5) everywhere is drawn as
    FMP marks at every sampled live cell, whichever option it picks."""
    import matplotlib.axes

    from cellplan.strategies.policy.decisions import Action, fmp_option_of

    setup, path, _, _ = pending_base
    strat = Strategy.load(path, setup.scenario)
    m = strat.mode_index("{P1,S1,D1; P1,S2,D1}")
    drawn: list[tuple] = []
    real = matplotlib.axes.Axes.plot

    def record(self, *args, **kwargs):
        drawn.append(args)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", record)
    # A pick of that option (a typed action, as Strategy.action answers).
    pick = Action("pick", code, step=(0.0, 0.0), region="S1", option=fmp_option_of(code))
    monkeypatch.setattr(Strategy, "action", lambda self, q, mode: pick)
    plot_mode(strat, setup.workcell, m, tmp_path / "m.png", arrows=12)
    marks = [a[2] for a in drawn if len(a) == 3]
    assert marks and set(marks) == {"o"}
    assert len(marks) == int(strat.mdp.live[m].sum())  # 12 x 12 grid, every cell sampled


def test_frames_and_gif_draw_q_modes(pending_base, tmp_path):
    setup, path, _, _ = pending_base
    strat = Strategy.load(path, setup.scenario)
    labels = ["NR", "{P1,S1,D1}", "{P1,S1,D1; P1,S2,D1}", "{P1,S2,D1} + <P1,S1,D1>", "NR"]
    modes = np.repeat([strat.mode_index(x) for x in labels], 4)
    n = len(modes)
    q = np.column_stack([np.linspace(5.0, 25.0, n), np.full(n, 8.0)])
    sim = Simulation(q, modes, np.zeros(n - 1, np.int64), np.zeros(n - 1))
    paths = plot_frames(strat, setup.workcell, sim, tmp_path / "frames", each=True)
    assert len(paths) == 6 and all(p.stat().st_size > 0 for p in paths)
    gif = save_animation(strat, setup.workcell, sim, tmp_path / "run.gif", max_frames=6)
    assert gif.stat().st_size > 0


def test_q_modes_highlight_waiting_sources_and_the_carried_request():
    both = Mode("Q", waiting=("P1,S1,D1", "P1,S2,D1"))
    assert mode_regions(both) == ["S1", "S2"] and carried_part(both) is None
    carrying = Mode("Q", "P1", "S1", "D2", waiting=("P1,S2,D1",))
    assert mode_regions(carrying) == ["S2", "S1", "D2"] and carried_part(carrying) == "P1"
    assert carried_part(Mode("C", "P1", "S1", "D1")) == "P1"
    assert carried_part(Mode("W", "P1", "S1", "D1")) is None
    long = "(1) " + Mode("Q", "P1", "S1", "D2", waiting=("P1,S1,D1",) * 4).label
    wrapped = wrap_title(long, 30)
    assert all(len(line) <= 30 for line in wrapped.splitlines())
    assert wrapped.replace("\n", " ") == long


def test_validate_counts_the_modes_of_each_max_pending(cellplan, tmp_path):
    path = tmp_path / "pending.yaml"
    path.write_text(pending_text(max_pending=3))
    r = cellplan("validate", str(path))
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if "assembly modes:" in x)
    # the modes pending_modes lists; of max_pending 3: 20 empty (multisets of at most 3
    # of the 3 types: 1 + 3 + 6 + 10) and 3 x 10 carrying (at most 2 waiting)
    each = [len(pending_modes(3, k)) for k in (1, 2, 3)]
    empty = sum(carried < 0 for _, carried in pending_modes(3, 3))
    assert (empty, each[2] - empty) == mode_counts(3, 3) == (20, 30)
    expected = (
        f"assembly modes: {each[2]} (Section VI-2: up to 3 open requests of 3 types: {empty} "
        f"empty + {each[2] - empty} carrying; max_pending 1: {each[0]}, 2: {each[1]}, "
        f"3: {each[2]}); states: "
    )
    assert expected in line
    states = int(line.split("states: ")[1].replace(",", ""))
    assert 0 < states <= each[2] * 12 * 12

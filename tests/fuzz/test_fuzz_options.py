"""Fuzzing the command-line options of every command.

Each case is one command with one option surely out of its domain (a negative count,
NaN, 1e21, text for a number, an unwritable output path ...) and up to three other
options drawn from values that may be valid or not. The command must answer before any
work: exit 2, each stderr line ``error: WHERE: what`` where WHERE is an option, the
argument, or a path given on the line, and no output left behind. Valid cheap requests
(validate, show, cspace, plot on the tiny scenario) are fuzzed too and must exit 0 or 2.
The default run is a few cases per command with a fixed seed; the ``slow`` run tries
``CELLPLAN_FUZZ_OPTION_EXAMPLES`` per command:

    CELLPLAN_FUZZ_OPTION_EXAMPLES=120 pytest -m slow tests/fuzz/test_fuzz_options.py
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from fuzz_harness import FailureLog, bad_lines, fuzz_settings, run_cli
from hypothesis import given
from hypothesis import strategies as st

FAST_EXAMPLES = 4
SLOW_EXAMPLES = int(os.environ.get("CELLPLAN_FUZZ_OPTION_EXAMPLES", "120"))

BAD_INT = ["-5", "-1", "1e21", "10" * 11, "-9223372036854775809", "abc", "", "1.5", "nan", "inf"]
BAD_COUNT = [*BAD_INT, "0", str(10**21), str(2**64)]
BAD_SEED = ["-5", "-1", "abc", "", "1.5", "nan", "1e21"]
BAD_FLOAT = ["nan", "inf", "-inf", "abc", "", "1e400"]
BAD_POSITIVE = [*BAD_FLOAT, "0", "-0", "-1", "-1e308"]
EXTREME_POSITIVE = ["1e-300", "5e-324", "1e308"]  # valid numbers; must not crash either
ODD_TEXT = ["", " ", "$x^$", "[/x]", "nosuch", "é", "1,2,3", "NR,", "-", "--", "x" * 300]


@dataclass
class Opt:
    """An option, values surely wrong for it, and values that may be fine (cheap ones)."""

    flag: str
    bad: list[str]
    other: list[str] = field(default_factory=list)


def commands(tmp: Path, strategy: Path) -> dict[str, tuple[list[str], list[Opt]]]:
    """For each command: its fixed arguments and its options."""
    afile = tmp / "a-file"
    afile.write_text("x")
    ro = tmp / "read-only"
    ro.mkdir(exist_ok=True)
    ro.chmod(0o500)
    folder = tmp / "a-folder"
    folder.mkdir(exist_ok=True)
    bad_image = [
        str(folder),
        str(afile / "x.png"),
        *([str(ro / "x.png")] if os.geteuid() != 0 else []),  # root may write anywhere
        "x.bmp",
        "x",
        "",
    ]
    bad_folder = [str(afile), str(afile / "sub")]
    if os.geteuid() != 0:
        bad_folder.append(str(ro / "out"))
    bad_strategy = [str(folder), str(afile), "/nonexistent.npz", "", str(tmp / "none.npz")]
    ok_image = [str(tmp / "ok.png"), str(tmp / "ok.svg")]
    ok_folder = [str(tmp / "out")]
    return {
        "validate": ([], [Opt("SCENARIO", [*ODD_TEXT, str(folder), str(afile)], [])]),
        "show": (["strategies_tiny"], [Opt("--output", bad_image, ok_image)]),
        "cspace": (
            ["strategies_tiny"],
            [
                Opt("--output", bad_image, ok_image),
                Opt(
                    "--cells",
                    [
                        "0,0",
                        "3,3",
                        "4097,4",
                        "-1,8",
                        "1e21,8",
                        "8",
                        "8,8,8",
                        "a,b",
                        "",
                        "8,,8",
                        "nan,8",
                    ],
                    ["8,8", "16,12"],
                ),
                Opt("--carrying", ODD_TEXT, ["P1"]),
                Opt("--slice", BAD_INT, ["0"]),
            ],
        ),
        "solve": (
            ["strategies_tiny"],
            [
                Opt("--output", [*bad_folder, str(folder), str(tmp / "x.txt")], []),
                Opt("--cells", ["0,0", "3,3", "1e21,8", "8", "a,b", "", "5000,5000"], ["8,8"]),
                Opt("--method", ODD_TEXT, ["auto", "general"]),
                Opt("--sample-stages", BAD_COUNT, ["2"]),
                Opt("--seed", BAD_SEED, ["0", "3"]),
            ],
        ),
        "simulate": (
            ["strategies_tiny"],
            [
                Opt("--strategy", bad_strategy, [str(strategy)]),
                Opt("--stages", BAD_COUNT, ["2"]),
                Opt("--seed", BAD_SEED, ["0"]),
                Opt("--output", bad_folder, ok_folder),
                Opt("--policy", ODD_TEXT, ["optimal", "home"]),
                Opt("--max-wait", BAD_POSITIVE, [*["10"], *EXTREME_POSITIVE]),
            ],
        ),
        "plot": (
            ["strategies_tiny"],
            [
                Opt("--strategy", bad_strategy, [str(strategy)]),
                Opt("--mode", [*ODD_TEXT, "9,9,9,9", "0,0,0,0", "1,1,1,1|X"], ["NR"]),
                Opt("--output", bad_image, ok_image),
            ],
        ),
        "adapt": (
            ["adaptive_fig3"],
            [
                Opt("--repair", ODD_TEXT, ["A0", "A3"]),
                Opt("--tasks", BAD_COUNT, ["1"]),
                Opt("--seed", ["abc", "1e21", "", "1.5"], ["0", "-5"]),
                Opt("--db", [str(folder), str(afile / "x.db"), ""], []),
                Opt("--output", bad_folder, ok_folder),
            ],
        ),
        "assemble": (
            ["discs_swap"],
            [
                Opt("--algorithm", ODD_TEXT, ["gradient", "sequential"]),
                Opt("--k", BAD_POSITIVE, [*["20"], *EXTREME_POSITIVE]),
                Opt("--epsilon", BAD_POSITIVE, [*["0.001"], *EXTREME_POSITIVE]),
                Opt("--tolerance", BAD_POSITIVE, [*["0.01"], *EXTREME_POSITIVE]),
                Opt("--rule", ODD_TEXT, ["paper", "place"]),
                Opt("--escapes", BAD_INT, ["2"]),
                Opt("--escape", ODD_TEXT, ["place"]),
                Opt("--integrator", ODD_TEXT, ["rk4"]),
                Opt("--frames", [*BAD_COUNT, "1"], ["3"]),
                Opt("--output", bad_folder, ok_folder),
            ],
        ),
        "assemble --random": (
            [],
            [
                Opt("--random", [*BAD_COUNT, "501"], ["2"]),
                Opt("--seed", BAD_SEED, ["1"]),
                Opt("--radius", BAD_POSITIVE, [*["1", "0.5"], *EXTREME_POSITIVE]),
                Opt("--fill", [*BAD_POSITIVE, "0.6", "1"], ["0.05", *EXTREME_POSITIVE]),
                Opt("--log10-beta", BAD_FLOAT, ["-5"]),
                Opt("--frames", [*BAD_COUNT, "1"], ["3"]),
                Opt("--output", bad_folder, ok_folder),
            ],
        ),
        "reproduce": (
            [],
            [
                Opt("--runs", BAD_COUNT, []),
                Opt("--only", [*ODD_TEXT, "nosuch,other"], []),
                Opt("--output", bad_folder, []),
            ],
        ),
        "demo": ([], [Opt("--output", bad_folder, [])]),
    }


@st.composite
def option_case(draw: st.DrawFn, table: dict, name: str) -> tuple[list[str], str]:
    """(argv, the option given a surely-bad value); "" when every value may be valid."""
    fixed, opts = table[name]
    words = name.split()
    argv = [words[0], *fixed]
    if len(words) > 1:
        argv.append(words[1])  # e.g. assemble --random: its value comes with the options
    candidates = [o for o in opts if o.bad]
    bad_opt = draw(st.sampled_from(candidates)) if candidates else None
    others = [o for o in opts if o is not bad_opt and (o.other or o.bad)]
    chosen = (
        draw(st.lists(st.sampled_from(others), unique_by=lambda o: o.flag, max_size=3))
        if others
        else []
    )
    if bad_opt is not None and bad_opt.flag == "--random" and len(words) > 1:
        argv.pop()
    elif len(words) > 1 and not any(o.flag == "--random" for o in chosen):
        argv.pop()
        argv += ["--random", "2"]  # assemble --random needs a count to mean anything
    bad_flag = ""
    if bad_opt is not None:
        value = draw(st.sampled_from(bad_opt.bad))
        # an upper-case name is the positional argument
        argv += [value] if bad_opt.flag.isupper() else [bad_opt.flag, value]
        bad_flag = bad_opt.flag
    for o in chosen:
        if o.flag == "--random" and "--random" in argv:
            continue
        argv += [o.flag, draw(st.sampled_from(o.other or o.bad))]
    return argv, bad_flag


@pytest.fixture(scope="module")
def table(tmp_path_factory: pytest.TempPathFactory) -> dict:
    tmp = tmp_path_factory.mktemp("fuzz-options")
    strategy = tmp / "tiny.npz"
    r = run_cli(["solve", "strategies_tiny", "-o", str(strategy)], timeout=600)
    assert r.code == 0, r.describe()
    return commands(tmp, strategy)


COMMANDS = [
    "validate", "show", "cspace", "solve", "simulate", "plot", "adapt", "assemble",
    "assemble --random", "reproduce", "demo",
]  # fmt: skip


def check_case(argv: list[str], bad_flag: str, where: Path) -> None:
    outputs = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("--output", "--db")]
    before = {p: Path(p).exists() for p in outputs if p}
    cwd = os.getcwd()
    os.chdir(where)  # default outputs land in the test's folder
    try:
        r = run_cli(argv)
    finally:
        os.chdir(cwd)
    if bad_flag:
        assert r.code == 2, r.describe()
    else:
        assert r.code in (0, 1, 2), r.describe()
    if r.code == 2:
        # a line may name a value given on the command line (a path, the scenario)
        given = [a for a in argv[1:] if a.strip()]
        bad = bad_lines(r.stderr, files=given, roots=[], options=True)
        assert not bad, f"{r.describe()}\nlines naming no option, argument or file: {bad[:5]}"
        for p, existed in before.items():
            assert existed or not Path(p).exists(), f"{r.describe()}\nleft {p} behind"


@pytest.mark.parametrize("name", COMMANDS)
def test_options(name: str, table: dict, tmp_path: Path) -> None:
    @fuzz_settings(FAST_EXAMPLES)
    @given(case=option_case(table, name))
    def check(case: tuple[list[str], str]) -> None:
        check_case(*case, tmp_path)

    check()


@pytest.mark.slow
@pytest.mark.parametrize("name", COMMANDS)
def test_options_thousands(name: str, table: dict, tmp_path: Path) -> None:
    log = FailureLog("options", name)

    @fuzz_settings(SLOW_EXAMPLES)
    @given(case=option_case(table, name))
    def check(case: tuple[list[str], str]) -> None:
        log.check(lambda: check_case(*case, tmp_path), "\0".join(case[0]))

    check()
    log.finish()

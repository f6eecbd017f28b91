"""``cellplan demo`` and ``cellplan reproduce``: end to end on fake experiments, argument checks."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

import fake_sweep_experiments as fake
from cellplan import experiments as ex
from cellplan import reproduce_cli
from cellplan.core import MIN_RUNS, Claim, Experiment, ReportPiece, RunSpec
from cellplan.demo import run_demo
from cellplan.errors import ArgumentError

DEMO_SEEDS = 3
"""The fake grid's demo seeds (its claims are not statistical)."""


def open_run(spec):
    return {"value": float(spec.seed)}


def open_report(rows, outdir):
    """A report with one decided and one undecided claim."""
    return ReportPiece(
        "Open",
        claims=[
            Claim("decided", "yes", "yes", True),
            Claim("open", "above 0", "0.1 ± 17.2", None, n=5, rule="interval above 0"),
        ],
    )


def open_experiment(paper: str) -> Experiment:
    """A fake experiment in the demo whose demo run leaves one claim undecided."""
    name = f"{paper}.open"
    return Experiment(
        name,
        paper,
        "Fake open",
        lambda runs, quick: [RunSpec(name, {"x": 1}, s) for s in range(runs)],
        open_run,
        open_report,
        demo_runs=MIN_RUNS,
    )


@pytest.fixture
def fake_papers(monkeypatch):
    """Every paper offers the fake grid (in the demo) and a second grid that is not in the
    demo, except adaptive, which has none yet; strategies also has an experiment whose
    demo run leaves a claim open."""

    def experiments(p: str) -> list[Experiment]:
        if p == "adaptive":
            return []
        found = [
            replace(fake.grid(f"{p}.grid", paper=p), demo_runs=DEMO_SEEDS),
            fake.grid(f"{p}.big", paper=p),
        ]
        return [*found, open_experiment(p)] if p == "strategies" else found

    def discover(papers=None):
        papers = list(ex.experiment_modules()) if papers is None else papers
        return [
            ex.PaperExperiments(p, experiments(p), "" if p != "adaptive" else "no experiments yet")
            for p in papers
        ]

    monkeypatch.setattr(ex, "discover", discover)


def test_demo_writes_the_quick_report(tmp_path, fake_papers):
    from rich.console import Console

    index = run_demo(tmp_path / "out", console=Console(quiet=True), serial=True, showcase=False)
    assert index == tmp_path / "out" / "index.html"
    text = index.read_text(encoding="utf-8")
    HTMLParser().feed(text)
    assert "cellplan demo" in text and "no experiments yet" in text
    assert 'id="workcells"' in text
    # quick version: two sizes, the experiment's demo seeds, two shapes
    with (tmp_path / "out" / "data" / "assembly.grid.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 2 * DEMO_SEEDS
    assert (
        "--quick" in text
        and "cellplan reproduce strategies --only strategies.grid --runs 3" in text
    )
    # an experiment without demo_runs is not swept but listed apart, with the full command
    assert not (tmp_path / "out" / "data" / "assembly.big.csv").exists()
    assert 'id="to-decide-assembly"' in text
    assert "cellplan reproduce assembly --only assembly.big -o cellplan-reproduce</pre>" in text
    # bundled workcells are drawn when the foundation can draw them, listed otherwise
    pictures = list((tmp_path / "out" / "workcells").glob("*.png"))
    assert all(p.stat().st_size > 0 for p in pictures)
    assert text.count("data:image/png") == 2 + len(pictures)


def verdict_lines(text: str) -> list[str]:
    """The verdict lines of a report (the paper sections' verdict lists)."""
    return [
        line
        for block in re.findall(r'<div class="verdicts">(.*?)</div>', text, re.S)
        for line in re.findall(r"<li[^>]*>(.*?)</li>", block, re.S)
    ]


def test_demo_shows_only_decided_verdicts_and_lists_the_rest_apart(
    tmp_path, fake_papers, monkeypatch
):
    from rich.console import Console

    import cellplan.demo as demo

    # the pictures are the other test's; this one reads the verdicts
    monkeypatch.setattr(demo, "make_pictures", lambda output, console, showcase: [])
    index = run_demo(tmp_path / "out", console=Console(quiet=True), serial=True, showcase=False)
    text = index.read_text(encoding="utf-8")
    lines = verdict_lines(text)
    assert lines and all("not enough runs" not in line for line in lines)
    assert any("✔ reproduced" in line for line in lines)
    assert any("✘ differs" in line for line in lines)
    assert 'class="verdict undecided"' not in text and '<li class="undecided"' not in text
    # the open claim of the demo run is listed apart, with what was measured and its command
    apart = re.search(r'<div class="to-decide" id="to-decide-strategies">(.*?)</div>', text, re.S)
    assert apart is not None
    assert "<b>open</b> (strategies.open): the demo&#x27;s run with n = 5" in apart.group(1)
    assert "cellplan reproduce strategies --only strategies.open -o cellplan-reproduce" in (
        apart.group(1)
    )
    assert "<b>decided</b>" not in apart.group(1)
    # the summary counts what is left apart, per paper: strategies.big and the open claim
    summary = re.search(r'<table class="summary">(.*?)</table>', text, re.S)
    assert summary is not None and "left to <code>cellplan reproduce</code>" in summary.group(1)
    assert '<a href="#to-decide-strategies">2</a>' in summary.group(1)
    assert '<a href="#to-decide-assembly">1</a>' in summary.group(1)


def test_demo_split_and_commands():
    grid = replace(fake.grid("assembly.grid"), demo_runs=MIN_RUNS)
    big = fake.grid("assembly.big")
    assert reproduce_cli.demo_split([grid, big]) == ([grid], [big])
    assert reproduce_cli.full_command(big) == (
        "cellplan reproduce assembly --only assembly.big -o cellplan-reproduce"
    )


def test_a_sweep_may_give_one_experiment_its_own_seed_count(tmp_path):
    from rich.console import Console

    grid = fake.grid("assembly.grid")
    other = fake.grid("assembly.other")
    sweep = ex.run_sweep(
        [grid, other],
        {"assembly": 2, "assembly.grid": 1},
        True,
        tmp_path,
        serial=True,
        console=Console(quiet=True),
    )
    assert [len(r.rows) for r in sweep.runs] == [2 * 2 * 1, 2 * 2 * 2]


def test_every_demo_experiment_runs_enough_seeds_to_decide():
    """The real experiments: each one in the demo runs at least the rules' minimum seeds,
    and its quick version honours that count."""
    in_demo = [e for f in ex.discover() for e in f.experiments if e.demo_runs is not None]
    assert in_demo
    for exp in in_demo:
        assert exp.demo_runs >= MIN_RUNS, exp.name
        seeds = {spec.seed for spec in exp.make_runs(exp.demo_runs, True)}
        assert seeds == set(range(exp.demo_runs)), exp.name


def test_a_real_demo_experiment_decides_every_claim(tmp_path):
    """One real experiment of the demo, swept at its demo size: every claim it states is
    decided (the slow test below runs the whole demo)."""
    from rich.console import Console

    from cellplan.strategies.experiments.paper import EXPERIMENTS

    exp = next(e for e in EXPERIMENTS if e.name == "strategies.anticipation")
    assert exp.demo_runs is not None
    sweep = ex.run_sweep(
        [exp], exp.demo_runs, True, tmp_path, serial=True, console=Console(quiet=True)
    )
    assert sweep.n_failed == 0
    piece = exp.report(sweep.runs[0].ok_rows, tmp_path)
    assert piece.claims
    assert [c.reproduced is not None for c in piece.claims] == [True] * len(piece.claims)
    assert all(c.n >= MIN_RUNS for c in piece.claims)


def test_demo_refuses_a_file_as_output(tmp_path):
    target = tmp_path / "file"
    target.write_text("x")
    with pytest.raises(ArgumentError) as info:
        run_demo(target)
    assert info.value.problems[0].field == "--output"


def cli() -> typer.Typer:
    app = typer.Typer()
    reproduce_cli.register(app)

    @app.command()
    def other() -> None:  # a second command keeps typer from collapsing the group
        pass

    return app


@pytest.mark.parametrize(
    ("args", "fields"),
    [
        (["reproduce", "all", "--runs", "many"], ["--runs"]),
        (["reproduce", "all", "--runs", "0"], ["--runs"]),
        (["reproduce", "everything"], ["TARGET"]),
        (["reproduce", "assembly", "--scheduler", "localhost"], ["--scheduler"]),
        (["reproduce", "--scheduler", "tcp://h:8786", "--serial"], ["--serial"]),
        (["reproduce", "nope", "--runs", "-3"], ["TARGET", "--runs"]),
    ],
)
def test_reproduce_checks_every_argument_first(tmp_path, args, fields, fake_papers):
    result = CliRunner().invoke(cli(), [*args, "-o", str(tmp_path / "out")])
    assert isinstance(result.exception, ArgumentError), result.output
    assert [p.field for p in result.exception.problems] == fields
    assert not (tmp_path / "out").exists()


def test_reproduce_refuses_unknown_experiment_and_file_output(tmp_path, fake_papers):
    (tmp_path / "f").write_text("")
    result = CliRunner().invoke(cli(), ["reproduce", "-o", str(tmp_path / "f")])
    assert [p.field for p in result.exception.problems] == ["--output"]
    result = CliRunner().invoke(
        cli(), ["reproduce", "--only", "assembly.nope", "-o", str(tmp_path / "o")]
    )
    assert [p.field for p in result.exception.problems] == ["--only"]
    assert "assembly.grid" in str(result.exception)


def test_reproduce_one_paper_one_experiment(tmp_path, fake_papers):
    out = tmp_path / "out"
    args = ["reproduce", "assembly", "--runs", "2", "--serial", "-o", str(out)]
    result = CliRunner().invoke(cli(), [*args, "--only", "assembly.grid"])
    # the fake grid fails one run per shape: a sweep with failed runs exits 1 (issue 36)
    assert result.exit_code == 1, result.output
    assert "error: 2 of 12 runs failed; report written: " in result.output
    assert [p.name for p in (out / "data").glob("*.csv")] == ["assembly.grid.csv"]
    with (out / "data" / "assembly.grid.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 3 * 2 * 2
    html = (out / "index.html").read_text()
    assert 'id="paper-assembly"' in html and 'id="paper-strategies"' not in html


def test_cellplan_reproduce_bad_runs_is_one_line_and_exit_2(tmp_path):
    cellplan = Path(sys.executable).parent / "cellplan"
    proc = subprocess.run(
        [str(cellplan), "reproduce", "all", "--runs", "x", "-o", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "error: --runs: expected a positive integer, got 'x'"
    ]


@pytest.mark.slow
def test_real_demo_runs_every_package(tmp_path):
    """The real demo on the real packages (slow; the fake-experiment tests cover the code):
    every verdict it shows is decided, and what it leaves undecided is listed apart with
    its command."""
    index = run_demo(tmp_path / "demo")
    text = index.read_text(encoding="utf-8")
    for paper in ex.experiment_modules():
        assert f'id="paper-{paper}"' in text
    assert "report failed" not in text and "failed to import" not in text
    lines = verdict_lines(text)
    assert lines and all("not enough runs" not in line for line in lines)
    assert '<li class="undecided"' not in text and 'class="verdict undecided"' not in text
    # strategies.failures decides nothing at demo size: listed apart with its command
    assert "cellplan reproduce strategies --only strategies.failures -o cellplan-reproduce" in text


def test_showcase_runs_each_package_and_reports_failures(tmp_path):
    import cellplan.demo as demo
    from cellplan.core import Package, ShowcaseItem

    def good(folder):
        folder.mkdir(parents=True)
        (folder / "a.png").write_bytes(b"png")
        return [
            ShowcaseItem("A picture", [folder / "a.png"], "what it shows", "cellplan.plan(...)")
        ]

    def bad(folder):
        raise RuntimeError("broken")

    pkgs = {
        "good": Package("good", "Good", "", "", showcase=good),
        "bad": Package("bad", "Bad", "", "", showcase=bad),
        "none": Package("none", "None", "", ""),
    }
    section = demo.run_showcase(tmp_path / "showcase", pkgs)
    assert [item.title for item in section.items] == ["A picture"]
    assert section.items[0].figures == [tmp_path / "showcase" / "good" / "a.png"]
    assert section.errors == ["bad: showcase failed: RuntimeError: broken"]
    from cellplan.report import _extra_section

    html = _extra_section(section)
    assert '<pre class="cmd"><code>cellplan.plan(...)</code></pre>' in html
    assert html.count('class="error"') == 1


def test_quick_honours_runs_in_every_experiment():
    """``--quick --runs N`` runs N seeds per point in every package's quick version."""
    for found in ex.discover():
        for exp in found.experiments:
            seeds = {spec.seed for spec in exp.make_runs(4, True)}
            assert seeds == {0, 1, 2, 3}, exp.name


def test_interrupt_is_one_line_with_the_cached_count(tmp_path, monkeypatch, capsys):
    from cellplan.cli import main

    cache = tmp_path / "out" / "cache" / "assembly.x" / "ab"
    cache.mkdir(parents=True)
    for i in range(3):
        (cache / f"ab{i}.json").write_text("{}")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(reproduce_cli, "reproduce_sweep", interrupted)
    monkeypatch.setattr(
        sys, "argv", ["cellplan", "reproduce", "assembly", "-o", str(tmp_path / "out")]
    )
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"interrupted; 3 runs cached in {tmp_path / 'out' / 'cache'}; run the same "
        "command to resume"
    ]


def test_an_experiment_with_nothing_to_report_is_listed_apart(tmp_path):
    """A demo experiment whose runs were all skipped has no claims to show: it is listed
    apart with its command, not dropped."""
    from cellplan.report import ExperimentReport, set_apart_undecided

    grid = fake.grid("assembly.grid")
    run = ex.ExperimentRun(grid, [], tmp_path / "a.csv", tmp_path / "a.json")
    empty = ExperimentReport(run, None, "no run succeeded, nothing to report", "cmd")
    opened = ExperimentReport(run, open_report([], tmp_path), "", "cmd")
    apart = set_apart_undecided([empty, opened], reproduce_cli.full_command)
    assert [(t.experiment, t.title) for t in apart] == [
        ("assembly.grid", "Fake grid assembly.grid"),
        ("assembly.grid", "open"),
    ]
    assert "no run succeeded" in apart[0].why
    assert apart[0].command == reproduce_cli.full_command(grid)
    assert opened.piece is not None and [c.claim for c in opened.piece.claims] == ["decided"]


def test_pictures_made_in_the_background_hand_back_their_value_or_error():
    from cellplan.demo import _Background

    assert _Background(lambda: ["section"]).join() == ["section"]

    def broken() -> list:
        raise RuntimeError("drawing failed")

    with pytest.raises(RuntimeError, match="drawing failed"):
        _Background(broken).join()

"""``cellplan demo`` and ``cellplan reproduce``: end to end on fake experiments, argument checks."""

from __future__ import annotations

import csv
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

import fake_sweep_experiments as fake
from cellplan import experiments as ex
from cellplan import reproduce_cli
from cellplan.demo import run_demo
from cellplan.errors import ArgumentError


@pytest.fixture
def fake_papers(monkeypatch):
    """Every paper offers one fake experiment, except adaptive, which has none yet."""

    def discover(papers=None):
        papers = list(ex.experiment_modules()) if papers is None else papers
        return [
            ex.PaperExperiments(
                p,
                [fake.grid(f"{p}.grid", paper=p)] if p != "adaptive" else [],
                "" if p != "adaptive" else "no experiments yet",
            )
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
    # quick version: two sizes, DEMO_RUNS seeds, two shapes
    with (tmp_path / "out" / "data" / "assembly.grid.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 2 * 3
    assert (
        "--quick" in text
        and "cellplan reproduce strategies --only strategies.grid --runs 3" in text
    )
    # bundled workcells are drawn when the foundation can draw them, listed otherwise
    pictures = list((tmp_path / "out" / "workcells").glob("*.png"))
    assert all(p.stat().st_size > 0 for p in pictures)
    assert text.count("data:image/png") == 2 + len(pictures)


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
    """The real demo on the real packages (slow; the fake-experiment test covers the code)."""
    index = run_demo(tmp_path / "demo")
    text = index.read_text(encoding="utf-8")
    for paper in ex.experiment_modules():
        assert f'id="paper-{paper}"' in text
    assert "report failed" not in text and "failed to import" not in text


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

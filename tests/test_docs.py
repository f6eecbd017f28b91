"""Every code block of the README and the guide runs, so the documentation cannot go stale.

Blocks run in order, per document, in one scratch folder: ```` ```yaml title="NAME" ````
blocks are written to ``NAME``; ```` ```sh ```` blocks run each ``cellplan`` line through the
command-line entry point in-process (exit status 0 expected; ``> FILE`` redirects stdout;
``make`` lines are what this test suite itself runs, so they are skipped); ```` ```python ````
blocks run in one namespace per document.

The fast test runs every block but parses, without running, the few command lines listed
in :data:`PARSED_ONLY` (each takes 10-60 s, and its package's tests run the same code); the
``slow`` twin runs every line.
"""

from __future__ import annotations

import gc
import re
import shlex
import sys
from pathlib import Path

import pytest
import typer.main

from cellplan.cli import app, main

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```", re.S | re.M)
TITLE = re.compile(r'title="([^"]+)"')


def blocks(path: Path) -> list[tuple[str, str, str]]:
    """``(language, info, body)`` of each fenced block of a Markdown file."""
    return [(m.group(1), m.group(2), m.group(3)) for m in FENCE.finditer(path.read_text())]


PARSED_ONLY = (
    # README: Section VI solves (tests/strategies/test_strategies_{failures,noise,pending,
    # periodic}.py), a 400-stage simulation with frames (test_strategies_cli.py), 20 adaptive
    # tasks (tests/adaptive/test_cli.py), an assembly with frames (tests/assembly/test_cli.py).
    "cellplan solve strategies_failures",
    "cellplan solve strategies_noise",
    "cellplan solve strategies_pending",
    "cellplan solve strategies_conveyor",
    "cellplan simulate strategies_p1",
    "cellplan adapt adaptive_fig4",
    "cellplan assemble discs_seven",
    # The guide: the same commands on the reader's own files.
    "cellplan simulate first_cell.yaml",
    "cellplan assemble first_discs.yaml",
    "cellplan adapt first_cell.yaml",
    "cellplan export motion.csv --format ros2-yaml",
)
"""Command lines the fast documentation test parses instead of running."""


def parse_cli(argv: list[str]) -> None:
    """Parse ``argv`` against the command-line interface without running the command.

    A renamed command or option, a wrong option type or a missing argument fails here as it
    would for a reader.
    """
    group = typer.main.get_command(app)
    ctx = group.make_context("cellplan", argv[1:])
    # typer's vendored click keeps the subcommand's name among the "protected" arguments.
    name, command, rest = group.resolve_command(ctx, [*ctx._protected_args, *ctx.args])
    assert command is not None, f"no command {name!r}"
    command.make_context(name, rest, parent=ctx)


def run_cli(line: str, capsys, *, full: bool = True) -> None:
    argv = shlex.split(line, comments=True)
    if not argv or argv[0] == "make":
        return
    assert argv[0] == "cellplan", f"not a cellplan command: {line}"
    if not full and line.startswith(PARSED_ONLY):
        parse_cli(argv)
        return
    target = None
    if ">" in argv:
        k = argv.index(">")
        target, argv = argv[k + 1], argv[:k]
    sys.argv = argv
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    assert code == 0, f"{line!r} exited {code}: {out.err[-2000:]}"
    if target is not None:
        Path(target).write_text(out.out)


@pytest.mark.parametrize(
    "full", [False, pytest.param(True, marks=pytest.mark.slow)], ids=["parsed", "run"]
)
@pytest.mark.parametrize("doc", ["README.md", "docs/guide.md"])
def test_every_code_block_runs(doc, full, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["cellplan"])
    namespace: dict[str, object] = {"__name__": "__docs__"}
    found = blocks(ROOT / doc)
    assert found, f"no code blocks in {doc}"
    for i, (lang, info, body) in enumerate(found):
        if lang == "yaml":
            name = TITLE.search(info)
            assert name, f'{doc} block {i}: a yaml block needs title="FILE"'
            Path(name.group(1)).write_text(body)
        elif lang == "sh":
            for line in body.splitlines():
                run_cli(line, capsys, full=full)
        elif lang == "python":
            exec(compile(body, f"{doc}[block {i}]", "exec"), namespace)
        else:
            pytest.fail(f"{doc} block {i}: unexpected language {lang!r}")
    gc.collect()


def _build_api():
    import importlib.util

    spec = importlib.util.spec_from_file_location("build_api", ROOT / "docs" / "build_api.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_api_reference_of_the_core_builds_without_warnings(tmp_path):
    """The core modules' reference; the slow twin below renders the paper packages too."""
    build_api = _build_api()
    core = tuple(m for m in build_api.MODULES if m not in build_api.PAPER_PACKAGES)
    assert build_api.build(tmp_path, core) == []
    for page in ("cellplan.html", "cellplan/api.html", "cellplan/trajectory.html"):
        assert (tmp_path / page).stat().st_size > 0


@pytest.mark.slow
def test_api_reference_builds_without_warnings(tmp_path):
    """``make docs`` in-process: pdoc renders every module from its numpydoc docstrings."""
    build_api = _build_api()
    assert build_api.build(tmp_path) == []
    for page in ("cellplan.html", "cellplan/api.html", "cellplan/trajectory.html"):
        assert (tmp_path / page).stat().st_size > 0
    assert (tmp_path / "cellplan" / "strategies").is_dir()


def test_parse_cli_refuses_what_a_reader_would_hit():
    parse_cli(["cellplan", "simulate", "strategies_p1", "--strategy", "q.npz", "--stages", "4"])
    with pytest.raises(Exception, match="No such option"):
        parse_cli(["cellplan", "simulate", "strategies_p1", "--strategy", "q.npz", "--stagse", "4"])
    with pytest.raises(Exception, match="valid integer"):
        parse_cli(
            ["cellplan", "simulate", "strategies_p1", "--strategy", "q.npz", "--stages", "four"]
        )
    with pytest.raises(Exception, match="No such command"):
        parse_cli(["cellplan", "simulat", "strategies_p1"])


def test_every_parsed_only_line_is_in_a_document():
    text = (ROOT / "README.md").read_text() + (ROOT / "docs" / "guide.md").read_text()
    assert [p for p in PARSED_ONLY if p not in text] == []

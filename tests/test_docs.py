"""Every code block of the README and the guide runs, so the documentation cannot go stale.

Blocks run in order, per document, in one scratch folder: ```` ```yaml title="NAME" ````
blocks are written to ``NAME``; ```` ```sh ```` blocks run each ``cellplan`` line through the
command-line entry point in-process (exit status 0 expected; ``> FILE`` redirects stdout;
``make`` lines are what this test suite itself runs, so they are skipped); ```` ```python ````
blocks run in one namespace per document.
"""

from __future__ import annotations

import gc
import re
import shlex
import sys
from pathlib import Path

import pytest

from cellplan.cli import main

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```", re.S | re.M)
TITLE = re.compile(r'title="([^"]+)"')


def blocks(path: Path) -> list[tuple[str, str, str]]:
    """``(language, info, body)`` of each fenced block of a Markdown file."""
    return [(m.group(1), m.group(2), m.group(3)) for m in FENCE.finditer(path.read_text())]


def run_cli(line: str, capsys) -> None:
    argv = shlex.split(line, comments=True)
    if not argv or argv[0] == "make":
        return
    assert argv[0] == "cellplan", f"not a cellplan command: {line}"
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


@pytest.mark.parametrize("doc", ["README.md", "docs/guide.md"])
def test_every_code_block_runs(doc, tmp_path, monkeypatch, capsys):
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
                run_cli(line, capsys)
        elif lang == "python":
            exec(compile(body, f"{doc}[block {i}]", "exec"), namespace)
        else:
            pytest.fail(f"{doc} block {i}: unexpected language {lang!r}")
    gc.collect()


def test_api_reference_builds_without_warnings(tmp_path):
    """``make docs`` in-process: pdoc renders every module from its numpydoc docstrings."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("build_api", ROOT / "docs" / "build_api.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.build(tmp_path) == []
    for page in ("cellplan.html", "cellplan/api.html", "cellplan/trajectory.html"):
        assert (tmp_path / page).stat().st_size > 0
    assert (tmp_path / "cellplan" / "strategies").is_dir()

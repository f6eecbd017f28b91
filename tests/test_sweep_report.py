"""The HTML report on a tiny sweep: parses, well nested, self-contained, expected tables."""

from __future__ import annotations

import base64
import csv
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path

import pytest

import fake_sweep_experiments as fake
from cellplan.core import ReportPiece
from cellplan.experiments import PaperExperiments, run_sweep
from cellplan.report import ExtraSection, make_pieces, reproduce_command, write_report

VOID = {"meta", "img", "br", "hr", "link", "input", "col", "source", "wbr"}
MAGIC = {"image/png": b"\x89PNG\r\n\x1a\n", "image/gif": b"GIF8"}


class Page(HTMLParser):
    """Parses the report, checks nesting, and collects images, links and tables."""

    def __init__(self, text: str) -> None:
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.images: list[str] = []
        self.hrefs: list[str] = []
        self.ids: list[str] = []
        self.tables: list[dict] = []  # {"caption", "class", "rows": [[cell text]]}
        self.text_parts: list[str] = []
        self._cell: list[str] | None = None
        self._caption: list[str] | None = None
        self.feed(text)
        self.close()
        if self.stack:
            self.errors.append(f"unclosed tags {self.stack}")

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.append(a["id"])
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag == "a":
            self.hrefs.append(a.get("href", ""))
        if tag == "table":
            self.tables.append(
                {"caption": "", "class": a.get("class", ""), "rows": [], "body": False}
            )
        if tag == "tbody":
            self.tables[-1]["body"] = True
        if tag == "tr" and self.tables[-1]["body"]:
            self.tables[-1]["rows"].append([])
        if tag in ("td", "th"):
            self._cell = []
        if tag == "caption":
            self._caption = []
        if tag not in VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:]} ")
            return
        self.stack.pop()
        if tag == "td" and self._cell is not None and self.tables[-1]["body"]:
            self.tables[-1]["rows"][-1].append("".join(self._cell))
        if tag in ("td", "th"):
            self._cell = None
        if tag == "caption" and self._caption is not None:
            self.tables[-1]["caption"] = "".join(self._caption)
            self._caption = None
        if tag == "tbody":
            self.tables[-1]["body"] = False

    def handle_data(self, data):
        self.text_parts.append(data)
        if self._cell is not None:
            self._cell.append(data)
        if self._caption is not None:
            self._caption.append(data)

    @property
    def text(self) -> str:
        return " ".join(self.text_parts)


def build(tmp_path: Path, exps, found=None, extra=(), runs=2) -> tuple[Path, Page]:
    sweep = run_sweep(exps, runs, False, tmp_path, serial=True, progress=False)
    pieces = make_pieces(sweep, lambda e: reproduce_command(e, runs, False, tmp_path))
    if found is None:
        found = [
            PaperExperiments(p, [e for e in exps if e.paper == p])
            for p in ("strategies", "adaptive", "assembly")
        ]
    index = write_report(tmp_path, found, pieces, sweep, extra=extra)
    return index, Page(index.read_text(encoding="utf-8"))


def decoded_images(page: Page) -> list[tuple[str, bytes]]:
    out = []
    for src in page.images:
        assert src.startswith("data:"), src[:40]
        header, payload = src[5:].split(",", 1)
        mime, encoding = header.split(";")
        assert encoding == "base64"
        out.append((mime, base64.b64decode(payload, validate=True)))
    return out


def test_report_of_a_tiny_sweep(tmp_path):
    exps = [fake.grid("fake.grid"), fake.grid("fake.other", paper="strategies")]
    found = [
        PaperExperiments("strategies", [exps[1]]),
        PaperExperiments("adaptive", [], note="no experiments yet"),
        PaperExperiments("assembly", [exps[0]]),
    ]
    picture = tmp_path / "extra.png"
    from PIL import Image

    Image.new("RGB", (10, 10)).save(picture)
    index, page = build(
        tmp_path, exps, found, extra=[ExtraSection("Extras", "x", [picture], anchor="extras")]
    )
    assert index == tmp_path / "index.html"
    assert page.errors == []

    # every image is embedded, decodes, is non-empty and is what its type says
    images = decoded_images(page)
    assert len(images) == 2 * 2 + 1  # PNG and GIF per experiment, plus the extra picture
    assert sorted(m for m, _ in images) == ["image/gif"] * 2 + ["image/png"] * 3
    for mime, data in images:
        assert data.startswith(MAGIC[mime]) and len(data) > len(MAGIC[mime])
    # the figure files the pieces referenced exist and are non-empty
    for name in ("fake.grid", "fake.other"):
        for figure in ("bars.png", "anim.gif"):
            assert (tmp_path / "figures" / name / figure).stat().st_size > 0

    # readable offline: nothing is fetched, links are local files that exist
    assert not any(s.startswith(("http:", "https:", "//")) for s in page.images + page.hrefs)
    for href in page.hrefs:
        if not href.startswith("#"):
            assert (tmp_path / href).is_file(), href
        else:
            assert href[1:] in page.ids, href

    # tables: summary per paper, claims, the piece's table, failures, machine
    (summary,) = [t["rows"] for t in page.tables if t["class"] == "summary"]
    assert [row[1:4] for row in summary] == [["1", "12", "2"], ["0", "0", "0"], ["1", "12", "2"]]
    assert [row[4:] for row in summary] == [["1", "1", "0"], ["0", "0", "0"], ["1", "1", "0"]]
    claims = [t["rows"] for t in page.tables if t["caption"] == "The paper beside cellplan"]
    assert len(claims) == 2
    for rows in claims:
        assert len(rows) == 2
        assert rows[0][3] == "✔ reproduced"
        assert rows[1][3] == "✘ differs: pi, not 3"
    means = [t["rows"] for t in page.tables if t["caption"] == "Mean area per point"]
    assert [len(rows) for rows in means] == [6, 6]
    failures = [t["rows"] for t in page.tables if t["caption"].startswith("Failed runs")]
    assert [[r[:3] for r in rows] for rows in failures] == [
        [["3", "disc", "1"], ["3", "square", "1"]]
    ] * 2
    assert all("ValueError" in r[3] for rows in failures for r in rows)

    # the CSV the report links has one row per run
    with (tmp_path / "data" / "fake.grid.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 12

    # one section per paper, the missing one saying so; commands to regenerate each piece
    assert {"paper-strategies", "paper-adaptive", "paper-assembly", "extras", "machine"} <= set(
        page.ids
    )
    assert "no experiments yet" in page.text
    assert "cellplan reproduce assembly --only fake.grid --runs 2 -o" in page.text
    assert "What was run." in page.text and "n ∈ {1, 2, 3}" in page.text
    assert not list(tmp_path.glob(".index.*"))  # no temporary file left behind

    # each paper with claims lists its verdicts up front, one line per claim
    text = index.read_text(encoding="utf-8")
    assert text.count('class="verdicts"') == 2
    assert text.count('<li class="ok">area grows with n — ✔ reproduced') == 2
    assert text.count('<li class="bad">area of the unit disc — ✘ differs: pi, not 3') == 2


def test_a_failing_report_and_bad_figures_do_not_hide_the_rest(tmp_path):
    def broken(rows, outdir):
        raise KeyError("missing column")

    def bad_figures(rows, outdir):
        empty = Path(outdir) / "empty.png"
        empty.write_bytes(b"")
        return ReportPiece("Bad figures", figures=[Path(outdir) / "nope.png", empty, "rel.bmp"])

    (tmp_path / "figures" / "fake.figs").mkdir(parents=True)
    (tmp_path / "figures" / "fake.figs" / "rel.bmp").write_bytes(b"BM")
    exps = [
        replace(fake.grid("fake.broken"), report=broken),
        replace(fake.grid("fake.figs"), report=bad_figures),
        replace(fake.grid("fake.none"), report=lambda rows, outdir: "not a piece"),
        replace(fake.grid("fake.allfail"), run=lambda spec: 1 / 0),
        replace(fake.grid("fake.empty"), make_runs=lambda runs, quick: []),
        fake.grid("fake.fine"),
    ]
    _, page = build(tmp_path, exps, runs=1)
    assert page.errors == []
    assert "report failed: KeyError: 'missing column' (at test_sweep_report.py:" in page.text
    assert "missing figure" in page.text and "empty.png is empty" in page.text
    assert "unsupported type .bmp" in page.text
    assert "report failed: TypeError: report returned a str" in page.text
    assert "no run succeeded, nothing to report" in page.text
    assert "make_runs listed no runs" in page.text
    assert len(decoded_images(page)) == 2  # only the fine experiment's figures
    assert len([t for t in page.tables if t["caption"] == "Mean area per point"]) == 1


@pytest.mark.parametrize("text", ["<script>alert(1)</script>", 'a "quoted" & <b>', "é ü ∈ β(d)"])
def test_text_is_escaped(tmp_path, text):
    def report(rows, outdir):
        return ReportPiece(text, text=text, tables=[(text, [{text: text}])])

    _, page = build(tmp_path, [replace(fake.grid(), title=text, report=report)], runs=1)
    assert page.errors == []
    assert "script" not in page.stack and text in page.text


def test_markdown_code_spans_become_code_and_text_is_escaped():
    from cellplan.report import _paragraphs

    html = _paragraphs("Run `cellplan demo -o <dir>` now.\n\nA lone ` stays.")
    assert html == (
        "<p>Run <code>cellplan demo -o &lt;dir&gt;</code> now.</p><p>A lone ` stays.</p>"
    )


@pytest.mark.parametrize(
    ("low", "high", "n", "expected"),
    [
        (0.1, 0.3, 10, True),  # the whole interval above 0
        (-0.3, -0.1, 10, False),  # the whole interval below
        (-0.1, 0.3, 10, None),  # straddles: not enough runs to decide
        (0.1, 0.3, 3, None),  # too few runs
        (float("nan"), 0.3, 10, None),
    ],
)
def test_decide_interval(low, high, n, expected):
    from cellplan.core import decide_interval

    assert decide_interval(low, high, n, above=0.0) is expected


def test_verdicts_state_their_basis():
    from cellplan.core import Claim
    from cellplan.report import verdict

    undecided = Claim("c", "p", "o", None, "interval contains 0", n=3, rule="95% CI above 0")
    assert verdict(undecided) == (
        "? not enough runs to decide: interval contains 0 [n = 3; rule: 95% CI above 0]"
    )
    differs = Claim("c", "p", "o", False, "half", n=25, explanation="docs/assembly.md#ratio")
    assert verdict(differs) == "✘ differs: half (why: docs/assembly.md#ratio) [n = 25]"


def test_figures_carry_their_experiment_caption(tmp_path):
    from cellplan.report import _figure

    png = tmp_path / "f.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + b"0" * 16)
    html = _figure(png, tmp_path, "Ratio for 5 discs over `3` seeds")
    assert "<figcaption>Ratio for 5 discs over <code>3</code> seeds (f.png)</figcaption>" in html
    assert 'alt="Ratio for 5 discs over 3 seeds"' in html
    assert "<figcaption>f.png</figcaption>" in _figure(png, tmp_path)


def test_an_experiment_skipped_for_time_is_a_note_not_an_error(tmp_path):
    """A budgeted sweep on a busy machine may skip every run of an experiment: by design,
    so the report says so in a note (and the demo lists it apart), with no error."""
    exps = [fake.sleepy(sleep=0.01)]
    sweep = run_sweep(exps, 3, False, tmp_path, serial=True, progress=False, time_budget_s=0.0)
    pieces = make_pieces(sweep, lambda e: reproduce_command(e, 3, False, tmp_path))
    assert [(p.skipped, p.piece) for p in pieces] == [(True, None)]
    found = [PaperExperiments("adaptive", exps)]
    html = write_report(tmp_path, found, pieces, sweep).read_text(encoding="utf-8")
    assert Page(html).errors == []
    assert 'class="error"' not in html
    assert '<p class="note">every run was skipped: the sweep&#x27;s time budget' in html

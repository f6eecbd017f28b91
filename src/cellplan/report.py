"""The self-contained HTML report: ``DIR/index.html``, one section per paper.

The report is a single file a browser opens with no network: styles are inline
and every figure (PNG, GIF animation, JPEG, SVG) is embedded as a base64
``data:`` URI. Per experiment it shows what was run (runs, parameter values,
failures, compute time), the experiment's own text, the paper's claim beside
ours with a plain verdict line (reproduced, or differs and how), the figures,
the tables, the runs that failed, the tidy CSV, and the command that
regenerates the piece. The file is written atomically.

Pages of their own (the demo's 3-D viewers, :class:`EmbeddedPage`) are the one thing not
inlined: each is a self-contained HTML file in the report's folder, shown in an
``<iframe>`` by its relative path, so the folder still opens offline as a whole.
"""

from __future__ import annotations

import base64
import html
import math
import os
import shlex
import traceback
import urllib.parse
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cellplan.core import Claim, Experiment, ReportPiece, Scalar, ShowcaseItem
from cellplan.experiments import SKIPPED, ExperimentRun, PaperExperiments, SweepResult
from cellplan.fileio import write_text

MIME = {
    ".png": "image/png",
    ".gif": "image/gif",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".svg": "image/svg+xml",
}


@dataclass(frozen=True)
class PaperInfo:
    """How the report introduces a paper."""

    title: str
    citation: str
    summary: str


def _package_names() -> list[str]:
    from cellplan.registry import packages

    return list(packages())


def paper_info(name: str) -> PaperInfo:
    """Title, citation and summary of a registered package (just its name otherwise)."""
    from cellplan.registry import packages

    pkg = packages().get(name)
    if pkg is None:
        return PaperInfo(name, "", "")
    return PaperInfo(pkg.title, pkg.citation, pkg.summary)


@dataclass
class EmbeddedPage:
    """A page of its own (a 3-D viewer) shown inside the report in an ``<iframe>``.

    The report links the page by its path relative to the report's folder, so it must
    lie inside that folder for the report to keep working when the folder is moved or
    opened offline; a link under the frame opens it alone.

    Parameters
    ----------
    path
        The page's HTML file.
    title
        The frame's title (read out by screen readers) and the text of the link.
    caption
        Shown under the frame; Markdown's inline `code` spans are rendered as code.
    height_px
        The frame's height in CSS pixels (its width is the column's).
    """

    path: Path
    title: str
    caption: str = ""
    height_px: int = 520


@dataclass
class Article:
    """One titled piece of an :class:`ExtraSection`: figures, tables and embedded pages.

    Parameters
    ----------
    title
        The piece's heading.
    caption
        A paragraph under the heading (inline `code` spans rendered as code).
    figures
        PNG, GIF, JPEG or SVG files, embedded in the report.
    tables
        ``(caption, rows)`` pairs, each row a mapping from column to value.
    pages
        Pages shown in frames (:class:`EmbeddedPage`).
    code
        The Python or ``cellplan`` lines that make the piece, shown as a code block.
    """

    title: str
    caption: str = ""
    figures: list[Path] = field(default_factory=list)
    tables: list[tuple[str, list[dict[str, Scalar]]]] = field(default_factory=list)
    pages: list[EmbeddedPage] = field(default_factory=list)
    code: str = ""


@dataclass
class ExtraSection:
    """A section that is not a paper's (the demo's showcase, bundled workcells, 3-D cells).

    ``notes`` are plain remarks; ``errors`` (something that failed) alone are drawn in
    red. ``items`` are :class:`~cellplan.core.ShowcaseItem` s: figures with a caption and
    the code that made them, shown as a code block. ``articles`` are :class:`Article` s,
    which may also hold tables and embedded pages.
    """

    title: str
    text: str = ""
    figures: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    anchor: str = "extra"
    errors: list[str] = field(default_factory=list)
    items: list[ShowcaseItem] = field(default_factory=list)
    articles: list[Article] = field(default_factory=list)


@dataclass(frozen=True)
class ToDecide:
    """A claim (or a whole experiment) the demo shows apart, with the command that decides it.

    The demo runs only experiments that decide their claims at a small size
    (:attr:`cellplan.core.Experiment.demo_runs`); the others, and any claim a demo run
    still left undecided, are listed under "run ``cellplan reproduce`` to decide"
    instead of among the verdicts.

    Attributes
    ----------
    experiment
        The experiment's name (``<paper>.<name>``).
    paper
        The package it belongs to.
    title
        The experiment's title, or the claim left undecided.
    why
        Why the demo does not decide it (one line).
    command
        The ``cellplan reproduce`` command that decides it.
    """

    experiment: str
    paper: str
    title: str
    why: str
    command: str


@dataclass
class ExperimentReport:
    """One experiment's sweep with the piece its ``report`` produced (or why it did not)."""

    run: ExperimentRun
    piece: ReportPiece | None
    error: str
    command: str
    skipped: bool = False
    """Every run was skipped for time: the report says so as a note, not as an error
    (a budgeted sweep on a busy machine does this by design, see ``time_budget_s``)."""


def make_pieces(
    sweep: SweepResult, command_for: Callable[[Experiment], str]
) -> list[ExperimentReport]:
    """Call each experiment's ``report(rows, figdir)`` on its successful rows.

    A ``report`` that raises does not stop the others: its error (with the line
    that raised) goes into the HTML instead of its piece.
    """
    out = []
    for run in sweep.runs:
        exp = run.experiment
        piece: ReportPiece | None = None
        error = run.error
        skipped = bool(run.rows) and all(row["run_status"] == SKIPPED for row in run.rows)
        if skipped:
            error = "every run was skipped: the sweep's time budget was spent before it"
        elif not error and not run.ok_rows:
            error = (
                "no run succeeded, nothing to report" if run.rows else "make_runs listed no runs"
            )
        if not error:
            figdir = sweep.outdir / "figures" / exp.name
            figdir.mkdir(parents=True, exist_ok=True)
            try:
                piece = exp.report(run.ok_rows, figdir)
                if not isinstance(piece, ReportPiece):
                    raise TypeError(f"report returned a {type(piece).__name__}, not a ReportPiece")
            except Exception as exc:
                frames = traceback.extract_tb(exc.__traceback__)
                where = (
                    f" (at {Path(frames[-1].filename).name}:{frames[-1].lineno})" if frames else ""
                )
                error = f"report failed: {type(exc).__name__}: {exc}{where}"
                piece = None
        out.append(ExperimentReport(run, piece, error, command_for(exp), skipped))
    return out


def set_apart_undecided(
    pieces: Sequence[ExperimentReport], command_for: Callable[[Experiment], str]
) -> list[ToDecide]:
    """Take every undecided claim out of ``pieces``; return them as :class:`ToDecide` items.

    The demo's report shows only decided claims among its results: a claim its small
    run left undecided, or a whole experiment with nothing to report (every run skipped
    for time, say), is listed apart with ``command_for(experiment)``, the command that
    decides it (the full reproduction). The pieces are changed in place.
    """
    apart = []
    for item in pieces:
        exp = item.run.experiment
        if item.piece is None:  # nothing to decide from (every run skipped, say)
            why = f"the demo did not decide it ({item.error})"
            apart.append(ToDecide(exp.name, exp.paper, exp.title, why, command_for(exp)))
            continue
        kept = []
        for claim in item.piece.claims:
            if claim.reproduced is not None:
                kept.append(claim)
                continue
            basis = f" with n = {claim.n}" if claim.n else ""
            apart.append(
                ToDecide(
                    exp.name,
                    exp.paper,
                    claim.claim,
                    f"the demo's run{basis} did not decide it ({claim.ours})",
                    command_for(exp),
                )
            )
        item.piece.claims = kept
    return apart


def reproduce_command(
    exp: Experiment,
    runs: int | None,
    quick: bool,
    outdir: Path | str,
    scheduler: str | None = None,
) -> str:
    """The ``cellplan reproduce`` command that regenerates one experiment's piece
    (``runs`` None: the paper's own count, no ``--runs``)."""
    args = ["cellplan", "reproduce", exp.paper, "--only", exp.name]
    if runs is not None:
        args += ["--runs", str(runs)]
    if quick:
        args.append("--quick")
    if scheduler:
        args += ["--scheduler", scheduler]
    args += ["-o", str(outdir)]
    return shlex.join(args)


def write_report(
    outdir: Path,
    found: Sequence[PaperExperiments],
    pieces: Sequence[ExperimentReport],
    sweep: SweepResult | None,
    title: str = "cellplan: the three papers, reproduced",
    intro: str = "",
    extra: Sequence[ExtraSection] = (),
    to_decide: Sequence[ToDecide] = (),
) -> Path:
    """Write ``outdir/index.html`` atomically and return its path.

    Parameters
    ----------
    outdir
        The report folder (CSV files are linked relative to it).
    found
        What :func:`cellplan.experiments.discover` found per paper, so that a
        package without experiments still gets its section saying so.
    pieces
        The experiments' pieces from :func:`make_pieces`.
    sweep
        The sweep (for its command line, scheduler and versions).
    title, intro
        Page heading and a first paragraph.
    extra
        Further sections, placed after the papers.
    to_decide
        Claims and experiments not decided here (the demo's), listed apart in their
        paper's section under "run ``cellplan reproduce`` to decide", each with its
        command, and counted in their own column of the summary.
    """
    outdir = Path(outdir)
    page = _Page()
    page.add("<!DOCTYPE html>")
    page.add('<html lang="en"><head><meta charset="utf-8">')
    page.add('<meta name="viewport" content="width=device-width, initial-scale=1">')
    page.add(f"<title>{_e(title)}</title><style>{CSS}</style></head><body>")
    page.add(f"<header><h1>{_e(title)}</h1>")
    if intro:
        page.add(_paragraphs(intro))
    generated = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    page.add(f'<p class="meta">Generated {generated}')
    if sweep is not None:
        page.add(
            f" by <code>{_e(sweep.command)}</code> on {_e(sweep.scheduler)}, "
            f"in {sweep.wall_s:.1f} s"
        )
    page.add(".</p>")
    page.add(_summary_table(found, pieces, to_decide))
    page.add(_toc(found, extra))
    page.add("</header><main>")
    by_paper: dict[str, list[ExperimentReport]] = {}
    for item in pieces:
        by_paper.setdefault(item.run.experiment.paper, []).append(item)
    papers = [f.paper for f in found] + [p for p in by_paper if p not in {f.paper for f in found}]
    notes = {f.paper: f.note for f in found}
    for paper in papers:
        apart = [t for t in to_decide if t.paper == paper]
        page.add(
            _paper_section(paper, notes.get(paper, ""), by_paper.get(paper, []), outdir, apart)
        )
    for section in extra:
        page.add(_extra_section(section, outdir))
    if sweep is not None:
        page.add(_machine_section(sweep.metadata))
    page.add("</main></body></html>")
    return write_text(outdir / "index.html", page.text())


# --- sections -----------------------------------------------------------------------------------


def _summary_table(
    found: Sequence[PaperExperiments],
    pieces: Sequence[ExperimentReport],
    to_decide: Sequence[ToDecide] = (),
) -> str:
    rows = []
    papers = [f.paper for f in found] or list(_package_names())
    for paper in papers:
        items = [p for p in pieces if p.run.experiment.paper == paper]
        claims = [c for p in items if p.piece for c in p.piece.claims]
        good = sum(1 for c in claims if c.reproduced is True)
        bad = sum(1 for c in claims if c.reproduced is False)
        open_ = len(claims) - good - bad
        runs = sum(len(p.run.rows) for p in items)
        failed = sum(p.run.n_failed for p in items)
        name = paper_info(paper).title
        rows.append(
            f'<tr><td><a href="#paper-{_e(paper)}">{_e(name)}</a></td><td>{len(items)}</td>'
            f"<td>{runs}</td><td>{failed}</td>"
            f'<td class="ok">{good}</td><td class="{"bad" if bad else ""}">{bad}</td>'
            f'<td class="{"undecided" if open_ else ""}">{open_}</td>'
            + (
                f'<td><a href="#to-decide-{_e(paper)}">'
                f"{sum(1 for t in to_decide if t.paper == paper)}</a></td>"
                if to_decide
                else ""
            )
            + "</tr>"
        )
    apart = "<th>left to <code>cellplan reproduce</code></th>" if to_decide else ""
    return (
        '<table class="summary"><thead><tr><th>paper</th><th>experiments</th><th>runs</th>'
        "<th>failed runs</th><th>claims reproduced</th><th>claims that differ</th>"
        f"<th>not enough runs to decide</th>{apart}</tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>"
    )


def _toc(found: Sequence[PaperExperiments], extra: Sequence[ExtraSection]) -> str:
    links = [
        f'<li><a href="#paper-{_e(f.paper)}">{_e(paper_info(f.paper).title)}</a></li>'
        for f in found
    ]
    links += [f'<li><a href="#{_e(s.anchor)}">{_e(s.title)}</a></li>' for s in extra]
    links.append('<li><a href="#machine">Machine and versions</a></li>')
    return f"<nav><ul>{''.join(links)}</ul></nav>"


def _paper_section(
    paper: str,
    note: str,
    items: Sequence[ExperimentReport],
    outdir: Path,
    apart: Sequence[ToDecide] = (),
) -> str:
    info = paper_info(paper)
    parts = [f'<section id="paper-{_e(paper)}"><h2>{_e(info.title)}</h2>']
    if info.citation:
        parts.append(f'<p class="cite">{_e(info.citation)}</p>')
    if info.summary:
        parts.append(f'<p class="paper-claims"><b>What the paper shows.</b> {_e(info.summary)}</p>')
    if note:
        parts.append(f'<p class="note">{_e(note)}.</p>')
    elif not items:
        parts.append('<p class="note">no experiments selected for this paper.</p>')
    parts.append(_verdict_list(items))
    if apart:
        parts.append(_to_decide_list(paper, apart))
    parts += [_experiment_article(item, outdir) for item in items]
    parts.append("</section>")
    return "\n".join(parts)


def _experiment_article(item: ExperimentReport, outdir: Path) -> str:
    run, piece = item.run, item.piece
    exp = run.experiment
    title = piece.title if piece and piece.title else exp.title
    parts = [f'<article id="exp-{_e(exp.name)}"><h3>{_e(title)}</h3>']
    parts.append(f'<p class="what"><b>What was run.</b> {_e(_what_was_run(run))}</p>')
    if item.error:
        kind = "note" if item.skipped else "error"
        parts.append(f'<p class="{kind}">{_e(item.error)}</p>')
    if piece is not None:
        if piece.text:
            parts.append(_paragraphs(piece.text))
        if piece.claims:
            parts.append(_claims_table(piece.claims))
        for figure in piece.figures:
            caption = piece.captions.get(Path(figure).name, "")
            parts.append(_figure(Path(figure), outdir / "figures" / exp.name, caption))
        for caption, rows in piece.tables:
            parts.append(_table(caption, rows))
    if run.n_failed:
        parts.append(_failures_table(run))
    links = []
    for path in (run.csv_path, run.meta_path):
        try:
            href = path.relative_to(outdir).as_posix()
        except ValueError:
            href = path.as_posix()
        links.append(f'<a href="{_e(href)}">{_e(href)}</a>')
    parts.append(f'<p class="data">Data: {" and ".join(links)} (one row per run).</p>')
    parts.append(_command("Regenerate this piece:", item.command))
    if piece is not None and piece.command and piece.command != item.command:
        parts.append(_command("The package's own command:", piece.command))
    parts.append("</article>")
    return "\n".join(parts)


def _command(label: str, command: str) -> str:
    return f'<p class="cmd-label">{_e(label)}</p><pre class="cmd">{_e(command)}</pre>'


def _what_was_run(run: ExperimentRun) -> str:
    n = len(run.rows)
    text = f"{n} run{'s' if n != 1 else ''}"
    values = []
    for name in run.param_names:
        distinct = sorted({row[name] for row in run.rows if name in row}, key=_sort_key)
        shown = ", ".join(_fmt_value(v) for v in distinct[:8])
        shown += ", …" if len(distinct) > 8 else ""
        values.append(f"{name} ∈ {{{shown}}}")
    seeds = sorted({int(row["seed"]) for row in run.rows})
    if seeds:
        values.append(f"{len(seeds)} seed{'s' if len(seeds) != 1 else ''} ({_ranges(seeds)})")
    if values:
        text += " over " + "; ".join(values)
    text += f". {run.n_failed} failed, {run.n_cached} from the cache"
    text += f", {run.compute_s:.1f} s of compute."
    return text


def verdict(claim: Claim) -> str:
    """The plain verdict line with its basis: ``✔ reproduced``, ``✘ differs: how``, or
    ``? not enough runs to decide``, then the sample size and the decision rule."""
    if claim.reproduced is None:
        text = "? not enough runs to decide" + (f": {claim.detail}" if claim.detail else "")
    elif claim.reproduced:
        text = "✔ reproduced" + (f": {claim.detail}" if claim.detail else "")
    else:
        text = "✘ differs: " + (claim.detail or f"the paper has {claim.paper}, we get {claim.ours}")
        if claim.explanation:
            text += f" (why: {claim.explanation})"
    basis = [f"n = {claim.n}"] if claim.n else []
    if claim.rule:
        basis.append(f"rule: {claim.rule}")
    return text + (f" [{'; '.join(basis)}]" if basis else "")


def _verdict_class(claim: Claim) -> str:
    return {True: "ok", False: "bad", None: "undecided"}[claim.reproduced]


def _verdict_list(items: Sequence[ExperimentReport]) -> str:
    """Every claim of a paper on one line each, linking to its experiment."""
    lines = [
        f'<li class="{_verdict_class(c)}">{_e(c.claim)} — {_e(verdict(c))} '
        f'(<a href="#exp-{_e(item.run.experiment.name)}">{_e(item.run.experiment.name)}</a>)</li>'
        for item in items
        if item.piece is not None
        for c in item.piece.claims
    ]
    if not lines:
        return ""
    return f'<div class="verdicts"><b>Verdicts.</b><ul>{"".join(lines)}</ul></div>'


def _to_decide_list(paper: str, apart: Sequence[ToDecide]) -> str:
    """The claims and experiments of a paper not decided here, each with its command."""
    lines = [
        f"<li><b>{_e(t.title)}</b> ({_e(t.experiment)}): {_e(t.why)}."
        f'<pre class="cmd">{_e(t.command)}</pre></li>'
        for t in apart
    ]
    return (
        f'<div class="to-decide" id="to-decide-{_e(paper)}"><b>Run <code>cellplan reproduce'
        "</code> to decide.</b> Not decided at the demo's size (so not among the verdicts "
        f"above); each command below decides it.<ul>{''.join(lines)}</ul></div>"
    )


def _claims_table(claims: Sequence[Claim]) -> str:
    rows = []
    for claim in claims:
        cls = _verdict_class(claim)
        rows.append(
            f"<tr><td>{_e(claim.claim)}</td><td>{_e(claim.paper)}</td><td>{_e(claim.ours)}</td>"
            f'<td class="verdict {cls}">{_e(verdict(claim))}</td></tr>'
        )
    return (
        '<table class="claims"><caption>The paper beside cellplan</caption><thead><tr>'
        "<th>claim</th><th>paper</th><th>cellplan</th><th>verdict</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>"
    )


def _figure(path: Path, figdir: Path, caption: str = "") -> str:
    candidates = [path] if path.is_absolute() else [path, figdir / path]
    found = next((p for p in candidates if p.is_file()), None)
    if found is None:
        return f'<p class="error">missing figure {_e(str(path))}</p>'
    mime = MIME.get(found.suffix.lower())
    if mime is None:
        return f'<p class="error">figure {_e(found.name)}: unsupported type {_e(found.suffix)}</p>'
    data = found.read_bytes()
    if not data:
        return f'<p class="error">figure {_e(found.name)} is empty</p>'
    uri = f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"
    kind = "animation" if found.suffix.lower() == ".gif" else "figure"
    text = f"{_inline(caption)} ({_e(found.name)})" if caption else _e(found.name)
    alt = caption.replace("`", "") or found.stem
    return (
        f'<figure class="{kind}"><img src="{uri}" alt="{_e(alt)}">'
        f"<figcaption>{text}</figcaption></figure>"
    )


def _table(caption: str, rows: Sequence[Mapping[str, Scalar]]) -> str:
    columns: dict[str, None] = {}
    for row in rows:
        columns.update(dict.fromkeys(row))
    head = "".join(f"<th>{_e(c)}</th>" for c in columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{_e(_fmt(row.get(c, '')))}</td>" for c in columns) + "</tr>"
        for row in rows
    )
    return (
        '<table class="data">'
        + (f"<caption>{_e(caption)}</caption>" if caption else "")
        + f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
    )


def _failures_table(run: ExperimentRun) -> str:
    failed = [row for row in run.rows if row["run_status"] != "ok"]
    shown = [
        {
            **{name: row.get(name, "") for name in run.param_names},
            "seed": row["seed"],
            "error": row["run_error"],
        }
        for row in failed[:20]
    ]
    skipped = any(row["run_status"] == "skipped" for row in failed)
    caption = "Failed and skipped runs" if skipped else "Failed runs"
    caption += f" ({len(failed)}" + (", first 20 shown)" if len(failed) > 20 else ")")
    return _table(caption, shown)


def _extra_section(section: ExtraSection, outdir: Path | None = None) -> str:
    """The section's HTML; ``outdir`` is the report's folder, which embedded pages are
    linked relative to (absolute ``file:`` links without it)."""
    parts = [f'<section id="{_e(section.anchor)}"><h2>{_e(section.title)}</h2>']
    if section.text:
        parts.append(_paragraphs(section.text))
    parts += [f'<p class="error">{_e(error)}</p>' for error in section.errors]
    parts += [f'<p class="note">{_inline(note)}</p>' for note in section.notes]
    for item in section.items:
        parts.append(f'<article class="showcase"><h3>{_e(item.title)}</h3>')
        parts.append(f"<p>{_inline(item.caption)}</p>")
        parts.append('<div class="gallery">')
        parts += [_figure(Path(f), Path(f).parent) for f in item.figures]
        parts.append("</div>")
        if item.code:
            parts.append(f'<pre class="cmd"><code>{_e(item.code)}</code></pre>')
        parts.append("</article>")
    parts += [_article(article, outdir) for article in section.articles]
    if section.figures:
        parts.append('<div class="gallery">')
        parts += [_figure(Path(f), Path(f).parent) for f in section.figures]
        parts.append("</div>")
    parts.append("</section>")
    return "\n".join(parts)


def _article(article: Article, outdir: Path | None) -> str:
    parts = [f'<article class="showcase"><h3>{_e(article.title)}</h3>']
    if article.caption:
        parts.append(f"<p>{_inline(article.caption)}</p>")
    if article.figures:
        parts.append('<div class="gallery">')
        parts += [_figure(Path(f), Path(f).parent) for f in article.figures]
        parts.append("</div>")
    for caption, rows in article.tables:
        parts.append(_table(caption, rows))
    parts += [_embedded_page(page, outdir) for page in article.pages]
    if article.code:
        parts.append(f'<pre class="cmd"><code>{_e(article.code)}</code></pre>')
    parts.append("</article>")
    return "\n".join(parts)


def _embedded_page(page: EmbeddedPage, outdir: Path | None) -> str:
    """An ``<iframe>`` of the page (linked relative to ``outdir``) and a link to open it."""
    path = Path(page.path)
    if not path.is_file():
        return f'<p class="error">missing page {_e(path.name)}</p>'
    if outdir is None:
        href = path.resolve().as_uri()
    else:
        relative = os.path.relpath(path.resolve(), Path(outdir).resolve())
        href = urllib.parse.quote(Path(relative).as_posix())
    caption = f"{_inline(page.caption)} " if page.caption else ""
    return (
        f'<figure class="embedded"><iframe src="{_e(href)}" title="{_e(page.title)}" '
        f'height="{int(page.height_px)}"></iframe>'
        f'<figcaption>{caption}(<a href="{_e(href)}" target="_blank">open '
        f"{_e(path.name)} alone</a>)</figcaption></figure>"
    )


def _machine_section(metadata: Mapping[str, Any]) -> str:
    rows: list[dict[str, Scalar]] = []
    for key in ("command", "scheduler", "quick", "runs_per_point", "started", "finished", "wall_s"):
        if key in metadata:
            rows.append({"item": key, "value": str(metadata[key])})
    for group in ("machine", "versions"):
        for key, value in metadata.get(group, {}).items():
            rows.append({"item": f"{group}.{key}", "value": str(value)})
    return f'<section id="machine"><h2>Machine and versions</h2>{_table("", rows)}</section>'


# --- small helpers ------------------------------------------------------------------------------


class _Page:
    def __init__(self) -> None:
        self.parts: list[str] = []

    def add(self, text: str) -> None:
        self.parts.append(text)

    def text(self) -> str:
        return "\n".join(self.parts) + "\n"


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _paragraphs(text: str) -> str:
    blocks = [b.strip() for b in text.split("\n\n") if b.strip()]
    return "".join(f"<p>{_inline(' '.join(b.split()))}</p>" for b in blocks)


def _inline(text: str) -> str:
    """Escape text for HTML and render Markdown's inline `code` spans as code."""
    parts = text.split("`")
    if len(parts) % 2 == 0:  # an unmatched backtick is shown as it is
        return _e(text)
    return "".join(_e(p) if i % 2 == 0 else f"<code>{_e(p)}</code>" for i, p in enumerate(parts))


def _fmt(value: Any) -> str:
    if isinstance(value, float) and not isinstance(value, bool):
        if math.isnan(value) or math.isinf(value):
            return str(value)
        return f"{value:.4g}"
    return str(value)


def _fmt_value(value: Any) -> str:
    """A parameter value in a set: strings with commas or spaces are quoted."""
    if isinstance(value, str) and ("," in value or " " in value or not value):
        return f"“{value}”"
    return _fmt(value)


def _sort_key(value: Any) -> tuple[int, Any]:
    return (
        (0, value)
        if isinstance(value, int | float) and not isinstance(value, bool)
        else (1, str(value))
    )


def _ranges(values: Sequence[int]) -> str:
    """``0-24`` for consecutive integers, a short list otherwise."""
    if len(values) > 1 and values[-1] - values[0] == len(values) - 1:
        return f"{values[0]}–{values[-1]}"
    shown = ", ".join(str(v) for v in values[:8])
    return shown + (", …" if len(values) > 8 else "")


CSS = """
body{font:16px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;
max-width:1100px;padding:1rem 1.5rem;color:#1d2329;background:#fff}
h1{margin-bottom:.2rem}h2{border-bottom:2px solid #d0d7de;padding-bottom:.2rem;margin-top:2.5rem}
h3{margin-top:2rem}
.meta,.cite{color:#57606a;font-size:.9rem}
.paper-claims{background:#f6f8fa;border-left:4px solid #8c959f;padding:.5rem .8rem}
.note{color:#9a6700;background:#fff8c5;padding:.4rem .8rem;border-radius:4px}
.error{color:#82071e;background:#ffebe9;padding:.4rem .8rem;border-radius:4px}
table{border-collapse:collapse;margin:.8rem 0;font-size:.9rem}
caption{text-align:left;font-weight:600;padding:.2rem 0}
th,td{border:1px solid #d0d7de;padding:.25rem .5rem;vertical-align:top;text-align:left}
th{background:#f6f8fa}
td.ok,li.ok{color:#116329}td.bad,li.bad{color:#82071e}td.undecided,li.undecided{color:#7d4e00}
.verdicts{border:1px solid #d0d7de;border-radius:4px;padding:.4rem .8rem;margin:.8rem 0}
.verdicts ul,.to-decide ul{margin:.3rem 0;padding-left:1.2rem}
.to-decide{border:1px dashed #8c959f;border-radius:4px;padding:.4rem .8rem;margin:.8rem 0}
td.verdict{font-weight:600}
figure{display:inline-block;margin:.5rem 1rem .5rem 0;max-width:100%}
figure img{max-width:100%;height:auto;border:1px solid #d0d7de}
figcaption{font-size:.8rem;color:#57606a}
.gallery figure{max-width:100%}
figure.embedded{display:block;margin:.8rem 0}
figure.embedded iframe{display:block;width:100%;border:1px solid #d0d7de}
code{background:#f6f8fa;padding:0 .2rem;border-radius:3px}
pre.cmd code{background:none;padding:0}
pre.cmd{background:#1d2329;color:#e6edf3;padding:.5rem .8rem;border-radius:4px;overflow-x:auto}
.cmd-label{margin-bottom:0;font-size:.9rem}
nav ul{columns:2}
@media print{pre.cmd{background:#fff;color:#000;border:1px solid #000}}
"""

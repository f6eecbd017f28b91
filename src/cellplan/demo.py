"""``cellplan demo``: the quick version of every experiment plus the bundled workcells, as HTML.

The demo is the main job of ``make demo``: it must finish in under two minutes
on a 2-core machine. It sweeps every experiment of every paper package with
``quick=True`` and :data:`DEMO_RUNS` seeds (cached under ``OUTPUT/cache``, so a
second run is fast), draws each bundled workcell, and writes ``OUTPUT/index.html``
in the same format as ``cellplan reproduce``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

DEMO_RUNS = 3
"""Seeds per parameter point in the demo (enough for a mean and a spread)."""

SWEEP_BUDGET_S = 75.0
"""Seconds the demo's sweep may take. Runs not finished by then are shown as skipped
in the report, so the whole demo (drawings, cluster start, sweep, figures) stays
under two minutes on two cores even if an experiment's quick version is too slow."""

INTRO = (
    "This is the quick demonstration: every experiment of the three papers in its small "
    "version, with few seeds, so it runs in about a minute on a laptop. The full "
    "reproduction, with the papers' own repetition counts, is `cellplan reproduce all -o DIR` "
    "(see docs/reproduce.md for how long it takes and how to run it on a Dask cluster)."
)


def run_demo(
    output: Path, console: Any = None, serial: bool = False, showcase: bool = True
) -> Path:
    """Run the demo into ``output`` and return the path of ``output/index.html``.

    Parameters
    ----------
    output
        The report folder (created if missing; must not be a file).
    console
        A :class:`rich.console.Console` for progress and notes (default: stderr).
    serial
        Run the experiments in this process instead of on a local Dask cluster.
    showcase
        Also run each planner once through its command (:func:`run_showcase`).
    """
    from rich.console import Console

    from cellplan.reproduce_cli import check_output_dir, reproduce_sweep

    output = check_output_dir(Path(output))
    console = console if console is not None else Console(stderr=True)
    t0 = time.perf_counter()
    workcells = draw_bundled_workcells(output / "workcells")
    console.print(
        f"drew {len(workcells.figures)} bundled workcells in {time.perf_counter() - t0:.1f} s",
        highlight=False,
    )
    extra = [workcells]
    if showcase:
        t0 = time.perf_counter()
        pictures = run_showcase(output / "showcase")
        extra.insert(0, pictures)
        console.print(
            f"ran the showcase ({len(pictures.items)} items) in {time.perf_counter() - t0:.1f} s",
            highlight=False,
        )
    index, _ = reproduce_sweep(
        None,
        output,
        runs=DEMO_RUNS,
        quick=True,
        serial=serial,
        console=console,
        title="cellplan demo: the three papers in small",
        intro=INTRO,
        extra=extra,
        time_budget_s=SWEEP_BUDGET_S,
    )
    return index


def draw_bundled_workcells(folder: Path) -> Any:
    """Draw every bundled scenario's workcell into ``folder``; return the report section.

    A scenario that cannot be loaded or drawn is listed in the section's errors
    instead of stopping the demo.
    """
    from cellplan.registry import scenario_names
    from cellplan.report import ExtraSection

    section = ExtraSection(
        "Bundled workcells",
        "Every scenario shipped with cellplan (`cellplan scenarios` lists them; "
        "`cellplan show NAME -o file.png` draws one).",
        anchor="workcells",
    )
    from cellplan.api import load
    from cellplan.plots import save_scenario

    names = scenario_names()
    if not names:
        section.notes.append("no bundled scenarios yet")
    for name in names:
        target = folder / f"{name}.png"
        try:
            save_scenario(load(name), target)
        except Exception as exc:  # one bad scenario must not hide the rest of the demo
            section.errors.append(f"{name}: {type(exc).__name__}: {exc}")
            continue
        section.figures.append(target)
    return section


def run_showcase(folder: Path, packages: Any = None) -> Any:
    """Run each registered package's showcase through the library API; return the report section.

    These are the pictures a person looks at first (each package's
    :attr:`~cellplan.core.Package.showcase`: the strategy's cost-to-go and a sample path,
    a disc assembly, the experience graph), each with a caption and the Python lines that
    make it. A package whose showcase fails is listed as an error in the section instead of
    stopping the demo.
    """
    from cellplan.registry import packages as registered
    from cellplan.report import ExtraSection

    section = ExtraSection(
        "Showcase: one run of each planner",
        "Each picture comes from the Python shown under it, run on a bundled scenario "
        "through the planning API (`cellplan.load`, `cellplan.plan`).",
        anchor="showcase",
    )
    pkgs = registered() if packages is None else packages
    for name, pkg in pkgs.items():
        if pkg.showcase is None:
            continue
        try:
            section.items.extend(pkg.showcase(folder / name))
        except Exception as exc:  # one failing package must not hide the rest of the demo
            section.errors.append(f"{name}: showcase failed: {type(exc).__name__}: {exc}")
    return section

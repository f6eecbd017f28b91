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

    from cellplan.reproduce_cli import check_output_dir, reproduce

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
            f"ran the showcase ({len(pictures.figures)} pictures) in "
            f"{time.perf_counter() - t0:.1f} s",
            highlight=False,
        )
    return reproduce(
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


def draw_bundled_workcells(folder: Path) -> Any:
    """Draw every bundled scenario's workcell into ``folder``; return the report section.

    A scenario that cannot be loaded or drawn is listed in the section's notes
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
    try:
        from cellplan.plots import save_workcell
        from cellplan.workcell import load_workcell
    except ImportError as exc:
        section.notes.append(f"workcell drawing is not available yet ({exc})")
        return section
    names = scenario_names()
    if not names:
        section.notes.append("no bundled scenarios yet")
    for name in names:
        target = folder / f"{name}.png"
        try:
            _, cell = load_workcell(name)
            save_workcell(cell, target)
        except Exception as exc:  # one bad scenario must not hide the rest of the demo
            section.notes.append(f"{name}: {type(exc).__name__}: {exc}")
            continue
        section.figures.append(target)
    return section


# One run of each planner through its own command, with the files each one writes
# that the report shows: (command line, pictures relative to the showcase folder).
SHOWCASE: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = (
    (("solve", "strategies_p1", "-o", "{dir}/p1.npz"), ()),
    (
        ("plot", "strategies_p1", "--strategy", "{dir}/p1.npz", "--mode", "1,1,1,W",
         "-o", "{dir}/p1_waiting.png"),
        ("p1_waiting.png",),
    ),
    (
        ("plot", "strategies_p1", "--strategy", "{dir}/p1.npz", "--mode", "1,1,1,C",
         "-o", "{dir}/p1_carrying.png"),
        ("p1_carrying.png",),
    ),
    (
        ("simulate", "strategies_p1", "--strategy", "{dir}/p1.npz", "--stages", "300",
         "--seed", "3", "-o", "{dir}/p1_simulation"),
        ("p1_simulation/frames.png", "p1_simulation/simulation.gif"),
    ),
    (
        ("assemble", "discs_seven", "--algorithm", "gradient", "-o", "{dir}/discs_gradient"),
        ("discs_gradient/sequence.png", "discs_gradient/assembly.gif"),
    ),
    (
        ("assemble", "discs_seven", "--algorithm", "sequential", "-o", "{dir}/discs_sequential"),
        ("discs_sequential/sequence.png",),
    ),
    (
        ("adapt", "adaptive_fig3", "-o", "{dir}/adaptive_fig3"),
        ("adaptive_fig3/snapshots.png",),
    ),
)


def run_showcase(folder: Path) -> Any:
    """Run each planner once through its command (:data:`SHOWCASE`); return the report section.

    These are the pictures a person looks at first: the strategy's cost-to-go and
    actions (Fig. 8), a simulated sample path with its animation (Fig. 9), a disc
    assembly (Fig. 1-2) and the experience graph of Fig. 3. A command that fails is
    listed in the section's notes instead of stopping the demo.
    """
    import contextlib
    import io

    from cellplan.errors import CellplanError
    from cellplan.report import ExtraSection

    section = ExtraSection(
        "Showcase: one run of each planner",
        "Each picture comes from the command shown below it in the notes, run on a bundled "
        "scenario: the problem 1 strategy's cost-to-go and optimal actions while waiting for "
        "and carrying part 1 (Fig. 8), a sample path with a new frame at each mode change "
        "(Fig. 9) and its animation, a seven-disc assembly by the gradient flow and by the "
        "sequential algorithm (Figs. 1-2), and the experience graph of Chen's Fig. 3.",
        anchor="showcase",
    )
    from cellplan.cli import app

    folder.mkdir(parents=True, exist_ok=True)
    for args, pictures in SHOWCASE:
        argv = [a.format(dir=folder) for a in args]
        command = "cellplan " + " ".join(a.replace(str(folder), "showcase") for a in argv)
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                app(argv, standalone_mode=False)
        except (CellplanError, OSError, ValueError, RuntimeError) as exc:
            section.notes.append(f"{command}: failed: {type(exc).__name__}: {exc}")
            continue
        section.notes.append(command)
        section.figures.extend(folder / p for p in pictures if (folder / p).is_file())
    return section

"""Build the API reference from the docstrings (numpydoc) with pdoc; any warning fails it.

Usage: ``python docs/build_api.py OUTPUT_DIR`` (``make docs`` writes ``build/api``).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

#: The modules documented; packages bring their submodules. ``cellplan`` itself lists only
#: what its ``__all__`` exports, so the core modules are named one by one.
MODULES = (
    "cellplan",
    "cellplan.api",
    "cellplan.core",
    "cellplan.setup",
    "cellplan.trajectory",
    "cellplan.drawing",
    "cellplan.warmup",
    "cellplan.timing",
    "cellplan.export",
    "cellplan.validity",
    "cellplan.scenario3d",
    "cellplan.workcell3d",
    "cellplan.arm",
    "cellplan.solids",
    "cellplan.scene3d",
    "cellplan.view3d",
    "cellplan.budget",
    "cellplan.arrayfile",
    "cellplan.errors",
    "cellplan.registry",
    "cellplan.scenario",
    "cellplan.schema",
    "cellplan.workcell",
    "cellplan.robots",
    "cellplan.geometry",
    "cellplan.cspace",
    "cellplan.plots",
    "cellplan.cliutil",
    "cellplan.fileio",
    "cellplan.experiments",
    "cellplan.report",
    "cellplan.strategies",
    "cellplan.adaptive",
    "cellplan.assembly",
)


PAPER_PACKAGES = ("cellplan.strategies", "cellplan.adaptive", "cellplan.assembly")
"""The three papers' packages: most of the build's time goes to their submodules."""


def build(output: Path, modules: tuple[str, ...] = MODULES) -> list[str]:
    """Render ``modules`` (all by default) into ``output``; return the warnings pdoc gave."""
    import pdoc
    import pdoc.render

    import cellplan

    # The conveniences cellplan imports on first use: imported now, so that pdoc finds
    # them among the package's attributes.
    for name in ("simulate", "ExperiencePlanner"):
        getattr(cellplan, name)
    pdoc.render.configure(docformat="numpy")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pdoc.pdoc(*modules, output_directory=output)
    return [str(w.message) for w in caught]


if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "build/api")
    problems = build(out)
    for line in problems:
        print(f"warning: {line}", file=sys.stderr)
    if problems:
        sys.exit(1)
    print(f"API reference: {out / 'index.html'}")

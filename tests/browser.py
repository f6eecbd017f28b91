"""The headless Chromium the browser tests drive, and how they launch it (one place)."""

from __future__ import annotations

import shutil

CHROMIUM = next(
    (
        p
        for p in map(shutil.which, ("chromium-headless-shell", "chromium", "chromium-browser"))
        if p
    ),
    None,
)
"""Debian's Chromium (``make browser-test`` installs it), or None."""

# No network, no first-run or background work: the pages must stand alone.
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

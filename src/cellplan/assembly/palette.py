"""One colour per disc, shared by every assembly picture (``assemble``, ``show``, 3-D).

Starts and goals of a disc share its colour and its number, so a reader pairs them by
either; the colours are distinct hues, never light/dark pairs of one hue (issue 34).
"""

from __future__ import annotations

#: Hues for more than 10 discs: evenly spread around the colour wheel, visited by the
#: golden angle so discs numbered next to each other get far-apart hues, at one
#: lightness (no light/dark pairs as in tab20); the numbers tell discs of similar hue
#: apart.
_GOLDEN = 0.6180339887498949


def disc_colors(n: int) -> list[tuple[float, float, float, float]]:
    """One colour per disc: matplotlib's ``tab10`` (ten distinct hues) up to 10 discs,
    hues spread by the golden angle at one saturation and value beyond."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import hsv_to_rgb

    if n <= 10:
        cmap = plt.get_cmap("tab10")
        return [cmap(i) for i in range(n)]
    out = []
    for i in range(n):
        r, g, b = hsv_to_rgb(((i * _GOLDEN) % 1.0, 0.75, 0.85))
        out.append((float(r), float(g), float(b), 1.0))
    return out

"""Colour by category: named parts (a garment's panels) each in a colour of a categorical
palette, and a legend naming them beside the render instead of a colour bar."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from taichi_ndf.render.mpl import figure_image, new_figure

__all__ = ["Legend", "PALETTE_BGR", "legend_panel"]

# Matplotlib's "tab10" (distinct hues, also to the colour-blind for the first few), BGR [0, 255];
# the 11th category on takes the colours again.
PALETTE_BGR = np.array([[180, 119, 31], [14, 127, 255], [44, 160, 44], [40, 39, 214],
                        [189, 103, 148], [75, 86, 140], [194, 119, 227], [127, 127, 127],
                        [34, 189, 188], [207, 190, 23]], dtype=np.float64)
MISSING_BGR = np.array([128.0, 128.0, 128.0])  # a value that names no category


@dataclass(frozen=True)
class Legend:
    """The categories' names, category k drawn in PALETTE_BGR[k mod 10]."""

    names: tuple[str, ...]

    def __post_init__(self):
        if not self.names:
            raise ValueError("a legend needs at least one name")

    @property
    def colours(self) -> np.ndarray:
        """(K, 3) BGR [0, 255] of the categories, in order."""
        return PALETTE_BGR[np.arange(len(self.names)) % len(PALETTE_BGR)]

    def entries(self) -> list[tuple[str, tuple[int, int, int]]]:
        """(name, BGR colour) of each category, as the legend shows them."""
        return [(n, tuple(int(c) for c in colour))
                for n, colour in zip(self.names, self.colours, strict=True)]

    def colour_of(self, index: np.ndarray) -> np.ndarray:
        """BGR [0, 255] (..., 3) of category indices (rounded; NaN or out of range: grey)."""
        index = np.asarray(index, dtype=np.float64)
        known = np.isfinite(index) & (index > -0.5) & (index < len(self.names) - 0.5)
        k = np.rint(np.where(known, index, 0.0)).astype(np.int64)
        return np.where(known[..., None], self.colours[k], MISSING_BGR)


def legend_panel(legend: Legend, height: int, *, title: str = "",
                 background_bgr=(235, 235, 235)) -> np.ndarray:
    """A panel (height, w, 3) uint8 BGR: `title` over one line per category, a square swatch
    of its colour and its name."""
    return _panel(legend, title, int(height), tuple(int(c) for c in background_bgr)).copy()


@lru_cache(maxsize=32)
def _panel(legend: Legend, title: str, height: int, background_bgr) -> np.ndarray:
    from matplotlib.patches import Rectangle

    font = max(7.0, min(11.0, height / 50))  # [pt], as the colour bar's
    line = font * 100 / 72 * 1.6  # [pixels] per entry at 100 dpi
    char = font * 100 / 72 * 0.62  # [pixels] per character, about
    swatch = max(8, int(round(font * 100 / 72)))
    width = int(max(font * 8.5, swatch + 10 + max(len(n) for n in legend.names) * char + 8,
                    len(title) * char + 12))
    figure = new_figure(width, height)
    figure.patch.set_alpha(0.0)
    top = 4 + (1.6 * font * 100 / 72 if title else 0)
    if title:
        figure.text(4 / width, 1.0 - 4 / height, title, fontsize=font, ha="left", va="top")
    for k, (name, colour) in enumerate(zip(legend.names, legend.colours, strict=True)):
        y = top + (k + 0.5) * line  # [pixels] from the top, the entry's middle
        figure.patches.append(Rectangle(
            (6 / width, 1.0 - (y + swatch / 2) / height), swatch / width, swatch / height,
            transform=figure.transFigure, facecolor=tuple(colour[::-1] / 255.0),
            edgecolor="none", antialiased=False))
        figure.text((swatch + 12) / width, 1.0 - y / height, name, fontsize=font, ha="left",
                    va="center")
    return figure_image(figure, background_bgr)

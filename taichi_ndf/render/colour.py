"""Colour of per-vertex values: the viridis map, a robust range (percentiles) that says what it
clipped, and a colour bar with 5–7 round ticks, units and that statement, drawn by matplotlib.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from taichi_ndf.render.mpl import figure_image, new_figure, viridis_bgr, viridis_colormap

__all__ = ["ColourScale", "colour_scale", "colour_range", "colormap", "colour_bar",
           "bar_ticks", "ROBUST_PERCENTILES", "BAR_TICKS"]

ROBUST_PERCENTILES = (1.0, 99.0)  # default range of the colour map over the values
BAR_TICKS = (5, 7)  # fewest and most ticks on a colour bar
MISSING_BGR = np.array([128.0, 128.0, 128.0])  # a NaN value


@dataclass(frozen=True)
class ColourScale:
    """The values at the ends of the colour map [lo, hi] and what lies beyond them.

    minimum, maximum: the extremes of the finite values (NaN when there are none);
    below, above: the fractions of the finite values under lo and over hi (drawn in the end
    colours); percentiles: the percentiles lo and hi are, or None for a range given by hand.
    """

    lo: float
    hi: float
    minimum: float = math.nan
    maximum: float = math.nan
    below: float = 0.0
    above: float = 0.0
    percentiles: tuple[float, float] | None = None

    def __post_init__(self):
        if not (math.isfinite(self.lo) and math.isfinite(self.hi)) or self.hi < self.lo:
            raise ValueError(f"colour range needs finite lo <= hi, got ({self.lo}, {self.hi})")

    @property
    def range(self) -> tuple[float, float]:
        return self.lo, self.hi

    def clipped_note(self) -> str:
        """What the bar does not show, e.g. '1st–99th percentile; 1 % below: min 0.0012;
        1 % above: max 31.4'; empty when nothing is clipped."""
        parts = []
        if self.percentiles is not None and self.percentiles != (0.0, 100.0):
            lo, hi = self.percentiles
            parts.append(f"{_ordinal(lo)}–{_ordinal(hi)} percentile")
        if self.below > 0:
            parts.append(f"{_percent(self.below)} below: min {_number(self.minimum)}")
        if self.above > 0:
            parts.append(f"{_percent(self.above)} above: max {_number(self.maximum)}")
        return "; ".join(parts)


def colour_scale(values, percentiles=ROBUST_PERCENTILES,
                 value_range: tuple[float, float] | None = None) -> ColourScale:
    """The colour range of `values` (any shape): these percentiles of the finite values, or
    `value_range` if given, with the clipped fractions and extremes; (0, 1) without values."""
    values = np.asarray(values, dtype=np.float64).ravel()
    finite = values[np.isfinite(values)]
    if not len(finite):
        lo, hi = value_range or (0.0, 1.0)
        return ColourScale(float(lo), float(hi))
    if value_range is None:
        lo, hi = (float(v) for v in np.percentile(finite, percentiles))
        used = tuple(float(p) for p in percentiles)
    else:
        (lo, hi), used = (float(v) for v in value_range), None
    return ColourScale(lo, hi, float(finite.min()), float(finite.max()),
                       float(np.mean(finite < lo)), float(np.mean(finite > hi)), used)


def colour_range(values, percentiles=(0.0, 100.0)) -> tuple[float, float]:
    """(lo, hi) of `colour_scale`: these percentiles of the finite values (their minimum and
    maximum by default), (0, 1) when there is none."""
    return colour_scale(values, percentiles).range


def colormap(values: np.ndarray, value_range) -> np.ndarray:
    """Viridis BGR colours in [0, 255] (float) of ``values`` over ``value_range`` ((lo, hi) or
    a ColourScale); NaN is grey."""
    lo, hi = value_range.range if isinstance(value_range, ColourScale) else value_range
    span = hi - lo if hi > lo else 1.0
    t = np.clip((np.asarray(values, dtype=np.float64) - lo) / span, 0.0, 1.0)
    finite = np.isfinite(t)
    index = np.rint(np.where(finite, t, 0.0) * 255).astype(np.int64)
    return np.where(finite[..., None], viridis_bgr()[index].astype(np.float64), MISSING_BGR)


def bar_ticks(lo: float, hi: float) -> list[float]:
    """Between BAR_TICKS[0] and BAR_TICKS[1] round values in [lo, hi], 1, 2, 2.5 or 5 (else
    1.5, 3, 4, 6, 7.5 or 8) times a power of ten apart, as many as fit; else evenly spaced;
    lo alone when lo == hi."""
    if not hi > lo:
        return [lo]
    fewest, most = BAR_TICKS
    decade = math.floor(math.log10(hi - lo))
    for multiples in ((1.0, 2.0, 2.5, 5.0), (1.5, 3.0, 4.0, 6.0, 7.5, 8.0)):
        best = None
        for multiple in multiples:
            for power in range(decade - 2, decade + 2):
                step = multiple * 10.0**power
                first, last = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
                count = last - first + 1
                if fewest <= count <= most and (best is None or count > len(best)):
                    best = [round(k * step, 12) + 0.0 for k in range(first, last + 1)]
        if best is not None:
            return best
    return [float(v) for v in np.linspace(lo, hi, most)]


def colour_bar(value_range, label: str, height: int, *,
               background_bgr=(235, 235, 235)) -> np.ndarray:
    """A panel (height, w, 3) uint8 BGR: a vertical viridis bar over `value_range` ((lo, hi)
    or a ColourScale), 5–7 round ticks, `label` (name and units) beside it and, for a
    ColourScale, the clipped values (`ColourScale.clipped_note`) under the label."""
    scale = value_range if isinstance(value_range, ColourScale) else ColourScale(*value_range)
    return _colour_bar(scale, label, int(height), tuple(int(c) for c in background_bgr)).copy()


def _has_factor(lo: float, hi: float) -> bool:
    """Whether matplotlib writes the ticks of [lo, hi] with a common factor (e.g. 1e−5)."""
    from matplotlib.ticker import ScalarFormatter

    if hi <= lo:
        return False
    formatter = ScalarFormatter()
    formatter.create_dummy_axis()
    formatter.axis.set_view_interval(lo, hi)
    formatter.set_locs(bar_ticks(lo, hi))
    return bool(formatter.get_offset())


@lru_cache(maxsize=32)
def _colour_bar(scale: ColourScale, label: str, height: int, background_bgr) -> np.ndarray:
    from matplotlib.colorbar import ColorbarBase
    from matplotlib.colors import Normalize

    note = scale.clipped_note().split("; ") if scale.clipped_note() else []
    font = max(7.0, min(11.0, height / 50))  # [pt]
    line = font * 100 / 72 * 1.25  # [pixels] per line of text at 100 dpi
    char = font * 100 / 72 * 0.62  # [pixels] per character, about
    width = int(max(font * 8.5, max(len(s) for s in [label, *note]) * 0.8 * char + 12,
                    (len(label) + 7 * _has_factor(*scale.range)) * char + 12))
    top = 1.0 - (1.6 * line + 6) / height
    bottom = (len(note) * 0.8 * line + 14) / height if note else 0.06
    figure = new_figure(width, height)
    figure.patch.set_alpha(0.0)
    axes = figure.add_axes([8 / width, bottom, 16 / width, max(top - bottom, 0.1)])
    lo, hi = scale.range
    if hi <= lo:
        lo, hi = lo - 0.5 * max(abs(lo), 1.0), hi + 0.5 * max(abs(hi), 1.0)
    bar = ColorbarBase(axes, cmap=viridis_colormap(), norm=Normalize(lo, hi),
                       orientation="vertical", ticks=bar_ticks(lo, hi))
    bar.ax.tick_params(labelsize=font)
    # a common factor of the ticks (e.g. 1e−5) goes into the label: matplotlib draws it at
    # the bar's top, where the label is
    formatter = bar.ax.yaxis.get_major_formatter()
    formatter.set_locs(bar.ax.get_yticks())
    factor = formatter.get_offset()
    bar.ax.yaxis.get_offset_text().set_visible(False)
    figure.text(4 / width, 1.0 - 4 / height, f"{label} ×{factor}" if factor else label,
                fontsize=font, ha="left", va="top")
    if note:
        figure.text(4 / width, bottom - 8 / height, "\n".join(note), fontsize=0.8 * font,
                    ha="left", va="top", color="0.3", linespacing=1.15)
    return figure_image(figure, background_bgr)


def _ordinal(percentile: float) -> str:
    value = f"{percentile:g}"
    if value.endswith(("11", "12", "13")) or "." in value:
        return value + "th"
    return value + {"1": "st", "2": "nd", "3": "rd"}.get(value[-1], "th")


def _percent(fraction: float) -> str:
    return f"{100 * fraction:.2g} %"


def _number(value: float) -> str:
    return f"{value:.3g}"

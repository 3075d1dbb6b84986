"""Line plots drawn with matplotlib into BGR images, e.g. Π over iterations.

Labels may use mathtext (r"$\\Pi$ [J]") and Unicode. An axis whose points all lie on a few
integers (grid levels, sweep indices) gets integer ticks and a marker at every point.
"""

from __future__ import annotations

import numpy as np

from taichi_ndf.render.mpl import figure_image, new_figure

__all__ = ["plot_curves", "integer_axis", "PALETTE"]

# Tableau-10, distinguishable and colour-blind tolerant (matplotlib's default cycle).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf")
INTEGER_AXIS_MAX = 20  # at most this many distinct integers count as an integer axis


def integer_axis(values) -> bool:
    """Whether finite `values` all are integers, at most INTEGER_AXIS_MAX distinct ones."""
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return bool(len(values)) and bool(np.all(values == np.round(values))) and \
        len(np.unique(values)) <= INTEGER_AXIS_MAX


def plot_curves(
    series: dict[str, tuple[np.ndarray, np.ndarray]],
    *,
    title: str,
    xlabel: str,
    ylabel: str,
    log_y: bool = False,
    width: int = 800,
    height: int = 500,
) -> np.ndarray:
    """Plot named (x, y) curves on common axes; returns a uint8 BGR image (height, width, 3).

    Non-finite points (and with ``log_y`` non-positive y) are left out, breaking the line
    there. An integer x axis (`integer_axis`) gets integer ticks and markers.
    """
    if width < 200 or height < 150:
        raise ValueError(f"plot size must be at least 200 x 150, got {width} x {height}")
    curves = {}
    for name, (x, y) in series.items():
        x, y = np.asarray(x, dtype=np.float64).ravel(), np.asarray(y, dtype=np.float64).ravel()
        if x.shape != y.shape:
            raise ValueError(f"series {name!r}: x and y differ in length ({len(x)}, {len(y)})")
        keep = np.isfinite(x) & np.isfinite(y) & ((y > 0) if log_y else True)
        curves[name] = (x, np.where(keep, y, np.nan))
    figure = new_figure(width, height)
    axes = figure.add_subplot()
    all_x = np.concatenate([x for x, _ in curves.values()] + [np.empty(0)])
    discrete = integer_axis(all_x)
    for index, (name, (x, y)) in enumerate(curves.items()):
        axes.plot(x, y, color=PALETTE[index % len(PALETTE)], linewidth=1.8, label=name,
                  marker="o" if discrete or np.count_nonzero(np.isfinite(y)) == 1 else None,
                  markersize=5)
    style_axes(axes, title=title, xlabel=xlabel, ylabel=ylabel, log_y=log_y,
               integer_x=discrete)
    if curves:
        axes.legend(loc="best", fontsize=9, framealpha=0.9)
    figure.tight_layout()
    return figure_image(figure)


def style_axes(axes, *, title: str, xlabel: str, ylabel: str, log_y: bool = False,
               integer_x: bool = False) -> None:
    """Title, labels, grid and (log y, integer x) tick locators of one matplotlib Axes."""
    from matplotlib.ticker import MaxNLocator

    if log_y and any(np.isfinite(line.get_ydata()).any() for line in axes.get_lines()):
        axes.set_yscale("log")
    if integer_x:
        axes.xaxis.set_major_locator(MaxNLocator(integer=True, nbins=10))
    axes.set_title(title, fontsize=11)
    axes.set_xlabel(xlabel, fontsize=10)
    axes.set_ylabel(ylabel, fontsize=10)
    axes.grid(True, color="0.88", linewidth=0.8)
    axes.set_axisbelow(True)
    axes.tick_params(labelsize=9)

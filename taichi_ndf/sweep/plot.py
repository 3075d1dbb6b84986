"""The summary plot of a one- or two-axis study: one output of the finished runs over an axis.

One axis: the output over the axis values. Two axes: the output over one axis (the first with
numeric values, else the first), one curve per value of the other. A numeric axis is plotted
at its values, any other (names, vectors) at positions 0, 1, ... listed in the axis label.
Studies with more axes get no plot (the table holds everything).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from taichi_ndf.sweep.naming import value_text

log = logging.getLogger(__name__)


def _numeric(values) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


def plotted_output(rows: list[dict], named: set[str]) -> str | None:
    """The output to plot: Π where there is one, else the first numeric output column."""
    for row in rows:
        if "energy_J" in row:
            return "energy_J"
    for row in rows:
        for key, value in row.items():
            if key not in named and _numeric([value]) and not key.endswith("_s"):
                return key
    return None


def _positions(key: str, values: list) -> tuple[dict, str]:
    if _numeric(values):
        return {i: float(v) for i, v in enumerate(values)}, key
    legend = ", ".join(f"{i}={value_text(v)}" for i, v in enumerate(values))
    return {i: float(i) for i in range(len(values))}, f"{key} ({legend})"


def summary_plot(path: Path, axes: tuple[str, ...], points, rows: dict[int, dict],
                 named: set[str]) -> Path | None:
    """Write the plot (module docstring) of the rows with status ok to `path`; None (and
    nothing written) for a study of more than two axes or without a numeric output."""
    from taichi_ndf.render import plot_curves, save_png

    ok = {i: r for i, r in rows.items() if r.get("status") == "ok"}
    quantity = plotted_output(list(ok.values()), named)
    if len(axes) not in (1, 2) or quantity is None or not ok:
        return None
    values = {k: list(dict.fromkeys(_hashable(p.parameters[k]) for p in points)) for k in axes}
    x_key = next((k for k in axes if _numeric(values[k])), axes[0])
    other = [k for k in axes if k != x_key]
    x_of, x_label = _positions(x_key, values[x_key])
    series = {}
    for group in (values[other[0]] if other else [None]):
        label = quantity if group is None else f"{other[0]} = {value_text(group)}"
        xs, ys = [], []
        for i, row in sorted(ok.items()):
            p = points[i].parameters
            if group is not None and _hashable(p[other[0]]) != group:
                continue
            xs.append(x_of[values[x_key].index(_hashable(p[x_key]))])
            ys.append(float(row[quantity]))
        order = np.argsort(xs)
        series[label] = (np.array(xs)[order], np.array(ys)[order])
    image = plot_curves(series, title=f"{quantity} over {' and '.join(axes)}",
                        xlabel=x_label[:110], ylabel=quantity)
    save_png(path, image)
    log.info("summary plot %s", path)
    return path


def _hashable(value):
    return tuple(_hashable(v) for v in value) if isinstance(value, list) else value

"""The energy figure of a run (energy.png): Π over iterations with the load-step and grid-level
boundaries marked, each solve's distance to its own final Π on a log axis, and for a spline
run on several grids Π per level (integer axis, markers) with the Richardson value and its
error bar. Drawn with matplotlib (`taichi_ndf.render.mpl`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from taichi_ndf.render.mpl import figure_image, new_figure
from taichi_ndf.render.plot import PALETTE, style_axes

__all__ = ["energy_figure", "segments"]

PANEL_HEIGHT = 330  # [pixels] per panel
WIDTH = 820
MAX_LABELLED_BOUNDARIES = 8  # more load-step boundaries than this are drawn without text


def _records(history) -> list[dict]:
    """The history as dicts, iterations counted through the run: a history whose iterations
    restart at each load step (a garment's) is renumbered 0, 1, ... in order."""
    records = [dataclasses.asdict(h) if dataclasses.is_dataclass(h) else dict(h)
               for h in history]
    iterations = [r["iteration"] for r in records]
    if any(b <= a for a, b in zip(iterations, iterations[1:], strict=False)):
        records = [{**r, "iteration": k} for k, r in enumerate(records)]
    return records


def segments(history) -> list[tuple[int, int, float, int]]:
    """The solves of a history (records or dicts with iteration, optional load_factor and level):
    (first index, end index, load factor, level) of each run of records at one load factor on
    one grid level, in order."""
    records = _records(history)
    keys = [(r.get("level", 0), r.get("load_factor", 1.0)) for r in records]
    out, start = [], 0
    for k in range(1, len(keys) + 1):
        if k == len(keys) or keys[k] != keys[start]:
            out.append((start, k, keys[start][1], keys[start][0]))
            start = k
    return out


def energy_figure(history, refinement: dict | None = None) -> np.ndarray:
    """uint8 BGR image of the energy figure (module docstring) of `history` (MonitorRecord /
    NewtonRecord or their dicts in result.json) and `refinement` (`SplineRun.refinement`)."""
    records = _records(history)
    if not records:
        raise ValueError("no history to plot")
    panels = 3 if refinement is not None else 2
    figure = new_figure(WIDTH, PANEL_HEIGHT * panels)
    grid = figure.add_gridspec(panels, 1)
    iteration = np.array([r["iteration"] for r in records], dtype=np.float64)
    energy = np.array([r["energy"] for r in records], dtype=np.float64)
    parts = segments(records)

    top = figure.add_subplot(grid[0])
    top.plot(iteration, energy, color=PALETTE[0], linewidth=1.6, label=r"$\Pi$",
             marker="o" if len(records) <= 40 else None, markersize=3)
    style_axes(top, title="Total potential energy", xlabel="iteration",
               ylabel=r"$\Pi$ [J]")
    _mark_boundaries(top, records, parts)

    gap_axes = figure.add_subplot(grid[1])
    any_gap = False
    for index, (start, end, _, _) in enumerate(parts):
        final = energy[end - 1]
        gap = np.abs(energy[start:end - 1] - final) / max(abs(final), 1e-300)
        gap = np.where(gap > 0, gap, np.nan)
        any_gap = any_gap or bool(np.any(np.isfinite(gap)))
        gap_axes.plot(iteration[start:end - 1], gap, color=PALETTE[0], linewidth=1.6,
                      marker="o" if end - start <= 40 else None, markersize=3,
                      label="each solve" if index == 0 else None)
    style_axes(gap_axes, title="Distance to the final energy of each load step and grid",
               xlabel="iteration", ylabel=r"$|\Pi - \Pi_\mathrm{end}|\,/\,|\Pi_\mathrm{end}|$",
               log_y=any_gap)
    _mark_boundaries(gap_axes, records, parts, text=False)

    if refinement is not None:
        _refinement_panel(figure.add_subplot(grid[2]), refinement)
    figure.tight_layout()
    return figure_image(figure)


def _mark_boundaries(axes, records, parts, *, text: bool = True) -> None:
    """Vertical lines where a load step (dotted) or a grid level (solid) begins, labelled
    with the load factor (every load step, the first too, where there are several) and the
    level's spans."""
    from matplotlib.lines import Line2D

    load_starts = [k for k, (_, _, _, lv) in enumerate(parts) if k and parts[k - 1][3] == lv]
    level_starts = [k for k, (_, _, _, lv) in enumerate(parts) if k and parts[k - 1][3] != lv]
    several_loads = len({factor for _, _, factor, _ in parts}) > 1
    transform = axes.get_xaxis_transform()
    label_loads = text and several_loads and len(parts) <= MAX_LABELLED_BOUNDARIES
    for k, (start, _, factor, _) in enumerate(parts):
        x = records[start]["iteration"] - 0.5
        if k in load_starts:
            axes.axvline(x, color="0.55", linestyle=":", linewidth=1.0)
        elif k in level_starts:
            axes.axvline(x, color="0.25", linestyle="-", linewidth=1.2)
        if label_loads:
            axes.text(x, 0.98, f" load {factor:g}", transform=transform, fontsize=8,
                      va="top", ha="left", color="0.35")
        if text and (k in level_starts or (k == 0 and level_starts)):
            spans = records[start].get("spans")
            grid = f": {spans[0]} × {spans[1]}" if spans else ""
            axes.text(x, 0.02, f" level {parts[k][3]}{grid}", transform=transform,
                      fontsize=8, va="bottom", ha="left", color="0.15")
    handles = axes.get_legend_handles_labels()[0]
    if load_starts:
        handles.append(Line2D([], [], color="0.55", linestyle=":", label="new load step"))
    if level_starts:
        handles.append(Line2D([], [], color="0.25", linestyle="-", label="new grid level"))
    if handles:
        axes.legend(handles=handles, fontsize=8, loc="best", framealpha=0.9)


def _refinement_panel(axes, refinement: dict) -> None:
    """Π per grid level (markers on an integer axis) with the extrapolated value ± error."""
    energy = refinement["energy"]
    values = np.asarray(energy["values"], dtype=np.float64)
    level = np.arange(len(values))
    value, bar = energy["extrapolated"], energy["estimated_error"]
    basis = energy.get("order_basis", "observed")
    if basis == "observed" and energy.get("order") is not None:
        how = f"observed order {energy['order']:.2f}"
    elif basis == "assumed":
        how = f"order {energy.get('order', 0):g} assumed"
    else:
        how = f"order {basis}"
    axes.fill_between([-0.3, len(values) - 0.7], value - bar, value + bar, color=PALETTE[1],
                      alpha=0.18, linewidth=0, label="error bar")
    axes.axhline(value, color=PALETTE[1], linestyle="--", linewidth=1.4,
                 label=rf"Richardson ({how}): $\Pi_\infty$ = {value:.6g} ± {bar:.2g} J")
    axes.plot(level, values, color=PALETTE[0], marker="o", markersize=6, linewidth=1.6,
              label=r"$\Pi$ on each grid")
    style_axes(axes, title="Refinement: spans doubled per level", xlabel="grid level",
               ylabel=r"$\Pi$ [J]", integer_x=True)
    spans = refinement.get("spans")
    if spans:
        axes.set_xticks(level, [f"{k}\n{s[0]} × {s[1]}" for k, s in zip(level, spans,
                                                                      strict=False)])
    axes.set_xlim(-0.3, len(values) - 0.7)
    axes.legend(fontsize=8, loc="best", framealpha=0.9)

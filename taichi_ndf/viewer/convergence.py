"""The viewer's convergence plot (uPlot, viser's own): Π [J] per iteration and, where the run
reports it (projected Newton), log₁₀ of the Newton decrement λ² [J] on a second axis; rows
without a positive λ² are gaps. One plot for a finished run (result.json's history) and a live
one (`taichi_ndf.viewer.live`, from progress.jsonl)."""

from __future__ import annotations

import numpy as np

PI_RGB, DECREMENT_RGB = "#1f77b4", "#d62728"


def convergence_data(iterations, energies, decrements=None) -> tuple[np.ndarray, ...]:
    """The plot's columns: iterations, Π and (with `decrements`) log₁₀ λ² (NaN where λ² ≤ 0)."""
    data = [np.asarray(iterations, dtype=np.float64), np.asarray(energies, dtype=np.float64)]
    if decrements is not None:
        decrements = np.asarray(decrements, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            data.append(np.where(decrements > 0, np.log10(decrements), np.nan))
    return tuple(data)


def add_convergence_plot(gui, iterations, energies, decrements=None, *, title="convergence"):
    """The plot in the viser `gui` panel; its handle's `data` takes `convergence_data(...)` of
    the same shape (with or without decrements) to redraw it."""
    series = [{"label": "iteration"}, {"label": "Π [J]", "stroke": PI_RGB, "scale": "Pi"}]
    axes = [{"label": "iteration"},
            {"label": "Π [J]", "scale": "Pi", "stroke": PI_RGB, "size": 60}]
    scales = {"x": {"time": False}, "Pi": {"auto": True}}
    if decrements is not None:
        series.append({"label": "log₁₀ λ² [J]", "stroke": DECREMENT_RGB, "scale": "decrement"})
        axes.append({"label": "log₁₀ λ² [J]", "scale": "decrement", "side": 1,
                     "stroke": DECREMENT_RGB, "size": 50, "grid": {"show": False}})
        scales["decrement"] = {"auto": True}
    return gui.add_uplot(convergence_data(iterations, energies, decrements), tuple(series),
                         title=title, axes=tuple(axes), scales=scales, aspect=1.2,
                         padding=(12, 8, 0, 0))

"""Matplotlib figures drawn off-screen (Agg, no pyplot state) into BGR images.

Matplotlib sets the plots' and colour bars' text: mathtext (Π, κ, exponents), proper tick
placement and a readable font, which OpenCV's Hershey font (ASCII only) cannot.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["new_figure", "figure_image", "viridis_bgr", "viridis_colormap"]

DPI = 100


def new_figure(width: int, height: int):
    """A matplotlib Figure of width x height pixels on its own Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
    FigureCanvasAgg(figure)
    return figure


def figure_image(figure, background_bgr=(255, 255, 255)) -> np.ndarray:
    """The drawn figure as uint8 BGR (height, width, 3), transparency over `background_bgr`."""
    figure.canvas.draw()
    rgba = np.asarray(figure.canvas.buffer_rgba(), dtype=np.float64)
    alpha = rgba[..., 3:4] / 255.0
    background = np.asarray(background_bgr, dtype=np.float64)[::-1]
    rgb = rgba[..., :3] * alpha + background * (1.0 - alpha)
    return np.ascontiguousarray(np.clip(np.rint(rgb[..., ::-1]), 0, 255).astype(np.uint8))


@functools.cache
def viridis_bgr() -> np.ndarray:
    """(256, 3) uint8: the colour map of every render (OpenCV's viridis; made on first use, so
    importing the renderer does not import cv2: issue 28)."""
    import cv2

    ramp = np.arange(256, dtype=np.uint8)[:, None]
    return cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS)[:, 0]


def __getattr__(name: str):
    if name == "VIRIDIS_BGR":  # the table under its former name
        return viridis_bgr()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def viridis_colormap():
    """VIRIDIS_BGR as a matplotlib colour map, so bars show exactly the render's colours."""
    from matplotlib.colors import ListedColormap

    return ListedColormap(viridis_bgr()[:, ::-1] / 255.0, name="viridis_bgr")

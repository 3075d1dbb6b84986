"""What a video shows of its held edge's motion, smoothed in time for the handles to follow
(`inverse.sft.swing`): per-frame values (the held corners' positions, each vertex coordinate)
smoothed by a cubic smoothing spline whose smoothing GCV chooses
(`scipy.interpolate.make_smoothing_spline`: a reconstruction's noise would otherwise enter
the run as accelerations of ~σ/Δt²)."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import make_smoothing_spline


def smoothed(values: np.ndarray, times: np.ndarray) -> tuple[list, tuple]:
    """Each entry of values (F, …) smoothed over times (F,) [s] by a cubic smoothing spline
    whose smoothing GCV chooses: (splines, the entries' shape), read by `evaluate_smoothed`."""
    flat = values.reshape(len(times), -1)
    splines = [make_smoothing_spline(times, flat[:, j]) for j in range(flat.shape[1])]
    return splines, values.shape[1:]


def evaluate_smoothed(smooth, t: np.ndarray, nu: int = 0) -> np.ndarray:
    """`smoothed`'s entries (…, shape) at times t [s], or their nu-th time derivative."""
    splines, shape = smooth
    out = np.stack([s(t, nu) if nu else s(t) for s in splines], axis=-1)
    return out.reshape(*np.shape(t), *shape)

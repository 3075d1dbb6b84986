"""What a video shows of its held edge's motion, smoothed in time for the handles to follow
(`inverse.sft.swing`): per-frame values (the held corners' positions, each vertex coordinate)
smoothed by a cubic smoothing spline whose smoothing GCV chooses
(`scipy.interpolate.make_smoothing_spline`: a reconstruction's noise would otherwise enter
the run as accelerations of ~σ/Δt²). The last few smoothings are kept (`smoothed`, keyed by
the values' and times' bytes): a sequence's problem rebuilt at other settings (a grid level,
gravity, a time scale as mass: `swing_capture`) smooths the same data once — R1's 1024
vertices took 57 s CPU of a 59 s build (GCV per coordinate, 3072 splines)."""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np
from scipy.interpolate import make_smoothing_spline

KEPT = 4  # smoothings kept (`smoothed`)
_kept: OrderedDict[bytes, tuple[list, tuple]] = OrderedDict()


def smoothed(values: np.ndarray, times: np.ndarray) -> tuple[list, tuple]:
    """Each entry of values (F, …) smoothed over times (F,) [s] by a cubic smoothing spline
    whose smoothing GCV chooses: (splines, the entries' shape), read by `evaluate_smoothed`;
    the same values and times again: the kept answer (module docstring; not to be changed)."""
    values, times = np.asarray(values, dtype=np.float64), np.asarray(times, dtype=np.float64)
    key = hashlib.sha256(repr((values.shape, times.shape)).encode() + values.tobytes()
                         + times.tobytes()).digest()
    if key in _kept:
        _kept.move_to_end(key)
        return _kept[key]
    flat = values.reshape(len(times), -1)
    splines = [make_smoothing_spline(times, flat[:, j]) for j in range(flat.shape[1])]
    _kept[key] = (splines, values.shape[1:])
    while len(_kept) > KEPT:
        _kept.popitem(last=False)
    return _kept[key]


def evaluate_smoothed(smooth, t: np.ndarray, nu: int = 0) -> np.ndarray:
    """`smoothed`'s entries (…, shape) at times t [s], or their nu-th time derivative."""
    splines, shape = smooth
    out = np.stack([s(t, nu) if nu else s(t) for s in splines], axis=-1)
    return out.reshape(*np.shape(t), *shape)


def edge_turn(vertices: np.ndarray, corners: np.ndarray, rows: np.ndarray, axis: np.ndarray,
              across: np.ndarray) -> np.ndarray:
    """The held edge's turn per frame (F,) [rad] about the corner line: the angle, in the
    plane ⊥ `axis` (3,) (the reference corner line's direction) from `across` (3,) (the
    reference plane's direction into the sheet, ⊥ axis) towards axis × across, of the summed
    offsets of the vertices `rows` (indices: the rows nearest the held edge) from each
    frame's corner line; vertices (F, V, 3) [m], corners (F, 2, 3) [m] (corner a, b). An
    angle of the rows as a whole, so its noise is that of their mean."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    across = np.asarray(across, dtype=np.float64)
    normal = np.cross(axis, across)
    line = corners[:, 1] - corners[:, 0]
    line = line / np.linalg.norm(line, axis=1, keepdims=True)
    offsets = vertices[:, rows] - corners[:, None, 0]
    offsets = offsets - np.sum(offsets * line[:, None], axis=2, keepdims=True) * line[:, None]
    total = offsets.sum(axis=1)
    return np.arctan2(total @ normal, total @ across)

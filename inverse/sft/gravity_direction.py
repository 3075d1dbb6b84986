"""Gravity's direction in a camera's frame, for a sheet hanging from two held corners.

A camera is not level in general, so "down the image" is not the vertical. Two ways to give
the vertical to the swing model (`inverse.sft.swing`, its `gravity` argument):
- `tilted_gravity`: image-down (the camera's +y, OpenCV axes) made perpendicular to the
  corner line, turned by a pitch about the corner line (towards e1 × across: away from the
  camera for a line along +x) and then by a roll towards corner b (in the sheet's plane),
  both in degrees — two unknowns of any capture, to be scanned or fitted.
- `pendulum_swing`: read off the video. A sheet that swings about its corner line turns as a
  pendulum about its hanging equilibrium: the angle θ_n of the line from the corner line's
  middle to the sheet's centroid, about frame 0's corner line (0 = image-down made
  perpendicular to the line), is fitted per frame n by θ_n = α + A cos(Ω n + φ) (least
  squares). α estimates the vertical's pitch (the equilibrium), Ω [rad per frame] the
  swing's frequency in frames: with the model's own frequency ω [rad/s] of the same swing
  (e.g. a forward run), Ω / ω is the frame interval [s] the two share. The fit needs the
  record to cover a turning point (about half a period or more); its s.e. are the least
  squares' (residuals taken as independent), and a swing that is driven rather than free
  does not follow the form (its rms says so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

IMAGE_DOWN = np.array([0.0, 1.0, 0.0])  # OpenCV camera axes: +y points down the image


def _frame(corners: np.ndarray, down: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(e1, across, normal): the corner line's direction, `down` made perpendicular to it,
    and e1 × across; corners (2, 3) [m]."""
    corners = np.asarray(corners, dtype=np.float64)
    line = corners[1] - corners[0]
    e1 = line / np.linalg.norm(line)
    across = np.asarray(down, dtype=np.float64) - (np.asarray(down) @ e1) * e1
    if not np.linalg.norm(across) > 1e-9:
        raise ValueError("the corner line is along image-down: no plane hangs across it")
    across = across / np.linalg.norm(across)
    return e1, across, np.cross(e1, across)


def tilted_gravity(corners: np.ndarray, pitch: float, roll: float = 0.0,
                   magnitude: float = 9.81, down: np.ndarray = IMAGE_DOWN) -> np.ndarray:
    """Gravity (3,) [m/s²] of `magnitude`: `down` made ⊥ the corner line (corners (2, 3) [m],
    a then b) turned by `pitch` [deg] about the line (towards e1 × across) and by `roll`
    [deg] towards corner b. ValueError on angles outside (−90, 90) or not finite."""
    for name, value in (("pitch", pitch), ("roll", roll)):
        if not (math.isfinite(value) and -90 < value < 90):
            raise ValueError(f"gravity {name} must be finite and in (-90, 90) degrees, got "
                             f"{value!r}")
    if not (math.isfinite(magnitude) and magnitude > 0):
        raise ValueError(f"gravity's magnitude must be finite and > 0, got {magnitude!r}")
    e1, across, normal = _frame(corners, down)
    p, r = math.radians(pitch), math.radians(roll)
    return magnitude * (math.cos(r) * (math.cos(p) * across + math.sin(p) * normal)
                        + math.sin(r) * e1)


@dataclass(frozen=True)
class PendulumSwing:
    """`pendulum_swing`'s answer: equilibrium α and amplitude A [deg], frequency Ω [rad per
    frame], phase φ [rad], each with its least-squares s.e. (`*_se`); rms: the fit's rms
    residual [deg]; angles: the measured θ_n (F,) [deg]."""

    equilibrium: float
    equilibrium_se: float
    amplitude: float
    amplitude_se: float
    frequency: float
    frequency_se: float
    phase: float
    rms: float
    angles: np.ndarray


def sheet_pitch(vertices: np.ndarray, held: tuple[int, int],
                down: np.ndarray = IMAGE_DOWN) -> np.ndarray:
    """The sheet's angle per frame (F,) [deg] about frame 0's corner line: of the line from
    each frame's corner line's middle to the centroid of the vertices (F, V, 3) [m] (held
    corners excluded), from `down` made ⊥ the line, towards e1 × across."""
    vertices = np.asarray(vertices, dtype=np.float64)
    corners = vertices[:, list(held)]
    _, across, normal = _frame(corners[0], down)
    keep = np.ones(vertices.shape[1], dtype=bool)
    keep[list(held)] = False
    offset = vertices[:, keep].mean(axis=1) - corners.mean(axis=1)
    return np.degrees(np.arctan2(offset @ normal, offset @ across))


def pendulum_swing(vertices: np.ndarray, held: tuple[int, int],
                   down: np.ndarray = IMAGE_DOWN) -> PendulumSwing:
    """The sheet's swing about its corner line fitted as a pendulum (module docstring);
    vertices (F, V, 3) [m], F ≥ 6; held: the two corner vertex indices."""
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 3 or vertices.shape[0] < 6 or vertices.shape[2] != 3:
        raise ValueError(f"vertices must be (F, V, 3) with F >= 6 frames, got "
                         f"{vertices.shape}")
    angles = sheet_pitch(vertices, held, down)
    n = np.arange(len(angles), dtype=np.float64)

    def residual(x):
        return x[0] + x[1] * np.cos(x[2] * n + x[3]) - angles

    spread = float(np.ptp(angles)) / 2 or 1.0
    best = None
    for frequency in 2 * np.pi / len(n) * np.array([0.25, 0.5, 1.0, 2.0, 4.0]):
        for phase in np.linspace(-np.pi, np.pi, 8, endpoint=False):
            fit = least_squares(residual, [angles.mean(), spread, frequency, phase])
            if best is None or fit.cost < best.cost:
                best = fit
    x = best.x.copy()
    if x[1] < 0:  # one sign of the amplitude: A ≥ 0
        x[1], x[3] = -x[1], x[3] + np.pi
    if x[2] < 0:
        x[2], x[3] = -x[2], -x[3]
    x[3] = (x[3] + np.pi) % (2 * np.pi) - np.pi
    jac = best.jac
    dof = max(1, len(n) - 4)
    sigma2 = 2 * best.cost / dof
    try:
        se = np.sqrt(np.diag(np.linalg.inv(jac.T @ jac)) * sigma2)
    except np.linalg.LinAlgError:
        se = np.full(4, np.inf)
    return PendulumSwing(float(x[0]), float(se[0]), float(x[1]), float(se[1]), float(x[2]),
                         float(se[2]), float(x[3]), float(np.sqrt(2 * best.cost / len(n))),
                         angles)

"""Exactly isometric deformations of a flat sheet: rolls and folds about a moving generator.

A flat rectangular sheet lies in its own frame (x along the width, y along the height, z the
normal; centre at the origin). Bending it about a straight generator line onto a circular
cylinder of radius R tangent to the sheet, with flat continuation after an arc angle θ, maps the
plane to a developable C¹ surface that preserves every geodesic distance: each point at signed
distance s past the generator goes to arc length s on the cylinder (s ≤ Rθ) or along the tangent
plane beyond. A roll is the case where everything past the generator lies on the cylinder.

The sheet is then placed in front of the camera by a rigid pose (OpenCV axes). Everything here is
exact, so rendered frames come with exact ground-truth vertices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def cylindrical_bend(
    points: np.ndarray,
    *,
    direction: tuple[float, float],
    offset: float,
    radius: float,
    angle: float,
    lift: float = -1.0,
) -> np.ndarray:
    """Bend flat sheet points about a generator line; isometric.

    points: flat positions in the sheet plane [m], shape (n, 2).
    direction: unit vector in the plane, perpendicular to the generator, pointing into the part
        that bends; offset: position of the generator along it [m] (s = direction·p − offset).
    radius: cylinder radius [m] (> 0); angle: arc angle θ [rad] before flat continuation.
    lift: +1 bends towards +z of the sheet frame, −1 towards −z.
    Returns positions in the sheet frame [m], shape (n, 3).
    """
    if radius <= 0:
        raise ValueError(f"radius must be positive, got {radius}")
    if angle < 0:
        raise ValueError(f"angle must be non-negative, got {angle}")
    if lift not in (-1.0, 1.0):
        raise ValueError(f"lift must be +1 or -1, got {lift}")
    d = np.asarray(direction, dtype=np.float64)
    if not np.isclose(np.linalg.norm(d), 1.0):
        raise ValueError(f"direction must be a unit vector, got {direction}")
    points = np.asarray(points, dtype=np.float64)
    s = points @ d - offset
    along_generator = points - np.outer(points @ d, d)
    arc = np.clip(s, 0.0, radius * angle)
    beyond = np.clip(s - radius * angle, 0.0, None)
    # Arc part on the cylinder, then the straight tangent at the end of the arc.
    t = offset + radius * np.sin(arc / radius) + beyond * np.cos(angle)
    height = radius * (1.0 - np.cos(arc / radius)) + beyond * np.sin(angle)
    flat = s <= 0.0
    t = np.where(flat, points @ d, t)
    height = np.where(flat, 0.0, height)
    planar = along_generator + np.outer(t, d)
    return np.column_stack([planar, lift * height])


def rotation_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation matrix R = Rz @ Ry @ Rx for angles [rad] about the camera axes."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@dataclass(frozen=True)
class Pose:
    """Rigid placement of the sheet frame in camera coordinates, moving linearly in time.

    rotation (rx, ry, rz) [rad] and translation [m] at t = 0, and their change by t = 1.
    """

    rotation: tuple[float, float, float] = (0.35, -0.25, 0.05)
    translation: tuple[float, float, float] = (0.0, 0.0, 0.45)
    rotation_change: tuple[float, float, float] = (0.0, 0.15, 0.0)
    translation_change: tuple[float, float, float] = (0.01, 0.0, 0.02)

    def apply(self, sheet_points: np.ndarray, t: float) -> np.ndarray:
        """Sheet-frame points [m], shape (n, 3), in camera coordinates at time t ∈ [0, 1]."""
        angles = np.add(self.rotation, t * np.asarray(self.rotation_change))
        shift = np.add(self.translation, t * np.asarray(self.translation_change))
        return sheet_points @ rotation_xyz(*angles).T + shift


@dataclass(frozen=True)
class Roll:
    """A flat sheet progressively rolled onto a cylinder from its +x edge.

    radius [m]; rolled: fraction of the sheet width wound on the cylinder at t = 1;
    lift: +1 rolls away from the camera (sheet +z), −1 towards it.
    """

    radius: float = 0.05
    rolled: float = 0.45
    lift: float = 1.0

    def __post_init__(self):
        if self.radius <= 0:
            raise ValueError(f"Roll.radius must be positive, got {self.radius}")
        if not 0.0 <= self.rolled <= 1.0:
            raise ValueError(f"Roll.rolled must be in [0, 1], got {self.rolled}")

    def shape(self, points: np.ndarray, t: float, *, sheet_width: float) -> np.ndarray:
        """Sheet-frame positions [m] (n, 3) of flat points (n, 2) at time t ∈ [0, 1]."""
        length = t * self.rolled * sheet_width
        if length / self.radius >= 2.0 * np.pi:
            raise ValueError(
                f"Roll winds {length / self.radius:.2f} rad >= 2π: the sheet would pass through "
                "itself; use a larger radius or a smaller rolled fraction"
            )
        return cylindrical_bend(
            points, direction=(1.0, 0.0), offset=sheet_width / 2 - length, radius=self.radius,
            angle=np.pi * 2, lift=self.lift,
        )


@dataclass(frozen=True)
class Fold:
    """Bending about an oblique generator that moves across the sheet while the fold closes.

    direction_deg: direction (in the sheet plane, from +x) perpendicular to the generator;
    offset_start, offset_end: generator position along it at t = 0 and 1 [m];
    radius [m]; angle: arc angle at t = 1 [rad]; lift: +1 away from the camera, −1 towards it.
    """

    direction_deg: float = 25.0
    offset_start: float = 0.06
    offset_end: float = -0.01
    radius: float = 0.04
    angle: float = 1.4
    lift: float = -1.0

    def __post_init__(self):
        if self.radius <= 0:
            raise ValueError(f"Fold.radius must be positive, got {self.radius}")
        if not 0.0 <= self.angle <= np.pi:
            raise ValueError(f"Fold.angle must be in [0, π], got {self.angle}")

    def shape(self, points: np.ndarray, t: float, *, sheet_width: float) -> np.ndarray:
        """Sheet-frame positions [m] (n, 3) of flat points (n, 2) at time t ∈ [0, 1]."""
        phi = np.radians(self.direction_deg)
        return cylindrical_bend(
            points, direction=(np.cos(phi), np.sin(phi)),
            offset=(1 - t) * self.offset_start + t * self.offset_end,
            radius=self.radius, angle=t * self.angle, lift=self.lift,
        )


@dataclass(frozen=True)
class CornerLift:
    """A corner lifted and dropped again: bending about a generator that cuts off a corner,
    the arc angle rising from 0 to `angle` at t = ½ and back to 0 at t = 1 (sin(π t)).

    direction_deg: direction (in the sheet plane, from +x) perpendicular to the generator,
    pointing into the corner; offset: generator position along it [m]; radius [m];
    angle: peak arc angle [rad]; lift: +1 away from the camera, −1 towards it.
    """

    direction_deg: float = -140.0
    offset: float = 0.07
    radius: float = 0.03
    angle: float = 1.3
    lift: float = -1.0

    def __post_init__(self):
        if self.radius <= 0:
            raise ValueError(f"CornerLift.radius must be positive, got {self.radius}")
        if not 0.0 <= self.angle <= np.pi:
            raise ValueError(f"CornerLift.angle must be in [0, π], got {self.angle}")

    def shape(self, points: np.ndarray, t: float, *, sheet_width: float) -> np.ndarray:
        """Sheet-frame positions [m] (n, 3) of flat points (n, 2) at time t ∈ [0, 1]."""
        phi = np.radians(self.direction_deg)
        return cylindrical_bend(
            points, direction=(np.cos(phi), np.sin(phi)), offset=self.offset,
            radius=self.radius, angle=self.angle * np.sin(np.pi * t), lift=self.lift,
        )


@dataclass(frozen=True)
class Wave:
    """A flag-like travelling wave: the sheet's cross-section along x is the curve of arc
    length s (from the −x edge, which stays put like a flagpole) whose slope angle is
    θ(s, t) = t · amplitude · (s / W) · sin(2π (s / wavelength − cycles · t)), W the sheet
    width; lines of constant x stay straight, so the map is isometric (a generalised
    cylinder), exact up to the quadrature of x(s) = ∫ cos θ, z(s) = ∫ sin θ (trapezoid rule on
    `QUADRATURE_POINTS` nodes, isometry error ~ (W / nodes)² relative).

    amplitude: slope angle [rad] at the free edge at t = 1; wavelength [m]; cycles: waves
    travelled by t = 1.
    """

    amplitude: float = 0.6
    wavelength: float = 0.2
    cycles: float = 1.0

    QUADRATURE_POINTS = 8192

    def __post_init__(self):
        if not 0.0 <= self.amplitude < np.pi / 2:
            raise ValueError(f"Wave.amplitude must be in [0, π/2), got {self.amplitude}")
        if self.wavelength <= 0:
            raise ValueError(f"Wave.wavelength must be positive, got {self.wavelength}")

    def shape(self, points: np.ndarray, t: float, *, sheet_width: float) -> np.ndarray:
        """Sheet-frame positions [m] (n, 3) of flat points (n, 2) at time t ∈ [0, 1]."""
        points = np.asarray(points, dtype=np.float64)
        s = np.linspace(0.0, sheet_width, self.QUADRATURE_POINTS)
        theta = (t * self.amplitude * s / sheet_width
                 * np.sin(2 * np.pi * (s / self.wavelength - self.cycles * t)))
        ds = np.diff(s)
        x = np.concatenate([[0.0], np.cumsum(0.5 * ds * (np.cos(theta[1:]) + np.cos(theta[:-1])))])
        z = np.concatenate([[0.0], np.cumsum(0.5 * ds * (np.sin(theta[1:]) + np.sin(theta[:-1])))])
        arc = np.clip(points[:, 0] + sheet_width / 2, 0.0, sheet_width)
        return np.column_stack([np.interp(arc, s, x) - sheet_width / 2, points[:, 1],
                                np.interp(arc, s, z)])

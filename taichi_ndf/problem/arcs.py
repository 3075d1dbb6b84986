"""A curved edge of a panel's outline: a circular arc given by its chord and a bulge (issue 30).

An outline's edge from point a to point b (ξ [m]) with bulge β (as in DXF polylines) is the
circular arc through a and b whose signed central angle is θ = 4 atan β: β = 0 the straight
edge, β > 0 an arc turning counter-clockwise from a to b (bulging to the right of a → b: outward
for a counter-clockwise outline), β < 0 one turning clockwise (bulging inward: a notch cut as
a curve); |β| = 1 a half circle, |β| = tan(π/8) a quarter circle. The radius is
R = |a − b| / (2 sin(|θ|/2)), the centre o on the chord's perpendicular bisector, and the arc

    c(t) = o + R (cos ψ(t), sin ψ(t)),   ψ(t) = φ_a + θ t,   t ∈ [0, 1],

runs at constant speed |dc/dt| = R |θ|: t is the fraction of its arclength R |θ|, so a seam
along it is parametrised by arclength as a straight edge's is (`Arc.path`). The region between
the chord and the arc, the circular segment, has the signed area ½ R² (θ − sin θ) (> 0: it adds
to the polygon of the outline's points, < 0: it is cut from it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Largest |θ| of one arc: a bulge up to tan(π/2 − ε) (nearly a whole circle).
MAX_ANGLE = 2 * math.pi * (1 - 1e-9)


def bulge_angle(bulge: float) -> float:
    """The signed central angle θ = 4 atan β [rad] of bulge β."""
    return 4.0 * math.atan(bulge)


@dataclass(frozen=True)
class Arc:
    """The arc from `start` to `end` [m] with signed central angle `angle` [rad] (0 < |angle|
    < 2π; module docstring)."""

    start: tuple[float, float]
    end: tuple[float, float]
    angle: float

    @classmethod
    def of_bulge(cls, start, end, bulge: float) -> Arc | None:
        """The arc of an edge with bulge β; None for β = 0 (a straight edge)."""
        if bulge == 0.0:
            return None
        return cls(tuple(start), tuple(end), bulge_angle(bulge))

    @property
    def radius(self) -> float:
        """R [m]."""
        chord = math.dist(self.start, self.end)
        return chord / (2.0 * math.sin(abs(self.angle) / 2.0))

    @property
    def centre(self) -> np.ndarray:
        """o (2,) [m]: from the chord's midpoint, (|chord|/2) cot(θ/2) along its left normal."""
        a, b = np.asarray(self.start, float), np.asarray(self.end, float)
        d = b - a
        left = np.array([-d[1], d[0]])
        return 0.5 * (a + b) + 0.5 / math.tan(self.angle / 2.0) * left

    @property
    def start_angle(self) -> float:
        """φ_a [rad]: the direction of the start point from the centre."""
        o = self.centre
        return math.atan2(self.start[1] - o[1], self.start[0] - o[0])

    @property
    def length(self) -> float:
        """The arclength R |θ| [m]."""
        return self.radius * abs(self.angle)

    @property
    def segment_area(self) -> float:
        """The signed area ½ R² (θ − sin θ) [m²] between the chord and the arc."""
        return 0.5 * self.radius ** 2 * (self.angle - math.sin(self.angle))

    def at(self, t) -> np.ndarray:
        """Points c(t) (M, 2) [m] at fractions t (M,) of the arclength."""
        psi = self.start_angle + self.angle * np.asarray(t, float)
        return self.centre + self.radius * np.stack((np.cos(psi), np.sin(psi)), axis=-1)

    def path(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At fractions t (M,): the points (M, 2), dc/dt (M, 2) [m] (speed R |θ|) and the
        unit outward normals (M, 2) (the right-hand normal of dc/dt: the outline on the left)."""
        psi = self.start_angle + self.angle * np.asarray(t, float)
        e = np.stack((np.cos(psi), np.sin(psi)), axis=-1)
        run = self.radius * self.angle * np.stack((-e[:, 1], e[:, 0]), axis=-1)
        normal = np.stack((run[:, 1], -run[:, 0]), axis=-1) / (self.radius * abs(self.angle))
        return self.centre + self.radius * e, run, normal

    def crossings(self, axis: int, value: float) -> list[float]:
        """The fractions t ∈ (0, 1) (sorted) where the arc crosses the line ξ[axis] = value."""
        o, radius = self.centre, self.radius
        ratio = (value - o[axis]) / radius
        if abs(ratio) > 1.0:
            return []
        base = math.acos(ratio) if axis == 0 else math.asin(ratio)
        candidates = (base, -base) if axis == 0 else (base, math.pi - base)
        found = []
        for psi in candidates:
            turn = (psi - self.start_angle) % (2 * math.pi)
            if self.angle < 0:
                turn = turn - 2 * math.pi if turn > 0 else 0.0
            t = turn / self.angle
            if 1e-12 < t < 1.0 - 1e-12:
                found.append(t)
        return sorted(found)

    def splits(self, max_angle: float, cuts=((), ())) -> list[float]:
        """Fractions 0 = t₀ < t₁ < … < t_n = 1 that cut the arc into pieces of at most
        `max_angle` [rad] and at every crossing of the lines ξ¹ = cuts[0][k], ξ² = cuts[1][k]
        (a piece then crosses none of them)."""
        pieces = max(1, math.ceil(abs(self.angle) / max_angle - 1e-12))
        ts = {k / pieces for k in range(pieces + 1)}
        for axis in range(2):
            for value in cuts[axis]:
                ts.update(self.crossings(axis, float(value)))
        ordered = sorted(ts)
        kept = [ordered[0]]
        for t in ordered[1:]:
            if t - kept[-1] > 1e-12:
                kept.append(t)
            else:
                kept[-1] = t if t in (0.0, 1.0) else kept[-1]
        return kept

    def nearest(self, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The arc's point nearest to each ξ (N, 2) and its distance (N,)."""
        o = self.centre
        rel = np.asarray(xi, float) - o
        psi = np.arctan2(rel[:, 1], rel[:, 0])
        turn = np.mod(psi - self.start_angle, 2 * math.pi)
        if self.angle < 0:
            turn = np.where(turn > 0, turn - 2 * math.pi, 0.0)
        t = turn / self.angle
        on_arc = (t >= 0.0) & (t <= 1.0)
        foot = self.at(np.clip(t, 0.0, 1.0))
        ends = self.at(np.array([0.0, 1.0]))
        to_ends = np.linalg.norm(xi[:, None, :] - ends[None], axis=2)
        nearer_end = ends[np.argmin(to_ends, axis=1)]
        foot = np.where(on_arc[:, None], foot, nearer_end)
        return foot, np.linalg.norm(xi - foot, axis=1)

    def in_segment(self, xi: np.ndarray) -> np.ndarray:
        """Whether each ξ (N, 2) lies strictly inside the circular segment (the disc's part on
        the arc's side of the chord); bool (N,)."""
        o, radius = self.centre, self.radius
        xi = np.asarray(xi, float)
        in_disc = np.linalg.norm(xi - o, axis=1) < radius
        a, b = np.asarray(self.start, float), np.asarray(self.end, float)
        side = (b[0] - a[0]) * (xi[:, 1] - a[1]) - (b[1] - a[1]) * (xi[:, 0] - a[0])
        # the arc lies right of a → b for θ > 0, left for θ < 0: the segment is the disc's
        # part on that side (the smaller part for |θ| < π, the larger beyond)
        beyond = side < 0 if self.angle > 0 else side > 0
        return in_disc & beyond

    def extremes(self) -> list[tuple[float, float]]:
        """The arc's points at ψ = 0, π/2, π, 3π/2 that it passes (its bounding box's sides)."""
        found = []
        for k in range(4):
            psi = k * math.pi / 2
            turn = (psi - self.start_angle) % (2 * math.pi)
            if self.angle < 0:
                turn = turn - 2 * math.pi if turn > 0 else 0.0
            t = turn / self.angle
            if 0.0 <= t <= 1.0:
                p = self.at(np.array([t]))[0]
                found.append((float(p[0]), float(p[1])))
        return found


def snapped(point, cuts) -> tuple[float, float]:
    """`point` with a coordinate within 1e-12 (relative) of a cut line's value set to it."""
    out = [float(point[0]), float(point[1])]
    for axis in range(2):
        for value in cuts[axis]:
            if abs(out[axis] - value) <= 1e-12 * max(1.0, abs(value)):
                out[axis] = float(value)
    return out[0], out[1]


def fan_weights(apex: np.ndarray, arc: Arc, s_rule, t_rule) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature points (M, 2) and weights (M,) of the region swept from `apex` to the arc,
    x(s, t) = apex + s (c(t) − apex), dA = s (c − apex) × dc/dt ds dt: Gauss–Legendre rules
    `s_rule`, `t_rule` (nodes, weights on [0, 1]); exact in s for a polynomial integrand of
    degree ≤ 2 len(s) − 3, spectrally accurate in t. The weights are positive where every ray
    from the apex meets the arc once, the arc turning counter-clockwise about the apex (the
    trimmed quadrature's lenses: `taichi_ndf.discretise.trimmed`)."""
    s, ws = s_rule
    t, wt = t_rule
    c, run, _ = arc.path(t)
    rel = c - apex
    jac = rel[:, 0] * run[:, 1] - rel[:, 1] * run[:, 0]  # (c − apex) × dc/dt (T,)
    xi = apex + s[:, None, None] * rel[None, :, :]  # (S, T, 2)
    weight = (ws * s)[:, None] * (wt * jac)[None, :]
    return xi.reshape(-1, 2), weight.reshape(-1)


"""Knot lines on given positions, per direction: a C² monotone map η = h(ξ) of one coordinate
onto itself that sends given breakpoints b_i of ξ onto knots η_i of the field's uniform grid.

Why. Where the data of the model have a jump in a third derivative along a coordinate line
(a vanishing factor's band end, `taichi_ndf.boundary.vanishing`: φ is C² and u/φ jumps in its
third derivative there), a cubic spline converges at a reduced and erratic rate set by where
the line falls within a span, unless the line is a knot line (benchmarks/RESULTS.md, issue 33:
the full square plate's band ends at 45 and 55 m, off every dyadic knot line). With the
breakpoints on knots of the coarsest grid, dyadic refinement keeps them knot lines on every
level.

The map. h is the natural cubic spline interpolant of (lo, lo), (b_i, η_i), (hi, hi): C², its
third derivative jumps only at the breakpoints, which are knot lines (the field composed with
it, N(ξ) = S(h(ξ)), then has its own third-derivative jumps only there), h″ = 0 at both ends
(so a mirrored end stays mirrored: the composed field's odd derivatives across it vanish as
S's do), and within each piece h is one cubic, smooth on the scale of the pieces — the
smoothest interpolant (least ∫h″²). (A quintic Hermite map with h″ = 0 at every breakpoint was
measured first: it squeezes the map's curvature into the pieces, and its fourth derivative
then dominates the field's; the plate's errors were larger than the uniform grid's.)

Where the knots go (`knot_lines_for`): the breakpoints sorted, each onto a distinct interior
knot of the grid, in order, the assignment of least Σ Δb log²(Δη/Δb) over the pieces
(dynamic programming: the nearest knots unless two breakpoints compete for one). None where
the grid has too few interior knots, or the interpolant is not monotone.

Pure torch, float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf.field.grading import monotone_inverse

_MONOTONE_SAMPLES = 4001  # points per direction at which h′ > 0 is checked


@dataclass(frozen=True)
class KnotLines:
    """Breakpoints `breaks` (units of ξ, strictly increasing, strictly inside the domain) sent
    onto the knots `knots` (units of ξ, as many, strictly increasing, strictly inside)."""

    breaks: tuple[float, ...]
    knots: tuple[float, ...]

    def __post_init__(self):
        breaks = tuple(float(b) for b in self.breaks)
        knots = tuple(float(k) for k in self.knots)
        if (not breaks or len(breaks) != len(knots)
                or not all(math.isfinite(v) for v in breaks + knots)
                or any(b <= a for a, b in zip(breaks[:-1], breaks[1:], strict=True))
                or any(b <= a for a, b in zip(knots[:-1], knots[1:], strict=True))):
            raise ValueError(f"KnotLines: breaks and knots must be as many (one or more) "
                             f"strictly increasing finite positions, got {self.breaks!r} and "
                             f"{self.knots!r}")
        object.__setattr__(self, "breaks", breaks)
        object.__setattr__(self, "knots", knots)

    @property
    def features(self) -> tuple[float, ...]:
        """The positions in ξ that must lie inside the domain (`SplineConfig`'s check)."""
        return self.breaks + self.knots

    @classmethod
    def of(cls, value) -> KnotLines:
        """A `KnotLines` or its dict (a checkpoint's)."""
        if isinstance(value, KnotLines):
            return value
        if isinstance(value, dict):
            return cls(**value)
        raise ValueError(f"knot lines must be a KnotLines or its dict, got {value!r}")


class KnotLineMap:
    """η = h(ξ) of one direction (module docstring), with h′ and h″, and its inverse.

    lo, hi: the domain of the direction (an open one). ValueError where a breakpoint or knot
    is not strictly inside, or h is not monotone."""

    def __init__(self, lines: KnotLines, lo: float, hi: float):
        x = [lo, *lines.breaks, hi]
        y = [lo, *lines.knots, hi]
        if not (lo < lines.breaks[0] and lines.breaks[-1] < hi
                and lo < lines.knots[0] and lines.knots[-1] < hi):
            raise ValueError(f"KnotLines: breaks {lines.breaks} and knots {lines.knots} must "
                             f"lie strictly inside [{lo}, {hi}]")
        self.lo, self.hi = lo, hi
        self._x = torch.tensor(x, dtype=torch.float64)
        self._y = torch.tensor(y, dtype=torch.float64)
        self._m = _natural_second_derivatives(self._x, self._y)
        samples = torch.linspace(lo, hi, _MONOTONE_SAMPLES, dtype=torch.float64)
        if float(self.jets(samples)[1].min()) <= 0:
            raise ValueError(f"KnotLines: the map sending {lines.breaks} onto {lines.knots} "
                             f"is not monotone on [{lo}, {hi}]")

    def jets(self, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """h, h′, h″ at ξ (N,) float64 (h in units of ξ; h′ dimensionless; h″ 1/ξ). Past the
        ends, h continues as its second-order Taylor polynomial at the end (linear: h″ = 0)."""
        x = xi.to(torch.float64)
        end = x.clamp(self.lo, self.hi)
        i = (torch.searchsorted(self._x, end.contiguous(), right=True) - 1).clamp(
            0, self._x.numel() - 2)
        x0, x1 = self._x[i], self._x[i + 1]
        y0, y1, m0, m1 = self._y[i], self._y[i + 1], self._m[i], self._m[i + 1]
        d = x1 - x0
        a, b = (x1 - end) / d, (end - x0) / d
        h = a * y0 + b * y1 + ((a ** 3 - a) * m0 + (b ** 3 - b) * m1) * d * d / 6
        dh = (y1 - y0) / d + (-(3 * a * a - 1) * m0 + (3 * b * b - 1) * m1) * d / 6
        ddh = a * m0 + b * m1
        past = x - end
        return h + dh * past + ddh * past * past / 2, dh + ddh * past, ddh

    def inverse(self, eta: torch.Tensor) -> torch.Tensor:
        """ξ = h⁻¹(η) (N,) float64, by safeguarded Newton to rounding."""
        return monotone_inverse(self.jets, eta.to(torch.float64), self.lo, self.hi,
                                self.hi - self.lo)


def _natural_second_derivatives(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """h″ at the interpolation points of the natural cubic spline through (x, y)."""
    n = x.numel()
    d = x[1:] - x[:-1]
    slope = (y[1:] - y[:-1]) / d
    m = torch.zeros(n, dtype=torch.float64)
    if n > 2:
        a = torch.zeros(n - 2, n - 2, dtype=torch.float64)
        for k in range(n - 2):
            a[k, k] = (d[k] + d[k + 1]) / 3
            if k > 0:
                a[k, k - 1] = d[k] / 6
            if k < n - 3:
                a[k, k + 1] = d[k + 1] / 6
        m[1:-1] = torch.linalg.solve(a, slope[1:] - slope[:-1])
    return m


def knot_lines_for(breaks, spans: int, lo: float, hi: float) -> KnotLines | None:
    """Knot lines sending the breakpoints (positions in ξ strictly inside (lo, hi)) onto
    distinct interior knots of `spans` uniform spans (module docstring); None where there are
    fewer interior knots than breakpoints, or the map would not be monotone."""
    found = sorted({float(b) for b in breaks if lo < b < hi})
    if not found or len(found) > spans - 1:
        return None
    step = (hi - lo) / spans
    knots = [lo + j * step for j in range(spans + 1)]

    def cost(b0, e0, b1, e1):
        return (b1 - b0) * math.log((e1 - e0) / (b1 - b0)) ** 2

    best = {0: (0.0, ())}  # knot number of the last breakpoint -> (cost, knot numbers)
    previous = lo
    for b in found:
        best = {j: min(((c + cost(previous, knots[i], b, knots[j]), chosen + (j,))
                        for i, (c, chosen) in best.items() if i < j), key=lambda o: o[0])
                for j in range(1, spans) if any(i < j for i in best)}
        previous = b
    _, chosen = min(((c + cost(previous, knots[j], hi, hi), chosen)
                     for j, (c, chosen) in best.items()), key=lambda o: o[0])
    lines = KnotLines(tuple(found), tuple(knots[j] for j in chosen))
    try:
        KnotLineMap(lines, lo, hi)
    except ValueError:
        return None
    return lines

"""Graded knots of a spline field, per direction: a smooth monotone map η = h(ξ) of one
coordinate onto itself, under which the field's uniform knots in η are graded in ξ.

The grading law. A density ρ(ξ) > 0 sets the knot spacing, Δξ ∝ 1/ρ:

    ρ(ξ) = 1 + A Σ_f ε / √(d_f(ξ)² + ε²),

d_f the distance to the feature f (a pin, a point load, a hinged line ...), ε the core [units
of ξ]. Near a feature (d ≪ ε) the spacing is least, about (1 + A) times below the far one;
for ε ≪ d ≪ A ε it grows in proportion to d, so consecutive spans grow by a constant ratio
(a geometric mesh towards a point singularity, as for corner singularities in the
h-version of finite elements); far away it is uniform. The strength A is set so that the
graded part ∫(ρ − 1) takes a given share of the spans (`strength_for`).

The map. R(ξ) = ∫ρ is sampled at the M + 3 Greville points (the knots, for a uniform cubic)
of a cubic B-spline on M spans of the same domain, and h is that spline (Schoenberg's
variation-diminishing approximation of R), scaled so that h(lo) = lo and h(hi) = hi: its
coefficients increase, so h is monotone, and it is C² as every cubic spline is, whatever
the features. Symmetries are those of the density:
- periodic direction (period P): distances wrapped to [−P/2, P/2], ρ is P-periodic and
  h(ξ + P) = h(ξ) + P;
- mirrored end (an even end of the field): the features' mirror images are features too (with
  both ends mirrored, distances wrapped with period 2L), so ρ is even about the end, R odd,
  and h odd about it: h″ = 0 there and the composed field stays even.

A tabulated density (`Grading.density` at the points `Grading.at`, the adaptive loop's,
`taichi_ndf.solve.error_indicator`): ρ(ξ) is the piecewise-linear interpolant of the given
values (constant past the first and last point), added to the features' part; with the same
symmetries (ξ wrapped into a periodic domain, reflected across a mirrored end, so ρ is even
there).

Pure torch, float64: the map is evaluated once per point set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf.field.bspline import basis_matrices

# Spans of the map's cubic spline per direction (it must resolve the core ε: ≥ 8 per ε
# wherever ε ≥ L/64, the finest grid spacing the grading rule uses as a core).
MAP_SPANS = 512
_GAUSS = 8  # Gauss–Legendre nodes per map span for R = ∫ρ


@dataclass(frozen=True)
class Grading:
    """The graded knots of one direction.

    features: positions in ξ (units of ξ) the knots are graded towards, inside the domain
        (may be empty with a tabulated density).
    core: ε (units of ξ), positive: the distance within which the spacing is least.
    strength: A ≥ 0: the spacing at a feature is about (1 + A) times below the far one.
    density, at: a tabulated density (module docstring): values > 0 (relative: only their
        ratios matter) at increasing points `at` in ξ, as many; empty: ρ = 1 + the features'.
    """

    features: tuple[float, ...]
    core: float
    strength: float
    density: tuple[float, ...] = ()
    at: tuple[float, ...] = ()

    def __post_init__(self):
        features = tuple(float(f) for f in self.features)
        density = tuple(float(v) for v in self.density)
        at = tuple(float(x) for x in self.at)
        if len(density) != len(at) or not all(math.isfinite(v) and v > 0 for v in density) \
                or not all(math.isfinite(x) for x in at) \
                or any(b <= a for a, b in zip(at[:-1], at[1:], strict=True)):
            raise ValueError(f"Grading: density must be positive values at as many increasing "
                             f"points, got {self.density!r} at {self.at!r}")
        object.__setattr__(self, "density", density)
        object.__setattr__(self, "at", at)
        if (not features and not density) or not all(math.isfinite(f) for f in features):
            raise ValueError(f"Grading: features must be one or more finite positions, got "
                             f"{self.features!r}")
        object.__setattr__(self, "features", tuple(sorted(set(features))))
        for name in ("core", "strength"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and (value > 0 if name == "core" else value >= 0)):
                sign = "positive" if name == "core" else "non-negative"
                raise ValueError(f"Grading: {name} must be a {sign} number, got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def of(cls, value) -> Grading | None:
        """A `Grading`, its dict (a checkpoint's) or None."""
        if value is None or isinstance(value, Grading):
            return value
        if isinstance(value, dict):
            return cls(**value)
        raise ValueError(f"grading must be a Grading, its dict or None, got {value!r}")


def _images(grading: Grading, lo: float, hi: float, periodic: bool,
            even: tuple[str, ...]) -> tuple[list[float], float | None]:
    """The features with their mirror images and the period of the distance (None: plain)."""
    images = list(grading.features)
    if periodic:
        return images, hi - lo
    if "min" in even and "max" in even:  # mirrored at both ends: period 2L, one image each
        return images + [2 * lo - f for f in grading.features], 2 * (hi - lo)
    if "min" in even:
        images += [2 * lo - f for f in grading.features]
    if "max" in even:
        images += [2 * hi - f for f in grading.features]
    return images, None


def _density_kernel(x: torch.Tensor, images: list[float], period: float | None,
                    core: float) -> torch.Tensor:
    """Σ_f ε / √(d_f² + ε²) at x."""
    total = torch.zeros_like(x)
    for f in images:
        d = x - f
        if period is not None:
            d = d - period * torch.round(d / period)
        total = total + core / torch.sqrt(d * d + core * core)
    return total


def _tabulated(x: torch.Tensor, grading: Grading, lo: float, hi: float, periodic: bool,
               even: tuple[str, ...]) -> torch.Tensor:
    """The tabulated density at x (module docstring): x wrapped (periodic) or reflected
    (mirrored ends) into [lo, hi], then interpolated linearly, constant past the ends."""
    at = torch.tensor(grading.at, dtype=torch.float64)
    values = torch.tensor(grading.density, dtype=torch.float64)
    if at.numel() == 1:
        return values[0].expand_as(x).clone()
    if periodic:  # one wrapped point each side, so the interpolant is periodic
        period = hi - lo
        x = lo + torch.remainder(x - lo, period)
        at = torch.cat((at[-1:] - period, at, at[:1] + period))
        values = torch.cat((values[-1:], values, values[:1]))
    else:
        if "min" in even:
            x = torch.where(x < lo, 2 * lo - x, x)
        if "max" in even:
            x = torch.where(x > hi, 2 * hi - x, x)
    x = x.clamp(float(at[0]), float(at[-1]))
    right = torch.searchsorted(at, x.contiguous()).clamp(1, at.numel() - 1)
    left = right - 1
    t = (x - at[left]) / (at[right] - at[left])
    return values[left] + t * (values[right] - values[left])


def strength_for(features, core: float, share: float, lo: float, hi: float, *,
                 periodic: bool = False, even: tuple[str, ...] = ()) -> float:
    """A such that the graded part of the density, ∫_lo^hi (ρ − 1), is `share` / (1 − share)
    times the uniform part (hi − lo): the graded part then takes `share` of the spans."""
    if not 0 <= share < 1:
        raise ValueError(f"share must be in [0, 1), got {share!r}")
    images, period = _images(Grading(features, core, 0.0), lo, hi, periodic, even)
    nodes, weights = _gauss(4 * MAP_SPANS, lo, hi)
    integral = float((_density_kernel(nodes, images, period, core) * weights).sum())
    return share / (1 - share) * (hi - lo) / integral


def _gauss(spans: int, lo: float, hi: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite Gauss–Legendre nodes and weights on `spans` equal parts of [lo, hi]."""
    import numpy as np

    x, w = np.polynomial.legendre.leggauss(_GAUSS)
    x, w = torch.from_numpy((x + 1) / 2), torch.from_numpy(w / 2)
    step = (hi - lo) / spans
    starts = lo + step * torch.arange(spans, dtype=torch.float64)
    return (starts[:, None] + step * x).reshape(-1), (step * w).repeat(spans)


class GradedMap:
    """η = h(ξ) of one direction (module docstring), with h′ and h″, and its inverse.

    lo, hi: the domain of the direction; periodic: whether it is periodic (period hi − lo);
    even: its mirrored ends among ("min", "max")."""

    def __init__(self, grading: Grading, lo: float, hi: float, *, periodic: bool = False,
                 even: tuple[str, ...] = ()):
        self.grading, self.lo, self.hi, self.periodic = grading, lo, hi, periodic
        images, period = _images(grading, lo, hi, periodic, even)
        m, step = MAP_SPANS, (hi - lo) / MAP_SPANS
        self.step = step
        # R at the Greville points lo + (j − 1)·step, j = 0 … M + 2, R(lo) = 0.
        nodes, weights = _gauss(m + 2, lo - step, hi + step)
        rho = grading.strength * _density_kernel(nodes, images, period, grading.core)
        rho = rho + (_tabulated(nodes, grading, lo, hi, periodic, even) if grading.density
                     else 1.0)
        per_span = (rho * weights).view(m + 2, _GAUSS).sum(dim=1)
        cumulative = torch.cat((torch.zeros(1, dtype=torch.float64), per_span.cumsum(0)))
        cumulative = cumulative - cumulative[1]
        self._coefficients = cumulative
        self._matrices = basis_matrices(3, torch.float64, "cpu")
        # Scale so that h(lo) = lo, h(hi) = hi.
        ends = self._spline(torch.tensor([lo, hi], dtype=torch.float64), 0)
        self._offset, self._scale = float(ends[0]), (hi - lo) / float(ends[1] - ends[0])

    def _spline(self, x: torch.Tensor, order: int) -> torch.Tensor:
        """The order-th derivative of the unscaled spline S at x in [lo, hi] (extrapolated past)."""
        t = (x - self.lo) / self.step
        s = torch.clamp(torch.floor(t), 0, MAP_SPANS - 1).long()
        u = t - s
        out = torch.zeros_like(x)
        for a in range(4):
            row = self._matrices[order, a]
            acc = torch.full_like(x, float(row[3]))
            for k in (2, 1, 0):
                acc = acc * u + float(row[k])
            out = out + self._coefficients[s + a] * acc
        return out / self.step ** order

    def _wrap(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if not self.periodic:
            return x, torch.zeros_like(x)
        period = self.hi - self.lo
        turns = torch.floor((x - self.lo) / period)
        return x - turns * period, turns * period

    def jets(self, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """h, h′, h″ at ξ (N,) float64 (h in units of ξ; h′ dimensionless; h″ 1/ξ). Past an
        open direction's ends, h continues as its second-order Taylor polynomial at the end."""
        x, shift = self._wrap(xi.to(torch.float64))
        end = x.clamp(self.lo, self.hi)
        h = self.lo + self._scale * (self._spline(end, 0) - self._offset) + shift
        dh, ddh = self._scale * self._spline(end, 1), self._scale * self._spline(end, 2)
        past = x - end
        return h + dh * past + ddh * past * past / 2, dh + ddh * past, ddh

    def inverse(self, eta: torch.Tensor) -> torch.Tensor:
        """ξ = g(η) = h⁻¹(η) (N,) float64, by safeguarded Newton to rounding."""
        y, shift = self._wrap(eta.to(torch.float64))
        return monotone_inverse(self.jets, y, self.lo, self.hi, self.step) + shift


def monotone_inverse(jets, y: torch.Tensor, lo: float, hi: float, margin: float
                     ) -> torch.Tensor:
    """ξ (N,) float64 with h(ξ) = y for an increasing map h of [lo, hi] (`jets`: ξ ↦ (h, h′,
    h″)), by Newton safeguarded by a bracket that starts `margin` past the ends (a step
    leaving it bisects), to rounding (|Δξ| ≤ 1e-15 max(1, |lo| + |hi|)). Serves
    `GradedMap` and `field.knot_lines.KnotLineMap`."""
    lo_b, hi_b = torch.full_like(y, lo - margin), torch.full_like(y, hi + margin)
    x = y.clone()
    for _ in range(100):
        h, dh, _ = jets(x)
        r = h - y
        lo_b = torch.where(r < 0, x, lo_b)
        hi_b = torch.where(r > 0, x, hi_b)
        step = x - r / dh
        new = torch.where((step <= lo_b) | (step >= hi_b), (lo_b + hi_b) / 2, step)
        done = bool((new - x).abs().max() <= 1e-15 * max(1.0, abs(hi) + abs(lo)))
        x = new
        if done:
            break
    return x

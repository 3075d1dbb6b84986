"""Jets of the smooth factors φ that vanish on a constrained set, and the jet algebra they need.

All functions work on scalar jets of shape (N, 6, 1) (channel order of `taichi_ndf.jets`).

A constraint set is described by a *level*: s, a signed distance divided by the band width ℓ
(edges, whole lines), or q ≥ 0, a squared distance divided by ℓ² (points, segments, a
held patch's rim). The factor is a polynomial blend of the level that reaches exactly 1 with
zero first and second derivatives at distance ℓ, so it is C² everywhere (C¹ at a patch's
rim) and leaves the field untouched outside the band (unlike a Gaussian mask
1 − exp(−d²/s), which damps it everywhere):

    quadratic vanishing   φ = 1 − (1 − q)³                for q < 1, else 1     (φ ≈ 3 q)
    linear vanishing      φ = (15 s − 10 s³ + 3 s⁵) / 8   for |s| < 1, else sign(s)  (φ ≈ 15 s / 8)
"""

from __future__ import annotations

import torch

from taichi_ndf import jets


def affine(value: torch.Tensor, d1: float, d2: float) -> torch.Tensor:
    """Jet (N, 6, 1) of an affine function with the given values (N,) and constant gradient."""
    out = value.new_zeros(value.shape[0], jets.CHANNELS, 1)
    out[:, jets.VALUE, 0] = value
    out[:, jets.D1, 0] = d1
    out[:, jets.D2, 0] = d2
    return out


def chain(f0: torch.Tensor, f1: torch.Tensor, f2: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
    """Jet of f(a) from the values f(a), f'(a), f''(a) (each (N, 1)) and the jet a (N, 6, 1)."""
    a1, a2 = a[:, jets.D1], a[:, jets.D2]
    return torch.stack(
        (
            f0,
            f1 * a1,
            f1 * a2,
            f2 * a1 * a1 + f1 * a[:, jets.D11],
            f2 * a1 * a2 + f1 * a[:, jets.D12],
            f2 * a2 * a2 + f1 * a[:, jets.D22],
        ),
        dim=1,
    )


def square(a: torch.Tensor) -> torch.Tensor:
    return jets.product(a, a)


def sqrt(a: torch.Tensor) -> torch.Tensor:
    """Jet of √a for a ≥ 0. Where a's value and gradient both vanish the floored value keeps
    f' and f'' finite (they then multiply zeros), so the jet is 0 instead of NaN."""
    floor = 4.0 * torch.finfo(a.dtype).tiny ** (2.0 / 3.0)
    v = a[:, jets.VALUE].clamp_min(floor)
    root = v.sqrt()
    return chain(root, 0.5 / root, -0.25 / (v * root), a)


def beyond(a: torch.Tensor, r: float) -> torch.Tensor:
    """Jet of max(a − r, 0)²: 0 for a ≤ r (C¹; its second derivatives jump at a = r)."""
    s = (a[:, jets.VALUE] - r).clamp_min(0.0)
    return chain(s * s, 2.0 * s, 2.0 * (s > 0).to(s.dtype), a)


def reciprocal(a: torch.Tensor) -> torch.Tensor:
    """Jet of 1/a (a's value must not vanish)."""
    inv = 1.0 / a[:, jets.VALUE]
    return chain(inv, -inv * inv, 2.0 * inv * inv * inv, a)


def quadratic_vanishing(q: torch.Tensor) -> torch.Tensor:
    """φ = 1 − (1 − q)³ (q < 1), 1 beyond: vanishes with its gradient where q = 0."""
    w = (1.0 - q[:, jets.VALUE]).clamp_min(0.0)
    return chain(1.0 - w**3, 3.0 * w**2, -6.0 * w, q)


def linear_vanishing(s: torch.Tensor) -> torch.Tensor:
    """φ = (15 s − 10 s³ + 3 s⁵)/8 (|s| < 1), sign(s) beyond: odd, vanishes linearly at s = 0."""
    c = s[:, jets.VALUE].clamp(-1.0, 1.0)
    c2 = c * c
    return chain(
        c * (15.0 - 10.0 * c2 + 3.0 * c2 * c2) / 8.0,
        1.875 * (1.0 - c2) ** 2,
        -7.5 * c * (1.0 - c2),
        s,
    )


def segment_level(
    eta: torch.Tensor,
    start: tuple[float, float],
    end: tuple[float, float],
    scale: tuple[float, float],
) -> torch.Tensor:
    """Squared approximate distance (N, 6, 1) to the segment start–end in η-coordinates.

    eta: points (N, 2) in the coordinates of `start`/`end`; `scale` = dη/dξ per coordinate.
    Trimmed distance function of Sukumar & Srivastava (2022, CMAME 389, 114333): with f the
    signed distance to the segment's line, L its length, c its midpoint and
    t = (L²/4 − |η − c|²)/L, the level f² + ((√(t² + f⁴) − t)/2)² is smooth away from the two
    end points, equals f² + O(f⁸) next to the segment and grows like the distance squared
    beyond its ends. (At the end points its second derivatives are bounded but not continuous.)
    """
    (a1, a2), (b1, b2) = start, end
    length = ((b1 - a1) ** 2 + (b2 - a2) ** 2) ** 0.5
    n1, n2 = -(b2 - a2) / length, (b1 - a1) / length
    x = affine(eta[:, 0] - 0.5 * (a1 + b1), scale[0], 0.0)
    y = affine(eta[:, 1] - 0.5 * (a2 + b2), 0.0, scale[1])
    f = n1 * x + n2 * y
    t = -(square(x) + square(y)) / length
    t[:, jets.VALUE] += 0.25 * length
    f2 = square(f)
    trim = sqrt(square(t) + square(f2)) - t
    return f2 + 0.25 * square(trim)

"""Self-contact's settings, stiffness rule, resolution limit, edge points and candidate pairs
(issue 30).

The barrier between points of the sheet itself is `taichi_ndf.objective.self_contact`
(the energy, its rules stated there), its step test `taichi_ndf.contact.self_step`; both
find the pairs they act on here (`candidate_pairs`: scipy's cKDTree).

Edge points (`edge_points`): the Gauss points stop short of the chart's edges (by 0.069 of a
span with 4 points per span), so a free edge would carry no self-contact point and could come
closer to the other layer than the offset. Each Gauss point of an outermost row is projected
onto the free edge(s) next to it (ξ^d set to the edge's value; a corner point also onto the
corner), and the point and its projections share its self-contact area equally (k points:
(1 + n₁)(1 + n₂), n_d its projections in direction d), so the total area is unchanged. A
periodic direction has no free edge; a masked chart (`ParameterDomain.inside`) gets none (its
outline is not the rectangle's edges).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

# A step may close at most this fraction of any point's gap (`taichi_ndf.contact.self_step`).
STEP_FRACTION = 0.8
# Default exclusion radius: this × (o + ĝ), the reach of the barrier.
EXCLUSION_FACTOR = 2.0


@dataclass(frozen=True)
class SelfContactConfig:
    """activation: ĝ [m]; offset: o [m] (mid-surface distance at zero gap); stiffness: κ
    [N/m⁵]; exclusion: ρ [m], pairs closer at rest never interact (default EXCLUSION_FACTOR ×
    (o + ĝ)); step_fraction: the most of a gap one step may close; edges: whether the chart's
    free edges carry self-contact points (`edge_points`, module docstring)."""

    activation: float
    offset: float
    stiffness: float
    exclusion: float | None = None
    step_fraction: float = STEP_FRACTION
    edges: bool = True

    def __post_init__(self):
        for name in ("activation", "offset", "stiffness"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"self-contact {name} must be finite and > 0, got {value!r}")
        if self.exclusion is None:
            object.__setattr__(self, "exclusion",
                               EXCLUSION_FACTOR * (self.offset + self.activation))
        reach = self.offset + self.activation
        if not (math.isfinite(self.exclusion) and self.exclusion > reach):
            raise ValueError(f"self-contact exclusion {self.exclusion!r} m must exceed offset + "
                             f"distance = {reach:.4g} m (else neighbours on a flat sheet repel)")
        if not 0 < self.step_fraction < 1:
            raise ValueError(f"self-contact step_fraction must be in (0, 1), got "
                             f"{self.step_fraction!r}")


def default_stiffness(load_per_area: float, activation: float, offset: float) -> float:
    """κ [N/m⁵] whose layer pressure 2π κ D b(g) carries `load_per_area` q [N/m²] at g = ĝ/2
    (`taichi_ndf.objective.self_contact`): b(ĝ/2) = (ĝ/2)² ln 2, D = o + ĝ/2."""
    pressure_per_stiffness = 2 * math.pi * (offset + 0.5 * activation) * (
        0.25 * activation ** 2 * math.log(2.0))
    return load_per_area / pressure_per_stiffness


def hole_radius(spacing: tuple[float, float], quadrature_points: int) -> float:
    """The largest half-diagonal [m] of the cells between neighbouring Gauss points of a grid
    with knot spacing (h1, h2) [m] and `quadrature_points` per span and direction (the
    widest gap: inside a span or across a knot)."""
    nodes = np.polynomial.legendre.leggauss(quadrature_points)[0] * 0.5 + 0.5
    widest = max(float(np.diff(nodes).max(initial=0.0)), float(nodes[0] + 1.0 - nodes[-1]))
    return 0.5 * math.hypot(widest * spacing[0], widest * spacing[1])


@dataclass(frozen=True)
class EdgePoints:
    """The self-contact points on a chart's free edges (module docstring): xi (E, 2), their
    chart-area weights (E,) [ξ units²] (the shared Gauss weight w / k); outer: per direction
    the ξ of the outermost Gauss rows (low, high), None for a periodic direction."""

    xi: torch.Tensor
    weight: torch.Tensor
    outer: tuple

    def shares(self, xi: torch.Tensor) -> torch.Tensor:
        """k (N,): how many points share the area of the Gauss points at ξ (N, 2)."""
        k = torch.ones(len(xi), dtype=xi.dtype, device=xi.device)
        for d, rows in enumerate(self.outer):
            if rows is not None:
                k = k * (1 + sum((xi[:, d] == v).to(xi.dtype) for v in rows))
        return k


def edge_points(xi: torch.Tensor, weight: torch.Tensor, bounds, periodic) -> EdgePoints:
    """The edge points of Gauss points ξ (N, 2) with chart weights (N,) on the rectangle
    `bounds` ((lo1, hi1), (lo2, hi2)) with `periodic` flags (module docstring)."""
    outer = tuple(None if periodic[d] else (float(xi[:, d].min()), float(xi[:, d].max()))
                  for d in range(2))
    options = []  # per direction: (mask of the points projected, the edge's ξ), own first
    for d, rows in enumerate(outer):
        own = [(None, None)]
        if rows is not None:
            own += [(xi[:, d] == v, float(edge)) for v, edge in zip(rows, bounds[d],
                                                                     strict=True)]
        options.append(own)
    share = EdgePoints(xi[:0], weight[:0], outer).shares(xi)
    points, weights = [xi[:0]], [weight[:0]]
    for mask1, edge1 in options[0]:
        for mask2, edge2 in options[1]:
            if mask1 is None and mask2 is None:
                continue
            mask = torch.ones(len(xi), dtype=torch.bool, device=xi.device)
            for m in (mask1, mask2):
                if m is not None:
                    mask = mask & m
            p = xi[mask].clone()
            for d, edge in enumerate((edge1, edge2)):
                if edge is not None:
                    p[:, d] = edge
            points.append(p)
            weights.append(weight[mask] / share[mask])
    return EdgePoints(torch.cat(points), torch.cat(weights), outer)


def candidate_pairs(x: np.ndarray, radius: float, rest: np.ndarray, exclusion: float
                    ) -> np.ndarray:
    """Pairs (P, 2) int64, a < b, of points x (M, 3) [m] within `radius` of each other whose
    rest positions (M, 3) are at least `exclusion` apart."""
    from scipy.spatial import cKDTree  # on first use: not on ndf-sim's solve path (issue 28)

    pairs = cKDTree(x).query_pairs(radius, output_type="ndarray").astype(np.int64)
    if len(pairs):
        apart = np.linalg.norm(rest[pairs[:, 0]] - rest[pairs[:, 1]], axis=1) >= exclusion
        pairs = pairs[apart]
    return pairs.reshape(-1, 2)

"""Line loads: a force per unit length along a curve of the surface (physics.md §4).

A line load acts along a polyline in ξ (an edge of the parameter rectangle is the segment
along it). Its work is Π_line = −λ ∫ q·u dℓ, with q [N/m] a dead load (fixed direction and
magnitude, per unit length of the *reference* curve), λ the load factor and dℓ = |dr/ds| ds
the reference arclength. The integral is evaluated by Gauss–Legendre quadrature on each
segment: each quadrature node becomes a concentrated force q w |dr/ds| at that node, so the
field is evaluated exactly at the nodes (the samples carry them like point loads, before the
point-load samples) and the shell term's point-force work is the line load's work. The
quadrature is exact for the resultant and moment whenever q|dr/ds| and r|dr/ds| are
polynomials of degree < 2·nodes along each segment (a straight edge of a plane: always).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf import jets
from taichi_ndf.checks import finite_vector

Vector3 = tuple[float, float, float]


# Most Gauss–Legendre nodes per segment: numpy's leggauss builds an n × n companion matrix
# (8 n² bytes: 10⁹ nodes ran the fuzz test out of memory while the scene was read), and 24
# nodes already give a circle's resultant to 1e-12.
MAX_NODES = 1000


@dataclass(frozen=True)
class LineLoad:
    """Force per unit reference length `force` [N/m] along the polyline `path` in ξ (two or
    more points, consecutive points distinct), integrated with `nodes` Gauss–Legendre nodes
    per segment (≥ 1)."""

    path: tuple[tuple[float, float], ...]
    force: Vector3
    nodes: int = 8

    def __post_init__(self):
        try:
            points = tuple(finite_vector("line load path point", p, 2, "units of ξ")
                           for p in self.path)
        except TypeError as err:
            raise ValueError(f"line load path must be a list of [ξ¹, ξ²] points, got "
                             f"{self.path!r}") from err
        if len(points) < 2:
            raise ValueError(f"line load path needs at least 2 points, got {len(points)}")
        for a, b in zip(points, points[1:], strict=False):
            if a == b:
                raise ValueError(f"line load path has two equal consecutive points {a}")
        object.__setattr__(self, "path", points)
        object.__setattr__(self, "force", finite_vector("line load force", self.force, 3, "N/m"))
        if (isinstance(self.nodes, bool) or not isinstance(self.nodes, int)
                or not 1 <= self.nodes <= MAX_NODES):
            raise ValueError(f"line load nodes must be an integer in [1, {MAX_NODES}], got "
                             f"{self.nodes!r}")

    def scaled(self, factor: float) -> LineLoad:
        return LineLoad(self.path, tuple(factor * v for v in self.force), self.nodes)


def edge_path(edge: str, bounds, periodic: tuple[bool, bool] = (False, False)
              ) -> tuple[tuple[float, float], tuple[float, float]]:
    """The edge `xi1_min`, `xi1_max`, `xi2_min` or `xi2_max` of the rectangle `bounds` as a
    segment in ξ (in the direction of the other coordinate). periodic: the domain's periodic
    flags; an edge across a periodic coordinate is refused (ValueError): it is the seam, an
    interior line, not an edge."""
    (lo1, hi1), (lo2, hi2) = bounds
    ends = {"xi1_min": ((lo1, lo2), (lo1, hi2)), "xi1_max": ((hi1, lo2), (hi1, hi2)),
            "xi2_min": ((lo1, lo2), (hi1, lo2)), "xi2_max": ((lo1, hi2), (hi1, hi2))}
    if edge not in ends:
        raise ValueError(f"edge must be one of {tuple(ends)}, got {edge!r}")
    k = 0 if edge.startswith("xi1") else 1
    if periodic[k]:
        raise ValueError(f"edge {edge!r}: ξ{k + 1} is periodic, so the domain has no such edge "
                         "(for a load along the seam give it as a path)")
    return ends[edge]


def quadrature(surface, line_loads, *, dtype: torch.dtype, device=None
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """The line loads' quadrature nodes ξ (Q, 2) and the concentrated force q w |dr/ds| [N]
    (Q, 3) at each node (in the order of the loads, their segments and nodes)."""
    xi_parts, force_parts = [], []
    for load in line_loads:
        s, w = np.polynomial.legendre.leggauss(load.nodes)
        s = torch.tensor((s + 1) / 2, dtype=dtype, device=device)    # nodes on [0, 1]
        w = torch.tensor(w / 2, dtype=dtype, device=device)
        q = torch.tensor(load.force, dtype=dtype, device=device)
        for a, b in zip(load.path, load.path[1:], strict=False):
            a = torch.tensor(a, dtype=dtype, device=device)
            delta = torch.tensor(b, dtype=dtype, device=device) - a
            xi = a + s[:, None] * delta
            r = surface.jets(xi).to(dtype)
            # |dr/ds| [m]: the reference arclength per unit of the segment parameter s
            speed = (r[:, jets.D1] * delta[0] + r[:, jets.D2] * delta[1]).norm(dim=1)
            xi_parts.append(xi)
            force_parts.append((w * speed)[:, None] * q)
    if not xi_parts:
        empty = torch.zeros(0, 2, dtype=dtype, device=device)
        return empty, torch.zeros(0, 3, dtype=dtype, device=device)
    return torch.cat(xi_parts), torch.cat(force_parts)

"""Folded coordinates: the field evaluated at m(ξ) so that its derivative across a symmetry
edge vanishes there exactly.

A symmetry plane makes the in-plane displacement components even across the plane: their
derivative across the edge vanishes while their value is free. That is not of the form φ N (a
factor fixes values, not slopes alone), so the raw field is evaluated at folded coordinates
m(ξ) = (m₁(ξ¹), m₂(ξ²)) with m_k' = 0 on each folded edge of coordinate k; every component of
N∘m then has zero derivative across the edge, and the odd components get a linearly vanishing
factor on top (`BoundaryConditions`). With s = (ξ − lo)/L, L = hi − lo, each m_k maps
[lo, hi] onto itself, monotonically:

    edge at min:  m = lo + L s²           edge at max:  m = lo + L (2s − s²)
    both edges:   m = lo + L (3s² − 2s³)   no edge:      m = ξ

A smooth even function of the distance d to the plane is a smooth function of d², so N∘m
loses nothing the symmetric solution needs. The pull-back of jets is linear in the raw jets
and needs only their first and second derivatives (chain rule, m separable):

    (N∘m)_,1 = m₁' N_,1    (N∘m)_,11 = m₁'² N_,11 + m₁'' N_,1    (N∘m)_,12 = m₁' m₂' N_,12

so per point u still depends on the raw jets at that point's own evaluation point m(ξ) only.
"""

from __future__ import annotations

import torch

from taichi_ndf.geometry import ParameterDomain


class Fold:
    """Folded coordinates of a domain. ends: per coordinate, the folded edges among
    {"min", "max"} (both empty: the identity)."""

    def __init__(self, domain: ParameterDomain, ends: tuple[frozenset[str], frozenset[str]]):
        self.domain = domain
        self.ends = tuple(frozenset(e) for e in ends)
        for e in self.ends:
            if not e <= {"min", "max"}:
                raise ValueError(f"fold ends must be among 'min', 'max', got {sorted(e)}")

    @classmethod
    def of_edges(cls, domain: ParameterDomain, edges) -> Fold:
        """The fold of the named edges (`xi1_min`, ...); ValueError if one repeats."""
        edges = list(edges)
        if len(set(edges)) != len(edges):
            raise ValueError(f"two symmetry planes on the same edge: {sorted(edges)}")
        ends = tuple(frozenset(e.split("_")[1] for e in edges if e.startswith(f"xi{k + 1}"))
                     for k in range(2))
        return cls(domain, ends)

    @property
    def edge_ends(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """The folded ends per coordinate as ordered tuples ("min" before "max")."""
        return tuple(tuple(e for e in ("min", "max") if e in side) for side in self.ends)

    @property
    def active(self) -> bool:
        return any(self.ends)

    def _map(self, xi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """m(ξ) (N, 2), m' (N, 2) and m'' (N, 2) per coordinate."""
        values, first, second = [], [], []
        for k, ends in enumerate(self.ends):
            lo, hi = self.domain.bounds[k]
            length = hi - lo
            s = (xi[:, k] - lo) / length
            one = torch.ones_like(s)
            if ends == {"min"}:
                m, d1, d2 = s * s, 2 * s, 2 * one
            elif ends == {"max"}:
                m, d1, d2 = 2 * s - s * s, 2 - 2 * s, -2 * one
            elif ends:
                m, d1, d2 = 3 * s * s - 2 * s**3, 6 * s * (1 - s), 6 - 12 * s
            else:
                m, d1, d2 = s, one, 0 * one
            values.append(lo + length * m)
            first.append(d1)
            second.append(d2 / length)
        return (torch.stack(values, dim=1), torch.stack(first, dim=1),
                torch.stack(second, dim=1))

    def _rates(self, xi: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """m₁', m₂', m₁'', m₂'' at ξ, each (N, 1) (to broadcast over components)."""
        _, first, second = self._map(xi)
        return first[:, :1], first[:, 1:], second[:, :1], second[:, 1:]

    def points(self, xi: torch.Tensor) -> torch.Tensor:
        """Where the raw field is evaluated: m(ξ) (N, 2)."""
        return self._map(xi)[0] if self.active else xi

    def pullback(self, xi: torch.Tensor, raw: torch.Tensor) -> torch.Tensor:
        """Jets (N, 6, C) at ξ of N∘m from the raw jets (N, 6, C) at m(ξ)."""
        if not self.active:
            return raw
        a, b, da, db = self._rates(xi)
        f0, f1, f2, f11, f12, f22 = raw.unbind(1)
        return torch.stack((f0, a * f1, b * f2, a * a * f11 + da * f1, a * b * f12,
                            b * b * f22 + db * f2), dim=1)

    def pullback_adjoint(self, xi: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
        """Gradient (N, 6, C) with respect to the raw jets of <grad, pullback(ξ, raw)>."""
        if not self.active:
            return grad
        a, b, da, db = self._rates(xi)
        g0, g1, g2, g11, g12, g22 = grad.unbind(1)
        return torch.stack((g0, a * g1 + da * g11, b * g2 + db * g22, a * a * g11,
                            a * b * g12, b * b * g22), dim=1)

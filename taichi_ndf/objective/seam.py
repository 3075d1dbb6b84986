"""A seam joining two edge segments of the chart, as a penalty term with pair couplings.

For the seam of a `SeamSpec` (`taichi_ndf.problem.seams`), the point ξ_A(s) of segment A is
joined to ξ_B(s) of segment B (s ∈ [0, 1] the fraction along each, B run backwards where
reversed), at Gauss points s_g of the seam's quadrature (equal parts × Gauss–Legendre nodes),
with weights w_g = ŵ_g |dr_A/ds| [m] (reference arclength along A):

    Π_seam = ½ Σ_g w_g ( k_x |x_A − x_B|² + k_d |d_A + d_B|² ),    x = r + u,
    d = x_,n / |r_,n|        (n the edge's outward unit normal in ξ, x_,n = n₁ x_,1 + n₂ x_,2:
                              on an edge of the parameter rectangle n = σ e_ν, ν the
                              coordinate across it, σ = −1 on a *_min edge, +1 on a *_max one;
                              d is the outward tangent across the edge per unit reference
                              length).

A side is a path in ξ at constant speed (`segment_path`): part of an edge of the parameter
rectangle (`EdgeSegment`) or an edge of a panel's outline (`problem.outline.PolygonEdge`: a
segment, or an arc, `problem.arcs.Arc`), so s is the fraction of its arclength on both sides,
and a straight edge sewn to an arc of the same length is sewn by arclength; the normal n and
dξ/ds are taken at each point.

(a) Positions: x_A = x_B (r + u, so a seam between edges apart at rest pulls them together:
the sewing; over load steps λ ∈ [0, 1] the ties are to (1 − λ) times their rest values, so a
continuation closes a seam that is open at rest gradually, and from λ = 1 on it is closed; a
seam whose sides coincide at rest is unchanged by λ). (b) Bending transmitted (k_d > 0): the
outward across-seam tangent of one side equals the inward one of the other, d_A = −d_B. With
the positions tied, the along-seam tangents agree too, so x is C¹ across the seam in the
joined chart: the displacement is in H², the space the Kirchhoff–Love energy (second
derivatives) is defined on, and any smooth solution (a periodic one above all: x and x_,ν
continuous across the wrap) satisfies both ties at zero penalty, so as k grows the seamed
minimiser tends to the smooth one. This ties the whole across tangent (its stretch too), not
only the normal: a stronger tie than G¹, exact for a chart that continues with the same
reference speed across the seam (a cut-open cylinder or annulus, two panels of one surface);
an edge pair that differs in direction at rest (a cylinder sector sewn shut) is sewn with a
hinge. Hinge (k_d = 0): positions only, the two sides turn freely about the seam.

Stiffness, scaled with the material: k_x = β D / h [N/m²] and k_d = β D h [N] = k_x h², D
the membrane stiffness (`small_strain_stiffness`) [N/m], h = L / segments [m] the seam's
segment length, β the spec's penalty factor (default `DEFAULT_PENALTY`): a gap of δ over one
segment then costs β times the membrane energy of stretching the segment by δ. The penalty's
error (the gap and the change of Π) falls as 1/β (tests/test_seam.py).

Π_seam is quadratic in u: its gradient and its pair blocks (`coupled_hessian`) are exact. The
term acts on zero-weight samples at its points: `with_seam_points` appends them to a
quadrature, and the term finds them among the samples it is given by their ξ (any order: an
`Assembly` reorders its samples), refusing samples that lack them.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable

import torch

from taichi_ndf import jets
from taichi_ndf.objective.couplings import Couplings
from taichi_ndf.problem.quadrature import gauss_legendre
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.problem.seams import LENGTH_TOLERANCE, EdgeSegment, SeamSpec, segment_path

_CHANNEL = (jets.D1, jets.D2)  # the jet channel of ∂/∂ξ¹, ∂/∂ξ²


class SeamTerm:
    """The seam of `spec` on `surface` for `material` (module docstring); surface_b: the
    surface of side B where it is another patch's (default `surface`). Raises ValueError
    naming the seam and the edge for an edge across a periodic coordinate, a range outside
    the edge, and reference lengths of A and B differing by more than `LENGTH_TOLERANCE`
    (relative)."""

    def __init__(self, spec: SeamSpec, surface, material, *, surface_b=None,
                 dtype=torch.float64):
        self.spec = spec
        surface_b = surface if surface_b is None else surface_b
        self.blocks: tuple[slice, slice] | None = None  # `between`
        for side, side_surface in ((spec.a, surface), (spec.b, surface_b)):
            if not isinstance(side, EdgeSegment):  # a polygon edge: a segment of its own
                continue
            domain = side_surface.domain
            bounds = domain.bounds
            if domain.periodic[side.across]:
                raise ValueError(f"seam {spec.name!r}: edge {side.edge!r} is on a periodic "
                                 f"coordinate ξ{side.across + 1}: the surface has no such edge")
            if side.span is not None:
                lo, hi = bounds[1 - side.across]
                if not all(lo - 1e-12 * (hi - lo) <= v <= hi + 1e-12 * (hi - lo)
                           for v in side.span):
                    raise ValueError(f"seam {spec.name!r}: edge {side.edge!r}: range "
                                     f"{list(side.span)} is outside [{lo}, {hi}]")
        nodes, weights = gauss_legendre(spec.nodes)
        parts = torch.arange(spec.segments, dtype=torch.float64)
        s = ((parts[:, None] + nodes) / spec.segments).reshape(-1)
        w = (weights / spec.segments).repeat(spec.segments)
        xi_a, run_a, normal_a = segment_path(spec.a, surface.domain.bounds, s)
        xi_b, run_b, normal_b = segment_path(spec.b, surface_b.domain.bounds,
                                             s if spec.orientation == "same" else 1 - s)
        r_a = surface.jets(xi_a).to(torch.float64)
        r_b = surface_b.jets(xi_b).to(torch.float64)
        speed_a = _along(r_a, run_a).norm(dim=1)
        speed_b = _along(r_b, run_b).norm(dim=1)
        length_a, length_b = float((w * speed_a).sum()), float((w * speed_b).sum())
        if abs(length_a - length_b) > LENGTH_TOLERANCE * max(length_a, length_b):
            raise ValueError(f"seam {spec.name!r}: edge {spec.a.edge!r} is {length_a:.6g} m "
                             f"long and edge {spec.b.edge!r} {length_b:.6g} m (more than "
                             f"{LENGTH_TOLERANCE:g} relative apart)")
        self.length = length_a
        self.spacing = length_a / spec.segments  # h [m]
        membrane = float(material.small_strain_stiffness()[0])
        self.position_stiffness = spec.penalty * membrane / self.spacing  # k_x [N/m²]
        self.tangent_stiffness = (spec.penalty * membrane * self.spacing
                                  if spec.bending == "transmitted" else 0.0)  # k_d [N]
        self.xi = torch.cat((xi_a, xi_b)).to(dtype)
        self.r_jets = torch.cat((r_a, r_b)).to(dtype)
        self.weight = (w * speed_a).to(dtype)  # w_g [m]
        # c_A, c_B (M, 2): d = c₁ x_,1 + c₂ x_,2 = x_,n / |r_,n|, n the outward normal in ξ
        self.scale = tuple((n / _along(r, n).norm(dim=1)[:, None]).to(dtype)
                           for n, r in ((normal_a, r_a), (normal_b, r_b)))
        self._rows_of: tuple[torch.Tensor, torch.Tensor] | None = None

    def points(self, side: int | None = None) -> SurfaceSamples:
        """The seam's points as zero-weight samples: A's Gauss points, then B's (side 0 or 1:
        one side's only)."""
        xi, r = self.xi, self.r_jets
        if side is not None:
            count = xi.shape[0] // 2
            xi, r = xi[side * count:(side + 1) * count], r[side * count:(side + 1) * count]
        zeros = xi.new_zeros(xi.shape[0])
        return SurfaceSamples(xi, r, zeros, xi.new_zeros(len(zeros), 3))

    def between(self, a: slice, b: slice) -> SeamTerm:
        """This seam with side A's points looked for in the sample rows `a` only and B's in
        `b` (two patches whose ξ overlap, one after the other in the samples)."""
        term = copy.copy(self)
        term.blocks, term._rows_of = (a, b), None
        return term

    def rows(self, samples: SurfaceSamples) -> torch.Tensor:
        """Row numbers (M, 2) of each Gauss point's A and B point in `samples` (found by ξ;
        remembered for the last samples given). Raises ValueError if any is missing."""
        if self._rows_of is not None and self._rows_of[0] is samples.xi:
            return self._rows_of[1]
        xi = self.xi.to(samples.xi).reshape(2, -1, 2)
        scale = float(samples.xi.abs().max()) + 1.0
        found = []
        for side, block in zip(xi, self.blocks or (slice(None),) * 2, strict=True):
            among = samples.xi[block]
            distance, rows = torch.cdist(side, among,
                                         compute_mode="donot_use_mm_for_euclid_dist").min(dim=1)
            if bool((distance > 1e-9 * scale).any()):
                raise ValueError(f"seam {self.spec.name!r}: its points are not among the "
                                 "samples (a quadrature without `with_seam_points`)")
            found.append(rows + (block.start or 0))
        pairs = torch.stack(found, dim=1)
        self._rows_of = (samples.xi, pairs)
        return pairs

    def _ties(self, samples: SurfaceSamples, u_jets: torch.Tensor, load_factor=1.0):
        """The rows, the position gap and the tangent tie (M, 3) less the sewing's share
        (1 − λ) of their rest values, and the tangent factors c_A, c_B."""
        if isinstance(load_factor, torch.Tensor):
            raise ValueError(f"seam {self.spec.name!r}: takes one load factor, not one per "
                             "sample")
        pairs = self.rows(samples)
        open_ = 1.0 - min(max(float(load_factor), 0.0), 1.0)
        ca, cb = (c.to(u_jets) for c in self.scale)
        ties = []
        for x in (samples.r_jets + u_jets, samples.r_jets):
            xa, xb = x[pairs[:, 0]], x[pairs[:, 1]]
            ties.append((xa[:, jets.VALUE] - xb[:, jets.VALUE],
                         _across(ca, xa) + _across(cb, xb)))
        (gap, tie), (gap0, tie0) = ties
        if open_:
            gap, tie = gap - open_ * gap0.to(gap), tie - open_ * tie0.to(tie)
        return pairs, gap, tie, ca, cb

    def gaps(self, samples: SurfaceSamples, u_jets: torch.Tensor) -> torch.Tensor:
        """|x_A − x_B| (M,) [m] at the seam's Gauss points."""
        return self._ties(samples, u_jets, 1.0)[1].norm(dim=1)

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float | torch.Tensor = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """Π_seam [J] and dΠ_seam/du_jets (N, 6, 3) (not scaled by the load factor: a seam
        is part of the garment, not a load; the load factor only sews, module docstring)."""
        pairs, gap, tie, ca, cb = self._ties(samples, u_jets, load_factor)
        w = self.weight.to(u_jets)
        kx, kd = self.position_stiffness, self.tangent_stiffness
        value = 0.5 * float((w * (kx * (gap * gap).sum(1) + kd * (tie * tie).sum(1))).sum())
        if not grad:
            return value, None
        gradient = torch.zeros_like(u_jets)
        force = kx * w[:, None] * gap
        gradient[:, jets.VALUE].index_add_(0, pairs[:, 0], force)
        gradient[:, jets.VALUE].index_add_(0, pairs[:, 1], -force)
        if kd:
            moment = kd * w[:, None] * tie
            for k, channel in enumerate(_CHANNEL):
                gradient[:, channel].index_add_(0, pairs[:, 0], ca[:, k, None] * moment)
                gradient[:, channel].index_add_(0, pairs[:, 1], cb[:, k, None] * moment)
        return value, gradient

    def coupled_hessian(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                        load_factor: float | torch.Tensor = 1.0) -> Couplings:
        """The pair blocks (exact: Π_seam is quadratic): k_x w [[I, −I], [−I, I]] on the value
        channels, k_d w c cᵀ ⊗ I on the across channels, c = (c_A, c_B)."""
        pairs = self.rows(samples)
        count = pairs.shape[0]
        w = self.weight.to(u_jets)
        eye = torch.eye(3, dtype=u_jets.dtype, device=u_jets.device)
        blocks = u_jets.new_zeros(count, 2, jets.CHANNELS, 3, 2, jets.CHANNELS, 3)
        spring = self.position_stiffness * w[:, None, None] * eye
        for a in range(2):
            for b in range(2):
                blocks[:, a, jets.VALUE, :, b, jets.VALUE, :] = spring if a == b else -spring
        if self.tangent_stiffness:
            c = [s.to(u_jets) for s in self.scale]
            for a in range(2):
                for b in range(2):
                    for i, ci in enumerate(_CHANNEL):
                        for j, cj in enumerate(_CHANNEL):
                            blocks[:, a, ci, :, b, cj, :] += self.tangent_stiffness * (
                                w * c[a][:, i] * c[b][:, j])[:, None, None] * eye
        size = 2 * 3 * jets.CHANNELS
        return Couplings(pairs, blocks.reshape(count, size, size))


def _along(r_jets: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """r_,1 v₁ + r_,2 v₂ (M, 3): the derivative of the jets along ξ-directions v (M, 2)."""
    return (r_jets[:, _CHANNEL[0]] * direction[:, :1]
            + r_jets[:, _CHANNEL[1]] * direction[:, 1:])


def _across(c: torch.Tensor, x_jets: torch.Tensor) -> torch.Tensor:
    """c₁ x_,1 + c₂ x_,2 (M, 3) for per-point factors c (M, 2)."""
    return c[:, :1] * x_jets[:, _CHANNEL[0]] + c[:, 1:] * x_jets[:, _CHANNEL[1]]


def with_seam_points(samples: SurfaceSamples, terms: Iterable) -> SurfaceSamples:
    """`samples` followed by the points of every `SeamTerm` among `terms` (zero weight, no
    force: only the seams act there)."""
    for term in terms:
        if isinstance(term, SeamTerm):
            samples = samples.joined(_like(term.points(), samples))
    return samples


def seam_points(terms: Iterable) -> int:
    """How many points `with_seam_points` appends after the samples for `terms`."""
    return sum(len(term.points()) for term in terms if isinstance(term, SeamTerm))


def _like(points: SurfaceSamples, samples: SurfaceSamples) -> SurfaceSamples:
    """`points` in the dtype and on the device of `samples`."""
    to = dict(dtype=samples.xi.dtype, device=samples.xi.device)
    return SurfaceSamples(points.xi.to(**to), points.r_jets.to(**to), points.weight.to(**to),
                          points.point_force.to(**to))

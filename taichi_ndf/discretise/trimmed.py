"""Trimmed quadrature: a spline over an outline's bounding box (or any rectangle holding it)
integrated over the outline only (a polygon panel, `taichi_ndf.problem.outline.Outline`;
issue 30).

The outline is cut into triangles once (ear clipping: it is simple and counter-clockwise),
and each triangle is clipped to every knot span's rectangle it overlaps (Sutherland–Hodgman:
a triangle against a rectangle is a convex piece, so there are no degenerate bridge edges,
which clipping the non-convex outline itself to a span would give where the span cuts it in
two). Per span:

- a span the outline covers (the pieces' area within `FULL` of the span's, relative) gets
  the span's own tensor Gauss–Legendre points (`span_points`: (p + 1)² points, the
  untrimmed rule, exact to degree 2p + 1 in each coordinate; so an outline that is the
  rectangle gives the rectangle's points exactly);
- a span the outline cuts gets, per piece, a fan of triangles and on each the collapsed
  (Duffy) Gauss rule with (p + 2)² points, positive weights that add up to the triangle's
  area, exact for polynomials of total degree ≤ 2p + 2 (cubic: 8, which covers the flat
  panel's linearised bending stiffness, products of second derivatives, total degree
  4p − 4 ≤ 2p + 2 for p ≤ 3, and the gravity load, degree 2p);
- a span outside the outline gets none.

Curved edges (`taichi_ndf.problem.arcs`): each arc is cut at every knot line it crosses and
into pieces of at most `ARC_ANGLE`, so each piece lies in one span (`_lenses`). The polygon
that is ear-clipped and clipped as above has a piece's chord where it bulges outward and the
two tangents at its ends where it is cut in (their meeting point T lies on the panel's side);
each piece then adds its lens, the circular segment beyond the chord or the region between
the tangents and the arc, integrated in the span the piece lies in by the fan from an apex
that sees the arc (the chord's midpoint, or T): x = apex + s (c(t) − apex), Gauss–Legendre
with p + 2 points in s (exact in s, as the triangle rule is) and `ARC_POINTS` in t along the
arc (spectrally accurate: polynomials of degree ≤ 7 on a disc and a half disc to 1e-13,
tests/test_curved_outline.py). All weights are positive (so Newton's projected point blocks
stay those of an energy), and an outline without arcs gets the points it had.

Graded knots (`SplineConfig.grading`; a garment's `[field] grading = "seam_corners"`): the
spans are those between the knots mapped back to ξ (`span_knots`), a whole span gets the
graded Gauss points of `span_points`, a cut span the same triangle rule in ξ; the field is a
polynomial in η, not in ξ, so neither rule is then exact (polynomials to about 1e-9 relative,
tests/test_garment_outline.py).

Coefficients whose basis function is zero at every quadrature point (support outside the
outline) have no stiffness: `TrimmedGrid` holds them at zero (added to the grid's held
unknowns), so Newton's matrix has no zero rows (measured, benchmarks/RESULTS.md "Garments:
polygon panels": left free, the damped solve still reached the same Π, to 4e-12, in 9–12
Newton iterations against 7). A coefficient whose support only grazes the outline keeps a
small stiffness (the known ill-conditioning of trimmed splines: mass diagonal down to 2e-6 of
the largest there); nothing stabilises it.

A mesh's own UV chart that does not fill its rectangle (a shape-from-template template whose
UVs were projected from a first frame) is the other trimmed domain: `sheet_quadrature` puts one
point per mesh triangle there (and the span Gauss points where the chart is the rectangle).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.geometry import MeshSurface
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.problem.arcs import fan_weights
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.outline import Outline
from taichi_ndf.problem.polygon import clip_to_box, cross, ear_clip, polygon_area
from taichi_ndf.problem.quadrature import gauss_legendre, span_points
from taichi_ndf.problem.sampling import SurfaceSamples, with_point_loads
from taichi_ndf.shell.hessian import COMPONENTS

# A span whose covered area is within this fraction of its own is integrated as a whole span.
FULL = 1e-9
# Curved edges: the largest angle [rad] of an arc's pieces (`_lenses`), and the Gauss points
# along each piece.
ARC_ANGLE = math.pi / 4
ARC_POINTS = 10


def triangle_rule(points: int) -> tuple[np.ndarray, np.ndarray]:
    """The collapsed Gauss rule on the reference triangle (0, 0), (1, 0), (0, 1): barycentric
    coordinates (u, v) (points², 2) and weights (points²,) adding up to ½, exact for total
    degree ≤ 2 points − 2."""
    nodes, weights = (t.numpy() for t in gauss_legendre(points))
    s, t = np.meshgrid(nodes, nodes, indexing="ij")
    ws, wt = np.meshgrid(weights, weights, indexing="ij")
    uv = np.stack(((s * (1 - t)).ravel(), (s * t).ravel()), axis=1)
    return uv, (ws * wt * s).ravel()


def span_knots(config: SplineConfig) -> tuple[np.ndarray, np.ndarray]:
    """The knots (n + 1,) [units of ξ] of each direction of `config`'s domain: uniform, or
    graded (the uniform knots in η mapped back to ξ, `SplineConfig.grading`)."""
    knots = []
    for (lo, _), n, h, graded in zip(config.domain, config.spans, config.spacing,
                                     config.graded_maps(), strict=True):
        eta = lo + h * torch.arange(n + 1, dtype=torch.float64)
        knots.append((eta if graded is None else graded.inverse(eta)).numpy())
    return knots[0], knots[1]


def _pieces(outline: Outline, config: SplineConfig, max_angle: float
            ) -> tuple[dict[tuple[int, int], list], dict[tuple[int, int], list]]:
    """The convex pieces (point lists) of the outline's straight part in each knot span
    (i, j) (`span_knots`), and per span the lenses its arcs add (`_lenses`)."""
    k1, k2 = span_knots(config)
    n1, n2 = config.spans
    polygon, lenses = _lenses(outline, (k1.tolist(), k2.tolist()), max_angle)
    pieces: dict[tuple[int, int], list] = {}
    for corners in (tuple(polygon[i] for i in tri) for tri in ear_clip(polygon)):
        if abs(cross(*corners)) <= 1e-14 * (k1[-1] - k1[0]) * (k2[-1] - k2[0]):
            continue
        xs, ys = [c[0] for c in corners], [c[1] for c in corners]
        i0 = max(0, min(n1 - 1, int(np.searchsorted(k1, min(xs), side="right")) - 1))
        i1 = max(0, min(n1 - 1, int(np.searchsorted(k1, max(xs), side="left")) - 1))
        j0 = max(0, min(n2 - 1, int(np.searchsorted(k2, min(ys), side="right")) - 1))
        j1 = max(0, min(n2 - 1, int(np.searchsorted(k2, max(ys), side="left")) - 1))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                box = ((k1[i], k1[i + 1]), (k2[j], k2[j + 1]))
                piece = clip_to_box(corners, box)
                if len(piece) >= 3:
                    pieces.setdefault((i, j), []).append(piece)
    by_span: dict[tuple[int, int], list] = {}
    for apex, arc in lenses:
        mid = arc.at(np.array([0.5]))[0]
        i = max(0, min(n1 - 1, int(np.searchsorted(k1, mid[0], side="right")) - 1))
        j = max(0, min(n2 - 1, int(np.searchsorted(k2, mid[1], side="right")) - 1))
        by_span.setdefault((i, j), []).append((apex, arc))
    return pieces, by_span


def _lenses(outline: Outline, cuts, max_angle: float) -> tuple[list, list]:
    """The outline's straight part and what its arcs add. Each arc is cut at the knot lines
    `cuts` and into pieces of at most `max_angle` (`Outline.flattened`), so each piece lies in
    one span. A piece bulging outward (θ > 0) adds the circular segment beyond its chord, swept
    from the chord's midpoint; one bulging inward (θ < 0) is replaced in the polygon by the two
    tangents at its ends, which meet at T = o + R e(ψ_mid) / cos(θ/2) on the panel's side, and
    adds the region between them and the arc, swept from T. Both regions are seen from their
    apex, so their weights are positive. Returns the polygon (points) and the lenses (apex
    (2,), arc piece)."""
    flat, owners = outline.flattened(max_angle, cuts)
    polygon, lenses = [], []
    for point, (_, arc) in zip(flat, owners, strict=True):
        polygon.append(point)
        if arc is None:
            continue
        if arc.angle > 0:
            lenses.append((0.5 * (np.asarray(arc.start) + np.asarray(arc.end)), arc))
            continue
        mid = arc.start_angle + 0.5 * arc.angle
        tangent = arc.centre + arc.radius / math.cos(0.5 * arc.angle) * np.array(
            [math.cos(mid), math.sin(mid)])
        polygon.append((float(tangent[0]), float(tangent[1])))
        lenses.append((tangent, arc))
    return polygon, lenses


def trimmed_points(outline: Outline, config: SplineConfig
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Quadrature points ξ (N, 2) [m] and weights (N,) [m²] of the outline on the knot spans
    of `config` (module docstring; graded knots: the spans between `span_knots`, a whole
    span's points those of `span_points`), float64, span by span (ξ¹ span major). Raises
    ValueError for a grid whose domain does not hold the outline's bounding box or is
    periodic."""
    if not all(lo - 1e-12 * (hi - lo) <= b_lo and b_hi <= hi + 1e-12 * (hi - lo)
               for (lo, hi), (b_lo, b_hi) in zip(config.domain, outline.bounds, strict=True)):
        # (to rounding: an arc that meets a side of the box, e.g. a held patch's rim)
        raise ValueError(f"the panel's grid {config.domain} does not hold its outline's "
                         f"bounding box {outline.bounds}")
    if any(config.periodic):
        raise ValueError("a trimmed panel needs an open grid")
    k1, k2 = span_knots(config)
    n1, n2 = config.spans
    full_xi, full_w = span_points(config)
    per_span = full_xi.shape[0] // (n1 * n2)
    uv, tw = triangle_rule(config.degree + 2)
    s_rule = tuple(t.numpy() for t in gauss_legendre(config.degree + 2))
    t_rule = tuple(t.numpy() for t in gauss_legendre(ARC_POINTS))
    xi, weight = [], []
    pieces_of, lenses_of = _pieces(outline, config, ARC_ANGLE)
    for (i, j) in sorted(set(pieces_of) | set(lenses_of)):
        pieces = pieces_of.get((i, j), [])
        lenses = [fan_weights(apex, arc, s_rule, t_rule) for apex, arc in lenses_of.get((i, j), [])]
        areas = [polygon_area(p) for p in pieces] + [float(w.sum()) for _, w in lenses]
        span_area = (k1[i + 1] - k1[i]) * (k2[j + 1] - k2[j])
        if abs(sum(areas) - span_area) <= FULL * span_area:
            span = slice((i * n2 + j) * per_span, (i * n2 + j + 1) * per_span)
            xi.append(full_xi[span].numpy())
            weight.append(full_w[span].numpy())
            continue
        for lens_xi, lens_w in lenses:
            xi.append(lens_xi)
            weight.append(lens_w)
        for piece in pieces:
            a = np.asarray(piece[0])
            for k in range(1, len(piece) - 1):
                b, c = np.asarray(piece[k]), np.asarray(piece[k + 1])
                twice = cross(a, b, c)
                if twice <= 1e-14 * span_area:
                    continue
                xi.append(a + uv[:, :1] * (b - a) + uv[:, 1:] * (c - a))
                weight.append(tw * twice)
    return (torch.from_numpy(np.concatenate(xi)), torch.from_numpy(np.concatenate(weight)))


def trimmed_quadrature(surface, outline: Outline, config: SplineConfig,
                       loads: Loads | None = None, *, dtype: torch.dtype = torch.float64
                       ) -> SurfaceSamples:
    """The samples of `trimmed_points` on `surface` (its chart the outline's plane), with the
    loads' line- and point-load samples (`with_point_loads`)."""
    xi, weight = trimmed_points(outline, config)
    if loads is not None:
        loads.check_domain(surface.domain)
    return with_point_loads(surface, xi.to(dtype), weight.to(dtype), loads)


def sheet_quadrature(surface: MeshSurface, config: SplineConfig, *, points: int | None,
                     dtype: torch.dtype) -> SurfaceSamples:
    """Samples of an energy over a mesh's own UV chart (`MeshSurface`: a shape-from-template
    template; the prior of `inverse.sft.spline_prior`), float `dtype`.

    A chart that fills its rectangle (synthetic sheets) gets Gauss–Legendre points on the knot
    spans (exact for the spline). A chart that does not (UVs found by projecting a template into
    its first frame: a tilted, perspective-distorted quadrilateral) would leave the spans cut by
    its outline integrated only where their Gauss points fall inside, and a strip along the
    outline where no energy acts: on φ-SfT's R1 the free edge, about one span from the
    rectangle's side, let its vertices zigzag in depth by up to 0.4 m over 50 frames. There one
    point per template triangle (its centroid in ξ, weight its ξ-area) covers the sheet up to
    its outline.
    """
    if surface.domain.inside is None:
        return GridLinearisation.quadrature(surface, config, points=points, dtype=dtype)
    corners = surface.uv.numpy()[surface.faces.numpy()]  # (F, 3, 2)
    edge1, edge2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = 0.5 * np.abs(edge1[:, 0] * edge2[:, 1] - edge1[:, 1] * edge2[:, 0])
    xi = torch.from_numpy(corners.mean(axis=1)).to(dtype)
    return with_point_loads(surface, xi, torch.from_numpy(area).to(dtype), None)


def unsupported(grid: GridLinearisation, xi: torch.Tensor) -> np.ndarray:
    """The coefficients (sorted) of `grid`'s field whose basis function is zero at all of ξ
    (N, 2): their support misses the quadrature points."""
    index = grid.at_points(xi, 1.0).index  # the basis functions nonzero at each point
    return np.setdiff1d(np.arange(grid.field.config.num_coefficients),
                        torch.unique(index).cpu().numpy())


class TrimmedGrid(GridLinearisation):
    """A `GridLinearisation` of a trimmed panel: its held unknowns also hold the coefficients
    with no support on its quadrature points `xi` (N, 2) at zero (`unsupported`)."""

    def __init__(self, field, boundary, xi: torch.Tensor, **kwargs):
        super().__init__(field, boundary, **kwargs)
        outside = unsupported(self, xi)
        self.unsupported = (outside[:, None] * COMPONENTS + np.arange(COMPONENTS)).reshape(-1)

    @property
    def fixed(self) -> np.ndarray | None:
        held = super().fixed
        if not self.unsupported.size:
            return held
        return self.unsupported if held is None else np.union1d(held, self.unsupported)


def patch_grid(patch, field, *, dtype: torch.dtype = torch.float64
               ) -> tuple[GridLinearisation, SurfaceSamples]:
    """A garment panel's (`problem.multipatch.Patch`) grid and quadrature: over its chart's
    knot spans (`GridLinearisation.quadrature`), or for a polygon panel (an outline) its
    `TrimmedGrid` and `trimmed_quadrature`."""
    model = patch.model
    length = math.sqrt(model.surface.domain.rectangle_area)
    if patch.outline is None:
        return (GridLinearisation(field, model.boundary, length=length),
                GridLinearisation.quadrature(model.surface, patch.config, model.loads,
                                             dtype=dtype))
    points = trimmed_quadrature(model.surface, patch.outline, patch.config, model.loads,
                                dtype=dtype)
    return TrimmedGrid(field, model.boundary, points.xi, length=length), points

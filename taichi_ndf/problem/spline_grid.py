"""The knot grid of a spline field for a scene: the grid rule and the coarse-to-fine plan.

Grid rule (`span_length = "auto"`, the one used by every validation case in
benchmarks/spline_newton.py): knot spans of physical size at most
min(L_long / 8, √(R_min h), ℓ_min L_short), with L_long, L_short the longer and shorter side of
the surface, R_min its least principal radius of curvature, h the shell thickness (√(R h) is the
bending boundary-layer length of a curved shell) and ℓ_min the narrowest vanishing band of the
boundary conditions (a fraction of the domain extent, `BoundaryConditions.narrowest_band`): the
Gauss points of one span must resolve the ramp of a vanishing factor (a clamped strip on spans
five times its band found energies far below the true minimum, from quadrature error alone).
The band term binds none of the validation cases (their bands are ≥ 1.3 spans wide), but it
does bind the napkin variants with edges and handles (ℓ = 0.1: 10 spans per side). A given
span length L gives ⌈length_i / L⌉ spans per direction, along a periodic direction rounded up
to a multiple of the order of the concentrated loads' symmetry (`load_symmetry`: two opposite
loads on a cylinder, an even count), so that symmetric loads meet a symmetric grid.

Graded knots (`[field] grading = "features"`, `graded_config`): the same spans, graded per
direction towards the model's known singular features (`singular_features`: point pins and
handles, point loads, interior lines along a coordinate and the ends of interior segments, line
loads along a coordinate and their ends), by the law of `taichi_ndf.field.grading` with the core
ε one span of the grid (the scale the uniform grid resolves; the least span is then about
(1 + A)⁻¹ of it) and the graded part taking GRADED_SHARE of the spans (the other half stays
uniform for the smooth far field). The unknowns are those of the uniform grid.

Knot lines on the band ends (`[field] band_end_knots`, opt-in, `band_end_config`): an
edge's vanishing factor that ends inside the domain (band ℓ < 1,
`band_ends`) leaves u/φ with a third-derivative jump along a coordinate
line; the knots of a uniform direction are moved onto those lines by the map of
`taichi_ndf.field.knot_lines` (each onto a distinct knot of the coarsest grid, so dyadic
refinement keeps it a knot line). The full square plate's band ends at 45 and 55 m: on
8² … 128², the centre deflection's changes fall at orders 3.06, 3.95, 4.16 with the rule
against −5.53, 3.19, 1.32 without (benchmarks/RESULTS.md, issue 33). Not the default: the
moved knot (up to half a span) costs accuracy on coarse grids — the hinged strip on a
foundation (tests/test_foundation.py, 16 spans) 1.2 → 1.7 % largest error, napkin_fold's Π
+32 % on its 32 × 8 (a different fold). A direction graded towards features keeps its grading
(one map per direction); a periodic one has no edges.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import torch

from taichi_ndf import jets
from taichi_ndf.boundary.constraints import (
    ClampedEdge,
    Handle,
    HingedEdge,
    InteriorLine,
    PinnedPoint,
    RimRotation,
    SymmetryPlane,
)
from taichi_ndf.boundary.gauges import gauge_points
from taichi_ndf.field import SplineConfig
from taichi_ndf.field.grading import Grading, strength_for
from taichi_ndf.field.knot_lines import KnotLines, knot_lines_for

log = logging.getLogger(__name__)

SPANS_PER_SIDE = 8
GRADINGS = ("uniform", "features")  # [field] grading
GRADED_SHARE = 0.5  # the share of the spans the grading puts near the features


@dataclass(frozen=True)
class SplinePlan:
    """A spline field solved coarse to fine: `config` is the coarsest grid, each of the
    `levels` grids refines the previous one dyadically; quadrature_points: Gauss–Legendre
    points per span and direction (None: degree + 1)."""

    config: SplineConfig
    levels: int = 1
    quadrature_points: int | None = None

    def __post_init__(self):
        if isinstance(self.levels, bool) or not isinstance(self.levels, int) or self.levels < 1:
            raise ValueError(f"levels must be an integer >= 1, got {self.levels!r}")
        q = self.quadrature_points
        if q is not None and (isinstance(q, bool) or not isinstance(q, int) or q < 1):
            raise ValueError(f"quadrature_points must be an integer >= 1, got {q!r}")

    def finest(self) -> SplineConfig:
        config = self.config
        for _ in range(self.levels - 1):
            config = config.refined()
        return config

    def to_dict(self) -> dict:
        return {"type": "spline", **self.config.to_dict(), "levels": self.levels,
                "quadrature_points": self.quadrature_points}


def surface_scales(surface, thickness: float) -> tuple[tuple[float, float], float]:
    """Mean physical lengths of the two coordinate directions [m] and √(R_min h) [m]
    (infinite for a flat surface), from the reference jets on a 33 × 33 grid."""
    (lo1, hi1), (lo2, hi2) = surface.domain.bounds
    g1, g2 = torch.meshgrid(torch.linspace(lo1, hi1, 33, dtype=torch.float64),
                            torch.linspace(lo2, hi2, 33, dtype=torch.float64), indexing="ij")
    r = surface.jets(torch.stack((g1.ravel(), g2.ravel()), dim=1)).double()
    a1, a2 = r[:, jets.D1], r[:, jets.D2]
    lengths = (float(a1.norm(dim=1).mean()) * (hi1 - lo1),
               float(a2.norm(dim=1).mean()) * (hi2 - lo2))
    normal = torch.linalg.cross(a1, a2)
    normal = normal / normal.norm(dim=1, keepdim=True).clamp_min(1e-300)
    b = torch.stack([(r[:, c] * normal).sum(dim=1) for c in (jets.D11, jets.D12, jets.D22)], 1)
    metric = torch.stack(((a1 * a1).sum(1), (a1 * a2).sum(1), (a2 * a2).sum(1)), dim=1)

    def sym(m):
        return torch.stack((torch.stack((m[:, 0], m[:, 1]), -1),
                            torch.stack((m[:, 1], m[:, 2]), -1)), -2)

    ok = torch.isfinite(b).all(dim=1) & (torch.linalg.det(sym(metric)) > 1e-12)
    shape_operator = torch.linalg.solve(sym(metric)[ok], sym(b)[ok])
    curvature = float(torch.linalg.eigvals(shape_operator).abs().max())
    bending = math.inf if curvature < 1e-12 else math.sqrt(thickness / curvature)
    return lengths, bending


def auto_span_length(surface, thickness: float, band: float | None = None) -> float:
    """The grid rule's span length [m] (module docstring); band: ℓ_min or None."""
    lengths, bending = surface_scales(surface, thickness)
    length = min(max(lengths) / SPANS_PER_SIDE, bending)
    return length if band is None else min(length, band * min(lengths))


def spans_for(surface, span_length: float, loads=None) -> tuple[int, int]:
    """Knot spans per direction of spans at most `span_length` [m] long; with `loads`, a
    periodic direction's count rounded up to a multiple of the loads' symmetry order along it
    (`load_symmetry`), so that the grid maps onto itself wherever the loads do."""
    if not (math.isfinite(span_length) and span_length > 0):
        raise ValueError(f"span_length must be a positive length [m], got {span_length!r}")
    lengths, _ = surface_scales(surface, 1.0)
    spans = [max(1, math.ceil(length / span_length - 1e-9)) for length in lengths]
    if loads is not None:
        spans = [m * math.ceil(n / m) for n, m in zip(spans, load_symmetry(surface, loads),
                                                     strict=True)]
    return tuple(spans)


def load_symmetry(surface, loads) -> tuple[int, int]:
    """Per direction, the order m of the concentrated loads' symmetry along a periodic
    coordinate: the largest m for which a shift of ξ_d by period / m maps the point loads
    (position and size of the force) and the vertices of the line loads' paths (with the size
    of their force per length) onto themselves; 1 for an open direction or without such loads
    (distributed loads are uniform along the surface and never break a shift). The pinched
    cylinder's two opposite loads have m = 2: on the grid rule's 63 spans around, the two load
    points moved 2.8 % apart."""
    marks = [(p.xi, math.hypot(*p.force)) for p in loads.point_loads]
    marks += [(xi, math.hypot(*line.force)) for line in loads.line_loads for xi in line.path]
    orders = []
    for d, (lo, hi) in enumerate(surface.domain.bounds):
        if not surface.domain.periodic[d] or not marks:
            orders.append(1)
            continue
        period, other = hi - lo, 1 - d
        tol = 1e-9 * period

        def same(a, b, d=d, other=other, period=period, tol=tol):
            gap = (a[0][d] - b[0][d]) % period
            return (min(gap, period - gap) <= tol and abs(a[0][other] - b[0][other]) <= tol
                    * max(1.0, abs(a[0][other])) and math.isclose(a[1], b[1], rel_tol=1e-9))

        def maps(m, d=d, period=period, same=same):
            shifted = [((*(x + period / m if k == d else x for k, x in enumerate(xi)),), f)
                       for xi, f in marks]
            return all(any(same(a, b) for b in marks) for a in shifted)

        orders.append(max(m for m in range(1, len(marks) + 1) if maps(m)))
    return tuple(orders)


def grid_spans(surface, thickness: float, band: float | None = None, loads=None
               ) -> tuple[int, int]:
    """The grid rule's spans (module docstring; `loads`: `spans_for`)."""
    return spans_for(surface, auto_span_length(surface, thickness, band), loads)


def singular_features(boundary, loads, domain, gauges=()
                      ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per direction, the coordinates ξ_d where the model has a known singular feature: point
    pins and handles (both coordinates), point loads (both), an interior line or line-load
    segment along a coordinate line ξ_d = c (c along d), the ends of an interior segment and
    of a line load's path (both coordinates); a line load along an edge, and its ends on an
    edge, give none (a loaded edge is a boundary condition, not a singular point). gauges:
    pinned points that carry no reaction (`boundary.gauges.gauge_points`: they only remove
    rigid motions under self-equilibrated loads), no feature. Periodic coordinates wrapped
    into the domain; oblique whole lines give nothing (a tensor-product grading cannot follow
    them)."""
    points: list[tuple[float, float]] = []
    lines: list[tuple[int, float]] = []
    for c in boundary.constraints:
        if any(c is g for g in gauges):
            continue
        if isinstance(c, PinnedPoint | Handle):
            points.append(tuple(c.xi))
        elif isinstance(c, InteriorLine):
            _segment(c.start, c.end, lines)
            if not c.extend:
                points += [tuple(c.start), tuple(c.end)]
    for p in loads.point_loads:
        points.append(tuple(p.xi))
    for line in loads.line_loads:  # an edge load is a boundary condition: no feature
        for a, b in zip(line.path[:-1], line.path[1:], strict=True):
            _segment(a, b, lines, domain)
        points += [tuple(xi) for xi in (line.path[0], line.path[-1])
                   if not _on_edge(xi, domain)]
    features: list[list[float]] = [[], []]
    for xi in points:
        for d in range(2):
            features[d].append(xi[d])
    for d, c in lines:
        features[d].append(c)
    out = []
    for d, (lo, hi) in enumerate(domain.bounds):
        wrapped = [lo + (f - lo) % (hi - lo) if domain.periodic[d] else min(max(f, lo), hi)
                   for f in features[d]]
        out.append(tuple(sorted({min(max(round(f, 12), lo), hi) for f in wrapped})))
    return tuple(out)


def no_singular_feature(model, gauges=None) -> bool:
    """Whether the model has no known singular feature: no `singular_features` (pins but the
    gauges — `gauge_points(model)` where None —, handles, point loads, interior lines,
    line-load ends), no obstacles (contact regions) and no further energy terms (seams join
    points; a term unknown here counts as a feature). Such a model's Π converges at the
    a-priori order of the field's degree (`minimise.extrapolation`, `richardson(...,
    smooth=True)`); corner singularities of the boundary conditions are not known here, so
    the rule also asks the observed order to reach the a-priori one."""
    if model.contact is not None or model.terms:
        return False
    gauges = gauge_points(model) if gauges is None else gauges
    features = singular_features(model.boundary, model.loads, model.surface.domain, gauges)
    return not any(features)


def _segment(a, b, lines: list[tuple[int, float]], domain=None) -> None:
    """A segment along a coordinate line ξ_d = c adds (d, c); with `domain`, not along an
    edge."""
    for d in range(2):
        if a[d] == b[d] and not (domain is not None and not domain.periodic[d]
                                 and a[d] in domain.bounds[d]):
            lines.append((d, float(a[d])))


def _on_edge(xi, domain) -> bool:
    """Whether ξ lies on an edge of the domain (an end of an open direction)."""
    return any(not domain.periodic[d] and xi[d] in domain.bounds[d] for d in range(2))


def graded_config(config: SplineConfig, boundary, loads, domain, *,
                  share: float = GRADED_SHARE, gauges=()) -> SplineConfig:
    """`config` with its knots graded towards the model's singular features
    (`singular_features`, its gauge points left out; module docstring), a direction without
    features uniform (its knot lines on band ends kept). The map stays with the refined grids
    (the core is one span of `config`, its coarsest)."""
    features = singular_features(boundary, loads, domain, gauges)
    if not any(features):
        log.warning("grading = \"features\": the model has no pin, point load or interior "
                    "line along a coordinate to grade towards; the knots stay uniform")
    else:
        log.info("knots graded towards ξ¹ = %s, ξ² = %s", features[0] or "none",
                 features[1] or "none")
    return graded_towards(config, features, share=share)


def graded_towards(config: SplineConfig, features, *, share: float = GRADED_SHARE
                   ) -> SplineConfig:
    """`config` with its knots graded per direction towards `features` (a tuple of positions
    in ξ per direction; empty: that direction uniform, its knot lines kept), by the law of
    `taichi_ndf.field.grading` with the core one span of `config` and the graded part taking
    `share` of the spans (module docstring)."""
    grading = []
    for d, ((lo, hi), found) in enumerate(zip(config.domain, features, strict=True)):
        if not found:  # uniform, but the band ends' knot lines stay (`band_end_config`)
            kept = config.grading[d]
            grading.append(kept if isinstance(kept, KnotLines) else None)
            continue
        core = (hi - lo) / config.spans[d]
        strength = strength_for(found, core, share, lo, hi, periodic=config.periodic[d],
                                even=config.even_ends[d])
        grading.append(Grading(tuple(found), core, strength))
    return dataclasses.replace(config, grading=tuple(grading))


EDGE_CONSTRAINTS = (ClampedEdge, HingedEdge, RimRotation, SymmetryPlane)


def band_ends(boundary) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per direction, the coordinates ξ_d [units of ξ] where an edge's vanishing factor ends
    inside the domain (its band ℓ < 1, at ℓ of the extent from the edge,
    `BoundaryConditions`): the factor is C² there and u/φ jumps in its third derivative, so
    a spline converges at its full order only if that line is a knot line."""
    ends: list[set[float]] = [set(), set()]
    for c in boundary.constraints:
        if not isinstance(c, EDGE_CONSTRAINTS):
            continue
        ell = boundary.length if c.length is None else float(c.length)
        if ell >= 1:
            continue
        k = 0 if c.edge.startswith("xi1") else 1
        lo, hi = boundary.domain.bounds[k]
        fraction = ell if c.edge.endswith("min") else 1 - ell
        ends[k].add(round(lo + fraction * (hi - lo), 12))
    return tuple(tuple(sorted(e)) for e in ends)


def band_end_config(config: SplineConfig, boundary) -> SplineConfig:
    """`config` with the knots of each uniform open direction moved onto the band ends of
    `boundary` (`band_ends`, module docstring), each onto a distinct knot
    of `config` (`knot_lines_for`); a direction graded already, periodic, without band ends,
    with its band ends on knots already, or with too few knots for them (then logged) stays
    as it is."""
    grading = list(config.grading)
    for d, ends in enumerate(band_ends(boundary)):
        if not ends or config.grading[d] is not None or config.periodic[d]:
            continue
        lo, hi = config.domain[d]
        step = (hi - lo) / config.spans[d]
        if all(abs(e - lo - step * round((e - lo) / step)) <= 1e-9 * step for e in ends):
            continue  # on knot lines already
        lines = knot_lines_for(ends, config.spans[d], lo, hi)
        if lines is None:
            log.info("band ends ξ%d = %s: %d spans have no monotone knot map onto them; the "
                     "knots stay uniform", d + 1, ends, config.spans[d])
            continue
        log.info("knot lines ξ%d = %s moved onto the band ends %s", d + 1, lines.knots,
                 lines.breaks)
        grading[d] = lines
    return dataclasses.replace(config, grading=tuple(grading))

"""Constraints resolved against a parameter domain: each constraint's set in normalised
coordinates η ∈ [0, 1]², its band length and the components it prescribes, with the checks
that it fits the domain and does not contradict another constraint
(`taichi_ndf.boundary.conditions` builds the vanishing factors from them)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf.boundary.constraints import (
    COMPONENTS,
    ClampedEdge,
    Constraint,
    Handle,
    HingedEdge,
    InteriorLine,
    PinnedPoint,
    RimRotation,
    SymmetryPlane,
)
from taichi_ndf.boundary.segments import (
    Segment,
    clip_to_unit_square,
    points_along,
    segment_distance,
)
from taichi_ndf.geometry import ParameterDomain, ReferenceSurface

# Distance (in η) below which two constraint sets count as touching.
_TOUCH_TOL = 1e-9

_EDGE_SETS = {
    "xi1_min": ((0.0, 0.0), (0.0, 1.0)),
    "xi1_max": ((1.0, 0.0), (1.0, 1.0)),
    "xi2_min": ((0.0, 0.0), (1.0, 0.0)),
    "xi2_max": ((0.0, 1.0), (1.0, 1.0)),
}

@dataclass(frozen=True)
class ResolvedConstraint:
    """A constraint resolved against the domain."""

    constraint: Constraint
    length: float
    where: tuple[Segment, ...]  # the constrained set in η, points as zero-length segments
    prescribes: frozenset[int]  # components (0, 1, 2) with a non-zero prescribed displacement
    radius: float = 0.0  # the set is every point within radius (η) of `where` (a held patch)

    @property
    def linear(self) -> bool:
        """Whether the factor vanishes linearly (odd, changes sign across the set)."""
        con = self.constraint
        return (isinstance(con, (HingedEdge, SymmetryPlane))
                or (isinstance(con, InteriorLine) and con.hinged))

    @property
    def components(self) -> frozenset[int]:
        return frozenset(COMPONENTS.index(c) for c in self.constraint.components)


def to_eta(domain: ParameterDomain, xi: tuple[float, float]) -> tuple[float, float]:
    """Normalised coordinates η = (ξ − lo)/(hi − lo) of a point."""
    (lo1, _), (lo2, _) = domain.bounds
    l1, l2 = domain.lengths
    return ((xi[0] - lo1) / l1, (xi[1] - lo2) / l2)


def _inside(domain: ParameterDomain, points: list[tuple[float, float]]) -> torch.Tensor:
    return domain.contains(torch.tensor(points, dtype=torch.float64))


def resolve(con: Constraint, domain: ParameterDomain, surface: ReferenceSurface | None,
            length: float, frame=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
            ) -> ResolvedConstraint:
    """The constraint resolved against the domain (its set in η, band, prescribed
    components along the axes of `frame`, rows e_x, e_y, e_z); ValueError naming the problem
    if it does not fit the domain."""
    frame = np.asarray(frame, dtype=np.float64)
    name = type(con).__name__
    ell = length if con.length is None else float(con.length)
    prescribes: frozenset[int] = frozenset()
    if isinstance(con, (ClampedEdge, HingedEdge, RimRotation, SymmetryPlane)):
        k = 0 if con.edge.startswith("xi1") else 1
        if domain.periodic[k]:
            raise ValueError(
                f"{name} on edge {con.edge!r}: ξ{k + 1} is periodic, so the domain has no "
                "such edge (a periodic direction needs no boundary condition)"
            )
        where = (_EDGE_SETS[con.edge],)
    elif ell >= 0.5:
        raise ValueError(
            f"{name}: band length {ell} must be below 0.5 for a point or line (its distance "
            "is taken to the nearest periodic image); only edges take wider bands"
        )
    elif isinstance(con, (PinnedPoint, Handle)):
        if not bool(_inside(domain, [con.xi])[0]):
            raise ValueError(f"{name} at ξ={con.xi} lies outside the parameter domain")
        p = to_eta(domain, con.xi)
        where = ((p, p),)
        if isinstance(con, Handle) and ell + con.radius >= 0.5:
            raise ValueError(
                f"Handle: radius {con.radius} plus band length {ell} must be below 0.5 (the "
                "distance is taken to the nearest periodic image)")
    elif isinstance(con, InteriorLine):
        where = (_resolve_line(con, domain, ell),)
    else:
        raise TypeError(f"unknown constraint type {type(con).__name__}")

    if isinstance(con, SymmetryPlane):
        _check_symmetry_plane(con, domain, surface, frame[COMPONENTS.index(con.normal)])
    if isinstance(con, RimRotation):
        if surface is None:
            raise ValueError("RimRotation needs the reference surface: pass surface=...")
        if con.angle != 0.0:
            prescribes = _turned(con.axis, con.components, frame)
    elif isinstance(con, (ClampedEdge, HingedEdge, Handle)):
        displacement = frame @ np.asarray(con.displacement, dtype=np.float64)
        size = float(np.abs(displacement).max())
        prescribes = frozenset(
            COMPONENTS.index(c)
            for c in con.components
            if abs(displacement[COMPONENTS.index(c)]) > 1e-14 * size
        )
        if any(getattr(con, "turn", ())):
            if surface is None:
                raise ValueError("Handle: a turn needs the reference surface: pass surface=...")
            prescribes = prescribes | _turned(con.turn, con.components, frame)
    return ResolvedConstraint(constraint=con, length=ell, where=where, prescribes=prescribes,
                              radius=float(getattr(con, "radius", 0.0)))


def _turned(axis, components: str, frame: np.ndarray) -> frozenset[int]:
    """The components (of `components`, along the frame's axes) that a rotation about `axis`
    (3,) moves: the row c of R − I vanishes for every angle only if the axis is along c."""
    axis = frame @ (np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis))
    return frozenset(COMPONENTS.index(c) for c in components
                     if abs(abs(axis[COMPONENTS.index(c)]) - 1.0) > 1e-14)


def _check_symmetry_plane(con: SymmetryPlane, domain: ParameterDomain,
                          surface: ReferenceSurface | None, normal: np.ndarray) -> None:
    """ValueError unless the edge lies in a plane normal to `normal` (the world direction of
    `con.normal`) and the surface crosses it at right angles (its tangent across the edge
    along the normal)."""
    if surface is None:
        raise ValueError("SymmetryPlane needs the reference surface: pass surface=...")
    start, end = (_from_eta(domain, p) for p in _EDGE_SETS[con.edge])
    r = surface.jets(torch.tensor(points_along(start, end), dtype=torch.float64))
    normal = torch.as_tensor(normal, dtype=torch.float64)
    across = r[:, 1 if con.edge.startswith("xi1") else 2]   # tangent across the edge
    speed = across.norm(dim=1)
    size = float((r[:, 0] - r[:, 0].mean(dim=0)).norm(dim=1).max() + speed.max())
    height = r[:, 0] @ normal
    spread = float(height.max() - height.min())
    tilt = float(((speed - (across @ normal).abs()) / speed).max())
    if spread > 1e-9 * size or tilt > 1e-9:
        raise ValueError(
            f"SymmetryPlane on edge {con.edge!r}: the edge must lie in a plane normal to "
            f"{con.normal} and the surface must cross it at right angles (spread of "
            f"{con.normal} along the edge {spread:.3g} m, tangent across it off the normal by "
            f"{tilt:.3g})")


def _resolve_line(con: InteriorLine, domain: ParameterDomain, ell: float) -> Segment:
    a, b = to_eta(domain, con.start), to_eta(domain, con.end)
    periodic = domain.periodic
    if con.extend:
        axis_parallel = a[0] == b[0] or a[1] == b[1]
        if any(periodic) and not axis_parallel:
            raise ValueError(
                f"InteriorLine through {con.start} and {con.end}: on a domain with a periodic "
                "coordinate a whole line must be parallel to a coordinate axis"
            )
        for k in range(2):
            # The line crosses the periodic coordinate k when it is normal to it.
            if periodic[k] and a[k] == b[k] and con.hinged:
                raise ValueError(
                    f"InteriorLine through {con.start} and {con.end}: a hinged line across "
                    f"the periodic coordinate ξ{k + 1} is impossible (a smooth periodic φ "
                    "changes sign an even number of times); use hinged=False"
                )
        clipped = clip_to_unit_square(a, b)
        if clipped is None:
            raise ValueError(
                f"InteriorLine through {con.start} and {con.end} misses the domain"
            )
        if domain.inside is not None:
            probes = points_along(_from_eta(domain, clipped[0]), _from_eta(domain, clipped[1]))
            if not bool(_inside(domain, probes).any()):
                raise ValueError(
                    f"InteriorLine through {con.start} and {con.end} misses the domain's mask"
                )
        return clipped
    probes = points_along(con.start, con.end)
    if not bool(_inside(domain, probes).all()):
        raise ValueError(
            f"InteriorLine from {con.start} to {con.end} leaves the parameter domain"
        )
    for k in range(2):
        if periodic[k] and abs(b[k] - a[k]) + 2 * ell >= 1.0:
            raise ValueError(
                f"InteriorLine from {con.start} to {con.end}: with its band (length {ell}) it "
                f"spans the whole period of ξ{k + 1}; use extend=True for a closed line"
            )
    return (a, b)


def _from_eta(domain: ParameterDomain, eta: tuple[float, float]) -> tuple[float, float]:
    (lo1, _), (lo2, _) = domain.bounds
    l1, l2 = domain.lengths
    return (lo1 + l1 * eta[0], lo2 + l2 * eta[1])


def check_contradictions(terms: tuple[ResolvedConstraint, ...], domain: ParameterDomain) -> None:
    """ValueError if a prescribed displacement's set touches another constraint's set on the
    same component."""
    for i, first in enumerate(terms):
        for second in terms[i + 1 :]:
            shared = first.components & second.components
            if not shared & (first.prescribes | second.prescribes):
                continue
            gap = _distance(domain, first.where, second.where) - first.radius - second.radius
            if gap <= _TOUCH_TOL:
                comps = "".join(COMPONENTS[c] for c in sorted(shared))
                raise ValueError(
                    f"contradictory constraints on component(s) {comps!r}: "
                    f"{first.constraint} and {second.constraint} meet, and at least one "
                    "prescribes a displacement there"
                )


def check_symmetry_planes(terms: tuple[ResolvedConstraint, ...],
                          domain: ParameterDomain) -> None:
    """ValueError if another constraint's factor on a component that a symmetry plane keeps
    even varies across the plane: u_c = φ N_c(m(ξ)) has zero derivative across the edge only
    if φ does too. Edges of the other coordinate (φ varies along the plane only) are fine;
    any other set must stay at least its band length away from the plane."""
    for plane in terms:
        if not isinstance(plane.constraint, SymmetryPlane):
            continue
        edge = plane.constraint.edge
        even = frozenset(range(3)) - plane.components
        for other in terms:
            shared = other.components & even
            if other is plane or not shared:
                continue
            con = other.constraint
            if (isinstance(con, (ClampedEdge, HingedEdge, RimRotation, SymmetryPlane))
                    and con.edge[:3] != edge[:3]):
                continue
            gap = _distance(domain, other.where, plane.where) - other.radius
            if gap < other.length - 1e-12:
                comps = "".join(COMPONENTS[c] for c in sorted(shared))
                raise ValueError(
                    f"symmetry plane on edge {edge!r}: the band of {type(con).__name__} on "
                    f"component(s) {comps!r} reaches the plane (distance {gap:.3g} < length "
                    f"{other.length:.3g}, fractions of the domain extent), so those components "
                    "would not be even there; shorten its length or move it away")


def _distance(domain: ParameterDomain, first: tuple[Segment, ...],
              second: tuple[Segment, ...]) -> float:
    shifts = [
        (s1, s2)
        for s1 in ((-1, 0, 1) if domain.periodic[0] else (0,))
        for s2 in ((-1, 0, 1) if domain.periodic[1] else (0,))
    ]
    best = math.inf
    for p, q in first:
        for r, s in second:
            for d1, d2 in shifts:
                shifted = ((r[0] + d1, r[1] + d2), (s[0] + d1, s[1] + d2))
                best = min(best, segment_distance((p, q), shifted))
    return best

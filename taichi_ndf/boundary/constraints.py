"""Boundary constraints: what is held, where, and which displacement components it acts on.

These are plain, validated data. Positions ξ are surface coordinates of the reference
surface's parameter domain; displacements are Cartesian [m]. Whether a constraint fits its
domain (inside it, not on a periodic "edge", not contradicting another constraint) is checked
by `BoundaryConditions`, which knows the domain.

Every constraint has an optional `length`: the width of the band around its set in which the
vanishing factor φ rises from 0 to 1, as a fraction of the domain's extent (see
`taichi_ndf.boundary.conditions`). None means the `BoundaryConditions` default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from taichi_ndf.checks import finite_vector

EDGES = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")
COMPONENTS = "xyz"
PIN_ROTATIONS = ("held", "free")


def _check_components(owner: str, components: str) -> str:
    if (
        not isinstance(components, str)
        or not components
        or any(c not in COMPONENTS for c in components)
        or len(set(components)) != len(components)
    ):
        raise ValueError(
            f"{owner}: components must be a non-empty selection of distinct letters from "
            f"'xyz', got {components!r}"
        )
    return "".join(c for c in COMPONENTS if c in components)


def _check_edge(owner: str, edge: str) -> None:
    if edge not in EDGES:
        raise ValueError(f"{owner}: edge must be one of {EDGES}, got {edge!r}")


def _check_length(owner: str, length: float | None, *, edge: bool = False) -> None:
    """Edge bands may be as wide as wanted (ℓ ≥ 1 makes φ one polynomial over the whole
    domain); point and line bands stay below 0.5, since their distance is taken to the nearest
    periodic image, which is not smooth half a period away."""
    limit = math.inf if edge else 0.5
    if length is not None and not (
        isinstance(length, (int, float)) and math.isfinite(length) and 0 < length < limit
    ):
        bound = "positive" if edge else "in (0, 0.5)"
        raise ValueError(
            f"{owner}: length is a fraction of the domain extent, {bound}, got {length!r}"
        )


def _set(obj, name: str, value) -> None:
    object.__setattr__(obj, name, value)


@dataclass(frozen=True)
class ClampedEdge:
    """An edge of the parameter rectangle held in position and rotation (φ vanishes
    quadratically), optionally moved rigidly by `displacement` [m] at t = 1 (linear in t)."""

    edge: str
    components: str = "xyz"
    displacement: tuple[float, float, float] = (0.0, 0.0, 0.0)
    length: float | None = None

    def __post_init__(self):
        _check_edge("ClampedEdge", self.edge)
        _set(self, "components", _check_components("ClampedEdge", self.components))
        _set(
            self,
            "displacement",
            finite_vector("ClampedEdge: displacement", self.displacement, 3, "m"),
        )
        _check_length("ClampedEdge", self.length, edge=True)


@dataclass(frozen=True)
class HingedEdge:
    """A simply supported edge: position held, rotation free (φ vanishes linearly), optionally
    moved rigidly by `displacement` [m] at t = 1 (linear in t)."""

    edge: str
    components: str = "xyz"
    displacement: tuple[float, float, float] = (0.0, 0.0, 0.0)
    length: float | None = None

    def __post_init__(self):
        _check_edge("HingedEdge", self.edge)
        _set(self, "components", _check_components("HingedEdge", self.components))
        _set(
            self,
            "displacement",
            finite_vector("HingedEdge: displacement", self.displacement, 3, "m"),
        )
        _check_length("HingedEdge", self.length, edge=True)


@dataclass(frozen=True)
class PinnedPoint:
    """A point ξ (on the boundary or in the interior) held in place.

    rotation: "held" (default): u = φ N with a smooth φ, which must vanish quadratically at a
        point, so the surface's slope is held there too, over a patch of the size of `length`.
        "free": u = N(ξ) − N(ξ₀), the pin holds the position only and the surface turns
        freely about it (a hanging sheet); `length` does not apply. A free pin must be the
        only constraint (`BoundaryConditions` refuses anything else).
    """

    xi: tuple[float, float]
    components: str = "xyz"
    length: float | None = None
    rotation: str = "held"

    def __post_init__(self):
        _set(self, "xi", finite_vector("PinnedPoint: xi", self.xi, 2))
        _set(self, "components", _check_components("PinnedPoint", self.components))
        _check_length("PinnedPoint", self.length)
        if self.rotation not in PIN_ROTATIONS:
            raise ValueError(f"PinnedPoint: rotation must be one of {PIN_ROTATIONS}, got "
                             f"{self.rotation!r}")
        if self.rotation == "free" and self.length is not None:
            raise ValueError("PinnedPoint: length does not apply with rotation='free' (no "
                             "vanishing factor); leave it out")


@dataclass(frozen=True)
class Handle:
    """A point ξ moved by `displacement` [m] at t = 1 (linearly in t), slope held like a
    pinned point: a grabbed or driven spot of the surface.

    radius: 0 (default) holds the point alone; > 0 holds a patch — every point within
    `radius` of ξ, a fraction of the domain extent measured like `length` in normalised
    coordinates (a disc on a square domain) — translated rigidly by the displacement, its
    tangent plane kept (a grip: fingers or a clip). The band of width `length` starts at
    the patch's rim. A point's held slope is not a bounded condition on the bending energy
    (`boundary.conditions`), so the field must resolve an ever sharper layer around it; a
    patch's is (RESULTS.md, issue 27, "a held patch (grip) and the grid").

    turn: a rotation vector [rad] (world components; zero, the default: no turn): the held
    spot (or patch) also turns by the angle t·|turn| about the axis along `turn` through its
    reference point r_h, its displacement t·displacement + (R(t·turn) − I)(r − r_h) — the
    held slope turned with it (a hand that turns what it holds). Needs the surface."""

    xi: tuple[float, float]
    displacement: tuple[float, float, float]
    components: str = "xyz"
    length: float | None = None
    radius: float = 0.0
    turn: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        _set(self, "xi", finite_vector("Handle: xi", self.xi, 2))
        _set(self, "displacement", finite_vector("Handle: displacement", self.displacement, 3, "m"))
        _set(self, "components", _check_components("Handle", self.components))
        _check_length("Handle", self.length)
        if not (isinstance(self.radius, (int, float)) and math.isfinite(self.radius)
                and 0 <= self.radius < 0.5):
            raise ValueError(f"Handle: radius is a fraction of the domain extent in [0, 0.5), "
                             f"got {self.radius!r}")
        _set(self, "turn", finite_vector("Handle: turn", self.turn, 3, "rad"))


@dataclass(frozen=True)
class InteriorLine:
    """A straight line in ξ held in place: the segment from `start` to `end`, or with
    `extend=True` the whole line through them across the domain.

    By default φ vanishes quadratically (position and the slope across the line held). A
    whole line may instead be `hinged` (φ vanishes linearly, rotation about the line free); a
    segment cannot, because a smooth function cannot change sign across a segment and still
    be non-zero around its ends.
    """

    start: tuple[float, float]
    end: tuple[float, float]
    components: str = "xyz"
    extend: bool = False
    hinged: bool = False
    length: float | None = None

    def __post_init__(self):
        _set(self, "start", finite_vector("InteriorLine: start", self.start, 2))
        _set(self, "end", finite_vector("InteriorLine: end", self.end, 2))
        if self.start == self.end:
            raise ValueError(f"InteriorLine: start and end coincide at {self.start}")
        _set(self, "components", _check_components("InteriorLine", self.components))
        if self.hinged and not self.extend:
            raise ValueError(
                "InteriorLine: hinged=True needs extend=True (a segment can only be held "
                "with quadratic vanishing)"
            )
        _check_length("InteriorLine", self.length)


@dataclass(frozen=True)
class RimRotation:
    """An edge (rim) clamped to a rigid cuff that rotates by `angle` [rad] at t = 1 (θ = t·angle)
    about the axis through `axis_point` [m] with direction `axis`: on the rim the displacement
    is exactly R(θ)(r − p) + p − r. Needs the reference surface for r."""

    edge: str
    axis_point: tuple[float, float, float]
    axis: tuple[float, float, float]
    angle: float
    components: str = "xyz"
    length: float | None = None

    def __post_init__(self):
        _check_edge("RimRotation", self.edge)
        _set(self, "axis_point", finite_vector("RimRotation: axis_point", self.axis_point, 3))
        axis = finite_vector("RimRotation: axis", self.axis, 3)
        if math.hypot(*axis) == 0.0:
            raise ValueError("RimRotation: axis must be a non-zero vector")
        _set(self, "axis", axis)
        if not (isinstance(self.angle, (int, float)) and math.isfinite(self.angle)):
            raise ValueError(
                f"RimRotation: angle must be a finite number [rad], got {self.angle!r}"
            )
        _set(self, "components", _check_components("RimRotation", self.components))
        _check_length("RimRotation", self.length, edge=True)


@dataclass(frozen=True)
class SymmetryPlane:
    """An edge of the parameter rectangle lying in a plane of mirror symmetry (a quarter or
    octant model) whose normal is the axis `normal` ("x", "y" or "z") of the boundary's frame
    (the world axes by default; a tilted plane: a frame with the plane's normal as an axis,
    `BoundaryConditions(frame=...)`).

    Symmetric (default): the displacement along the normal vanishes on the edge (its factor
    vanishes linearly: it is odd across the plane) and the other two components have zero
    derivative across the edge (they are even), so the rotation about the in-plane direction
    of the edge vanishes. Antisymmetric: the two in-plane components vanish (odd) and the
    normal one is even. The even part is exact by construction: the field is evaluated at
    folded coordinates whose derivative across the edge vanishes there
    (`taichi_ndf.boundary.fold`). `components` are those that vanish (derived, not given).
    """

    edge: str
    normal: str
    antisymmetric: bool = False
    length: float | None = None
    components: str = field(init=False)

    def __post_init__(self):
        _check_edge("SymmetryPlane", self.edge)
        if self.normal not in tuple(COMPONENTS):
            raise ValueError(f"SymmetryPlane: normal must be one of 'x', 'y', 'z' (an axis of "
                             f"the boundary's frame; a tilted plane: a tilted frame), got "
                             f"{self.normal!r}")
        if not isinstance(self.antisymmetric, bool):
            raise ValueError(f"SymmetryPlane: antisymmetric must be true or false, got "
                             f"{self.antisymmetric!r}")
        _check_length("SymmetryPlane", self.length, edge=True)
        others = "".join(c for c in COMPONENTS if c != self.normal)
        _set(self, "components", others if self.antisymmetric else self.normal)


Constraint = (ClampedEdge | HingedEdge | PinnedPoint | Handle | InteriorLine | RimRotation
              | SymmetryPlane)

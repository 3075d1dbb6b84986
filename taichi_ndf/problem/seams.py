"""Seams as plain specifications: two edge segments of the surface's chart joined (issue 30).

A seam joins segment A of one edge of the parameter rectangle to segment B of another, point
by point: the point at fraction s ∈ [0, 1] along A (from its `start` to its `end`) to the
point at s along B (`orientation = "same"`) or at 1 − s (`"reversed"`). The term that does it
is `taichi_ndf.objective.seam.SeamTerm`; this module only states and checks what was asked
(edge names, ranges, choices) without a surface. What needs the surface (ranges inside the
edge, a periodic coordinate, the two lengths) is checked where the term is built.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

EDGES = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")
ORIENTATIONS = ("same", "reversed")
BENDING = ("transmitted", "hinge")

# Default penalty factor β of k = β D / h (`taichi_ndf.objective.seam`): chosen by
# measurement (benchmarks/RESULTS.md "Seams (issue 30)": the seam's error in Π falls as 1/β).
DEFAULT_PENALTY = 1e4
# Most relative difference of the two segments' reference lengths.
LENGTH_TOLERANCE = 1e-3


@dataclass(frozen=True)
class EdgeSegment:
    """Part of an edge of the parameter rectangle: edge one of `EDGES`; span (start, end)
    the interval of the coordinate along the edge (ξ² for an `xi1_*` edge, ξ¹ for an `xi2_*`
    one) in units of ξ, None for the whole edge; start > end runs the segment backwards."""

    edge: str
    span: tuple[float, float] | None = None

    def __post_init__(self):
        if self.edge not in EDGES:
            raise ValueError(f"unknown edge {self.edge!r}: must be one of {list(EDGES)}")
        if self.span is not None:
            try:
                start, end = (float(v) for v in self.span)
            except (TypeError, ValueError) as err:
                raise ValueError(f"edge {self.edge!r}: range must be [start, end], got "
                                 f"{self.span!r}") from err
            if not (math.isfinite(start) and math.isfinite(end)) or start == end:
                raise ValueError(f"edge {self.edge!r}: range must be two finite, different "
                                 f"numbers, got {self.span!r}")
            object.__setattr__(self, "span", (start, end))

    @property
    def across(self) -> int:
        """The coordinate (0 or 1) constant along the edge: 0 for `xi1_*`."""
        return 0 if self.edge.startswith("xi1") else 1

    @property
    def outward(self) -> float:
        """−1 on a `*_min` edge, +1 on a `*_max` edge: the sign of ξ's outward direction."""
        return 1.0 if self.edge.endswith("max") else -1.0


@dataclass(frozen=True)
class SeamSpec:
    """One seam (module docstring). name: how errors and outputs call it; a, b: the joined
    segments; orientation: "same" or "reversed"; bending: "transmitted" (positions and the
    across-seam tangent tied: the surface continues smoothly) or "hinge" (positions only);
    penalty: the factor β of the stiffness (`taichi_ndf.objective.seam`), > 0; segments,
    nodes: the seam's quadrature, `segments` equal parts of s with `nodes` Gauss–Legendre
    points each."""

    name: str
    a: EdgeSegment
    b: EdgeSegment
    orientation: str = "same"
    bending: str = "transmitted"
    penalty: float = DEFAULT_PENALTY
    segments: int = 64
    nodes: int = 4

    def __post_init__(self):
        if self.orientation not in ORIENTATIONS:
            raise ValueError(f"seam {self.name!r}: orientation must be one of "
                             f"{list(ORIENTATIONS)}, got {self.orientation!r}")
        if self.bending not in BENDING:
            raise ValueError(f"seam {self.name!r}: bending must be one of {list(BENDING)}, "
                             f"got {self.bending!r}")
        if not (isinstance(self.penalty, (int, float)) and math.isfinite(self.penalty)
                and self.penalty > 0):
            raise ValueError(f"seam {self.name!r}: stiffness must be a finite number > 0, got "
                             f"{self.penalty!r}")
        for key in ("segments", "nodes"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 4096:
                raise ValueError(f"seam {self.name!r}: {key} must be an integer in [1, 4096], "
                                 f"got {value!r}")
        if self.a.edge == self.b.edge:
            raise ValueError(f"seam {self.name!r}: edge {self.a.edge!r} is on both sides")


def check_seams(seams: Sequence[SeamSpec]) -> None:
    """Refuse (ValueError naming the seam and the edge) an edge in two seams and two seams of
    one name."""
    owner: dict[str, str] = {}
    names = set()
    for seam in seams:
        if seam.name in names:
            raise ValueError(f"seam {seam.name!r}: two seams have this name")
        names.add(seam.name)
        for side in (seam.a, seam.b):
            if side.edge in owner:
                raise ValueError(f"seam {seam.name!r}: edge {side.edge!r} is already in seam "
                                 f"{owner[side.edge]!r}")
            owner[side.edge] = seam.name


def segment_path(side, bounds, s) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A seam side as a path in ξ at fractions s (M,) of its length: the points (M, 2), dξ/ds
    (M, 2) and the unit outward normals n (M, 2), float64. side: an `EdgeSegment` of the
    parameter rectangle `bounds` (a straight segment, n = ±e_across) or a polygon panel's
    `PolygonEdge` (its own `path`: a segment or an arc, at constant speed)."""
    s = torch.as_tensor(s, dtype=torch.float64)
    if not isinstance(side, EdgeSegment):
        return tuple(torch.as_tensor(v, dtype=torch.float64) for v in side.path(s.numpy()))
    across, along = side.across, 1 - side.across
    lo, hi = bounds[along]
    start, end = side.span if side.span is not None else (lo, hi)
    at = bounds[across][1] if side.outward > 0 else bounds[across][0]
    ends = torch.empty(2, 2, dtype=torch.float64)
    ends[:, across] = at
    ends[:, along] = torch.tensor((start, end), dtype=torch.float64)
    normal = torch.zeros(len(s), 2, dtype=torch.float64)
    normal[:, across] = side.outward
    run = (ends[1] - ends[0]).expand(len(s), 2).clone()
    return ends[0] + s[:, None] * run, run, normal

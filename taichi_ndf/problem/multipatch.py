"""Several spline patches as one plain specification (a garment's panels): `MultiPatchPlan`
of `Patch`es and the `PatchSeam`s between them, solved by
`taichi_ndf.discretise.multipatch.MultiPatchDiscretisation`."""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.outline import Outline, PolygonEdge
from taichi_ndf.problem.seams import EDGES, SeamSpec, segment_path
from taichi_ndf.problem.spline_grid import GRADED_SHARE, graded_towards
from taichi_ndf.problem.start_shape import StartShape
from taichi_ndf.shell.materials import ClydeFabric, LinearIsotropic, Material, OrthotropicStVK

COMPONENTS = 3
log = logging.getLogger(__name__)


def grain_turned(material: Material, grain: float) -> Material:
    """`material` cut with its warp at `grain` [deg] from the panel's ξ¹ direction: the woven
    laws' warp runs along ξ¹ (`taichi_ndf.shell.law_terms.material_frame_transform`), so a
    grain of 90° (mod 180) swaps warp and weft (a11 ↔ a22, h₁ ↔ h₂; Clyde: also η₁ ↔ η₃ and
    E₁₁max ↔ E₂₂max; E₁₂ → −E₁₂ leaves Ψ unchanged) and 0° (mod 180) keeps it; an isotropic
    law is the same at any grain. Any other grain (a bias cut) needs a material frame turned
    inside the law: ValueError."""
    if not math.isfinite(grain):
        raise ValueError(f"grain must be a finite angle [deg], got {grain}")
    if isinstance(material, LinearIsotropic):
        return material
    turns = grain / 90.0
    if abs(turns - round(turns)) > 1e-9:
        raise ValueError(f"grain {grain:g}°: the woven laws hold the warp along ξ¹ or (90°) "
                         f"along ξ², not at another angle (a bias cut is not supported)")
    if round(turns) % 2 == 0:
        return material
    if isinstance(material, OrthotropicStVK):
        return dataclasses.replace(material, a11=material.a22, a22=material.a11,
                                   thickness=material.weft_thickness,
                                   weft_thickness=material.thickness)
    if isinstance(material, ClydeFabric):
        eta, limits = material.eta, material.strain_limits
        return dataclasses.replace(material, a11=material.a22, a22=material.a11,
                                   eta=(eta[2], eta[1], eta[0], eta[3]),
                                   strain_limits=(limits[1], limits[0], limits[2]))
    raise ValueError(f"grain: no warp and weft known for a {type(material).__name__}")


@dataclass(frozen=True)
class Gathered:
    """The positions of a start shape moved radially about the axis through `point` [m] along
    `direction` by `factor` (> 0; < 1 towards the axis): x ↦ p + (x − p)·d d + factor ×
    the rest of x − p. Has the start shape's `positions`, so `fitted_start` fits it."""

    shape: StartShape
    point: tuple[float, float, float]
    direction: tuple[float, float, float]
    factor: float

    def __post_init__(self):
        if not (math.isfinite(self.factor) and self.factor > 0):
            raise ValueError(f"the gathering factor must be > 0, got {self.factor}")

    def positions(self, xi, r, r1, r2):
        """The gathered start positions (N, 3) [m] (`StartShape.positions`' arguments)."""
        x = self.shape.positions(xi, r, r1, r2)
        p = x.new_tensor(self.point)
        d = x.new_tensor(self.direction)
        d = d / d.norm()
        v = x - p
        along = (v @ d)[:, None] * d
        return p + along + self.factor * (v - along)


@dataclass(frozen=True)
class Patch:
    """One panel: its name, model (surface, material, loads, boundary, probes) and grid.

    start: where its solve starts (None: the rest shape; a flat-cut panel: its placement,
    fitted by the coefficients, `taichi_ndf.discretise.start.fitted_start`); held: edges
    clamped where the start put them (their position and derivative across the edge, as a
    clamp; their curvature free: `taichi_ndf.discretise.held_edges`), a flat-cut panel's
    clamped edges (a clamp of the model's boundary would hold them at the flat rest shape);
    held_target: where the held edges are at load factor 1 (None: where they start), their
    rows moved there linearly in the load factor (a waist gathered onto a smaller circle).
    outline: a polygon panel's outline (None: the whole chart): the model's surface is then
    the outline's plane over a chart holding its bounding box (the garment reader's: that
    box; `config.domain` the chart) and the panel is integrated over the outline only
    (`taichi_ndf.discretise.trimmed`); its held edges are sides of that box."""

    name: str
    model: ShellModel
    config: SplineConfig
    start: StartShape | None = None
    held: tuple[str, ...] = ()
    held_target: Gathered | None = None
    outline: Outline | None = None

    def __post_init__(self):
        if self.outline is not None:
            chart = self.model.surface.domain.bounds
            inside = all(lo <= b_lo and b_hi <= hi for (lo, hi), (b_lo, b_hi)
                         in zip(chart, self.outline.bounds, strict=True))
            if self.config.domain != chart or not inside:
                raise ValueError(f"panel {self.name!r}: its grid must be over its chart "
                                 f"{chart}, which must hold its outline's bounding box "
                                 f"{self.outline.bounds}")
        for edge in self.held:
            if edge not in EDGES:
                raise ValueError(f"panel {self.name!r}: no edge {edge!r} to hold")
        if self.held and self.start is None:
            raise ValueError(f"panel {self.name!r}: held edges need a start shape (a clamped "
                             f"edge holds the rest shape)")
        if self.held_target is not None and not self.held:
            raise ValueError(f"panel {self.name!r}: a held target needs held edges")
        if self.held and any(self.config.periodic):
            raise ValueError(f"panel {self.name!r}: held edges need an open grid")

    def held_unknowns(self) -> np.ndarray:
        """The unknowns (coefficient × 3 + component, sorted) of the p rows of coefficients
        nearest the `held` edges: on a uniform open grid the value and the first p − 1
        derivatives across an edge depend on these only (`taichi_ndf.field.bspline`); the
        hold fixes 2 combinations of them per edge point (`discretise.held_edges`)."""
        m1, m2 = self.config.coefficient_counts
        p = self.config.degree
        index = np.arange(m1 * m2).reshape(m1, m2)
        rows = {"xi1_min": index[:p], "xi1_max": index[m1 - p:],
                "xi2_min": index[:, :p], "xi2_max": index[:, m2 - p:]}
        held = np.unique(np.concatenate([rows[e].ravel() for e in self.held] or [[]])
                         ).astype(np.int64)
        return (held[:, None] * COMPONENTS + np.arange(COMPONENTS)).reshape(-1)


@dataclass(frozen=True)
class PatchSeam:
    """A seam from an edge of patch `a` (index) to an edge of patch `b` (`spec.a`, `spec.b`)."""

    spec: SeamSpec
    a: int
    b: int


@dataclass(frozen=True)
class MultiPatchPlan:
    """The patches and the seams between them; gravity [m/s²] acts on every patch (through
    each patch's own material: its areal density)."""

    patches: tuple[Patch, ...]
    seams: tuple[PatchSeam, ...] = ()
    gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if not self.patches:
            raise ValueError("a multi-patch plan needs at least one patch")
        for seam in self.seams:
            for index in (seam.a, seam.b):
                if not 0 <= index < len(self.patches):
                    raise ValueError(f"seam {seam.spec.name!r}: no patch {index}")

    @property
    def materials(self) -> tuple:
        """Each patch's material, in order."""
        return tuple(p.model.material for p in self.patches)

    def seam_material(self, seam: PatchSeam):
        """The material that sets a seam's penalty stiffness (`SeamTerm`): the side's with
        the larger membrane stiffness (the stronger tie)."""
        return max((self.patches[seam.a].model.material, self.patches[seam.b].model.material),
                   key=lambda m: m.small_strain_stiffness()[0])

    def seam_corners(self) -> tuple[tuple[tuple[float, ...], tuple[float, ...]], ...]:
        """Per patch, the coordinates (ξ¹ ones, ξ² ones; sorted) of its seam corners: the
        ends of seam sides where the sewn path turns on either side of the seam — two seam
        sides of one patch meeting there at an angle (a notch's corner, a side seam meeting
        an armhole) — and the points sewn to such an end on the other side (a straight
        sleeve end's points that meet an armhole's corners). There the two sides' traces
        cannot both be smooth: one turns, the other must fold (`graded_at_seam_corners`)."""
        ends: dict[int, list[tuple[tuple[float, float], tuple[float, float]]]] = {}
        sides = []  # per seam: its A and B ends as (patch, (start, end))
        for seam in self.seams:
            pair = []
            for patch, side in ((seam.a, seam.spec.a), (seam.b, seam.spec.b)):
                bounds = self.patches[patch].model.surface.domain.bounds
                points, runs, _ = (v.tolist() for v in segment_path(side, bounds, [0.0, 1.0]))
                start, end = points
                unit = [(r[0] / math.hypot(*r), r[1] / math.hypot(*r)) for r in runs]
                ends.setdefault(patch, []).extend(((tuple(start), unit[0]),
                                                   (tuple(end), unit[1])))
                pair.append((patch, (tuple(start), tuple(end))))
            if seam.spec.orientation == "reversed":
                pair[1] = (pair[1][0], pair[1][1][::-1])
            sides.append(pair)

        def turns(patch: int, point) -> bool:
            runs = [run for at, run in ends[patch] if math.dist(at, point) <= 1e-9]
            return any(abs(a[0] * b[1] - a[1] * b[0]) > 1e-6 for a in runs for b in runs)

        found: list[tuple[set, set]] = [(set(), set()) for _ in self.patches]
        for (pa, ends_a), (pb, ends_b) in sides:
            for k in range(2):
                if turns(pa, ends_a[k]) or turns(pb, ends_b[k]):
                    for patch, point in ((pa, ends_a[k]), (pb, ends_b[k])):
                        found[patch][0].add(round(point[0], 12))
                        found[patch][1].add(round(point[1], 12))
        return tuple((tuple(sorted(a)), tuple(sorted(b))) for a, b in found)

    def graded_at_seam_corners(self, share: float = GRADED_SHARE) -> MultiPatchPlan:
        """This plan with each patch's knots graded towards its `seam_corners` (the same
        spans: `taichi_ndf.problem.spline_grid.graded_towards`; a patch without seam
        corners keeps its grid); each patch's grading is logged."""
        patches = []
        for patch, corners in zip(self.patches, self.seam_corners(), strict=True):
            log.info("panel %r: knots graded towards ξ¹ = %s, ξ² = %s", patch.name,
                     corners[0] or "none", corners[1] or "none")
            patches.append(patch if not any(corners) else dataclasses.replace(
                patch, config=graded_towards(patch.config, corners, share=share)))
        return dataclasses.replace(self, patches=tuple(patches))

    def to_dict(self) -> dict:
        return {"type": "multipatch",
                "patches": [{"name": p.name, "spans": list(p.config.spans)}
                            for p in self.patches],
                "seams": [{"name": s.spec.name, "a": self.side_name(s.a, s.spec.a),
                           "b": self.side_name(s.b, s.spec.b)} for s in self.seams]}

    def outline_seams(self) -> tuple[tuple[int, int, int, int, bool], ...]:
        """The seams between two outline edges as (patch a, edge number a, patch b, edge
        number b, reversed) (what the output meshes sample alike: `ResultPart.seams`)."""
        return tuple((s.a, self.patches[s.a].outline.index(s.spec.a.edge.rpartition(".")[2]),
                      s.b, self.patches[s.b].outline.index(s.spec.b.edge.rpartition(".")[2]),
                      s.spec.orientation == "reversed")
                     for s in self.seams
                     if isinstance(s.spec.a, PolygonEdge) and isinstance(s.spec.b, PolygonEdge))

    def side_name(self, patch: int, side) -> str:
        """A seam side's "panel.edge" (a polygon edge's name holds its panel's already)."""
        if isinstance(side, PolygonEdge):
            return side.edge
        return f"{self.patches[patch].name}.{side.edge}"


"""Several spline patches as one plain specification (a garment's panels): `MultiPatchPlan`
of `Patch`es and the `PatchSeam`s between them, solved by
`taichi_ndf.discretise.multipatch.MultiPatchDiscretisation`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.seams import EDGES, SeamSpec
from taichi_ndf.problem.start_shape import StartShape

COMPONENTS = 3


@dataclass(frozen=True)
class Patch:
    """One panel: its name, model (surface, material, loads, boundary, probes) and grid.

    start: where its solve starts (None: the rest shape; a flat-cut panel: its placement,
    fitted by the coefficients, `taichi_ndf.discretise.start.fitted_start`); held: edges held
    where the start put them (position, slope and curvature: the `degree` rows of
    coefficients that act on the edge keep their start values), a flat-cut panel's clamped
    edges (a clamp of the model's boundary would hold them at the flat rest shape)."""

    name: str
    model: ShellModel
    config: SplineConfig
    start: StartShape | None = None
    held: tuple[str, ...] = ()

    def __post_init__(self):
        for edge in self.held:
            if edge not in EDGES:
                raise ValueError(f"panel {self.name!r}: no edge {edge!r} to hold")
        if self.held and self.start is None:
            raise ValueError(f"panel {self.name!r}: held edges need a start shape (a clamped "
                             f"edge holds the rest shape)")
        if self.held and any(self.config.periodic):
            raise ValueError(f"panel {self.name!r}: held edges need an open grid")

    def held_unknowns(self) -> np.ndarray:
        """The unknowns (coefficient × 3 + component, sorted) of the `held` edges: on a
        uniform open grid the value and the first p − 1 derivatives across an edge depend on
        its p nearest rows of coefficients only (`taichi_ndf.field.bspline`)."""
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
    """The patches and the seams between them; gravity [m/s²] acts on every patch."""

    patches: tuple[Patch, ...]
    seams: tuple[PatchSeam, ...] = ()
    gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if not self.patches:
            raise ValueError("a multi-patch plan needs at least one patch")
        first = self.patches[0].model.material
        for patch in self.patches[1:]:
            if patch.model.material != first:
                raise ValueError(f"panel {patch.name!r}: its material differs from panel "
                                 f"{self.patches[0].name!r}'s (one material for all panels)")
        for seam in self.seams:
            for index in (seam.a, seam.b):
                if not 0 <= index < len(self.patches):
                    raise ValueError(f"seam {seam.spec.name!r}: no patch {index}")

    def to_dict(self) -> dict:
        return {"type": "multipatch",
                "patches": [{"name": p.name, "spans": list(p.config.spans)}
                            for p in self.patches],
                "seams": [{"name": s.spec.name, "a": f"{self.patches[s.a].name}.{s.spec.a.edge}",
                           "b": f"{self.patches[s.b].name}.{s.spec.b.edge}"}
                          for s in self.seams]}

"""Several spline patches as one plain specification (a garment's panels): `MultiPatchPlan`
of `Patch`es and the `PatchSeam`s between them, solved by
`taichi_ndf.discretise.multipatch.MultiPatchDiscretisation`."""

from __future__ import annotations

from dataclasses import dataclass

from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.seams import SeamSpec


@dataclass(frozen=True)
class Patch:
    """One panel: its name, model (surface, material, loads, boundary, probes) and grid."""

    name: str
    model: ShellModel
    config: SplineConfig


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

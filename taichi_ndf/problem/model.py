"""The shell model: what is simulated, independent of how it is solved.

A model is immutable: reference surface, material, loads, boundary conditions and named probe
points. The solver's state (field weights, optimiser moments) lives elsewhere, so inverse
problems can swap materials or loads and reuse the same pieces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.geometry import ReferenceSurface
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.operator import DisplacementOperator


@dataclass(frozen=True)
class Probe:
    """A named surface point at which the displacement is reported.

    xi: surface coordinates (ξ¹, ξ²) in the reference surface's parameter domain.
    """

    name: str
    xi: tuple[float, float]


@dataclass(frozen=True)
class ShellModel:
    """Reference surface + material + loads + boundary conditions (+ probes, + rigid
    obstacles: contact, a `taichi_ndf.contact.ContactConfig` or None, + further energy terms:
    terms, `taichi_ndf.objective.Term`s that `Objective.of_model` adds to the shell's
    potential energy, e.g. an elastic foundation)."""

    surface: ReferenceSurface
    material: object
    loads: Loads
    boundary: BoundaryConditions
    probes: tuple[Probe, ...] = field(default_factory=tuple)
    contact: object = None
    terms: tuple = field(default_factory=tuple)

    def __post_init__(self):
        names = [p.name for p in self.probes]
        if len(set(names)) != len(names):
            raise ValueError(f"probe names must be unique, got {names}")
        for p in self.probes:
            xi = torch.tensor([p.xi], dtype=torch.float64)
            if not bool(self.surface.domain.contains(xi)[0]):
                raise ValueError(f"probe {p.name!r} at ξ={p.xi} lies outside the parameter domain")

    def with_material(self, material) -> ShellModel:
        return replace(self, material=material)

    def with_loads(self, loads: Loads) -> ShellModel:
        return replace(self, loads=loads)

    def with_boundary_length(self, length: float) -> ShellModel:
        """The model with the band width `length` of its boundary conditions' vanishing
        factors (a fraction of the domain; edges accept > 1, e.g. for a Newton basis)."""
        b = self.boundary
        return replace(self, boundary=BoundaryConditions(b.constraints, b.domain,
                                                         surface=b.surface, length=length))

    def operator(self, field) -> DisplacementOperator:
        """The displacement operator of a field under this model's boundary conditions."""
        return DisplacementOperator(field, self.boundary)

    def displacement_jets(self, field, xi: torch.Tensor, *, t: float = 1.0, conditioning=None):
        """Displacement jets u (N, 6, 3) [m] of a field at ξ, boundary conditions applied."""
        return self.operator(field).jets(xi, t=t, conditioning=conditioning)

    def displacement(self, field, xi: torch.Tensor, *, t: float = 1.0, conditioning=None):
        """Displacement u (N, 3) [m] at ξ (no tape kept: for outputs and probes)."""
        return self.operator(field).displacement(xi, t=t, conditioning=conditioning)

    def characteristic_length(self) -> float:
        """√(surface area) [m], estimated from the reference surface."""
        gen = torch.Generator().manual_seed(0)
        xi = self.surface.domain.sample(4096, gen)
        r = self.surface.jets(xi.to(torch.float64))
        sqrt_a = torch.linalg.cross(r[:, jets.D1], r[:, jets.D2], dim=-1).norm(dim=-1)
        return math.sqrt(float(sqrt_a.mean()) * self.surface.domain.area)

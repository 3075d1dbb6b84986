"""Shape-from-template on a spline displacement field, frame by frame by Gauss–Newton: the
spline's part of the one reconstruction (`inverse.sft.reconstruct.FrameReconstructor`).

Each frame's surface is x(ξ) = X(ξ) + u(ξ) on the template's UV domain (X the template itself,
piecewise linear for data and output, its C² spline fit `MeshSurface` for the energy), with u a
cubic tensor-product B-spline `SplineField` (spans about ``span_edges`` template edges long).
Frame 0 is the template. Frame t > 0 starts from the last frame's coefficients C_{t−1}
(``extrapolate``: from 2 C_{t−1} − C_{t−2}, which on φ-SfT's R1 carried weakly observed parts
of the free edge on at their last velocity: max vertex distance 35 against 24 mm by frame 13,
chamfer ×1e4 0.273 against 0.247 there) and minimises

    E(C) = E_data(u) + w_phys · Π_int(u) / E_ref

E_data the least-squares data terms of `inverse.sft.least_squares` (robust reprojection of the
tracked points, silhouette of the template vertices with masks, the outline of the visible
border vertices against the mask (`inverse.sft.outline`), smooth motion towards the
constant-velocity prediction), Π_int the Kirchhoff–Love internal energy of a fixed linear
isotropic material over the template (membrane + bending;
`taichi_ndf.discretise.trimmed.sheet_quadrature`: exact
Gauss–Legendre on the spline's knot spans, one point per triangle where the UV chart does not
fill its rectangle) and E_ref = B / 2 the bending energy of the template bent to uniform
curvature 1/√A, so Π_int / E_ref is dimensionless (`inverse.sft.reconstruct`).

Solver: the project's projected Newton over the spline coefficients
(`taichi_ndf.minimise.newton.minimise` on an `Assembly` of the quadrature points, the
tracked points and the vertices): the shell's per-point Hessian blocks (central differences of
its Taichi gradient, projected to PSD) plus the data terms' Gauss–Newton blocks JᵀWJ, summed by
`Objective.hessian_blocks` term by term, assembled sparse in coefficient space and solved with
Levenberg–Marquardt damping and an Armijo line search on E. So the data terms are Gauss–Newton
and the shell is Newton in one linear system per iteration; a frame takes a few iterations.

The global depth: a depth shift of the whole sheet at unchanged reprojection is a scaling
about the camera centre, a uniform membrane strain ε, which the prior charges
w_phys · 2 D (1 + ν) A ε² / B ≈ 1.2e4 ε² px² (cloth preset, w_phys = 1e-2; D / B = 12 / h²).
A pull that the data cannot see competes with it: the motion term at w_temp = 1 dragged the
accelerating corner sequence along its constant-velocity prediction, mostly in depth (e3D
0.0108 and 2.7 mm depth bias against 0.0020 and 0.3 mm at w_temp = 0.1; docs/sft_results.md).

Inertia (`SplinePriorConfig.frame_interval` Δt, off by default): E gains w_phys / E_ref ·
½ ρ_A/Δt² (C − Ĉ)ᵀ M (C − Ĉ), `taichi_ndf.objective.inertia.InertiaTerm` at the sheet's
quadrature points (M the spline's consistent mass matrix), Ĉ = 2 C_{t−1} − C_{t−2} (frame 1:
C_0). On R1 it made the figures worse at Δt = 1/30, 0.1 and 0.2 s (benchmarks/RESULTS.md).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from inverse.sft.least_squares import LeastSquaresData
from inverse.sft.sequential import FrameSolve
from inverse.sft.settings import SplinePriorConfig
from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.discretise.trimmed import sheet_quadrature
from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.geometry import MeshSurface
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.objective.inertia import InertiaTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.problem.spline_grid import spans_for
from taichi_ndf.shell.hessian import sample_hessians
from taichi_ndf.shell.materials import LinearIsotropic

log = logging.getLogger(__name__)

DTYPE = torch.float64  # the Hessian blocks are central differences: float64 only
JETS_SHAPE = (jets.CHANNELS, 3)
# Points per shell evaluation of the central-difference blocks: all 36 perturbed copies of R1's
# ~1900 quadrature points in one kernel launch (`sample_hessians`; ~100 MB of jets at most).
STACKED_POINTS = 1 << 17


class SplineFrameField:
    """The spline field's part of the frame fit (`inverse.sft.sequential.FrameField`): a
    `SplineField` over the template's UV rectangle, the prior on the fixed `sheet_quadrature`
    and projected Newton over the coefficients (`minimise` on the `GridLinearisation` of the
    quadrature and the frame's data points)."""

    dtype = DTYPE
    slope = "image"  # Newton: the distance image's own slope

    def __init__(self, surface: MeshSurface, conditions: BoundaryConditions | None,
                 config: SplinePriorConfig, *, mean_edge: float, material: LinearIsotropic,
                 energy_reference: float):
        self.config = cfg = config
        self.surface = surface
        spans = spans_for(surface, cfg.span_edges * mean_edge)
        self.field = SplineField(SplineConfig(spans, degree=cfg.degree,
                                              domain=surface.domain.bounds), dtype=DTYPE)
        self.quadrature = sheet_quadrature(surface, self.field.config,
                                           points=cfg.quadrature_points, dtype=DTYPE)
        self.operator = DisplacementOperator(self.field, conditions)
        # The prior in the data's units: stiffnesses scaled by λ = w_phys / E_ref.
        self.shell = None
        if cfg.physics_weight > 0:
            self.shell = QuadratureShellTerm(
                material.scaled(cfg.physics_weight / energy_reference), Loads())
        # The inertia of a step Δt = frame_interval, in the prior's units (λ ρ_A / Δt²).
        self.areal_density = material.areal_density
        self.inertia_scale = None
        if cfg.frame_interval is not None and self.shell is not None:
            self.inertia_scale = cfg.physics_weight / energy_reference / cfg.frame_interval**2
        # the linearisation of each frame's points (`rows`); the conditions' gauge held
        self.grid = GridLinearisation(self.field, conditions,
                                      length=math.sqrt(surface.domain.rectangle_area))
        self.linearisation = None
        self._previous = None  # the coefficients of the frame before the last
        self._last_blocks = {}  # id → (ξ, samples) of the last frame's blocks (`rows`)
        self.newton = NewtonConfig(
            max_iterations=cfg.max_iterations, decrement_tolerance=cfg.tolerance,
            gradient_tolerance=1e-8, floor_tolerance=cfg.tolerance)
        log.info("spline prior: %d x %d spans, %d coefficients, %d quadrature points", *spans,
                 self.field.config.num_coefficients, len(self.quadrature))

    def _samples_at(self, xi: torch.Tensor) -> SurfaceSamples:
        """Zero-weight samples at ξ (N, 2): points where only the data terms act."""
        n = xi.shape[0]
        return SurfaceSamples(xi, self.surface.jets(xi).to(DTYPE),
                              torch.zeros(n, dtype=DTYPE), torch.zeros(n, 3, dtype=DTYPE))

    def displacement(self, xi: torch.Tensor) -> torch.Tensor:
        """u (N, 3) [m] at ξ (N, 2) of the current coefficients."""
        return self.operator.displacement(xi)

    def rows(self, blocks: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """The frame's linearisation on the quadrature and the data points (zero weight) after
        it; the rows of each block in its assembly's (reordered) samples."""
        samples, kept = self.quadrature, {}
        for xi in blocks:
            # a block passed again (the same tensor: the template's vertices, the border
            # curve; never changed in place) keeps its samples from the last frame
            last = self._last_blocks.get(id(xi))
            block = last[1] if last is not None and last[0] is xi else self._samples_at(xi)
            kept[id(xi)] = (xi, block)
            samples = samples.joined(block)
        self._last_blocks = kept
        self.linearisation = self.grid.linearisation(1.0, samples)
        order = self.linearisation.assembly.order
        position = torch.empty_like(order)
        position[order] = torch.arange(len(order))
        rows, first = [], len(self.quadrature)
        for xi in blocks:
            rows.append(position[first:first + len(xi)])
            first += len(xi)
        return rows

    def solve(self, terms: Sequence[LeastSquaresData]) -> FrameSolve:
        """Projected Newton from the last frame's coefficients (``extrapolate``: from
        2 C_{t−1} − C_{t−2}), with the inertia towards that prediction where Δt is set."""
        cfg, assembly = self.config, self.linearisation.assembly
        terms = tuple(terms)
        # the constant-velocity prediction 2 C_{t−1} − C_{t−2} of the coefficients
        start = self.field.coefficients
        predicted = start if self._previous is None else 2.0 * start - self._previous
        inertia = None
        if self.inertia_scale is not None:
            inertia = InertiaTerm(self.areal_density, self.inertia_scale,
                                  assembly.displacement(predicted))
            terms = terms + (inertia,)
        potential = (_DataOnly(terms) if self.shell is None
                     else Objective(self.shell, terms).potential(1.0))
        if cfg.extrapolate:
            start = predicted
        self._previous = self.field.coefficients.clone()
        solution = minimise(self.linearisation, potential, start, self.newton)
        self.field.coefficients.copy_(solution.parameters)
        u = assembly.displacement(solution.parameters)
        parts = {}
        if inertia is not None:  # ½ ρ_A/Δt² ‖u − û‖²_M / E_ref
            parts["inertia"] = inertia.evaluate(assembly.samples, u, grad=False)[0] / (
                cfg.physics_weight)
        if self.shell is not None:
            result = self.shell.result(assembly.samples, u)
            parts["energy"] = result.internal / (cfg.physics_weight)  # Π_int / E_ref
        return FrameSolve(u, parts, len(solution.history))


class QuadratureShellTerm(ShellEnergyTerm):
    """The shell energy term whose Hessian blocks are differenced only at the samples with
    quadrature weight (the data points carry weight 0, so their shell blocks are 0): saves the
    central differences at every tracked point and vertex; the perturbed copies stacked into
    few evaluations (`STACKED_POINTS`: the shell's terms are per point)."""

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float = 1.0, *, steps: torch.Tensor) -> torch.Tensor:
        rows = torch.nonzero(samples.weight != 0).flatten()
        weighted = SurfaceSamples(samples.xi[rows], samples.r_jets[rows], samples.weight[rows],
                                  samples.point_force[rows])
        blocks = u_jets.new_zeros(u_jets.shape[0], *JETS_SHAPE, *JETS_SHAPE)
        blocks[rows] = sample_hessians(
            lambda s, u, grad: self.result(s, u, load_factor, grad=grad), weighted,
            u_jets[rows], steps=steps, stacked_points=STACKED_POINTS)
        return blocks


@dataclass(frozen=True)
class _DataOnly:
    """The data terms alone as a potential (w_phys = 0): callable (samples, u_jets, grad) ->
    an object with `.total` and `.grad_u_jets`, with Gauss–Newton `hessian_blocks`."""

    terms: tuple[LeastSquaresData, ...]

    def __call__(self, samples: SurfaceSamples, u_jets: torch.Tensor, grad: bool):
        results = [term.evaluate(samples, u_jets, grad=grad) for term in self.terms]
        gradient = sum(g for _, g in results) if grad else None
        return _Value(sum(v for v, _ in results), gradient)

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor, *,
                       steps: torch.Tensor) -> torch.Tensor:
        return sum(term.hessian_blocks(samples, u_jets, steps=steps) for term in self.terms)


@dataclass(frozen=True)
class _Value:
    total: float
    grad_u_jets: torch.Tensor | None


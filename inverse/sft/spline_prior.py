"""Shape-from-template on a spline displacement field, frame by frame by Gauss–Newton.

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
isotropic material over the template (membrane + bending; `sheet_quadrature`: exact
Gauss–Legendre on the spline's knot spans, one point per triangle where the UV chart does not
fill its rectangle) and E_ref = B / 2 the bending energy of the template bent to uniform
curvature 1/√A, so Π_int / E_ref is dimensionless (as in `inverse.sft.reconstruct`).

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
from dataclasses import dataclass

import numpy as np
import torch

from inverse.sft.contour import BorderCurve, CoverTerm, mean_border_edge, visible_points
from inverse.sft.inputs import Template, mean_edge_length
from inverse.sft.least_squares import LeastSquaresData
from inverse.sft.sequential import (
    DataWeights,
    FittedFrame,
    FrameData,
)
from inverse.sft.settings import SplinePriorConfig
from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import PinnedPoint
from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.geometry import MeshSurface
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.objective.inertia import InertiaTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.sampling import SurfaceSamples, with_point_loads
from taichi_ndf.problem.spline_grid import spans_for
from taichi_ndf.shell.hessian import sample_hessians
from taichi_ndf.shell.materials import preset

log = logging.getLogger(__name__)

DTYPE = torch.float64  # the Hessian blocks are central differences: float64 only
JETS_SHAPE = (jets.CHANNELS, 3)
# Points per shell evaluation of the central-difference blocks: all 36 perturbed copies of R1's
# ~1900 quadrature points in one kernel launch (`sample_hessians`; ~100 MB of jets at most).
STACKED_POINTS = 1 << 17


class SplinePriorReconstructor:
    """Holds the spline field, the template's quadrature and the per-frame solve (a
    `inverse.sft.sequential.FrameFit`)."""

    def __init__(self, template: Template, *, pinned: np.ndarray | None = None,
                 config: SplinePriorConfig | None = None):
        self.config = cfg = config or SplinePriorConfig()
        self.weights = DataWeights(cfg.huber_px, cfg.temporal_weight, cfg.silhouette_weight,
                                   cfg.outline_weight, cfg.silhouette_border_gap,
                                   cfg.silhouette_allowance, cfg.allowance_reach,
                                   cfg.allowance_fade)
        self.surface = MeshSurface(template.vertices, template.faces, template.uvs,
                                   name="template")
        mean_edge = mean_edge_length(template.vertices, template.faces)
        spans = spans_for(self.surface, cfg.span_edges * mean_edge)
        self.field = SplineField(SplineConfig(spans, degree=cfg.degree,
                                              domain=self.surface.domain.bounds), dtype=DTYPE)
        self.quadrature = sheet_quadrature(self.surface, self.field.config, template,
                                           points=cfg.quadrature_points)
        self.conditions = None
        if pinned is not None and len(pinned):
            points = [PinnedPoint(xi=tuple(float(c) for c in template.uvs[i])) for i in pinned]
            self.conditions = BoundaryConditions(points, self.surface.domain)
        self.operator = DisplacementOperator(self.field, self.conditions)
        material = preset(cfg.material)
        material = material.with_stiffness(
            membrane_stiffness=cfg.membrane_factor * material.membrane_stiffness)
        self.energy_reference = 0.5 * material.bending_stiffness
        # The prior in the data's units: stiffnesses scaled by λ = w_phys / E_ref.
        self.shell = None
        if cfg.physics_weight > 0:
            self.shell = QuadratureShellTerm(
                material.scaled(cfg.physics_weight / self.energy_reference), Loads())
        # The inertia of a step Δt = frame_interval, in the prior's units (λ ρ_A / Δt²).
        self.areal_density = material.areal_density
        self.inertia_scale = None
        if cfg.frame_interval is not None and self.shell is not None:
            self.inertia_scale = (cfg.physics_weight / self.energy_reference
                                  / cfg.frame_interval**2)
        self.vertex_xi = torch.from_numpy(template.uvs).to(DTYPE)
        self.vertex_samples = self._samples_at(self.vertex_xi)
        self.rest = torch.from_numpy(template.vertices).double()
        self.length = math.sqrt(self.surface.domain.rectangle_area)
        # the linearisation of each frame's points (`fit_frame`); the conditions' gauge held
        self.grid = GridLinearisation(self.field, self.conditions, length=self.length)
        self._previous = None  # the coefficients of the frame before the last
        self.newton = NewtonConfig(
            max_iterations=cfg.max_iterations, decrement_tolerance=cfg.tolerance,
            gradient_tolerance=1e-8, floor_tolerance=cfg.tolerance)
        # The mask's outline covered by the border (`inverse.sft.contour`; w_cover > 0).
        self.border_curve = self.border_samples = self.cover_allowance = None
        if cfg.cover_weight > 0:
            self.border_curve = BorderCurve.of(template.vertices, template.faces, template.uvs,
                                               per_edge=cfg.cover_points)
            self.border_samples = self._samples_at(self.border_curve.xi)
        log.info("spline prior: %d x %d spans, %d coefficients, %d quadrature points", *spans,
                 self.field.config.num_coefficients, len(self.quadrature))

    def _samples_at(self, xi: torch.Tensor) -> SurfaceSamples:
        """Zero-weight samples at ξ (N, 2): points where only the data terms act."""
        n = xi.shape[0]
        return SurfaceSamples(xi, self.surface.jets(xi).to(DTYPE),
                              torch.zeros(n, dtype=DTYPE), torch.zeros(n, 3, dtype=DTYPE))

    def vertices(self, coefficients: torch.Tensor | None = None) -> np.ndarray:
        """Surface at the template vertices [m], shape (n, 3), template order."""
        if coefficients is not None:
            self.field.coefficients.copy_(coefficients)
        return (self.rest + self.operator.displacement(self.vertex_xi).double()).numpy()

    def fit_frame(self, frame: FrameData) -> FittedFrame:
        """One frame's vertices, final data-term values and Newton iterations; the solve
        starts from the field's current coefficients (the last frame's)."""
        cfg = self.config
        samples = self.quadrature.joined(self._samples_at(frame.track_xi.to(DTYPE))).joined(
            self.vertex_samples)
        photo = frame.photometric
        if photo is not None:
            samples = samples.joined(self._samples_at(photo.xi.to(DTYPE)))
        cover = self.border_curve is not None and frame.distance is not None
        if cover:
            samples = samples.joined(self.border_samples)
        linearisation = self.grid.linearisation(1.0, samples)
        assembly = linearisation.assembly
        position = torch.empty_like(assembly.order)
        position[assembly.order] = torch.arange(len(assembly.order))
        n_q, n_t, n_v = len(self.quadrature), len(frame.track_xi), len(self.vertex_xi)
        data = frame.data_term(position[n_q:n_q + n_t], position[n_q + n_t:n_q + n_t + n_v])
        terms = (data,)
        if photo is not None:
            terms = (data, photo.term(frame.camera, position[n_q + n_t + n_v:]))
        if cover:
            terms = terms + (self._cover_term(frame, position[-len(self.border_curve.xi):]),)
        # the constant-velocity prediction 2 C_{t−1} − C_{t−2} of the coefficients
        start = self.field.coefficients
        predicted = start if self._previous is None else 2.0 * start - self._previous
        if self.inertia_scale is not None:
            terms = terms + (InertiaTerm(self.areal_density, self.inertia_scale,
                                         assembly.displacement(predicted)),)
        potential = (_DataOnly(terms) if self.shell is None
                     else Objective(self.shell, terms).potential(1.0))
        if cfg.extrapolate:
            start = predicted
        self._previous = self.field.coefficients.clone()
        solution = minimise(linearisation, potential, start, self.newton)
        self.field.coefficients.copy_(solution.parameters)
        u = assembly.displacement(solution.parameters)
        parts = data.parts(u)
        for term in terms[1:]:
            if isinstance(term, InertiaTerm):  # ½ ρ_A/Δt² ‖u − û‖²_M / E_ref
                parts["inertia"] = term.evaluate(assembly.samples, u, grad=False)[0] / (
                    cfg.physics_weight)
            else:
                parts.update(term.parts(u))
        if self.shell is not None:
            result = self.shell.result(assembly.samples, u)
            parts["energy"] = result.internal / (cfg.physics_weight)  # Π_int / E_ref
        return FittedFrame(self.vertices(), parts, len(solution.history))


    def _cover_term(self, frame: FrameData, rows: torch.Tensor) -> CoverTerm:
        """The frame's cover term (`inverse.sft.contour`) at sample rows `rows`, its outline
        points chosen near the border of the field's current shape (the frame's start)."""
        curve, cfg = self.border_curve, self.config
        if self.cover_allowance is None and frame.first_distance is not None:
            self.cover_allowance = curve.allowance(frame.camera, frame.first_distance)
        start = curve.rest + self.operator.displacement(curve.xi).double()
        start_pixels = frame.camera.project(start).numpy()
        edge = mean_border_edge(curve, frame.camera.project(torch.from_numpy(self.vertices())
                                                            ).numpy())
        return CoverTerm(frame.camera, rows, curve, frame.distance,
                         visible=visible_points(curve, frame.outline_offset),
                         allowance=self.cover_allowance, start=start_pixels,
                         weight=cfg.cover_weight, reach=cfg.cover_reach * edge,
                         slack=cfg.cover_slack * edge)


def sheet_quadrature(surface: MeshSurface, config: SplineConfig, template: Template, *,
                     points: int | None) -> SurfaceSamples:
    """Samples of the prior's energy over the sheet itself.

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
        return GridLinearisation.quadrature(surface, config, points=points, dtype=DTYPE)
    corners = template.uvs[template.faces]  # (F, 3, 2)
    edge1, edge2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = 0.5 * np.abs(edge1[:, 0] * edge2[:, 1] - edge1[:, 1] * edge2[:, 0])
    xi = torch.from_numpy(corners.mean(axis=1)).to(DTYPE)
    return with_point_loads(surface, xi, torch.from_numpy(area).to(DTYPE), None)


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


"""Estimates of a scene's displacement, used to scale the field's output.

The field's raw output is O(1) at initialisation-scale weights; multiplying it by a
characteristic displacement keeps Adam's step sizes meaningful across scenes whose
displacements differ by orders of magnitude (a pinched cylinder moves 1e-5, a napkin 1 m).
Three estimates (docs/scenes.md, "Field output scale", compares them):
`equilibrium_displacement`, the largest displacement of a coarse nonlinear equilibrium
(`output_scale = "equilibrium"`; not "auto": see scene_field.AUTO_ESTIMATE);
`linear_displacement`, that of one Newton step from the undeformed state (the linear
solution), which overshoots grossly for draped cloth; and `characteristic_displacement`,
dimensional (loads, stiffnesses, size; blind to supports and to where loads act; "auto").
The two solves are capped at the surface's size.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np
import torch

from taichi_ndf.boundary import ClampedEdge, Handle, HingedEdge, RimRotation
from taichi_ndf.line_loads import quadrature
from taichi_ndf.model import ShellModel
from taichi_ndf.shell.materials import ClydeFabric, LinearIsotropic, OrthotropicStVK

log = logging.getLogger(__name__)

# Most spans per direction of the grid of `linear_displacement` (the grid rule's, capped;
# measured on the pinched hemisphere, 75 x 20 by the rule: 16 spans lock, 0.040 against 0.094;
# 32: 0.126 in 2.2 s).
LINEAR_ESTIMATE_SPANS = 32
# The grid and the stopping rule of `equilibrium_displacement` (measured: docs/scenes.md;
# 16 spans keep it to seconds on the shipped scenes, the pinched hemisphere locks on them:
# 0.040 against 0.094, 24 spans 0.114; the largest displacement settles long before Π).
EQUILIBRIUM_ESTIMATE_SPANS = 16
EQUILIBRIUM_ESTIMATE_ITERATIONS = 40
EQUILIBRIUM_ESTIMATE_TOLERANCE = 1e-4


def membrane_and_bending_stiffness(material) -> tuple[float, float]:
    """Representative (D [N/m], B [N·m]) of any material law at small strain."""
    if isinstance(material, ClydeFabric):
        material = material.small_strain()
    if isinstance(material, LinearIsotropic):
        return material.membrane_stiffness, material.bending_stiffness
    if isinstance(material, OrthotropicStVK):
        return (0.5 * (material.a11 + material.a22),
                0.5 * (material.warp_bending + material.weft_bending))
    raise TypeError(f"unknown material type {type(material).__name__}")


def load_per_area(model: ShellModel) -> float:
    """Load per unit area f [N/m²]: |ρ_A g + body force| + |pressure| + (Σ|P_k| + Σ|line load
    resultants|) / L² (point and line loads spread over the surface of size L =
    `model.characteristic_length()`)."""
    length = model.characteristic_length()
    loads = model.loads
    f = float(np.linalg.norm(loads.distributed_force(model.material.areal_density)))
    f += abs(loads.pressure)
    f += sum(float(np.linalg.norm(p.force)) for p in loads.point_loads) / length**2
    _, line_forces = quadrature(model.surface, loads.line_loads, dtype=torch.float64)
    return f + float(line_forces.norm(dim=1).sum()) / length**2


def prescribed_displacement(model: ShellModel) -> float:
    """The largest prescribed displacement [m] of the boundary (a rim rotation counts angle ×
    L/2), 0 without."""
    length = model.characteristic_length()
    prescribed = 0.0
    for c in model.boundary.constraints:
        if isinstance(c, (ClampedEdge, HingedEdge, Handle)):
            prescribed = max(prescribed, float(np.linalg.norm(c.displacement)))
        elif isinstance(c, RimRotation):
            prescribed = max(prescribed, abs(c.angle) * length / 2)
    return prescribed


def _bounded(model: ShellModel, samples, u: torch.Tensor) -> float:
    """The largest of the displacements u (N, 3) [m] at the samples, at most the diameter of
    the sampled surface and at least the largest prescribed displacement."""
    positions = samples.r_jets[:, 0]
    diameter = float((positions.amax(dim=0) - positions.amin(dim=0)).norm())
    return max(min(float(u.norm(dim=1).max()), diameter), prescribed_displacement(model))


def coarse_grid(model: ShellModel, most_spans: int):
    """A cubic `SplineConfig` on the model's surface: the grid rule's spans
    (`spline_grid.grid_spans`), at most `most_spans` per direction (at least the degree
    along a symmetry plane)."""
    from taichi_ndf.field import SplineConfig
    from taichi_ndf.spline_grid import grid_spans

    domain, boundary, degree = model.surface.domain, model.boundary, 3
    even = boundary.fold.edge_ends
    rule = grid_spans(model.surface, model.material.thickness, boundary.narrowest_band)
    spans = tuple(max(min(n, most_spans), degree if side else 1)
                  for n, side in zip(rule, even, strict=True))
    return SplineConfig(spans=spans, degree=degree, domain=domain.bounds,
                        periodic=domain.periodic, even_ends=even)


def equilibrium_displacement(model: ShellModel) -> float:
    """The largest displacement [m], at the quadrature points, of the nonlinear equilibrium at
    load factor 1 on a coarse cubic spline grid (`coarse_grid`, at most
    EQUILIBRIUM_ESTIMATE_SPANS spans per direction), by projected Newton from the undeformed
    state with the model's obstacles and prescribed motions, stopped early
    (EQUILIBRIUM_ESTIMATE_TOLERANCE, EQUILIBRIUM_ESTIMATE_ITERATIONS: the largest displacement
    settles long before Π); at most the surface's diameter and at least the largest
    prescribed displacement. Raises what the spline path raises where it cannot solve the
    model (ValueError, RuntimeError)."""
    from taichi_ndf import jets
    from taichi_ndf.minimise.assembly import displacement_at
    from taichi_ndf.operator import DisplacementOperator
    from taichi_ndf.quadrature import span_quadrature
    from taichi_ndf.spline_grid import SplinePlan
    from taichi_ndf.spline_solver import solve_spline
    from taichi_ndf.training import SolverConfig

    config = coarse_grid(model, EQUILIBRIUM_ESTIMATE_SPANS)
    solver = SolverConfig(method="newton", progress=False,
                          newton_max_iterations=EQUILIBRIUM_ESTIMATE_ITERATIONS,
                          newton_tolerance=EQUILIBRIUM_ESTIMATE_TOLERANCE)
    started = time.perf_counter()
    run = solve_spline(model, SplinePlan(config), solver)
    samples = span_quadrature(model.surface, config, model.loads)
    operator = DisplacementOperator(run.field, model.boundary)
    u = displacement_at(operator, samples.xi, run.field.coefficients, 1.0)[:, jets.VALUE]
    if not bool(torch.isfinite(u).all()):
        raise RuntimeError("the coarse equilibrium is not finite")
    estimate = _bounded(model, samples, u)
    log.info("equilibrium displacement estimate %.4g m (%d x %d spans, %d Newton iterations, "
             "%.2f s%s)", estimate, *config.spans, run.levels[-1].iterations,
             time.perf_counter() - started, "" if run.levels[-1].converged else ", stopped early")
    return estimate


def linear_displacement(model: ShellModel) -> float:
    """The largest displacement [m], at the quadrature points, of the linear solution at load
    factor 1: one Newton step K₀ d = −g₀ from the undeformed state, exact (no line search),
    on a cubic spline grid (the grid rule's, at most LINEAR_ESTIMATE_SPANS spans per
    direction), without obstacles and without prescribed motions; at most the surface's
    diameter (the linear solution of a slender structure under a large load can be far
    larger) and at least the largest prescribed displacement. The dimensional estimate
    (`characteristic_displacement`) if nothing loads the shell."""
    from taichi_ndf.field import SplineField
    from taichi_ndf.minimise.assembly import Assembly, local_basis_at
    from taichi_ndf.minimise.linear_solve import damped_solve
    from taichi_ndf.minimise.newton import NewtonConfig, hessian_blocks
    from taichi_ndf.minimise.refinement import held_unknowns
    from taichi_ndf.objective import Objective
    from taichi_ndf.operator import DisplacementOperator
    from taichi_ndf.quadrature import span_quadrature
    from taichi_ndf.shell.hessian import flat_blocks, jet_steps, project_psd

    model = dataclasses.replace(model, contact=None)
    surface, domain, boundary = model.surface, model.surface.domain, model.boundary
    config = coarse_grid(model, LINEAR_ESTIMATE_SPANS)
    field = SplineField(config)
    operator = DisplacementOperator(field, boundary)
    samples = span_quadrature(surface, config, model.loads)
    basis = local_basis_at(operator, samples.xi)
    assembly = Assembly(samples, basis, config.num_coefficients).at_load(operator, 0.0)
    samples = assembly.samples
    potential = Objective.of_model(model).potential(1.0)
    u = assembly.displacement(field.coefficients)
    gradient = assembly.gradient(potential(samples, u, True).grad_u_jets).reshape(-1)
    fixed = held_unknowns(field, boundary, basis)
    if fixed is not None:
        gradient[torch.from_numpy(fixed)] = 0.0
    if float(gradient.abs().max()) == 0.0:
        return characteristic_displacement(model)
    steps = jet_steps(samples.r_jets, u, math.sqrt(domain.rectangle_area),
                      NewtonConfig().fd_step)
    blocks, _ = project_psd(flat_blocks(hessian_blocks(potential, samples, u, steps)))
    step, _ = damped_solve(assembly.hessian(blocks), -gradient.double().cpu().numpy(), 0.0,
                           fixed)
    moved = assembly.displacement(torch.from_numpy(step).to(u).reshape(-1, 3))
    estimate = _bounded(model, samples, moved[:, 0])
    log.info("linear displacement estimate %.4g m (%d x %d spans)", estimate, *config.spans)
    return estimate


def characteristic_displacement(model: ShellModel) -> float:
    """Order of magnitude of the displacement [m]: the smaller of the bending estimate
    f L⁴ / (8 B), the membrane estimate (f L⁴ / D)^{1/3} and the size L, where f is the load
    per unit area (point and line loads spread over the surface); at least the largest prescribed
    displacement; 1e-3 L if nothing loads the shell."""
    length = model.characteristic_length()
    d, b = membrane_and_bending_stiffness(model.material)
    f = load_per_area(model)
    prescribed = prescribed_displacement(model)
    if f == 0.0:
        return max(prescribed, 1e-3 * length)
    bending = f * length**4 / (8 * b)
    membrane = (f * length**4 / d) ** (1 / 3)
    return max(min(bending, membrane, length), prescribed)


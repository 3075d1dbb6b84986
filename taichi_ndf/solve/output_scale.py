"""The output scale a SIREN run starts with: the two estimates that solve, and the choice
among a scene's estimates at run start.

The field's raw output is O(1) at initialisation-scale weights; multiplying it by a
characteristic displacement keeps Adam's step sizes meaningful across scenes whose
displacements differ by orders of magnitude (a pinched cylinder moves 1e-5, a napkin 1 m).
Three estimates (docs/scenes.md, "Field output scale", compares them):
`equilibrium_displacement`, the largest displacement of a coarse nonlinear equilibrium
(`output_scale = "equilibrium"`, and "auto": `scaling.AUTO_ESTIMATE`);
`linear_displacement`, that of one Newton step from the undeformed state (the linear
solution), which overshoots grossly for draped cloth; and the dimensional one
(`scaling.characteristic_displacement`: loads, stiffnesses, size; blind to supports and to
where loads act), which the scene reader sets without solving anything. The two solves here
are capped at the surface's size. `field_for_run` makes them where a run needs them.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from itertools import pairwise

import torch

from taichi_ndf import jets
from taichi_ndf.field import FieldConfig, SplineConfig, SplineField
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.newton import NewtonConfig, hessian_blocks
from taichi_ndf.objective import Objective
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.scaling import (
    AUTO_ESTIMATE,
    characteristic_displacement,
    prescribed_displacement,
)
from taichi_ndf.problem.spline_grid import SplinePlan, grid_spans
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.shell.hessian import flat_blocks, project_psd
from taichi_ndf.solve.spline_solver import solve_spline

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
# The estimates that need a solve at run start, in the order tried for each name; the
# dimensional estimate, set when the scene is read, is what remains if all of them fail.
RUNTIME_ESTIMATES = {"equilibrium": ("equilibrium", "linear"), "linear": ("linear",),
                     "dimensional": ()}
# Fewer Adam iterations in all (a --quick smoke test: 1-15 per load step) keep the dimensional
# estimate: the estimate's solve (0.4-40 s, 106 s with a mesh obstacle) would cost more than
# the run.
MIN_ESTIMATE_ITERATIONS = 100


def field_for_run(field: FieldConfig, estimate: str | None, model: ShellModel,
                  config: SolverConfig) -> FieldConfig:
    """The SIREN configuration a run with `config` trains. A scene is read without solving,
    so an estimated `output_scale` (`estimate`: the scene's name of it,
    `Scene.output_scale_estimate`; None: the scene gave a number) holds the dimensional
    estimate until the run starts; where
    Adam trains the field for at least MIN_ESTIMATE_ITERATIONS iterations over all load steps,
    "equilibrium" and "linear" (and "auto", which is AUTO_ESTIMATE) become their estimate of
    `model` (each falls back to the next cheaper one, "equilibrium" -> "linear" ->
    "dimensional", with a logged warning naming why). Elsewhere (last-layer Newton only: the
    output layer absorbs the scale; a short smoke test) the dimensional estimate is kept."""
    if (estimate is None
            or config.iterations * len(config.load_steps) < MIN_ESTIMATE_ITERATIONS):
        return field
    chain = (*RUNTIME_ESTIMATES[AUTO_ESTIMATE if estimate == "auto" else estimate],
             "dimensional")
    for name, fallback in pairwise(chain):
        try:
            scale = (equilibrium_displacement(model) if name == "equilibrium"
                     else linear_displacement(model))
        except (ValueError, RuntimeError) as err:
            log.warning("output_scale = %r: the %s estimate failed (%s); trying the %s "
                        "estimate", estimate, name, err, fallback)
            continue
        return dataclasses.replace(field, output_scale=scale)
    return field  # the dimensional estimate, set when the scene was read


def _bounded(model: ShellModel, samples, u: torch.Tensor) -> float:
    """The largest of the displacements u (N, 3) [m] at the samples, at most the diameter of
    the sampled surface and at least the largest prescribed displacement."""
    positions = samples.r_jets[:, 0]
    diameter = float((positions.amax(dim=0) - positions.amin(dim=0)).norm())
    return max(min(float(u.norm(dim=1).max()), diameter), prescribed_displacement(model))


def coarse_grid(model: ShellModel, most_spans: int) -> SplineConfig:
    """A cubic `SplineConfig` on the model's surface: the grid rule's spans
    (`spline_grid.grid_spans`), at most `most_spans` per direction (at least the degree
    along a symmetry plane)."""
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
    config = coarse_grid(model, EQUILIBRIUM_ESTIMATE_SPANS)
    solver = SolverConfig(method="newton", progress=False,
                          newton_max_iterations=EQUILIBRIUM_ESTIMATE_ITERATIONS,
                          newton_tolerance=EQUILIBRIUM_ESTIMATE_TOLERANCE)
    started = time.perf_counter()
    run = solve_spline(model, SplinePlan(config), solver)
    samples = GridLinearisation.quadrature(model.surface, config, model.loads)
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
    model = dataclasses.replace(model, contact=None)
    surface, domain, boundary = model.surface, model.surface.domain, model.boundary
    config = coarse_grid(model, LINEAR_ESTIMATE_SPANS)
    field = SplineField(config)
    grid = GridLinearisation(field, boundary, length=math.sqrt(domain.rectangle_area))
    linear = grid.linearisation(0.0, grid.quadrature(surface, config, model.loads))
    samples = linear.samples
    potential = Objective.of_model(model).potential(1.0)
    u = linear.displacement(field.coefficients)
    gradient = linear.gradient(potential(samples, u, True).grad_u_jets)  # held unknowns 0
    if float(gradient.abs().max()) == 0.0:
        return characteristic_displacement(model)
    steps = linear.fd_steps(u, field.coefficients, NewtonConfig().fd_step)
    blocks, _ = project_psd(flat_blocks(hessian_blocks(potential, samples, u, steps)))
    step, _ = linear.solve(linear.hessian(blocks), gradient, 0.0)  # damped_solve
    moved = linear.displacement(step)
    estimate = _bounded(model, samples, moved[:, 0])
    log.info("linear displacement estimate %.4g m (%d x %d spans)", estimate, *config.spans)
    return estimate

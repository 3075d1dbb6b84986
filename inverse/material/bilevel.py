"""Bilevel estimate: minimise the distance between the equilibrium x*(θ) and the observation.

Inner problem: x*(θ) for every θ of a box, from one training of a material-conditioned field
per observed condition (`conditioned`). Outer problem: nonlinear least squares over the
coordinates z (ln θ for stiffness unknowns, the force itself for point-load components) with
the box as bounds (scipy's trust-region-reflective Gauss–Newton, Jacobian by finite
differences in z: the field is smooth in z and there are at most a few unknowns). The box is
centred on the equilibrium-residual estimate when that determines every unknown (clean data),
else on the start values (`search_box`). Residuals, all in metres:
- with correspondence, x*(ξ_k; θ) − p_k for every observed point;
- without, the signed point-to-surface distance n · (x*(ξ_k; θ) − p_k) at the closest point
  ξ_k of the current surface (projected afresh for every θ, so the residual is the distance
  function itself, whose derivative in θ is n · ∂x*/∂θ).

Fitting displacements, not their second derivatives, makes this robust to noise where the
equilibrium-residual estimate is not. Identifiability comes from JᵀJ of the misfit in log
coordinates (`identifiability.analyse`).

Under gravity alone (no known force: no point load, body force or pressure) the shape depends
on the stiffness only through B/(ρ_A g) (and D/(ρ_A g)): the absolute value then rests on the
scene's areal density, and the estimate reports the ratio and the bending length as the
determined quantities.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.optimize import least_squares

from inverse.material.conditioned import (
    CONDITIONABLE,
    ConditionedConfig,
    ConditionedEquilibrium,
    to_coordinates,
    to_values,
)
from inverse.material.identifiability import analyse
from inverse.material.observations import Observation, rms_point_distance
from inverse.material.projection import closest_points, grid_seeds, nearest_seeds
from inverse.material.residual import Estimate, ResidualConfig, residual_estimate, unknown_scales
from inverse.material.unknowns import Unknown
from taichi_ndf import jets

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BilevelConfig:
    """decades: half-width of the box of each unknown, in decades around its start value;
    centre_on_residual: first run the equilibrium-residual estimate (`residual`) and, when it
        determines every unknown, centre the box on it with half-width `residual_decades`
        (widened to 4 of its relative standard deviations) instead of the start values (off by
        default: on the cantilever strip the narrower box gave −4.9 % against −0.5 % for the
        wide box around the start, the conditioned field's own error dominating);
    load_box: half-width of the box of a point-load component (signed, linear coordinates)
        around its start, in units of the magnitude of the start force vector; around a
        determined residual estimate, half of that;
    max_iterations: outer Gauss–Newton iterations (Jacobian evaluations, about);
    tolerance: relative change of the misfit (and step in z) that stops the outer iterations;
    projection_grid: seeds per coordinate for the closest-point search of point clouds;
    field: training of the material-conditioned field."""

    decades: float = 1.3
    centre_on_residual: bool = False
    residual_decades: float = 0.3
    residual: ResidualConfig = ResidualConfig(samples=16384)
    load_box: float = 1.0
    max_iterations: int = 30
    tolerance: float = 1e-10
    projection_grid: int = 48
    field: ConditionedConfig = ConditionedConfig()

    def __post_init__(self):
        if not self.load_box > 0:
            raise ValueError(f"load_box must be positive, got {self.load_box!r}")
        for name in ("decades", "residual_decades"):
            if not 0 < getattr(self, name) <= 4:
                raise ValueError(f"{name} must be in (0, 4], got {getattr(self, name)!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations!r}")
        if not self.tolerance > 0:
            raise ValueError(f"tolerance must be positive, got {self.tolerance!r}")
        if self.projection_grid < 4:
            raise ValueError(f"projection_grid must be >= 4, got {self.projection_grid!r}")


@dataclass
class BilevelResult:
    """The estimate with what the outer problem needs afterwards: the trained equilibria;
    `ranges`: the box of coordinates (ln θ, or θ for point-load components); `box_centre`:
    what the box was centred on ("start values", "residual estimate" or "given equilibria")
    and `box_centre_values` its centre; `ratios`: determined ratios under gravity alone
    (name -> value, relative standard error); `notes`: caveats for the report."""

    estimate: Estimate
    equilibria: list[ConditionedEquilibrium]
    ranges: list[tuple[float, float]]
    box_centre: str = "start values"
    box_centre_values: list[float] = field(default_factory=list)
    ratios: dict[str, tuple[float, float]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def fitted_positions(self, index: int, xi: torch.Tensor) -> torch.Tensor:
        """Equilibrium positions (N, 3) [m] of observation `index` at the estimate."""
        return self.equilibria[index].positions(
            xi, to_coordinates(self.estimate.unknowns, self.estimate.values))


def gravity_only(model) -> bool:
    """True when gravity is the only load: nothing fixes a force scale apart from ρ_A g."""
    loads = model.loads
    return (not loads.point_loads and not any(loads.body_force) and loads.pressure == 0.0
            and any(loads.gravity))


def gravity_ratios(observations: list[Observation], unknowns: list[Unknown], values,
                   ident) -> tuple[dict[str, tuple[float, float]], list[str]]:
    """Under gravity alone: the determined stiffness values over ρ_A g (value, relative
    standard error) and a note that absolute values rest on the scene's areal density;
    otherwise nothing."""
    if not all(gravity_only(obs.model) for obs in observations):
        return {}, []
    model0 = observations[0].model
    rho_g = model0.material.areal_density * math.dist(model0.loads.gravity, (0, 0, 0))
    ratios = {f"{u.key}/(areal_density*g)": (values[j] / rho_g, float(ident.std[j]))
              for j, u in enumerate(unknowns) if u.kind == "stiffness" and ident.determined[j]}
    return ratios, [f"gravity is the only load: the shape determines stiffness only relative "
                    f"to the weight ρ_A g; absolute values assume the scene's areal density "
                    f"ρ_A = {model0.material.areal_density:g} kg/m²"]


def closest_surface_points(equilibrium, z, points: torch.Tensor, grid: int) -> torch.Tensor:
    """Closest points ξ (M, 2) of the equilibrium surface x*(·; θ) to `points`: nearest grid
    seed, then Gauss–Newton on |x(ξ) − p|² clipped to the parameter rectangle
    (`projection`). equilibrium: anything with `positions(ξ, z)` and `position_jets(ξ, z)`."""
    domain = equilibrium.model.surface.domain
    seeds = grid_seeds(domain, grid, points.dtype)
    xi = nearest_seeds(seeds, equilibrium.positions(seeds, z), points)
    return closest_points(lambda q: equilibrium.position_jets(q, z), domain.bounds, points, xi,
                          steps=8)


def _residuals(equilibrium: ConditionedEquilibrium, observation: Observation, z,
               grid: int) -> np.ndarray:
    points = observation.points.to(equilibrium.field.parameters[0].dtype)
    if observation.xi is not None:
        return (equilibrium.positions(observation.xi, z) - points).numpy().ravel()
    xi = closest_surface_points(equilibrium, z, points, grid)
    x = equilibrium.position_jets(xi, z)
    normal = torch.linalg.cross(x[:, jets.D1], x[:, jets.D2], dim=-1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    return ((x[:, jets.VALUE] - points) * normal).sum(dim=1).numpy()


def _box(unknowns: list[Unknown], values: np.ndarray, positive_half: list[float],
         load_half: float) -> list[tuple[float, float]]:
    """Coordinate ranges around `values`: ± positive_half[j] in ln θ for positive unknowns,
    ± load_half · |force vector| for point-load components."""
    scale = unknown_scales(unknowns, values)
    z = to_coordinates(unknowns, values)
    return [(zj - h, zj + h) if u.positive else (zj - load_half * s, zj + load_half * s)
            for u, zj, h, s in zip(unknowns, z, positive_half, scale, strict=True)]


def search_box(observations: list[Observation], unknowns: list[Unknown],
               config: BilevelConfig, start_values: np.ndarray
               ) -> tuple[list[tuple[float, float]], str, list[str]]:
    """Coordinate box of the conditioned field, what it is centred on, and notes.

    With `config.centre_on_residual`, the equilibrium-residual estimate (no inner solve) is
    tried first; when it determines every unknown (positive ones with a positive value), the
    box is centred on it with half-width max(`residual_decades`·ln 10, 4 relative standard
    deviations) for positive unknowns and `load_box`/2 · |force| for point-load components.
    Otherwise (noisy data, an undetermined unknown, the option off) the box is `decades`
    either side of the start values (`load_box` · |start force| for point loads)."""
    notes = []
    if config.centre_on_residual:
        try:
            residual = residual_estimate(observations, unknowns, config.residual)
        except ValueError as err:  # e.g. nothing known sets the scale
            residual = None
            notes.append(f"residual estimate not used for the search box: {err}")
        if residual is not None:
            positive = np.array([u.positive for u in unknowns])
            determined = all(residual.identifiability.determined) and bool(
                np.all(residual.values[positive] > 0))
            if determined:
                half = [max(config.residual_decades * math.log(10.0), 4.0 * float(s))
                        for s in residual.identifiability.std]
                return (_box(unknowns, residual.values, half, 0.5 * config.load_box),
                        "residual estimate", notes)
            notes.append("the equilibrium-residual estimate did not determine every unknown "
                         "(noisy data?): search box centred on the start values")
    half = [config.decades * math.log(10.0)] * len(unknowns)
    return _box(unknowns, start_values, half, config.load_box), "start values", notes


def bilevel_estimate(observations: list[Observation], unknowns: list[Unknown],
                     config: BilevelConfig = BilevelConfig(), *,
                     start: list[float] | None = None,
                     equilibria: list[ConditionedEquilibrium] | None = None) -> BilevelResult:
    """Estimate stiffness and point-load unknowns by fitting equilibria to the observations.

    start: start values of the unknowns (default: the first observation's model values); the
        box is centred on the equilibrium-residual estimate when that determines every
        unknown (`search_box`), else `config.decades` decades either side of the start, so
        the truth may be up to that far from the start.
    equilibria: already trained conditioned fields, one per observation (e.g. from a
        previous result for the same conditions and start); their boxes are used.
    """
    t0 = time.perf_counter()
    names = [u.name for u in unknowns]
    loads = [u.name for u in unknowns if u.kind not in CONDITIONABLE]
    if loads:
        raise ValueError(f"the bilevel method estimates stiffness and point-load unknowns "
                         f"only, not {loads}: estimate those with the residual method")
    model0 = observations[0].model
    start_values = np.array([u.value(model0) for u in unknowns] if start is None else start,
                            dtype=np.float64)
    positive = np.array([u.positive for u in unknowns])
    if len(start_values) != len(unknowns) or not np.all(start_values[positive] > 0):
        raise ValueError(f"start values must be one per unknown {names}, positive for "
                         f"stiffness unknowns, got {start_values.tolist()}")
    zero_force = any(u.kind == "point_load" and not np.any(start_values[[
        i for i, w in enumerate(unknowns) if (w.kind, w.key) == (u.kind, u.key)]])
        for u in unknowns)
    if zero_force or not np.all(np.isfinite(start_values)):
        raise ValueError(f"start values must be finite and a start force non-zero (it sets "
                         f"the size of the search box), got {start_values.tolist()}")
    notes = []
    if equilibria is None:
        ranges, centre, notes = search_box(observations, unknowns, config, start_values)
        log.info("bilevel search box centred on the %s: %s", centre,
                 dict(zip(names, zip(to_values(unknowns, [lo for lo, _ in ranges]),
                                     to_values(unknowns, [hi for _, hi in ranges]),
                                     strict=True), strict=True)))
        equilibria = [ConditionedEquilibrium(obs.model, unknowns, ranges,
                                             config.field).train() for obs in observations]
    elif len(equilibria) != len(observations):
        raise ValueError(f"need one trained equilibrium per observation, got "
                         f"{len(equilibria)} for {len(observations)}")
    else:
        centre = "given equilibria"
    ranges = equilibria[0].ranges
    lower = np.array([lo for lo, _ in ranges])
    upper = np.array([hi for _, hi in ranges])
    centre_values = to_values(unknowns, 0.5 * (lower + upper))
    # Start the outer iterations at the box centre when the box was centred on the residual
    # estimate (it is the better start), else at the start values.
    z0 = np.array(to_coordinates(unknowns, centre_values if centre == "residual estimate"
                                 else start_values))
    z0 = np.clip(z0, lower, upper)
    grid = config.projection_grid

    def residuals(z):
        return np.concatenate([_residuals(eq, obs, z, grid)
                               for eq, obs in zip(equilibria, observations, strict=True)])

    # Characteristic size of each coordinate (trust-region scaling): 1 for ln θ, the box for
    # forces.
    x_scale = np.where(positive, 1.0, 0.5 * (upper - lower))
    solution = least_squares(residuals, z0, bounds=(lower, upper), method="trf",
                             jac="2-point", diff_step=1e-5, x_scale=x_scale,
                             ftol=config.tolerance, xtol=config.tolerance,
                             gtol=config.tolerance, max_nfev=config.max_iterations * (
                                 len(unknowns) + 1))
    z = solution.x
    values = np.array(to_values(unknowns, z))
    r = solution.fun
    # Identifiability in normalised coordinates: ln θ, or a force over its vector's magnitude.
    scale = unknown_scales(unknowns, values)
    jac = np.atleast_2d(solution.jac) * np.where(positive, 1.0, scale)
    dof = max(len(r) - len(unknowns), 1)
    sigma2 = float(r @ r) / dof
    ident = analyse(jac, sigma2, names, positive.tolist())
    low_values, high_values = to_values(unknowns, lower), to_values(unknowns, upper)
    for j, name in enumerate(names):
        margin = 0.05 * 0.5 * (upper[j] - lower[j])
        if z[j] - lower[j] < margin or upper[j] - z[j] < margin:
            ident.determined[j] = False
            notes.append(f"{name} ended at the edge of its search box "
                         f"[{low_values[j]:.4g}, {high_values[j]:.4g}]: the truth may "
                         f"lie outside; start closer or widen the box")
    errors = np.where(ident.determined, ident.std * scale, np.inf)
    rms = rms_point_distance(r, observations)
    elapsed = time.perf_counter() - t0
    estimate = Estimate(unknowns, values, errors, ident, rms, int(solution.njev or 0),
                        elapsed, "bilevel", residuals=r)
    result = BilevelResult(estimate, equilibria, ranges, box_centre=centre,
                           box_centre_values=centre_values, notes=notes)
    ratios, note = gravity_ratios(observations, unknowns, values, ident)
    result.ratios.update(ratios)
    result.notes += note
    log.info("bilevel estimate: %s (rms misfit %.3g m, %d Jacobians, %.1f s)",
             dict(zip(names, values.tolist(), strict=True)), rms, estimate.iterations, elapsed)
    return result

"""Bilevel estimate: minimise the distance between the equilibrium x*(θ) and the observation.

Inner problem: x*(θ) for every θ of a box in log space, from one training of a
material-conditioned field per observed condition (`conditioned`). Outer problem: nonlinear
least squares over z = log θ with the box as bounds (scipy's trust-region-reflective
Gauss–Newton, Jacobian by finite differences in z: the field is smooth in z and there are at
most a few unknowns). Residuals, all in metres:
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
from scipy.spatial import cKDTree

from inverse.material.conditioned import (
    CONDITIONABLE,
    ConditionedConfig,
    ConditionedEquilibrium,
)
from inverse.material.identifiability import analyse
from inverse.material.observations import Observation
from inverse.material.residual import Estimate
from inverse.material.unknowns import Unknown
from taichi_ndf import jets

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BilevelConfig:
    """decades: half-width of the box of each unknown, in decades around its start value;
    max_iterations: outer Gauss–Newton iterations (Jacobian evaluations, about);
    tolerance: relative change of the misfit (and step in z) that stops the outer iterations;
    projection_grid: seeds per coordinate for the closest-point search of point clouds;
    field: training of the material-conditioned field."""

    decades: float = 1.3
    max_iterations: int = 30
    tolerance: float = 1e-10
    projection_grid: int = 48
    field: ConditionedConfig = ConditionedConfig()

    def __post_init__(self):
        if not 0 < self.decades <= 4:
            raise ValueError(f"decades must be in (0, 4], got {self.decades!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations!r}")
        if not self.tolerance > 0:
            raise ValueError(f"tolerance must be positive, got {self.tolerance!r}")
        if self.projection_grid < 4:
            raise ValueError(f"projection_grid must be >= 4, got {self.projection_grid!r}")


@dataclass
class BilevelResult:
    """The estimate with what the outer problem needs afterwards: the trained equilibria and
    the log-parameter box; `ratios`: determined ratios under gravity alone (name -> value,
    relative standard error); `notes`: caveats for the report."""

    estimate: Estimate
    equilibria: list[ConditionedEquilibrium]
    log_ranges: list[tuple[float, float]]
    ratios: dict[str, tuple[float, float]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def fitted_positions(self, index: int, xi: torch.Tensor) -> torch.Tensor:
        """Equilibrium positions (N, 3) [m] of observation `index` at the estimate."""
        return self.equilibria[index].positions(xi, np.log(self.estimate.values))


def gravity_only(model) -> bool:
    """True when gravity is the only load: nothing fixes a force scale apart from ρ_A g."""
    loads = model.loads
    return (not loads.point_loads and not any(loads.body_force) and loads.pressure == 0.0
            and any(loads.gravity))


def _project(equilibrium: ConditionedEquilibrium, z, points: torch.Tensor,
             grid: int) -> torch.Tensor:
    """Closest points ξ (M, 2) of the surface x*(·; θ) to `points`: nearest grid seed, then
    Gauss–Newton on |x(ξ) − p|² clipped to the parameter rectangle."""
    domain = equilibrium.model.surface.domain
    (lo1, hi1), (lo2, hi2) = domain.bounds
    dtype = points.dtype
    g1, g2 = torch.meshgrid(torch.linspace(lo1, hi1, grid, dtype=dtype),
                            torch.linspace(lo2, hi2, grid, dtype=dtype), indexing="ij")
    seeds = torch.stack([g1.ravel(), g2.ravel()], dim=1)
    seeds = seeds[domain.contains(seeds)]
    _, nearest = cKDTree(equilibrium.positions(seeds, z).numpy()).query(points.numpy())
    xi = seeds[torch.from_numpy(np.asarray(nearest))]
    lo = torch.tensor([lo1, lo2], dtype=dtype)
    hi = torch.tensor([hi1, hi2], dtype=dtype)
    for _ in range(8):
        x = equilibrium.position_jets(xi, z)
        tangent = torch.stack([x[:, jets.D1], x[:, jets.D2]], dim=1)  # (M, 2, 3)
        gap = points - x[:, jets.VALUE]
        normal = tangent @ tangent.transpose(1, 2)
        rhs = (tangent @ gap[:, :, None])[:, :, 0]
        xi = torch.minimum(torch.maximum(xi + torch.linalg.solve(normal, rhs), lo), hi)
    return xi


def _residuals(equilibrium: ConditionedEquilibrium, observation: Observation, z,
               grid: int) -> np.ndarray:
    points = observation.points.to(equilibrium.field.parameters[0].dtype)
    if observation.xi is not None:
        return (equilibrium.positions(observation.xi, z) - points).numpy().ravel()
    xi = _project(equilibrium, z, points, grid)
    x = equilibrium.position_jets(xi, z)
    normal = torch.linalg.cross(x[:, jets.D1], x[:, jets.D2], dim=-1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    return ((x[:, jets.VALUE] - points) * normal).sum(dim=1).numpy()


def bilevel_estimate(observations: list[Observation], unknowns: list[Unknown],
                     config: BilevelConfig = BilevelConfig(), *,
                     start: list[float] | None = None,
                     equilibria: list[ConditionedEquilibrium] | None = None) -> BilevelResult:
    """Estimate stiffness unknowns by fitting equilibria to the observations.

    start: start values of the unknowns (default: the first observation's model values); the
        box is `config.decades` decades either side of them, so the truth may be up to that
        far from the start.
    equilibria: already trained conditioned fields, one per observation (e.g. from a
        previous result for the same conditions and start); their boxes are used.
    """
    t0 = time.perf_counter()
    names = [u.name for u in unknowns]
    loads = [u.name for u in unknowns if u.kind not in CONDITIONABLE]
    if loads:
        raise ValueError(f"the bilevel method estimates stiffness unknowns only, not {loads}: "
                         f"estimate loads with the residual method")
    model0 = observations[0].model
    start_values = np.array([u.value(model0) for u in unknowns] if start is None else start,
                            dtype=np.float64)
    if len(start_values) != len(unknowns) or not np.all(start_values > 0):
        raise ValueError(f"start values must be positive, one per unknown {names}, got "
                         f"{start_values.tolist()}")
    z0 = np.log(start_values)
    if equilibria is None:
        half = config.decades * math.log(10.0)
        log_ranges = [(z - half, z + half) for z in z0]
        equilibria = [ConditionedEquilibrium(obs.model, unknowns, log_ranges,
                                             config.field).train() for obs in observations]
    elif len(equilibria) != len(observations):
        raise ValueError(f"need one trained equilibrium per observation, got "
                         f"{len(equilibria)} for {len(observations)}")
    log_ranges = equilibria[0].log_ranges
    half = 0.5 * min(hi - lo for lo, hi in log_ranges)
    z0 = np.clip(z0, [lo for lo, _ in log_ranges], [hi for _, hi in log_ranges])
    grid = config.projection_grid

    def residuals(z):
        return np.concatenate([_residuals(eq, obs, z, grid)
                               for eq, obs in zip(equilibria, observations, strict=True)])

    lower = np.array([lo for lo, _ in log_ranges])
    upper = np.array([hi for _, hi in log_ranges])
    solution = least_squares(residuals, z0, bounds=(lower, upper), method="trf",
                             jac="2-point", diff_step=1e-5, x_scale=1.0,
                             ftol=config.tolerance, xtol=config.tolerance,
                             gtol=config.tolerance, max_nfev=config.max_iterations * (
                                 len(unknowns) + 1))
    z = solution.x
    values = np.exp(z)
    r = solution.fun
    jac = np.atleast_2d(solution.jac)
    dof = max(len(r) - len(unknowns), 1)
    sigma2 = float(r @ r) / dof
    ident = analyse(jac, sigma2, names, [True] * len(unknowns))
    notes = []
    margin = 0.05 * half
    for j, name in enumerate(names):
        if z[j] - lower[j] < margin or upper[j] - z[j] < margin:
            ident.determined[j] = False
            notes.append(f"{name} ended at the edge of its search box "
                         f"[{math.exp(lower[j]):.4g}, {math.exp(upper[j]):.4g}]: the truth may "
                         f"lie outside; start closer or widen the box")
    errors = np.where(ident.determined, ident.std * values, np.inf)
    rms = math.sqrt(float(r @ r) / max(len(r), 1))
    elapsed = time.perf_counter() - t0
    estimate = Estimate(unknowns, values, errors, ident, rms, int(solution.njev or 0),
                        elapsed, "bilevel_conditioned_field")
    result = BilevelResult(estimate, equilibria, log_ranges, notes=notes)
    if all(gravity_only(obs.model) for obs in observations):
        rho_g = model0.material.areal_density * math.dist(model0.loads.gravity, (0, 0, 0))
        for j, u in enumerate(unknowns):
            if u.kind == "stiffness" and ident.determined[j]:
                result.ratios[f"{u.key}/(areal_density*g)"] = (values[j] / rho_g,
                                                               float(ident.std[j]))
        result.notes.append(
            f"gravity is the only load: the shape determines stiffness only relative to the "
            f"weight ρ_A g; absolute values assume the scene's areal density "
            f"ρ_A = {model0.material.areal_density:g} kg/m²")
    log.info("bilevel estimate: %s (rms misfit %.3g m, %d Jacobians, %.1f s)",
             dict(zip(names, values.tolist(), strict=True)), rms, estimate.iterations, elapsed)
    return result

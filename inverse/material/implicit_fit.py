"""Bilevel estimate with implicit-function gradients: the outer problem over the
equilibria of `inverse.material.implicit` (their residuals against observations and the
Jacobian from da*/dz).

Outer problem: Levenberg–Marquardt on the residuals (metres) over z, unbounded (no box: every
iterate is an exact re-solve, so nothing limits where z may go), each step capped at
`max_step` in normalised coordinates (ln θ; a signed unknown over the magnitude of its vector
group at the start) and accepted only if the misfit falls. Stops on a relative step below
`tolerance`.

Uncertainty: the Fisher matrix of the implicit Jacobian (`identifiability.analyse`) assumes an
exact forward model. The forward model's own error (its basis: the features) is measured by
repeating the estimate with feature seeds `seeds` (and `widths`); the estimate is the mean over
the bases (in z), and the reported standard error combines in quadrature the Fisher standard
error with the standard deviation of the estimates over the bases. An unknown whose combined
relative standard deviation exceeds `identifiability.UNDETERMINED_STD` is undetermined.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from inverse.material.bilevel import closest_surface_points, gravity_ratios
from inverse.material.conditioned import to_coordinates, to_values
from inverse.material.identifiability import UNDETERMINED_STD, Identifiability, analyse
from inverse.material.implicit import ImplicitConfig, ImplicitEquilibrium
from inverse.material.observations import Observation
from inverse.material.residual import Estimate, unknown_scales
from inverse.material.unknowns import Unknown
from taichi_ndf import jets

log = logging.getLogger(__name__)

# Levenberg–Marquardt trials per outer iteration (damping × 10 after each rejected one).
LM_ATTEMPTS = 6


def residuals(equilibrium: ImplicitEquilibrium, observation: Observation, grid: int,
              sensitivity: torch.Tensor | None = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals [m] of the current equilibrium against an observation (module docstring) and,
    given da*/dz, their Jacobian (R, p) in z."""
    points = observation.points.to(equilibrium.field.parameters[0].dtype)
    if observation.xi is not None:
        xi = observation.xi
        r = (equilibrium.positions(xi) - points).reshape(-1)
        if sensitivity is None:
            return r.numpy(), None
        dx = equilibrium.position_sensitivity(xi, sensitivity)
        return r.numpy(), dx.reshape(-1, dx.shape[-1]).numpy()
    xi = closest_surface_points(equilibrium, None, points, grid)
    x = equilibrium.position_jets(xi)
    normal = torch.linalg.cross(x[:, jets.D1], x[:, jets.D2], dim=-1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    r = ((x[:, jets.VALUE] - points) * normal).sum(dim=1)
    if sensitivity is None:
        return r.numpy(), None
    dx = equilibrium.position_sensitivity(xi, sensitivity)
    return r.numpy(), torch.einsum("nk,nkj->nj", normal, dx).numpy()


@dataclass
class BasisFit:
    """The outer fit on one feature basis: values, z, residuals and Jacobian in z at the end,
    outer iterations, Newton steps, time [s]."""

    seed: int
    width: int
    values: np.ndarray
    z: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    iterations: int
    newton_steps: int
    time: float
    converged: bool


@dataclass
class ImplicitResult:
    """The combined estimate, the per-basis fits, the forward models (one list per basis,
    one per observation), the spread of the per-basis estimates (absolute, per unknown) and
    the Fisher standard errors of the first basis; `ratios` and `notes` as `BilevelResult`."""

    estimate: Estimate
    fits: list[BasisFit]
    equilibria: list[list[ImplicitEquilibrium]]
    fisher_errors: np.ndarray
    spread: np.ndarray
    ratios: dict[str, tuple[float, float]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def fitted_positions(self, index: int, xi: torch.Tensor) -> torch.Tensor:
        """Equilibrium positions (N, 3) [m] of observation `index` on the first basis."""
        return self.equilibria[0][index].positions(xi)


def _evaluate(equilibria, observations, grid, jacobian: bool):
    rs, js, sens = [], [], []
    for eq, obs in zip(equilibria, observations, strict=True):
        s = eq.sensitivity() if jacobian else None
        r, j = residuals(eq, obs, grid, s)
        rs.append(r)
        js.append(j)
        sens.append(s)
    r = np.concatenate(rs)
    return r, (np.concatenate(js) if jacobian else None), sens


def fit_basis(equilibria: list[ImplicitEquilibrium], observations: list[Observation],
              unknowns: list[Unknown], start_values: np.ndarray,
              config: ImplicitConfig) -> BasisFit:
    """Levenberg–Marquardt over z on one feature basis, from the start values."""
    t0 = time.perf_counter()
    steps0 = sum(eq.newton_steps for eq in equilibria)
    grid = config.projection_grid
    z = np.array(to_coordinates(unknowns, start_values))
    positive = np.array([u.positive for u in unknowns])
    norm = np.where(positive, 1.0, unknown_scales(unknowns, start_values))
    for eq in equilibria:
        eq.solve(start_values, from_reference=True)
    r, jac, sens = _evaluate(equilibria, observations, grid, True)
    cost = float(r @ r)
    mu, iterations, converged = 1e-3, 0, False
    for iterations in range(1, config.max_iterations + 1):
        js = jac * norm
        a, g = js.T @ js, js.T @ r
        states = [eq.state() for eq in equilibria]
        accepted = False
        for _attempt in range(LM_ATTEMPTS):
            damped = a + mu * np.diag(np.maximum(np.diag(a), 1e-30 * np.trace(a) + 1e-300))
            step = -np.linalg.solve(damped, g)
            largest = float(np.abs(step).max())
            if largest > config.max_step:
                step *= config.max_step / largest
            dz = step * norm
            trial = z + dz
            values = np.array(to_values(unknowns, trial))
            for eq, s in zip(equilibria, sens, strict=True):
                eq.solve(values, prediction=torch.einsum("kaj,j->ka", s, torch.from_numpy(dz)))
            r_trial, _, _ = _evaluate(equilibria, observations, grid, False)
            cost_trial = float(r_trial @ r_trial)
            if math.isfinite(cost_trial) and cost_trial < cost:
                accepted = True
                mu = max(mu / 3, 1e-9)
                break
            for eq, state in zip(equilibria, states, strict=True):
                eq.set_state(state, to_values(unknowns, z))
            mu *= 10
        if not accepted:
            converged = True  # no step lowers the misfit: a minimum within rounding
            log.info("implicit fit: no step lowers the misfit at iteration %d", iterations)
            break
        relative = cost - cost_trial
        z, cost = trial, cost_trial
        r, jac, sens = _evaluate(equilibria, observations, grid, True)
        log.info("implicit fit (seed %d) iteration %d: %s, rms %.4g m, step %.3g, mu %.2g",
                 equilibria[0].seed, iterations,
                 dict(zip([u.name for u in unknowns], to_values(unknowns, z), strict=True)),
                 math.sqrt(cost / len(r)), float(np.abs(step).max()), mu)
        if float(np.abs(step).max()) < config.tolerance or relative <= 1e-14 * cost:
            converged = True
            break
    return BasisFit(seed=equilibria[0].seed, width=equilibria[0].field.config.width,
                    values=np.array(to_values(unknowns, z)), z=z, residuals=r, jacobian=jac,
                    iterations=iterations,
                    newton_steps=sum(eq.newton_steps for eq in equilibria) - steps0,
                    time=time.perf_counter() - t0, converged=converged)


def _check(observations: list[Observation], unknowns: list[Unknown], start) -> np.ndarray:
    if not observations:
        raise ValueError("need at least one observation")
    names = [u.name for u in unknowns]
    model0 = observations[0].model
    values = np.array([u.value(model0) for u in unknowns] if start is None else start,
                      dtype=np.float64)
    positive = np.array([u.positive for u in unknowns])
    if values.shape != (len(unknowns),) or not np.all(np.isfinite(values)) or \
            not np.all(values[positive] > 0):
        raise ValueError(f"start values must be finite, one per unknown {names} and positive "
                         f"for {[n for n, p in zip(names, positive, strict=True) if p]}, got "
                         f"{values.tolist()}")
    return values


def implicit_estimate(observations: list[Observation], unknowns: list[Unknown],
                      config: ImplicitConfig | None = None, *,
                      start: list[float] | None = None,
                      equilibria: list[list[ImplicitEquilibrium]] | None = None
                      ) -> ImplicitResult:
    """Estimate any unknowns of `parse_unknowns` by fitting Newton equilibria, one outer fit
    per feature basis of `config` (module docstring).

    start: start values (default: the first observation's model values).
    equilibria: forward models from an earlier result for the same conditions (one list per
        basis, one per observation): their start solution is reused."""
    config = config or ImplicitConfig()
    t0 = time.perf_counter()
    start_values = _check(observations, unknowns, start)
    names = [u.name for u in unknowns]
    positive = np.array([u.positive for u in unknowns])
    bases = config.bases()
    if equilibria is None:
        equilibria = [[ImplicitEquilibrium(obs.model, unknowns, config, seed, width)
                       for obs in observations] for seed, width in bases]
    elif len(equilibria) != len(bases) or any(len(e) != len(observations) for e in equilibria):
        raise ValueError(f"need one forward model per basis ({len(bases)}) and observation "
                         f"({len(observations)})")
    fits = [fit_basis(eqs, observations, unknowns, start_values, config) for eqs in equilibria]
    zs = np.array([f.z for f in fits])
    z = zs.mean(axis=0)
    values = np.array(to_values(unknowns, z))
    scale = unknown_scales(unknowns, values)
    norm = np.where(positive, 1.0, scale)  # normalised coordinates: ln θ, or θ / |group|
    spread_std = (zs.std(axis=0, ddof=1) / norm if len(fits) > 1
                  else np.zeros(len(unknowns)))
    first = fits[0]
    r = first.residuals
    dof = max(len(r) - len(unknowns), 1)
    sigma2 = float(r @ r) / dof
    ident = analyse(first.jacobian * norm, sigma2, names, positive.tolist())
    fisher_std = ident.std.copy()
    combined = np.sqrt(fisher_std**2 + spread_std**2)
    ident = Identifiability(ident.fisher, ident.eigenvalues, ident.eigenvectors, combined,
                            [bool(c < UNDETERMINED_STD) for c in combined], ident.combinations)
    notes = []
    if len(fits) > 1:
        notes.append(
            f"standard errors combine in quadrature the Fisher error (exact forward model) and "
            f"the standard deviation of the estimates over {len(fits)} feature bases "
            f"(seed, width) {[(f.seed, f.width) for f in fits]}")
    else:
        notes.append("one feature basis: the standard errors are Fisher errors only and "
                     "ignore the forward model's error")
    for f in fits:
        if not f.converged:
            notes.append(f"basis (seed {f.seed}, width {f.width}) stopped at the iteration "
                         f"limit ({f.iterations}) before the step fell below the tolerance")
    errors = np.where(ident.determined, combined * scale, np.inf)
    rms = math.sqrt(float(r @ r) / max(len(r), 1))
    elapsed = time.perf_counter() - t0
    estimate = Estimate(unknowns, values, errors, ident, rms, sum(f.iterations for f in fits),
                        elapsed, "bilevel_implicit_function")
    ratios, note = gravity_ratios(observations, unknowns, values, ident)
    result = ImplicitResult(estimate, fits, equilibria, np.where(
        np.isfinite(fisher_std), fisher_std * scale, np.inf), spread_std * scale,
        ratios=ratios, notes=notes + note)
    log.info("implicit estimate: %s ± %s (bases %s; rms misfit %.3g m, %.1f s)",
             dict(zip(names, values.tolist(), strict=True)), errors.tolist(),
             [f.values.tolist() for f in fits], rms, elapsed)
    return result

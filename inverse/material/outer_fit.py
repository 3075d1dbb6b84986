"""The outer problem of the implicit-function estimates, shared by their forward models.

A forward model (`implicit.ImplicitEquilibrium`: last-layer Newton on fixed SIREN features;
`spline_equilibrium.SplineEquilibrium`: projected Newton on a spline grid) gives, for unknowns
θ, the equilibrium and its sensitivity to the outer coordinates z (ln θ for positive unknowns,
the value for signed ones). Its interface: `solve(values, prediction=, from_reference=)`,
`state()` / `set_state(state, values)`, `sensitivity()`, `predicted_change(sensitivity, dz)`,
`positions(ξ)`, `position_jets(ξ)`, `position_sensitivity(ξ, sensitivity)`, `model`,
`field` (its dtype), `label` (a dict naming it in reports), `newton_steps`.

Outer problem (`fit`): Levenberg–Marquardt on the residuals (metres) over z, unbounded (no
box: every iterate is an exact re-solve), each step capped at `max_step` in normalised
coordinates (ln θ; a signed unknown over the magnitude of its vector group at the start) and
accepted only if the misfit falls. Stops on a relative step below `tolerance`, or when no
damped step lowers the misfit. Residuals: x*(ξ_k) − p_k with correspondence, else the signed
distance n · (x(ξ_k) − p_k) at the closest point ξ_k; an observation with `rows` gives
rows_k (x*(ξ_k) − p_k), the components it observed.

Local unknowns: a forward model may have unknowns of its observation alone
(`Equilibrium.local_count`, e.g. its held points' offsets, `inverse.material.handles`); they
join z in the Levenberg–Marquardt step (normalised by the model's `local_scale`), each
observation's in a column block of its own. The fit's `jacobian` is then θ's columns with
each observation's local columns projected out of its rows (`profiled`): the covariance of θ
from it is θ's block of the full covariance — θ's error with the local unknowns estimated.

Uncertainty (`combine`): the Fisher matrix JᵀJ/σ² of the final Jacobian (σ² from the residual
at the estimate; the Gauss–Newton covariance, `identifiability.analyse`) gives the noise part;
the caller gives the forward model's part (the spread over feature bases, or the difference
between two grid levels); the reported standard error combines both in quadrature, and an
unknown whose combined relative standard deviation exceeds `identifiability.UNDETERMINED_STD`
is undetermined.
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
from inverse.material.observations import Observation, rms_point_distance
from inverse.material.residual import Estimate, unknown_scales
from inverse.material.unknowns import Unknown
from taichi_ndf import jets, progress

log = logging.getLogger(__name__)

# Levenberg–Marquardt trials per outer iteration (damping × 10 after each rejected one).
LM_ATTEMPTS = 6


@dataclass(frozen=True)
class OuterConfig:
    """max_iterations: outer Levenberg–Marquardt iterations (Jacobians); tolerance: stop when
    the outer step is below this in normalised coordinates; max_step: largest outer step in
    normalised coordinates (1: a factor e in θ, or the start magnitude of a force);
    projection_grid: seeds per coordinate of the closest-point search of point clouds."""

    max_iterations: int = 30
    tolerance: float = 1e-4
    max_step: float = 1.0
    projection_grid: int = 48

    def __post_init__(self):
        for name in ("max_iterations", "projection_grid"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("tolerance", "max_step"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")


def residuals(equilibrium, observation: Observation, grid: int,
              sensitivity: torch.Tensor | None = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals [m] of the current equilibrium against an observation (module docstring) and,
    given its sensitivity, their Jacobian (R, p) in z."""
    points = observation.points.to(equilibrium.field.parameters[0].dtype)
    if observation.xi is not None:
        xi = observation.xi
        r = equilibrium.positions(xi) - points
        rows = None if observation.rows is None else observation.rows.to(points.dtype)
        if rows is not None:
            r = torch.einsum("mkj,mj->mk", rows, r)
        r = r.reshape(-1)
        if sensitivity is None:
            return r.numpy(), None
        dx = equilibrium.position_sensitivity(xi, sensitivity)
        if rows is not None:
            dx = torch.einsum("mkj,mjn->mkn", rows, dx)
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
class ForwardFit:
    """The outer fit on one forward model: its label, values, z, residuals and Jacobian in z at
    the end, outer iterations, Newton steps, time [s], whether the outer iteration converged,
    whether every equilibrium was stable at the end (K positive definite; True where not
    checked), and how many inner equilibrium solves of this fit stopped before their
    tolerance (`solves_converged`: none did)."""

    label: dict
    values: np.ndarray
    z: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    iterations: int
    newton_steps: int
    time: float
    converged: bool
    stable: bool = True
    unconverged_solves: int = 0
    local_values: list[np.ndarray] = field(default_factory=list)
    full_jacobian: np.ndarray | None = None

    @property
    def nuisance(self) -> int:
        """How many local unknowns (per observation, `Equilibrium.local_count`) were fitted."""
        return sum(len(v) for v in self.local_values)

    @property
    def solves_converged(self) -> bool:
        return self.unconverged_solves == 0


def _evaluate(equilibria, observations, grid, jacobian: bool, p: int):
    """Stacked residuals, their Jacobian (R, p + Σ local) — θ's columns, then each
    observation's local unknowns in a block of its own — and the sensitivities."""
    rs, js, sens = [], [], []
    for eq, obs in zip(equilibria, observations, strict=True):
        s = eq.sensitivity() if jacobian else None
        r, j = residuals(eq, obs, grid, s)
        rs.append(r)
        js.append(j)
        sens.append(s)
    r = np.concatenate(rs)
    if not jacobian:
        return r, None, sens
    counts = [j.shape[1] - p for j in js]
    full = np.zeros((len(r), p + sum(counts)))
    row, column = 0, p
    for j, k in zip(js, counts, strict=True):
        full[row:row + len(j), :p] = j[:, :p]
        full[row:row + len(j), column:column + k] = j[:, p:]
        row, column = row + len(j), column + k
    return r, full, sens


def profiled(jacobian: np.ndarray, p: int, rows: list[int], counts: list[int]) -> np.ndarray:
    """θ's columns (R, p) of a Jacobian with local blocks, each observation's local columns
    projected out of its rows: J̃_θ = (I − P_local) J_θ. Its Gauss–Newton (and sandwich)
    covariance is θ's block of the full one — θ's error with the local unknowns estimated,
    not held (the Schur complement)."""
    out = jacobian[:, :p].copy()
    row, column = 0, p
    for n, k in zip(rows, counts, strict=True):
        if k:
            local = jacobian[row:row + n, column:column + k]
            out[row:row + n] -= local @ np.linalg.lstsq(local, out[row:row + n], rcond=None)[0]
        row, column = row + n, column + k
    return out


def fit(equilibria: list, observations: list[Observation], unknowns: list[Unknown],
        start_values: np.ndarray, config: OuterConfig) -> ForwardFit:
    """Levenberg–Marquardt over z on one forward model per observation, from the start values
    (module docstring)."""
    t0 = time.perf_counter()
    steps0 = sum(eq.newton_steps for eq in equilibria)
    failed0 = sum(getattr(eq, "unconverged_solves", 0) for eq in equilibria)
    grid = config.projection_grid
    p = len(unknowns)
    z = np.array(to_coordinates(unknowns, start_values))
    positive = np.array([u.positive for u in unknowns])
    counts = [eq.local_count for eq in equilibria]
    ends = np.cumsum([p, *counts])
    local = np.concatenate([np.zeros(0), *(eq.local_values() for eq in equilibria)])
    norm = np.concatenate([np.where(positive, 1.0, unknown_scales(unknowns, start_values)),
                           *(np.full(k, eq.local_scale)
                             for eq, k in zip(equilibria, counts, strict=True))])
    for eq in equilibria:
        eq.solve(start_values, from_reference=True)
    r, jac, sens = _evaluate(equilibria, observations, grid, True, p)
    cost = float(r @ r)
    mu, iterations, converged = 1e-3, 0, False
    for iterations in progress.counted(range(1, config.max_iterations + 1),
                                       f"outer fit {equilibria[0].label}"):
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
            dw = step * norm  # θ's coordinates z, then the local unknowns
            dz, trial, local_trial = dw[:p], z + dw[:p], local + dw[p:]
            values = np.array(to_values(unknowns, trial))
            for f, (eq, s) in enumerate(zip(equilibria, sens, strict=True)):
                own = slice(ends[f] - p, ends[f + 1] - p)
                if counts[f]:
                    eq.set_local(local_trial[own])
                eq.solve(values, prediction=eq.predicted_change(
                    s, np.concatenate([dz, dw[p:][own]])))
            r_trial, _, _ = _evaluate(equilibria, observations, grid, False, p)
            cost_trial = float(r_trial @ r_trial)
            if math.isfinite(cost_trial) and cost_trial < cost:
                accepted = True
                mu = max(mu / 3, 1e-9)
                break
            for f, (eq, state) in enumerate(zip(equilibria, states, strict=True)):
                if counts[f]:
                    eq.set_local(local[ends[f] - p:ends[f + 1] - p])
                eq.set_state(state, to_values(unknowns, z))
            mu *= 10
        if not accepted:
            converged = True  # no step lowers the misfit: a minimum within rounding
            log.info("outer fit %s: no step lowers the misfit at iteration %d",
                     equilibria[0].label, iterations)
            break
        relative = cost - cost_trial
        z, local, cost = trial, local_trial, cost_trial
        r, jac, sens = _evaluate(equilibria, observations, grid, True, p)
        log.info("outer fit %s iteration %d: %s, rms %.4g m, step %.3g, mu %.2g",
                 equilibria[0].label, iterations,
                 dict(zip([u.name for u in unknowns], to_values(unknowns, z), strict=True)),
                 rms_point_distance(r, observations), float(np.abs(step).max()), mu)
        if float(np.abs(step).max()) < config.tolerance or relative <= 1e-14 * cost:
            converged = True
            break
    rows = [o.components * len(o.points) for o in observations]
    return ForwardFit(label=dict(equilibria[0].label), values=np.array(to_values(unknowns, z)),
                      z=z, residuals=r, jacobian=profiled(jac, p, rows, counts) if sum(counts)
                      else jac, iterations=iterations,
                      newton_steps=sum(eq.newton_steps for eq in equilibria) - steps0,
                      time=time.perf_counter() - t0, converged=converged,
                      stable=all(getattr(eq, "stable", True) for eq in equilibria),
                      unconverged_solves=sum(getattr(eq, "unconverged_solves", 0)
                                             for eq in equilibria) - failed0,
                      local_values=[local[a - p:b - p] for a, b in zip(ends[:-1], ends[1:],
                                                                       strict=True)],
                      full_jacobian=jac if sum(counts) else None)


def start_values(observations: list[Observation], unknowns: list[Unknown], start) -> np.ndarray:
    """The start values (default: the first observation's model values), checked."""
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


@dataclass
class OuterResult:
    """An estimate on forward models: the combined estimate, the fit on every forward model
    (feature basis or grid), the forward models (one list per fit, one per observation), the
    Fisher and the forward model's parts of the standard error (absolute, per unknown), the
    index of the fit whose equilibria are reported, and `ratios` and `notes` as
    `BilevelResult`."""

    estimate: Estimate
    fits: list[ForwardFit]
    equilibria: list[list]
    fisher_errors: np.ndarray
    model_errors: np.ndarray
    ratios: dict[str, tuple[float, float]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    reported: int = 0

    def fitted_positions(self, index: int, xi: torch.Tensor) -> torch.Tensor:
        """Equilibrium positions (N, 3) [m] of observation `index` on the reported fit."""
        return self.equilibria[self.reported][index].positions(xi)


@dataclass
class Combined:
    """An estimate with its standard error parts (absolute, per unknown): `fisher` (noise,
    exact forward model) and `model` (the forward model's own error); ratios and notes as
    `bilevel.gravity_ratios`."""

    estimate: Estimate
    fisher: np.ndarray
    model: np.ndarray
    ratios: dict
    notes: list[str]


def clustered_std(jacobian: np.ndarray, residuals: np.ndarray,
                  clusters: list[np.ndarray]) -> np.ndarray:
    """Cluster-robust (sandwich) standard deviations of the least-squares estimate:
    (JᵀJ)⁻¹ (Σ_c J_cᵀ r_c r_cᵀ J_c) (JᵀJ)⁻¹ · G / (G − 1) over G clusters of residual rows.
    Unlike the Fisher error it does not assume independent residuals: residuals correlated
    within a cluster (one observation's shared boundary conditions, a reconstruction's smooth
    error) count as one draw per cluster. inf where JᵀJ is singular."""
    g = len(clusters)
    normal = jacobian.T @ jacobian
    try:
        inverse = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return np.full(jacobian.shape[1], np.inf)
    scores = np.stack([jacobian[c].T @ residuals[c] for c in clusters])
    covariance = inverse @ (scores.T @ scores) @ inverse * g / max(g - 1, 1)
    return np.sqrt(np.maximum(np.diag(covariance), 0.0))


def combine(observations: list[Observation], unknowns: list[Unknown], z: np.ndarray,
            final: ForwardFit, model_part: np.ndarray, method: str, iterations: int,
            elapsed: float, *, clusters: list[np.ndarray] | None = None) -> Combined:
    """The estimate at z with the Fisher standard error of `final`'s residuals and Jacobian
    and the forward model's part `model_part` (normalised coordinates: relative for positive
    unknowns, over the vector group's magnitude for signed ones) in quadrature. clusters:
    residual rows that share their errors (e.g. one per observation): the noise part is then
    the larger of the Fisher and the cluster-robust error (`clustered_std`)."""
    names = [u.name for u in unknowns]
    positive = np.array([u.positive for u in unknowns])
    values = np.array(to_values(unknowns, z))
    scale = unknown_scales(unknowns, values)
    norm = np.where(positive, 1.0, scale)
    r = final.residuals
    dof = max(len(r) - len(unknowns) - final.nuisance, 1)
    sigma2 = float(r @ r) / dof
    ident = analyse(final.jacobian * norm, sigma2, names, positive.tolist())
    fisher_std = ident.std.copy()
    notes = []
    if clusters is not None and len(clusters) >= 2:
        robust = clustered_std(final.jacobian * norm, r, clusters)
        if np.any(robust > fisher_std):
            notes.append(f"the noise part of the standard error is the cluster-robust "
                         f"(sandwich) error over {len(clusters)} observations where it exceeds "
                         f"the Fisher error (residuals correlated within an observation): "
                         + ", ".join(f"{n} {f:.3g} -> {max(f, b):.3g}" for n, f, b in
                                     zip(names, fisher_std, robust, strict=True)))
        fisher_std = np.maximum(fisher_std, robust)
    combined = np.sqrt(fisher_std**2 + model_part**2)
    ident = Identifiability(ident.fisher, ident.eigenvalues, ident.eigenvectors, combined,
                            [bool(c < UNDETERMINED_STD) for c in combined], ident.combinations)
    errors = np.where(ident.determined, combined * scale, np.inf)
    rms = rms_point_distance(r, observations)
    estimate = Estimate(unknowns, values, errors, ident, rms, iterations, elapsed, method,
                        residuals=np.asarray(r))
    ratios, ratio_notes = gravity_ratios(observations, unknowns, values, ident)
    notes = list(ratio_notes) + notes
    fisher = np.where(np.isfinite(fisher_std), fisher_std * scale, np.inf)
    log.info("%s estimate: %s ± %s (rms misfit %.3g m, %.1f s)", method,
             dict(zip(names, values.tolist(), strict=True)), errors.tolist(), rms, elapsed)
    return Combined(estimate, fisher, model_part * scale, ratios, list(notes))

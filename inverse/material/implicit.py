"""Bilevel estimate with implicit-function (adjoint) gradients of a last-layer Newton equilibrium.

Inner problem, for given unknowns θ: a plain (unconditioned) `NeuralField` whose hidden layers
are fixed, untrained SIREN features; its output layer a*(θ) is solved by last-layer Newton
(`taichi_ndf.newton.solve_last_layer`) on one fixed set of scrambled-Sobol area samples plus a
zero-weight sample per point load, so that g(a*, θ) = ∇_a Π(a*; θ) = 0 (the Galerkin
equilibrium over the span of the features). The first solve goes through `load_steps` from the
reference state; later solves warm-start from the previous a* moved by the first-order
prediction (da*/dz) Δz.

Gradient: Π is linear in every unknown (Π = Π_known + Σ_j θ_j T_j, `unknowns`), so
∂g/∂θ_j = Jᵀ dT_j/du (`term_gradients`; J the output-layer Jacobian of the displacement jets),
and the implicit-function theorem gives da*/dθ_j = −H⁻¹ ∂g/∂θ_j with H = d²Π/da² at a*
(`newton.output_hessian`). In the coordinates z of the outer problem (z = ln θ for positive
unknowns, so ∂/∂z_j = θ_j ∂/∂θ_j; the value itself for signed ones: forces [N], gravity
[m/s²], ...) the observed positions x(ξ_k) = X(ξ_k) + u(ξ_k) are affine in a, so
dx/dz = J_obs da*/dz exactly. Without correspondence (point clouds) the residual is the signed
distance n · (x(ξ_k) − p_k) at the closest point ξ_k (as `bilevel`), its derivative n · dx/dz.

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

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from inverse.material.bilevel import closest_surface_points, gravity_ratios
from inverse.material.conditioned import to_coordinates, to_values
from inverse.material.identifiability import UNDETERMINED_STD, Identifiability, analyse
from inverse.material.observations import Observation
from inverse.material.residual import Estimate, unknown_scales
from inverse.material.unknowns import Unknown, apply, term_gradients
from taichi_ndf import checks, jets
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.model import ShellModel
from taichi_ndf.newton import (
    NewtonConfig,
    damped_step,
    output_hessian,
    output_jacobian,
    parameter_gradient,
    solve_last_layer,
)
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.sampling import SurfaceSamples, sobol, unit_to_domain, with_point_loads

log = logging.getLogger(__name__)

# Levenberg–Marquardt trials per outer iteration (damping × 10 after each rejected one).
LM_ATTEMPTS = 6


@dataclass(frozen=True)
class ImplicitConfig:
    """Implicit-function bilevel estimate.

    width, hidden_layers, omega0: the fixed (untrained) SIREN features of the forward model;
        a low ω₀ suits smooth equilibria.
    seeds, widths: the feature bases; the estimate is repeated for every (seed, width) pair in
        turn (zip; `widths` empty: `width` for all), and their spread enters the standard
        error (module docstring). At least one seed.
    boundary_length: band width of the boundary conditions' vanishing factors, a fraction of
        the domain (None: the model's); a Newton basis wants a wide band.
    output_scale: metres per unit of the field's linear output (numerical scaling only: the
        output layer starts at zero, the reference state).
    samples: area samples (scrambled Sobol) of the fixed Newton sample set.
    load_steps: load factors of the first solve from the reference state (the last is 1).
    newton_iterations: most Newton steps per solve (per load step). On wide low-ω₀ features
        the Newton tail is linear (most of H's Jacobi-scaled eigenvalues lie below 1e-8: nearly
        collinear features): 256 × 2 on the strip lowers Π by ~1e-6 of itself per step after
        ~12 steps, i.e. ~0.1 mm at the tip, so solves are capped rather than run to rounding.
    resolve_iterations: most Newton steps of a warm-started re-solve during the outer
        iterations (each continues from the previous a* plus the first-order prediction, so
        the inner iterations accumulate over the outer ones).
    relative_decrease: a solve stops when a Newton step lowers Π by less than this × |Π|.
    max_iterations: outer Levenberg–Marquardt iterations (Jacobians).
    tolerance: stop when the outer step is below this in normalised coordinates (relative).
    max_step: largest outer step in normalised coordinates (1: a factor e in θ, or the start
        magnitude of a force).
    projection_grid: seeds per coordinate of the closest-point search of point clouds.
    """

    width: int = 256
    hidden_layers: int = 2
    omega0: float = 3.0
    seeds: tuple[int, ...] = (2, 3)
    widths: tuple[int, ...] = ()
    boundary_length: float | None = 2.0
    output_scale: float = 0.05
    samples: int = 4096
    load_steps: tuple[float, ...] = (0.5, 1.0)
    newton_iterations: int = 12
    resolve_iterations: int = 5
    relative_decrease: float = 1e-10
    max_iterations: int = 30
    tolerance: float = 1e-4
    max_step: float = 1.0
    projection_grid: int = 48

    def __post_init__(self):
        for name in ("width", "hidden_layers", "samples", "newton_iterations",
                     "resolve_iterations", "max_iterations", "projection_grid"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not self.seeds:
            raise ValueError("seeds must name at least one feature seed")
        if self.widths and len(self.widths) != len(self.seeds):
            raise ValueError(f"widths must be empty or one per seed, got {self.widths} for "
                             f"seeds {self.seeds}")
        if any(int(w) < 1 for w in self.widths):
            raise ValueError(f"widths must be positive, got {self.widths}")
        checks.load_steps(self.load_steps)
        for name in ("omega0", "output_scale", "tolerance", "max_step"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if self.boundary_length is not None and not self.boundary_length > 0:
            raise ValueError(f"boundary_length must be positive or None, got "
                             f"{self.boundary_length!r}")
        if not 0 <= self.relative_decrease < 1:
            raise ValueError(f"relative_decrease must be in [0, 1), got "
                             f"{self.relative_decrease!r}")

    def bases(self) -> list[tuple[int, int]]:
        """(seed, width) of every feature basis."""
        widths = self.widths or (self.width,) * len(self.seeds)
        return [(int(s), int(w)) for s, w in zip(self.seeds, widths, strict=True)]


def sobol_samples(model: ShellModel, n: int, seed: int, dtype=torch.float64) -> SurfaceSamples:
    """n scrambled-Sobol area samples of the domain's rectangle (points outside a mask
    dropped, weight |Ω| / kept), then one zero-weight sample per point load of the model, in
    the model's order, with its force."""
    domain = model.surface.domain
    xi, _ = unit_to_domain(domain, sobol(2, n, seed, dtype))
    weight = torch.full((len(xi),), domain.area / len(xi), dtype=dtype)
    return with_point_loads(model.surface, xi, weight, model.loads)


class ImplicitEquilibrium:
    """The Galerkin equilibrium of `model` with the unknowns set to θ, on fixed features, and
    its sensitivity da*/dz (module docstring).

    model: the observation's model (unknowns at their scene values; a `scale` unknown is
    relative to its material); seed, width: the feature basis."""

    def __init__(self, model: ShellModel, unknowns: list[Unknown], config: ImplicitConfig,
                 seed: int, width: int | None = None):
        if config.boundary_length is not None:
            model = model.with_boundary_length(config.boundary_length)
        self.model = model
        self.unknowns = list(unknowns)
        self.config = config
        self.seed = seed
        domain = model.surface.domain
        self.field = NeuralField(FieldConfig(
            width=width or config.width, hidden_layers=config.hidden_layers,
            omega0=config.omega0, domain=domain.bounds, periodic=domain.periodic,
            output_scale=config.output_scale), seed=seed)
        dtype = self.field.parameters[0].dtype
        with torch.no_grad():  # the reference state: the first solve starts from u = 0
            for p in self.field.output_layer():
                p.zero_()
        self.samples = sobol_samples(model, config.samples, seed, dtype)
        self.values: np.ndarray | None = None  # θ of the current solution
        self.newton_steps = 0
        self.solve_time = 0.0
        self._first: tuple[np.ndarray, list[torch.Tensor]] | None = None

    # -- state of the output layer --------------------------------------------------------------
    def state(self) -> list[torch.Tensor]:
        return [p.clone() for p in self.field.output_layer()]

    def set_state(self, state: list[torch.Tensor], values) -> None:
        with torch.no_grad():
            for p, saved in zip(self.field.output_layer(), state, strict=True):
                p.copy_(saved)
        self.values = None if values is None else np.array(values, dtype=np.float64)

    # -- inner problem --------------------------------------------------------------------------
    def _system(self, values, load_factor: float):
        """The samples with θ's point forces and the potential of θ at a load factor."""
        loaded = apply(self.model, self.unknowns, values)
        loads = loaded.loads.scaled(load_factor)
        samples = self.samples
        if loads.point_loads:
            forces = samples.point_force.clone()
            forces[-len(loads.point_loads):] = torch.tensor(
                [p.force for p in loads.point_loads], dtype=forces.dtype)
            samples = dataclasses.replace(samples, point_force=forces)
        # The loads are scaled here already (the samples carry the point forces).
        return samples, Objective(ShellEnergyTerm(loaded.material, loads)).potential(1.0)

    def _newton(self, iterations: int | None = None) -> NewtonConfig:
        return NewtonConfig(iterations=iterations or self.config.newton_iterations,
                            relative_decrease=self.config.relative_decrease)

    def solve(self, values, *, prediction: torch.Tensor | None = None,
              from_reference: bool = False) -> int:
        """Solve for θ = values; returns the Newton steps taken. From the reference state
        through `load_steps` the first time (or with `from_reference`), the result kept and
        reused when asked for the same θ again; otherwise warm-started from the current a*
        plus `prediction` (3, width + 1)."""
        values = np.array(values, dtype=np.float64)
        t0 = time.perf_counter()
        steps = 0
        if self._first is not None and np.array_equal(values, self._first[0]):
            self.set_state(self._first[1], values)
            return 0
        if self.values is None or from_reference:
            self.set_state([torch.zeros_like(p) for p in self.field.output_layer()], None)
            for factor in self.config.load_steps:
                samples, potential = self._system(values, factor)
                steps += solve_last_layer(self.field, self.model.boundary, potential, samples,
                                          factor, self._newton()).steps
            if self._first is None:
                self._first = (values, self.state())
        else:
            if prediction is not None:
                weight, bias = self.field.output_layer()
                with torch.no_grad():
                    weight.add_(prediction[:, :-1])
                    bias.add_(prediction[:, -1])
            samples, potential = self._system(values, 1.0)
            steps += solve_last_layer(self.field, self.model.boundary, potential, samples, 1.0,
                                      self._newton(self.config.resolve_iterations)).steps
        self.values = values
        self.newton_steps += steps
        self.solve_time += time.perf_counter() - t0
        return steps

    def sensitivity(self) -> torch.Tensor:
        """da*/dz at the current solution, shape (3, width + 1, p): column j is
        −H⁻¹ Jᵀ dT_j/du, times θ_j for a positive unknown (z_j = ln θ_j)."""
        if self.values is None:
            raise RuntimeError("solve before asking for the sensitivity")
        samples, potential = self._system(self.values, 1.0)
        u, jacobian, hessian = output_hessian(self.field, self.model.boundary, potential,
                                              samples, 1.0, self._newton())
        columns, _ = term_gradients(self.model, self.unknowns, samples, u)
        shape = (jacobian.shape[0], jacobian.shape[3])
        out = []
        for unknown, value, column in zip(self.unknowns, self.values, columns, strict=True):
            dg = parameter_gradient(jacobian, column).reshape(-1)
            if unknown.positive:
                dg = dg * float(value)
            out.append(damped_step(hessian, dg, 0.0).reshape(shape))
        return torch.stack(out, dim=-1)

    # -- observation space ----------------------------------------------------------------------
    def position_jets(self, xi: torch.Tensor, z=None) -> torch.Tensor:
        """Jets (N, 6, 3) of the current equilibrium positions [m] (z: ignored, for the
        interface of `bilevel.closest_surface_points`)."""
        xi = xi.to(self.field.parameters[0].dtype)
        return self.model.surface.jets(xi) + self.model.displacement_jets(self.field, xi)

    def positions(self, xi: torch.Tensor, z=None) -> torch.Tensor:
        """Current equilibrium positions (N, 3) [m] at ξ (N, 2)."""
        return self.position_jets(xi)[:, jets.VALUE]

    def position_sensitivity(self, xi: torch.Tensor, sensitivity: torch.Tensor
                             ) -> torch.Tensor:
        """dx/dz (N, 3, p) at ξ from da*/dz (`sensitivity`): x is affine in a."""
        xi = xi.to(self.field.parameters[0].dtype)
        _, jacobian = output_jacobian(self.field, self.model.boundary, xi, 1.0)
        return torch.einsum("kna,kaj->nkj", jacobian[:, :, jets.VALUE], sensitivity)


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
                      config: ImplicitConfig = ImplicitConfig(), *,
                      start: list[float] | None = None,
                      equilibria: list[list[ImplicitEquilibrium]] | None = None
                      ) -> ImplicitResult:
    """Estimate any unknowns of `parse_unknowns` by fitting Newton equilibria, one outer fit
    per feature basis of `config` (module docstring).

    start: start values (default: the first observation's model values).
    equilibria: forward models from an earlier result for the same conditions (one list per
        basis, one per observation): their start solution is reused."""
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

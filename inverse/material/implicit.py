"""Bilevel estimate with implicit-function (adjoint) gradients of a last-layer Newton equilibrium.

Inner problem, for given unknowns θ: a plain (unconditioned) `NeuralField` whose hidden layers
are fixed, untrained SIREN features; its output layer a*(θ) is solved by last-layer Newton
(`taichi_ndf.minimise.last_layer.solve_last_layer`) on one fixed set of scrambled-Sobol area
samples plus a zero-weight sample per point load, so that g(a*, θ) = ∇_a Π(a*; θ) = 0 (the Galerkin
equilibrium over the span of the features). The first solve goes through `load_steps` from the
reference state; later solves warm-start from the previous a* moved by the first-order
prediction (da*/dz) Δz.

Gradient: Π is linear in every unknown (Π = Π_known + Σ_j θ_j T_j, `unknowns`), so
∂g/∂θ_j = Jᵀ dT_j/du (`term_gradients`; J the output-layer Jacobian of the displacement jets),
and the implicit-function theorem gives da*/dθ_j = −H⁻¹ ∂g/∂θ_j with H = d²Π/da² at a*
(`last_layer.output_hessian`). In the coordinates z of the outer problem (z = ln θ for positive
unknowns, so ∂/∂z_j = θ_j ∂/∂θ_j; the value itself for signed ones: forces [N], gravity
[m/s²], ...) the observed positions x(ξ_k) = X(ξ_k) + u(ξ_k) are affine in a, so
dx/dz = J_obs da*/dz exactly. Without correspondence (point clouds) the residual is the signed
distance n · (x(ξ_k) − p_k) at the closest point ξ_k (as `bilevel`), its derivative n · dx/dz.

What is the same for every field type (the solves over the load steps and warm starts, θ's
point forces, the sensitivity's columns, the positions) is `inverse.material.equilibrium`;
the outer problem (Levenberg–Marquardt over z) is `inverse.material.outer_fit`, the
uncertainty over feature bases `inverse.material.implicit_fit`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from inverse.material.equilibrium import Equilibrium
from inverse.material.unknowns import Unknown
from taichi_ndf import checks, jets
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.minimise.last_layer import (
    last_layer_config,
    output_hessian,
    output_jacobian,
    solve_last_layer,
)
from taichi_ndf.minimise.linearisation import damped_step, parameter_gradient
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.sampling import SurfaceSamples, sobol, unit_to_domain, with_point_loads

log = logging.getLogger(__name__)


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

    def features(self, model: ShellModel, width: int | None = None) -> FieldConfig:
        """The fixed features (`width`, else this width) on `model`'s domain."""
        domain = model.surface.domain
        return FieldConfig(width=width or self.width, hidden_layers=self.hidden_layers,
                           omega0=self.omega0, domain=domain.bounds, periodic=domain.periodic,
                           output_scale=self.output_scale)

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


class ImplicitEquilibrium(Equilibrium):
    """The Galerkin equilibrium of `model` with the unknowns set to θ, on fixed features, and
    its sensitivity da*/dz (module docstring): `Equilibrium` on a SIREN's output layer a.

    model: the observation's model (unknowns at their scene values; a `scale` unknown is
    relative to its material); seed, width: the feature basis; features: the fixed features'
    field specification (None: `config.features(model, width)`)."""

    def __init__(self, model: ShellModel, unknowns: list[Unknown], config: ImplicitConfig,
                 seed: int, width: int | None = None, *, features: FieldConfig | None = None):
        super().__init__(model, unknowns, boundary_length=config.boundary_length,
                         load_steps=config.load_steps)
        model = self.model
        self.config = config
        self.seed = seed
        features = features or config.features(model, width)
        self.label = {"seed": int(seed), "width": int(features.width)}
        self.field = NeuralField(features, seed=seed)
        with torch.no_grad():  # the reference state: the first solve starts from u = 0
            for p in self.field.output_layer():
                p.zero_()
        self.operator = model.operator(self.field)
        self.samples = sobol_samples(model, config.samples, seed, self.dtype)
        self.point_rows = slice(len(self.samples) - len(model.loads.point_loads), None)

    @classmethod
    def of_field(cls, spec: FieldConfig, model: ShellModel, unknowns: list[Unknown],
                 config: ImplicitConfig, *, seed: int = 0) -> ImplicitEquilibrium:
        """On the fixed features `spec` (`ImplicitConfig.features`) of seed `seed`."""
        return cls(model, unknowns, config, seed, features=spec)

    # -- the output layer a = (weight | bias), (3, width + 1) -------------------------------------
    def state(self) -> list[torch.Tensor]:
        return [p.clone() for p in self.field.output_layer()]

    def _set_parameters(self, state: list[torch.Tensor]) -> None:
        with torch.no_grad():
            for p, saved in zip(self.field.output_layer(), state, strict=True):
                p.copy_(saved)

    def _reference(self) -> list[torch.Tensor]:
        return [torch.zeros_like(p) for p in self.field.output_layer()]

    def _shifted(self, prediction: torch.Tensor | None) -> list[torch.Tensor]:
        weight, bias = self.state()
        if prediction is not None:
            weight.add_(prediction[:, :-1])
            bias.add_(prediction[:, -1])
        return [weight, bias]

    def predicted_change(self, sensitivity: torch.Tensor, dz: np.ndarray) -> torch.Tensor:
        """First-order change (3, width + 1) of the output layer for a step dz (p,) in z."""
        return torch.einsum("kaj,j->ka", sensitivity, torch.from_numpy(dz))

    def _newton(self, iterations: int | None = None) -> NewtonConfig:
        return last_layer_config(max_iterations=iterations or self.config.newton_iterations,
                                 relative_decrease=self.config.relative_decrease)

    def _minimise(self, values, potential, start: list[torch.Tensor], load_factor: float, *,
                  warm: bool) -> list[torch.Tensor]:
        """Last-layer Newton from `start`: at most `resolve_iterations` steps warm, else
        `newton_iterations` (capped, not run to rounding: `ImplicitConfig`)."""
        self._set_parameters(start)
        newton = self._newton(self.config.resolve_iterations if warm else None)
        self.newton_steps += solve_last_layer(self.operator, potential, self.samples,
                                              load_factor, newton).steps
        return self.state()

    def _linearised(self, potential):
        u, jacobian, hessian = output_hessian(self.operator, potential, self.samples, 1.0,
                                              self._newton())
        shape = (jacobian.shape[0], jacobian.shape[3])

        def solve(dg: list[torch.Tensor]) -> torch.Tensor:
            return torch.stack([damped_step(hessian, g, 0.0).reshape(shape) for g in dg],
                               dim=-1)

        return (self.samples, u,
                lambda column: parameter_gradient(jacobian, column).reshape(-1), solve)

    # -- observation space ----------------------------------------------------------------------
    def displacement_jets(self, xi: torch.Tensor) -> torch.Tensor:
        return self.model.displacement_jets(self.field, xi)

    def position_sensitivity(self, xi: torch.Tensor, sensitivity: torch.Tensor
                             ) -> torch.Tensor:
        """dx/dz (N, 3, p) at ξ from da*/dz (`sensitivity`): x is affine in a."""
        xi = xi.to(self.dtype)
        _, jacobian = output_jacobian(self.operator, xi, 1.0)
        return torch.einsum("kna,kaj->nkj", jacobian[:, :, jets.VALUE], sensitivity)

"""Material-conditioned equilibrium: one field u(ξ, z) trained over a box of log-parameters z.

The field takes z = log θ of the estimated stiffness unknowns as extra inputs. Every training
sample draws its own z (stratified uniform in the box) and its energy uses the stiffness of
that z (`ShellEnergy.evaluate(..., stiffness=...)`). Π is a sum over samples, so the training
objective is the mean over z of Π(u(·, z); z), whose minimiser is the equilibrium u*(·, z) for
every z in the box: after one training, x*(θ) is a cheap, smooth function of θ for the outer
(misfit) problem. The training loop is built from the solver's pieces: the displacement
operator (`taichi_ndf.problem.operator`: jets, boundary conditions and their adjoint), the shell
energy, Adam and the one L-BFGS (`taichi_ndf.minimise.minimisers`); it differs from
`taichi_ndf.solve.solver.Solver` in the conditioning inputs, the per-sample stiffness and the
per-z weights, so the loop is written here rather than as a hook in the solver.

Point-load components can be conditioning inputs too (signed, so in linear coordinates: the
input is the force component itself [N]). A point load acts at one ξ, so it gets
`point_load_copies` zero-weight samples of its own, each with its own z and a 1/copies share
of the force of that z: their sum estimates the mean over z of the load potential −P(z)·u(ξ_P, z)
as the area samples estimate the mean of the strain energy.

Optionally a last-layer Newton (Galerkin) phase follows Adam
(`taichi_ndf.minimise.last_layer`): on one fixed set of (ξ, z) samples the output layer, which
combines features of ξ and z, is solved exactly for the mean over z of the weighted Π. Adam
alone (and the L-BFGS polish) leaves the field short of equilibrium on these slender,
membrane-stiff sheets; after the Newton phase what remains is the error of the basis and of
the quadrature of its sample set (docs/inverse_material.md). A Newton basis wants a wide
field, a low ω₀ and a wide boundary band (`boundary_length`, docs/validation.md).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import torch

from inverse.material.unknowns import Unknown, apply
from taichi_ndf import jets
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.minimise.last_layer import last_layer_config, solve_last_layer
from taichi_ndf.minimise.minimisers import lbfgs
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.field_types import of_spec
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.optim import Adam, AdamConfig
from taichi_ndf.problem.sampling import (
    SurfaceSamples,
    sample_surface,
    sobol,
    stratified_uniform,
    unit_to_domain,
)
from taichi_ndf.problem.scaling import characteristic_displacement
from taichi_ndf.shell.energy import ShellEnergy

log = logging.getLogger(__name__)

CONDITIONABLE = ("stiffness", "scale", "point_load")


@dataclass(frozen=True)
class ConditionedConfig:
    """Training of a material-conditioned field.

    width, hidden_layers, omega0: field architecture (`FieldConfig`); equilibria of sheets
        are smooth, and a low SIREN frequency conditions the training better.
    output_scale: metres per network unit; None: the dimensional estimate of the softest
        material in the box (`characteristic_displacement`).
    iterations, samples: Adam iterations and area samples per iteration.
    point_load_copies: samples per point load of the model (module docstring).
    lbfgs_iterations, lbfgs_samples: deterministic L-BFGS polish on one fixed set of (ξ, z)
        samples afterwards (as the solver's polish): Adam alone creeps towards the
        equilibrium of slender, bending-dominated sheets.
    newton_iterations, newton_samples, newton_point_load_copies: a last-layer Newton phase
        after Adam and the L-BFGS polish (0: none), at most that many steps on one fixed set
        of `newton_samples` area samples and `newton_point_load_copies` samples per point load.
    boundary_length: band width of the boundary conditions' vanishing factors for this
        field (None: the model's); edges accept bands wider than the domain (a Newton basis
        needs a wide band).
    learning_rate, final_learning_rate_ratio: exponential decay from the first to the last.
    seed: field initialisation and sampling.
    """

    width: int = 64
    hidden_layers: int = 3
    omega0: float = 3.0
    output_scale: float | None = None
    iterations: int = 3000
    samples: int = 1024
    lbfgs_iterations: int = 500
    lbfgs_samples: int = 4096
    point_load_copies: int = 64
    newton_iterations: int = 0
    newton_samples: int = 8192
    newton_point_load_copies: int = 1024
    boundary_length: float | None = None
    learning_rate: float = 3e-3
    final_learning_rate_ratio: float = 0.02
    seed: int = 0

    def __post_init__(self):
        for name in ("lbfgs_iterations", "newton_iterations"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if self.boundary_length is not None and not self.boundary_length > 0:
            raise ValueError(f"boundary_length must be positive or None, got "
                             f"{self.boundary_length!r}")
        for name in ("width", "hidden_layers", "iterations", "samples", "lbfgs_samples",
                     "point_load_copies", "newton_samples", "newton_point_load_copies"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.output_scale is not None and not self.output_scale > 0:
            raise ValueError(f"output_scale must be positive or None, got {self.output_scale!r}")
        for name in ("omega0", "learning_rate"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if not 0 < self.final_learning_rate_ratio <= 1:
            raise ValueError(f"final_learning_rate_ratio must be in (0, 1], got "
                             f"{self.final_learning_rate_ratio!r}")

    @classmethod
    def of_field(cls, spec, **settings) -> ConditionedConfig:
        """The training `settings` of a conditioned field with the architecture of the SIREN
        specification `spec` (width, hidden_layers, omega0, output_scale). ValueError where
        `spec` is not a SIREN's: a conditioned field is a network taking θ as input, and a
        spline field has no such input (`FieldType.conditioned`)."""
        if not _takes_inputs(spec):
            raise ValueError("--method bilevel trains a material-conditioned SIREN with the "
                             "scene's [field] architecture, but the scene's [field] is not a "
                             "SIREN: give one (type = \"siren\") or use --method newton or "
                             "implicit")
        return cls(width=spec.width, hidden_layers=spec.hidden_layers, omega0=spec.omega0,
                   output_scale=spec.output_scale, **settings)


def _takes_inputs(spec) -> bool:
    """Whether the field type of the specification `spec` takes inputs beside ξ; False for
    a specification of no field type a scene names (a garment's panels)."""
    try:
        return of_spec(spec).conditioned
    except TypeError:
        return False


def to_values(unknowns: list[Unknown], z) -> list[float]:
    """Parameter values θ from coordinates z: exp for positive unknowns, z itself for signed."""
    return [math.exp(float(c)) if u.positive else float(c)
            for u, c in zip(unknowns, z, strict=True)]


def to_coordinates(unknowns: list[Unknown], values) -> list[float]:
    """Coordinates z of parameter values θ (inverse of `to_values`)."""
    return [math.log(float(v)) if u.positive else float(v)
            for u, v in zip(unknowns, values, strict=True)]


class ConditionedEquilibrium:
    """Equilibria x*(ξ; θ) of `model` for every θ of the estimated unknowns in a box.

    unknowns: stiffness, scale (positive) or point-load (signed) unknowns; ranges: (lo, hi) of
    the coordinate z per unknown: ln θ for positive unknowns, θ [N] for point-load components.
    """

    def __init__(self, model: ShellModel, unknowns: list[Unknown],
                 ranges: list[tuple[float, float]],
                 config: ConditionedConfig = ConditionedConfig()):
        bad = [u.name for u in unknowns if u.kind not in CONDITIONABLE]
        if bad:
            raise ValueError(f"the material-conditioned field takes stiffness and point-load "
                             f"unknowns only, not {bad}: estimate these with the residual method")
        DisplacementOperator(None, model.boundary).refuse_free_pin(
            "the material-conditioned field", "; use --method implicit or rotation = 'held'")
        if model.loads.line_loads:
            raise ValueError("the material-conditioned field does not support line loads "
                             "([[loads.line]]); use --method implicit")
        if len(ranges) != len(unknowns):
            raise ValueError(f"need one coordinate range per unknown, got {len(ranges)} for "
                             f"{len(unknowns)}")
        if config.boundary_length is not None:
            model = model.with_boundary_length(config.boundary_length)
        self.model = model
        self.unknowns = list(unknowns)
        self.ranges = [(float(lo), float(hi)) for lo, hi in ranges]
        self.config = config
        # The output scale is estimated for the softest material and the largest loads of the box.
        softest = apply(model, unknowns, [
            math.exp(lo) if u.positive else (lo if abs(lo) > abs(hi) else hi)
            for u, (lo, hi) in zip(unknowns, self.ranges, strict=True)])
        scale = config.output_scale or characteristic_displacement(softest)
        domain = model.surface.domain
        field_config = FieldConfig(width=config.width, hidden_layers=config.hidden_layers,
                                   omega0=config.omega0, domain=domain.bounds,
                                   periodic=domain.periodic,
                                   conditioning=tuple(self.ranges), output_scale=scale)
        self.field = NeuralField(field_config, seed=config.seed)
        self.operator = model.operator(self.field)
        self.history: list[tuple[int, float]] = []
        self.training_time = 0.0
        self.newton_result = None  # NewtonSolution of the Newton phase, if any

    # -- per-sample stiffness -------------------------------------------------------------------
    def stiffness(self, z: torch.Tensor) -> torch.Tensor:
        """Per-sample stiffness (N, K) in the order of `material.stiffness_names` for
        coordinates z (N, p)."""
        material = self.model.material
        base = torch.tensor(material.stiffness, dtype=z.dtype, device=z.device)
        out = base.expand(len(z), -1).clone()
        for j, u in enumerate(self.unknowns):
            if u.kind == "scale":
                out = out * torch.exp(z[:, j:j + 1]) / u.reference
            elif u.kind == "stiffness":
                out[:, material.stiffness_names.index(u.key)] = torch.exp(z[:, j])
        return out

    def point_forces(self, index: int, z: torch.Tensor) -> torch.Tensor:
        """Force (N, 3) [N] of the model's point load `index` for coordinates z (N, p): the
        scene's force with the estimated components taken from z."""
        force = torch.tensor(self.model.loads.point_loads[index].force, dtype=z.dtype,
                             device=z.device).expand(len(z), -1).clone()
        for j, u in enumerate(self.unknowns):
            if u.kind == "point_load" and u.key == index:
                force[:, u.axis] = z[:, j]
        return force

    def samples(self, n: int, generator: torch.Generator, dtype, device,
                copies: int | None = None):
        """n area samples with their z, plus `copies` (default `point_load_copies`) samples
        per point load, each with its own z and a 1/copies share of that z's force (module
        docstring)."""
        points = self.model.loads.point_loads
        copies = copies or self.config.point_load_copies
        repeated = Loads(point_loads=tuple(p for p in points for _ in range(copies)))
        samples = sample_surface(self.model.surface, n, repeated, generator, dtype=dtype,
                                 device=device)
        z = self._draw(len(samples), generator, dtype)
        if points:
            area = len(samples) - copies * len(points)
            forces = [self.point_forces(k, z[area + k * copies: area + (k + 1) * copies])
                      for k in range(len(points))]
            samples.point_force[area:] = torch.cat(forces) / copies
        return samples, z

    def quasi_samples(self, n: int, generator: torch.Generator, dtype, device,
                      copies: int) -> tuple[SurfaceSamples, torch.Tensor]:
        """Like `samples`, from scrambled Sobol sequences: n points of the unit (2 + p)-cube
        mapped to the domain's rectangle and the box jointly (points outside a mask dropped),
        plus `copies` samples per point load with z from a p-dimensional sequence. Used for
        the Newton phase, which solves exactly on its fixed sample set: on the point-load
        strip, 8192 Sobol samples gave the in-plane tip deflection of 32768 random ones
        (docs/inverse_material.md)."""
        domain = self.model.surface.domain
        lo = torch.tensor([r[0] for r in self.ranges], dtype=dtype)
        hi = torch.tensor([r[1] for r in self.ranges], dtype=dtype)

        def draw(dim: int, m: int) -> torch.Tensor:
            return sobol(dim, m, int(torch.randint(2**31 - 1, (1,), generator=generator)), dtype)

        u = draw(2 + len(self.ranges), n)
        xi, inside = unit_to_domain(domain, u)
        z = lo + (hi - lo) * u[inside, 2:]
        weight = torch.full((len(xi),), domain.area / len(xi), dtype=dtype)
        force = torch.zeros(len(xi), 3, dtype=dtype)
        points = self.model.loads.point_loads
        for k, point in enumerate(points):
            z_k = lo + (hi - lo) * draw(len(self.ranges), copies)
            xi = torch.cat((xi, torch.tensor(point.xi, dtype=dtype).expand(copies, 2)))
            z = torch.cat((z, z_k))
            weight = torch.cat((weight, weight.new_zeros(copies)))
            force = torch.cat((force, self.point_forces(k, z_k) / copies))
        samples = SurfaceSamples(xi=xi, r_jets=self.model.surface.jets(xi), weight=weight,
                                 point_force=force)
        return samples.to(dtype=dtype, device=device), z.to(device)

    def _draw(self, n: int, generator: torch.Generator, dtype) -> torch.Tensor:
        """Stratified uniform coordinates (n, p): each coordinate's n values cover its
        range in n equal strata, shuffled independently."""
        return torch.stack([stratified_uniform(n, lo, hi, generator, dtype=dtype)
                            for lo, hi in self.ranges], dim=1)

    # -- training -------------------------------------------------------------------------------
    def train(self) -> ConditionedEquilibrium:
        """Minimise the mean over the box of Π(u(·, z); z) (module docstring)."""
        cfg = self.config
        model, field = self.model, self.field
        dtype = field.parameters[0].dtype
        adam = Adam(field.parameters, field.gradients, config=AdamConfig(
            lr=cfg.learning_rate, schedule="exponential",
            decay_rate=cfg.final_learning_rate_ratio, decay_steps=cfg.iterations,
            total_steps=cfg.iterations))
        generator = torch.Generator().manual_seed(cfg.seed)
        energy = ShellEnergy(model.material, model.loads)
        start = time.perf_counter()
        for it in range(cfg.iterations):
            samples, z = self.samples(cfg.samples, generator, dtype, field.parameters[0].device)
            total = self._energy_and_gradient(energy, samples, z)
            adam.step()
            if (it + 1) % max(cfg.iterations // 10, 1) == 0:
                self.history.append((it + 1, total))
                log.debug("conditioned training %d/%d: mean Π %.6g J", it + 1, cfg.iterations,
                          total)
        if cfg.lbfgs_iterations:
            self._lbfgs(energy, generator)
        if cfg.newton_iterations:
            self.newton_result = self._newton(energy, generator)
        self.training_time = time.perf_counter() - start
        log.info("material-conditioned field trained: %d + %d L-BFGS iterations + %d Newton "
                 "steps at most in %.1f s", cfg.iterations, cfg.lbfgs_iterations,
                 cfg.newton_iterations, self.training_time)
        return self

    def _weighted(self, samples, z):
        """The samples with their energy weighted by w(z) = θ_centre / θ(z) of the first
        positive unknown (unchanged without one): the Hessian of Π grows with the stiffness,
        so without it the stiff end of the box dominates and the soft end hardly trains. A
        positive weight per z leaves every z's minimiser unchanged."""
        first = next((j for j, u in enumerate(self.unknowns) if u.positive), None)
        if first is None:
            return samples
        lo, hi = self.ranges[first]
        w = torch.exp(0.5 * (lo + hi) - z[:, first])
        return dataclasses.replace(samples, weight=samples.weight * w,
                                   point_force=samples.point_force * w[:, None])

    def _energy_and_gradient(self, energy: ShellEnergy, samples, z, *, grad: bool = True):
        """Mean-over-z of w(z) Π [J] on given samples (`_weighted`); fills the field's
        gradients."""
        samples = self._weighted(samples, z)
        u = self.operator.jets(samples.xi, conditioning=z)
        result = energy.evaluate(samples, u, stiffness=self.stiffness(z), grad=grad)
        if not math.isfinite(result.total):
            raise RuntimeError(f"conditioned training diverged: Π = {result.total}; lower the "
                               f"learning rate")
        if grad:
            self.operator.backward(result.grad_u_jets)
        return result.total

    def _lbfgs(self, energy: ShellEnergy, generator: torch.Generator) -> None:
        field = self.field
        dtype = field.parameters[0].dtype
        samples, z = self.samples(self.config.lbfgs_samples, generator, dtype,
                                  field.parameters[0].device)

        def evaluate(grad: bool) -> float:
            return self._energy_and_gradient(energy, samples, z, grad=grad)

        before, after = lbfgs(field, evaluate, self.config.lbfgs_iterations, history_size=30)
        log.info("conditioned L-BFGS polish: mean Π %.8g -> %.8g J", before, after)

    def _newton(self, energy: ShellEnergy, generator: torch.Generator):
        """Last-layer Newton phase on one fixed set of (ξ, z) Sobol samples
        (`quasi_samples`): each sample's energy
        with its own stiffness and force, weighted as in training (`_weighted`)."""
        cfg = self.config
        dtype, device = self.field.parameters[0].dtype, self.field.parameters[0].device
        samples, z = self.quasi_samples(cfg.newton_samples, generator, dtype, device,
                                        cfg.newton_point_load_copies)
        samples = self._weighted(samples, z)
        objective = Objective(ShellEnergyTerm(energy.material, energy.loads,
                                              stiffness=self.stiffness(z)))
        return solve_last_layer(self.operator, objective.potential(1.0),
                                samples, 1.0,
                                last_layer_config(max_iterations=cfg.newton_iterations),
                                conditioning=z)

    # -- evaluation -----------------------------------------------------------------------------
    def _conditioning(self, xi: torch.Tensor, z) -> torch.Tensor:
        z = torch.as_tensor(z, dtype=xi.dtype).reshape(1, -1)
        return z.expand(len(xi), -1)

    def positions(self, xi: torch.Tensor, z) -> torch.Tensor:
        """Equilibrium positions x*(ξ; θ) (N, 3) [m] at ξ (N, 2) for coordinates z (p,)."""
        xi = xi.to(self.field.parameters[0].dtype)
        r = self.model.surface.jets(xi)[:, jets.VALUE]
        return r + self.operator.displacement(xi, conditioning=self._conditioning(xi, z))

    def position_jets(self, xi: torch.Tensor, z) -> torch.Tensor:
        """Jets (N, 6, 3) of x*(ξ; θ) [m] (for projections onto the surface)."""
        xi = xi.to(self.field.parameters[0].dtype)
        u = self.operator.jets(xi, conditioning=self._conditioning(xi, z))
        return self.model.surface.jets(xi) + u

"""Implicit time stepping of a model on a spline field: every step minimises an incremental
potential with the one projected Newton (`taichi_ndf.minimise.newton.minimise`).

The state lives in the coefficients (n, 3) of one grid (the plan's finest): displacement C
[m], velocity V [m/s], acceleration A [m/s²], each a field u = U₀ + J P on the Gauss points of
the spline discretisation (`SplineDiscretisation.linearisation`). The loads act at the load
factor λ(t) (`DynamicsConfig.load_factor`: 1 from t = 0, or a linear ramp), each step's at its
end time. M is the consistent mass matrix of that field (`objective.inertia`), Π
the model's potential energy (strain energy − work of the loads, + its further terms), α the
mass-proportional Rayleigh damping [1/s] (force −α M v). A step of length h from (C, V, A):

- implicit Euler: x̂ = C + h V; C' = argmin ½ (x − x̂)ᵀ M (x − x̂)/h² + ½ α (x − C)ᵀ M (x − C)/h
  + Π(x); V' = (C' − C)/h, A' = (V' − V)/h (first order, dissipative);
- Newmark, average acceleration (β = ¼, γ = ½; trapezoidal): x̂ = C + h V + (½ − β) h² A,
  ṽ = V + (1 − γ) h A; C' = argmin ½ (x − x̂)ᵀ M (x − x̂)/(β h²) + α (x − x̂)ᵀ M (ṽ + ½ γ (x −
  x̂)/(β h)) + Π(x); A' = (C' − x̂)/(β h²), V' = ṽ + γ h A' (second order; conserves
  ½ VᵀMV + Π for a linear problem). A₀ solves M A₀ = −∇Π(C₀) − α M V₀.

Both inertia parts are one `InertiaTerm` ½ s (x − x*)ᵀ M (x − x*) (its constant dropped):
s = 1/h² + α/h, x* = x̂ − α V/s (implicit Euler); s = 1/(β h²) + α γ/(β h), x* = x̂ − α ṽ/s
(Newmark). Stiffness-proportional damping β_R [s] (force −β_R K₀ v, K₀ the shell's tangent
stiffness at the step's start, positive semi-definite through the strains) adds the same form
in K₀, one `StiffnessDampingTerm` ½ c (x − y)ᵀ K₀ (x − y): c = β_R/h, y = C (implicit Euler);
c = β_R γ/(β h), y = x̂ − β_R ṽ/c (Newmark); and −β_R K₀ V₀ to A₀'s right-hand side. These
formulas are written once, as the linear maps of `taichi_ndf.problem.dynamics.StepMap` (the
adjoint, `solve/dynamics_adjoint.py`, differentiates the same maps). Each step starts Newton
from x̂ at load factor 1 and stops on Newton's own test; a step whose Newton does not
converge is logged and split into two halves (recursively, at most
`DynamicsConfig.halvings` times; beyond that `DynamicsError`).

Contact (`[[obstacles]]`, the model's `ContactConfig`): each step is solved by the spline
path's `NewtonContact.solve` (the barrier, its lagged friction, the check points kept over the
steps, the line search bounded by the hook's `feasible`), with the inertia term passed as a
term at each round's samples (`terms_at`); its Newton starts from the step's start C (x̂
could be inside an obstacle), and friction lags from C. The smallest gap [m] of the dense
check grid after each step is recorded (`StepRecord.gap`). Not yet: stiffness damping with
contact (refused), prescribed motions in time (refused), adaptive steps, adjoints through
contact (`solve/dynamics_adjoint.py` refuses it).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from taichi_ndf import jets, progress
from taichi_ndf.contact.newton_contact import NewtonContact, PointMap
from taichi_ndf.discretise.spline import SplineDiscretisation
from taichi_ndf.field import SplineField
from taichi_ndf.minimise.newton import NewtonConfig, minimise
from taichi_ndf.objective import Objective
from taichi_ndf.objective.damping import StiffnessDampingTerm
from taichi_ndf.objective.inertia import InertiaTerm, kinetic_energy
from taichi_ndf.problem.dynamics import DynamicsConfig, StepMap, combine
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.shell.hessian import flat_blocks

log = logging.getLogger(__name__)


class DynamicsError(RuntimeError):
    """A time step did not converge even after the allowed halvings."""


@dataclass(frozen=True)
class Motion:
    """The state at a time [s]: coefficients (n, 3) of displacement [m], velocity [m/s] and
    acceleration [m/s²]."""

    time: float
    displacement: torch.Tensor
    velocity: torch.Tensor
    acceleration: torch.Tensor


@dataclass(frozen=True)
class StepRecord:
    """One time step: its index (1 = the first), the time reached [s], Newton iterations over
    its substeps, substeps (1: not halved), kinetic energy T, potential energy Π and T + Π [J]
    at its end, and the CPU seconds (user + sys of this process) and wall seconds it took."""

    step: int
    time: float
    newton_iterations: int
    substeps: int
    kinetic: float
    potential: float
    total: float
    cpu_seconds: float
    wall_seconds: float
    gap: float | None = None  # with contact: the dense check grid's smallest gap [m]


@dataclass
class Trajectory:
    """A dynamic run: its settings, spans of the grid, the state at t = 0 (energies), every
    step, the output frames (time [s], coefficients (n, 3)), the probes' displacement [m] at
    t = 0 and after every step, the final field."""

    config: DynamicsConfig
    spans: tuple[int, int]
    initial: StepRecord
    records: list[StepRecord] = field(default_factory=list)
    frames: list[tuple[float, torch.Tensor]] = field(default_factory=list)
    probes: dict[str, list[list[float]]] = field(default_factory=dict)
    field: SplineField | None = None

    @property
    def times(self) -> list[float]:
        return [self.initial.time] + [r.time for r in self.records]

    @property
    def cpu_seconds(self) -> float:
        return sum(r.cpu_seconds for r in self.records)

    def to_dict(self) -> dict:
        """result.json's `dynamics`: settings, per step times and energies, frames' times, and
        the CPU cost per step and per simulated second."""
        records = [self.initial, *self.records]
        steps = max(1, len(self.records))
        return {**self.config.to_dict(), "spans": list(self.spans),
                "times": self.times, "kinetic": [r.kinetic for r in records],
                "potential": [r.potential for r in records],
                "total": [r.total for r in records],
                "newton_iterations": [r.newton_iterations for r in self.records],
                "substeps": [r.substeps for r in self.records],
                **({"gaps": [r.gap for r in records]} if self.initial.gap is not None
                   else {}),
                "frame_times": [t for t, _ in self.frames], "probes": self.probes,
                "cpu_seconds": self.cpu_seconds,
                "wall_seconds": sum(r.wall_seconds for r in self.records),
                "cpu_per_step": self.cpu_seconds / steps,
                "cpu_per_simulated_second": self.cpu_seconds / max(self.times[-1], 1e-300)}


def _cpu() -> float:
    return time.process_time()


class TimeStepper:
    """The time steps of a model on the finest grid of a spline plan (module docstring).

    newton: Newton's settings per step (None: the float64 defaults); objective: Π (None: the
    model's). ValueError for what the dynamic path does not support yet: prescribed boundary
    motions, stiffness damping with contact."""

    def __init__(self, model: ShellModel, plan: SplinePlan, config: DynamicsConfig, *,
                 newton: NewtonConfig | None = None, objective: Objective | None = None):
        if model.contact is not None and config.stiffness_damping:
            raise ValueError("dynamics: stiffness damping with contact ([[obstacles]]) is not "
                             "supported by the dynamic path yet")
        finest = SplinePlan(plan.finest(), 1, plan.quadrature_points)
        self.discretisation = SplineDiscretisation(finest, model, objective=objective)
        self.model, self.config = model, config
        self.field = SplineField(finest.config)
        self.samples = self.discretisation.evaluation_points()
        self.linear = self.discretisation.linearisation(self.samples, 1.0)
        self.offset = self.linear.displacement(torch.zeros_like(self.field.coefficients))
        if float(self.offset.abs().max()) > 0:
            raise ValueError("dynamics: prescribed boundary motions (handles, rim rotations) "
                             "are not supported by the dynamic path yet")
        self.objective = objective or Objective.of_model(model)
        self.density = model.material.areal_density
        self.newton = newton or NewtonConfig()
        self.contact = None
        if model.contact is not None:
            self.contact = NewtonContact(model.contact, model, self.offset.dtype)
            self.grid = self.discretisation.linearise(self.field)
            self._on_grid = PointMap(self.grid, self.contact.points.grid_xi.to(
                self.offset.dtype), 1.0)

    def gap(self, displacement: torch.Tensor, t: float) -> float | None:
        """The smallest gap [m] of the dense check grid at coefficients C (None: no contact);
        its points within the activation distance become check points."""
        if self.contact is None:
            return None
        points = self.contact.points
        u = self._on_grid(displacement)
        return points.flag(points.point_gaps(points.grid_r.to(u.dtype) + u,
                                             self.config.load_factor(t)))

    # --- energies and the mass matrix --------------------------------------------------------
    def kinetic(self, velocity: torch.Tensor) -> float:
        """T = ½ Vᵀ M V [J]."""
        rate = self.linear.displacement(velocity) - self.offset
        return kinetic_energy(self.samples, self.density, rate)

    def potential_energy(self, displacement: torch.Tensor, t: float) -> float:
        """Π [J] at coefficients C and time t [s] (the loads at λ(t)); with contact + the
        barrier Π_c at the Gauss and check points (as the quasistatic solve's Π; friction is
        not a potential)."""
        load_factor = self.config.load_factor(t)
        if self.contact is None:
            potential = self.objective.potential(load_factor)
            return potential(self.samples, self.linear.displacement(displacement), False).total
        samples = self.contact.points.augment(self.samples)
        linear = self.grid.linearisation(load_factor, samples)
        potential = self.objective.with_terms(self.contact.points.term).potential(load_factor)
        return potential(linear.samples, linear.displacement(displacement), False).total

    def _mass_times(self, velocity: torch.Tensor) -> torch.Tensor:
        """M V (n, 3) (held unknowns 0)."""
        term = InertiaTerm(self.density, 1.0, self.offset)
        _, gradient = term.evaluate(self.samples, self.linear.displacement(velocity))
        return self.linear.gradient(gradient)

    def initial_acceleration(self, displacement: torch.Tensor, velocity: torch.Tensor
                             ) -> torch.Tensor:
        """A₀ from M A₀ = −∇Π(C₀) − α M V₀ − β_R K₀ V₀ (one solve with the mass matrix)."""
        u = self.linear.displacement(displacement)
        potential = self.objective.potential(self.config.load_factor(0.0))
        gradient = self.linear.gradient(potential(self.samples, u, True).grad_u_jets)
        if self.config.mass_damping:
            gradient = gradient + self.config.mass_damping * self._mass_times(velocity)
        if self.config.stiffness_damping:
            term = StiffnessDampingTerm(self._stiffness_blocks(displacement),
                                        self.config.stiffness_damping, self.offset)
            _, force = term.evaluate(self.samples, self.linear.displacement(velocity))
            gradient = gradient + self.linear.gradient(force)
        term = InertiaTerm(self.density, 1.0, u)
        mass = self.linear.hessian(flat_blocks(term.hessian_blocks(self.samples, u)))
        solved = self.linear.solve(mass, gradient, 0.0)
        if solved is None:
            raise DynamicsError("the mass matrix could not be factorised")
        return solved[0]

    def _stiffness_blocks(self, displacement: torch.Tensor) -> torch.Tensor:
        """The shell's per-point tangent-stiffness blocks (N, 6, 3, 6, 3) at coefficients C,
        positive semi-definite through the strains (K₀ of the stiffness damping)."""
        u = self.linear.displacement(displacement)
        steps = self.linear.fd_steps(u, displacement, self.newton.fd_step)
        return self.objective.shell.hessian_blocks(self.samples, u, 1.0, steps=steps, psd=True)

    # --- one step ----------------------------------------------------------------------------
    def step(self, state: Motion, h: float) -> tuple[Motion, object]:
        """The state after one step of length h [s] and Newton's solution (module docstring)."""
        c, v, a = state.displacement, state.velocity, state.acceleration
        scheme = StepMap.of(self.config, h)
        predicted = combine(scheme.predicted, (c, v, a))
        target = combine(scheme.target, (c, v, a))
        scale = scheme.scale
        terms = [InertiaTerm(self.density, scale, self.linear.displacement(target))]
        damping = self.config.stiffness_damping
        if damping:
            coefficient = damping * scheme.rate
            origin = predicted - combine(scheme.carried, (c, v, a)) / scheme.rate
            terms.append(StiffnessDampingTerm(self._stiffness_blocks(c), coefficient,
                                              self.linear.displacement(origin)))
        load_factor = self.config.load_factor(state.time + h)  # the loads at the step's end
        if self.contact is not None:  # from C: x̂ could be inside an obstacle
            def inertia(assembly) -> tuple:
                return (InertiaTerm(self.density, scale, assembly.displacement(target)),)
            solution = self.contact.solve(
                self.grid, self.samples, self.objective, c, self.newton,
                load_factor=load_factor, start_load_factor=self.config.load_factor(state.time),
                terms_at=inertia, report=False)
        else:
            solution = minimise(self.linear, self.objective.with_terms(*terms).potential(
                load_factor), predicted, self.newton, load_factor=load_factor, report=False)
        x = solution.parameters
        velocity, acceleration = scheme.apply(x, state)
        return Motion(state.time + h, x, velocity, acceleration), solution

    def advance(self, state: Motion, h: float, depth: int = 0) -> tuple[Motion, int, int]:
        """One step of h [s], halved where Newton does not converge (module docstring): the
        state, the Newton iterations and the substeps taken."""
        end, solution = self.step(state, h)
        iterations = len(solution.history)
        if solution.converged:
            return end, iterations, 1
        if depth >= self.config.halvings:
            raise DynamicsError(f"the time step from t = {state.time:.6g} s of {h:.3g} s did not "
                                f"converge in {iterations} Newton iterations, also after "
                                f"{depth} halvings")
        log.warning("time step from t = %.6g s of %.3g s: Newton did not converge in %d "
                    "iterations; halved", state.time, h, iterations)
        middle, first, n1 = self.advance(state, 0.5 * h, depth + 1)
        end, second, n2 = self.advance(middle, 0.5 * h, depth + 1)
        return end, iterations + first + second, n1 + n2

    # --- the run -----------------------------------------------------------------------------
    def _probes(self, displacement: torch.Tensor) -> dict[str, list[float]]:
        self.field.coefficients.copy_(displacement)
        return self.discretisation.probes(self.field, 1.0)

    def run(self, displacement: torch.Tensor | None = None,
            velocity: torch.Tensor | None = None, *,
            on_frame: Callable[[float, SplineField], None] | None = None) -> Trajectory:
        """Integrate from coefficients C₀ (None: the reference state) and V₀ (None: at rest)
        over `config.duration`; on_frame(time [s], field) at t = 0, every `frame_every` steps
        and at the end (one progress stage, one report per step)."""
        config = self.config
        zeros = torch.zeros_like(self.field.coefficients)
        c = zeros.clone() if displacement is None else displacement.to(zeros).clone()
        v = zeros.clone() if velocity is None else velocity.to(zeros).clone()
        a = self.initial_acceleration(c, v) if config.integrator == "newmark" else zeros.clone()
        state = Motion(0.0, c, v, a)
        kinetic, potential = self.kinetic(v), self.potential_energy(c, 0.0)
        gap = self.gap(c, 0.0)
        if gap is not None and gap <= 0:
            raise ValueError(f"dynamics: the initial state touches an obstacle (smallest gap "
                             f"{gap:.3g} m)")
        trajectory = Trajectory(config, tuple(self.field.config.spans),
                                StepRecord(0, 0.0, 0, 0, kinetic, potential, kinetic + potential,
                                           0.0, 0.0, gap))
        trajectory.probes = {k: [u] for k, u in self._probes(c).items()}

        def frame(state: Motion) -> None:
            trajectory.frames.append((state.time, state.displacement.clone()))
            if on_frame is not None:
                self.field.coefficients.copy_(state.displacement)
                on_frame(state.time, self.field)

        frame(state)
        every = config.frame_every
        with progress.stage(f"dynamics ({config.integrator}, {config.steps} steps of "
                            f"{config.dt:.3g} s)", config.steps):
            for k in range(1, config.steps + 1):
                cpu, wall = _cpu(), time.perf_counter()
                state, iterations, substeps = self.advance(state, config.dt)
                state = Motion(k * config.dt, state.displacement, state.velocity,
                               state.acceleration)  # no rounding drift of the clock
                kinetic = self.kinetic(state.velocity)
                potential = self.potential_energy(state.displacement, state.time)
                gap = self.gap(state.displacement, state.time)
                record = StepRecord(k, state.time, iterations, substeps, kinetic, potential,
                                    kinetic + potential, _cpu() - cpu,
                                    time.perf_counter() - wall, gap)
                trajectory.records.append(record)
                for name, u in self._probes(state.displacement).items():
                    trajectory.probes[name].append(u)
                progress.report(k, t=state.time, E=record.total)
                log.debug("step %d, t = %.6g s: T %.6g J, Π %.6g J, %d Newton iterations", k,
                          state.time, kinetic, potential, iterations)
                if (every is not None and k % every == 0) or k == config.steps:
                    frame(state)
        self.field.coefficients.copy_(state.displacement)
        trajectory.field = self.field
        return trajectory


def initial_velocity(stepper: TimeStepper, rate: Callable[[torch.Tensor], torch.Tensor]
                     ) -> torch.Tensor:
    """Coefficients V (n, 3) of the velocity field closest in the mass norm to rate(ξ) (N, 3)
    [m/s] at the Gauss points: M V = Jᵀ W rate (the L² projection; also for displacements)."""
    samples = stepper.samples
    values = rate(samples.xi).to(stepper.offset.dtype)
    target = stepper.offset.clone()
    target[:, jets.VALUE] += values
    term = InertiaTerm(stepper.density, 1.0, target)
    gradient = stepper.linear.gradient(term.evaluate(samples, stepper.offset)[1])
    mass = stepper.linear.hessian(flat_blocks(term.hessian_blocks(samples, stepper.offset)))
    solved = stepper.linear.solve(mass, gradient, 0.0)
    if solved is None:
        raise DynamicsError("the mass matrix could not be factorised")
    return solved[0]

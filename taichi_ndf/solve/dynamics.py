"""Implicit time stepping of a model on a spline field: every step minimises an incremental
potential with the one projected Newton (`taichi_ndf.minimise.newton.minimise`).

The state lives in the coefficients (n, 3) of one grid (the plan's finest): displacement C [m],
velocity V [m/s], acceleration A [m/s²], each a field u = U₀ + J P on the Gauss points of the
spline discretisation (`SplineDiscretisation.linearisation`). The loads act at the load factor λ(t)
(`DynamicsConfig.load_factor`: 1 from t = 0, or a linear ramp), each step's at its end time. M is
the consistent mass matrix of that field (`objective.inertia`), Π the model's potential energy
(strain energy − work of the loads, + its further terms), α the mass-proportional Rayleigh damping
[1/s] (force −α M v). Each step of length h from (C, V, A) minimises ½ s (x − x*)ᵀ M (x − x*) +
Π(x) (+ ½ c (x − y)ᵀ K₀ (x − y) with stiffness-proportional damping β_R [s]): implicit Euler
(first order, dissipative) or Newmark's average acceleration (β = ¼, γ = ½; second order); s, x*,
c, y and the new V', A' are the linear maps of `taichi_ndf.problem.dynamics.StepMap`, written once
there (docs/dynamics.md has the formulas; the adjoint, `solve/dynamics_adjoint.py`, differentiates
the same maps). Newmark's A₀ solves M A₀ = −∇Π(C₀) − α M V₀ − β_R K₀ V₀. Each step starts Newton
from x̂ and stops on Newton's own test (the minimiser interface); one not converged is logged and
split into two halves (recursively, at most `DynamicsConfig.halvings` times; beyond that
`DynamicsError`). The time steps are the steps of the one continuation loop (`solve_over`, a
step's value its end time), their sizes from the step control (`solve.time_steps`).

Contact (`[[obstacles]]`, the model's `ContactConfig`): each step is the spline path's
`ContactMinimiser` run through `run_phases` as a static step (the barrier, its lagged friction,
the check points kept over the steps, the line search bounded by the hook's `feasible`), with the
inertia term passed as a term at each round's samples (`terms_at`); its Newton starts from the
step's start C (x̂ could be inside an obstacle), and friction lags from C. The smallest gap [m]
of the dense check grid after each step is recorded (`StepRecord.gap`). Wind: one more per-point
term (`objective.wind`, its drag implicit in the velocity); a boundary motion μ(t): the
boundary's part g of the displacement is stepped by the same scheme (`Motion.boundary`,
docs/dynamics.md). Not yet: stiffness damping or a motion with contact (refused).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import torch

from taichi_ndf import jets, progress
from taichi_ndf.contact.newton_contact import NewtonContact, PointMap
from taichi_ndf.discretise.spline import SplineDiscretisation
from taichi_ndf.field import SplineField
from taichi_ndf.minimise.continuation import Hook, Stages, solve_over
from taichi_ndf.minimise.minimisers import NewtonMinimiser, Phase, run_phases
from taichi_ndf.minimise.newton import NewtonConfig
from taichi_ndf.objective import Objective
from taichi_ndf.objective.damping import StiffnessDampingTerm
from taichi_ndf.objective.inertia import InertiaTerm, kinetic_energy
from taichi_ndf.objective.wind import wind_term
from taichi_ndf.problem.dynamics import DynamicsConfig, StepMap, combine
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.shell.hessian import flat_blocks
from taichi_ndf.solve.dynamics_trajectory import Checkpoint, Motion, StepRecord, Trajectory
from taichi_ndf.solve.time_steps import TimeSteps

log = logging.getLogger(__name__)


class DynamicsError(RuntimeError):
    """A time step did not converge even after the allowed halvings."""


class TimeStepper:
    """The time steps of a model on the finest grid of a spline plan (module docstring).

    newton: Newton's settings per step (None: the float64 defaults); objective: Π (None: the
    model's). ValueError for what the dynamic path does not support yet: prescribed boundary
    motions, stiffness damping with contact."""

    def __init__(self, model: ShellModel, plan: SplinePlan, config: DynamicsConfig, *,
                 newton: NewtonConfig | None = None, objective: Objective | None = None):
        if model.contact is not None and config.stiffness_damping:
            raise ValueError("dynamics: stiffness damping with contact ([[obstacles]] or "
                             "[self_contact]) is not supported by the dynamic path yet")
        if model.contact is not None and config.motion is not None:
            raise ValueError("dynamics: a prescribed boundary motion with contact ([[obstacles]] "
                             "or [self_contact]) is not supported by the dynamic path yet")
        finest = SplinePlan(plan.finest(), 1, plan.quadrature_points)
        self.discretisation = SplineDiscretisation(finest, model, objective=objective)
        self.model, self.config = model, config
        self.field = SplineField(finest.config)
        self.samples = self.discretisation.evaluation_points()
        # One assembly at the Gauss points; its boundary offset g(μ) follows `_at` (μ(t)).
        self._grid = self.discretisation.linearise(self.field)
        self.linear = self._grid.linearisation(1.0, self.samples)
        self.samples = self.linear.samples  # the assembly's order, as linear.displacement's
        moves = float(self.offset_of(self.linear).abs().max()) > 0
        if moves != (config.motion is not None):
            raise ValueError("dynamics: the boundary prescribes displacements (handles, rim "
                             "rotations): give their motion in time, [dynamics.motion]"
                             if moves else "dynamics.motion: the boundary prescribes no "
                             "displacement to move (no handle, no rim rotation)")
        self.linear = self._at(0.0)
        self.offset = self.linear.displacement(torch.zeros_like(self.field.coefficients))
        self.objective = objective or Objective.of_model(model)
        self.density = model.material.areal_density
        self.newton = newton or NewtonConfig()
        self.contact = None
        if model.contact is not None:
            self.contact = NewtonContact(model.contact, model, self.offset.dtype)
            self.grid = self.discretisation.linearise(self.field)
            self._on_grid = PointMap(self.grid, self.contact.points.grid_xi.to(
                self.offset.dtype), 1.0)

    def _at(self, t: float):
        """The linearisation at the Gauss points with the boundary at μ(t) (t [s]); the one
        assembly's offset is moved there (without a motion: μ = 1, offset 0, unchanged)."""
        if self.config.motion is None:
            return self.linear
        return self._grid.linearisation(self.config.boundary_factor(t))

    def _jets(self, linear, coefficients: torch.Tensor, boundary=None) -> torch.Tensor:
        """Jets (N, 6, 3) of J P + b at the Gauss points: the free part of coefficients P and
        the boundary part b (jets, or None: 0)."""
        jets_ = linear.displacement(coefficients) - self.offset_of(linear)
        return jets_ if boundary is None else jets_ + boundary

    def offset_of(self, linear) -> torch.Tensor:
        """g: the boundary's displacement jets (N, 6, 3) [m] of a linearisation."""
        return linear.displacement(torch.zeros_like(self.field.coefficients))

    def gap(self, displacement: torch.Tensor, t: float) -> float | None:
        """The smallest gap [m] of the dense check grid at coefficients C (None: no contact,
        or no obstacle: self-contact alone); its points within the activation distance become
        check points."""
        if self.contact is None or not self.contact.config.obstacles:
            return None
        points = self.contact.points
        u = self._on_grid(displacement)
        return points.flag(points.point_gaps(points.grid_r.to(u.dtype) + u,
                                             self.config.load_factor(t)))

    def kinetic(self, velocity: torch.Tensor, boundary: torch.Tensor | None = None) -> float:
        """T = ½ Vᵀ M V [J]; with a boundary motion, of the velocity J V + ġ (boundary: ġ)."""
        return kinetic_energy(self.samples, self.density,
                              self._jets(self.linear, velocity, boundary))

    def potential_energy(self, displacement: torch.Tensor, t: float) -> float:
        """Π [J] at coefficients C and time t [s] (the loads at λ(t)); with contact + the
        barrier Π_c at the Gauss and check points (as the quasistatic solve's Π; friction is
        not a potential)."""
        load_factor = self.config.load_factor(t)
        if self.contact is None:
            potential = self.objective.potential(load_factor)
            return potential(self.samples, self._at(t).displacement(displacement), False).total
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
        """A₀ from M A₀ = −∇Π(C₀) − α M V₀ − β_R K₀ V₀ (one solve with the mass matrix; the
        boundary at rest at t = 0)."""
        u = self._at(0.0).displacement(displacement)
        potential = self.objective.potential(self.config.load_factor(0.0))
        gradient = self.linear.gradient(potential(self.samples, u, True).grad_u_jets)
        if self.config.mass_damping:
            gradient = gradient + self.config.mass_damping * self._mass_times(velocity)
        if self.config.stiffness_damping:
            term = StiffnessDampingTerm(self._stiffness_blocks(0.0, displacement),
                                        self.config.stiffness_damping, self.offset)
            _, force = term.evaluate(self.samples, self.linear.displacement(velocity))
            gradient = gradient + self.linear.gradient(force)
        term = InertiaTerm(self.density, 1.0, u)
        mass = self.linear.hessian(flat_blocks(term.hessian_blocks(self.samples, u)))
        solved = self.linear.solve(mass, gradient, 0.0)
        if solved is None:
            raise DynamicsError("the mass matrix could not be factorised")
        return solved[0]

    def _stiffness_blocks(self, t: float, displacement: torch.Tensor) -> torch.Tensor:
        """The shell's per-point tangent-stiffness blocks (N, 6, 3, 6, 3) at coefficients C
        and time t [s], positive semi-definite through the strains (K₀ of the stiffness
        damping)."""
        linear = self._at(t)
        u = linear.displacement(displacement)
        steps = linear.fd_steps(u, displacement, self.newton.fd_step)
        return self.objective.shell.hessian_blocks(self.samples, u, 1.0, steps=steps, psd=True)

    def _wind(self, state: Motion, scheme: StepMap):
        """None without wind; else from the step's start: the displacement jets, the points'
        velocities (N, 3) [m/s], and v' = k (x − y) of the scheme: k [1/s], y's coefficients
        and its boundary jets (None: no boundary motion)."""
        if self.config.wind is None:
            return None
        c, v, a, b = state.displacement, state.velocity, state.acceleration, state.boundary
        linear = self._at(state.time)
        rate = scheme.velocity[0]
        origin = combine(scheme.velocity[1:], (c, v, a)) / -rate
        boundary = None if b is None else combine(
            scheme.velocity[1:], (b.displacement, b.velocity, b.acceleration)) / -rate
        velocity = self._jets(linear, v, None if b is None else b.velocity)[:, jets.VALUE]
        return linear.displacement(c), velocity, rate, origin, boundary

    def step(self, state: Motion, h: float) -> tuple[Motion, object]:
        """The state after one step of length h [s] and Newton's solution (module docstring)."""
        c, v, a = state.displacement, state.velocity, state.acceleration
        scheme = StepMap.of(self.config, h)
        end_time = state.time + h
        wind = self._wind(state, scheme)
        stiffness = (self._stiffness_blocks(state.time, c) if self.config.stiffness_damping
                     else None)
        linear = self._at(end_time)  # the boundary at its step's end
        boundary = None
        if state.boundary is not None:  # g' given; its x* part as the free part's
            b = state.boundary
            g = self.offset_of(linear)
            boundary = (g, combine(scheme.target, (b.displacement, b.velocity, b.acceleration)),
                        combine(scheme.predicted, (b.displacement, b.velocity, b.acceleration)))
        predicted = combine(scheme.predicted, (c, v, a))
        target = combine(scheme.target, (c, v, a))
        scale = scheme.scale
        target_jets = self._jets(linear, target, None if boundary is None else boundary[1])
        terms = [InertiaTerm(self.density, scale, target_jets)]
        if wind is not None:
            u0, v0, rate, origin, origin_boundary = wind
            terms.append(wind_term(self.config.wind, end_time, self.samples, u0, v0, rate,
                                   self._jets(linear, origin, origin_boundary)))
        if stiffness is not None:
            origin = predicted - combine(scheme.carried, (c, v, a)) / scheme.rate
            origin_jets = self._jets(linear, origin, None if boundary is None else (
                boundary[2] - combine(scheme.carried, (b.displacement, b.velocity,
                                                       b.acceleration)) / scheme.rate))
            terms.append(StiffnessDampingTerm(stiffness, self.config.stiffness_damping
                                              * scheme.rate, origin_jets))
        load_factor = self.config.load_factor(end_time)  # the loads at the step's end
        if self.contact is not None:  # from C: x̂ could be inside an obstacle
            def step_terms(linear) -> tuple:  # at a contact round's samples
                extra = (InertiaTerm(self.density, scale, linear.displacement(target)),)
                if wind is not None:
                    u0, v0, rate, origin, _ = wind
                    extra += (wind_term(self.config.wind, end_time, self.samples, u0, v0, rate,
                                        linear.displacement(origin)),)
                return extra
            phase = Phase(self.contact.minimiser(
                self.newton, load_factor=load_factor, terms_at=step_terms, report=False,
                start_load_factor=self.config.load_factor(state.time)),
                lambda: (self.grid, self.samples, self.objective), lambda: c)
        else:  # Newton alone, from x̂
            phase = Phase(NewtonMinimiser(self.newton, load_factor=load_factor, report=False),
                          lambda: (linear, self.objective.with_terms(*terms).potential(
                              load_factor)), lambda: predicted)
        solution, = run_phases([phase])
        x = solution.parameters
        velocity, acceleration = scheme.apply(x, state)
        end_boundary = None
        if boundary is not None:
            end_boundary = Motion(end_time, boundary[0], *scheme.apply(boundary[0], b))
        return Motion(end_time, x, velocity, acceleration, end_boundary), solution

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

    def _probes(self, displacement: torch.Tensor, t: float) -> dict[str, list[float]]:
        self.field.coefficients.copy_(displacement)
        return self.discretisation.probes(self.field, self.config.boundary_factor(t))

    def start(self, displacement: torch.Tensor | None = None,
              velocity: torch.Tensor | None = None) -> Checkpoint:
        """Step 0 of a run from coefficients C₀ (None: the reference state) and V₀ (None: at
        rest), the boundary (with a motion) at rest in the reference state."""
        zeros = torch.zeros_like(self.field.coefficients)
        c = zeros.clone() if displacement is None else displacement.to(zeros).clone()
        v = zeros.clone() if velocity is None else velocity.to(zeros).clone()
        a = (self.initial_acceleration(c, v) if self.config.integrator == "newmark"
             else zeros.clone())
        boundary = None
        if self.config.motion is not None:
            g = self.offset_of(self._at(0.0))
            boundary = Motion(0.0, g, torch.zeros_like(g), torch.zeros_like(g))
        state = Motion(0.0, c, v, a, boundary)
        kinetic, potential = self.kinetic(v), self.potential_energy(c, 0.0)
        gap = self.gap(c, 0.0)
        if gap is not None and gap <= 0:
            raise ValueError(f"dynamics: the initial state touches an obstacle (smallest gap "
                             f"{gap:.3g} m)")
        trajectory = Trajectory(self.config, tuple(self.field.config.spans),
                                StepRecord(0, 0.0, 0, 0, kinetic, potential, kinetic + potential,
                                           0.0, 0.0, gap))
        trajectory.probes = {k: [u] for k, u in self._probes(c, 0.0).items()}
        return self._checkpoint(0, state, trajectory)

    def _checkpoint(self, step: int, state: Motion, trajectory: Trajectory,
                    size: float | None = None, easy: int = 0) -> Checkpoint:
        if self.contact is None:
            return Checkpoint(step, state, trajectory, size, easy)
        points = self.contact.points
        return Checkpoint(step, state, trajectory, size, easy, points.active.clone(),
                          float(points.term.stiffness))

    def _record(self, k: int, state: Motion, iterations: int, substeps: int, size: float,
                cpu: float, wall: float) -> StepRecord:
        """Step k's record: energies and gap at its end (the CPU and wall clock from the
        step's start, `cpu` and `wall`, to now)."""
        kinetic = self.kinetic(state.velocity, None if state.boundary is None
                               else state.boundary.velocity)
        potential = self.potential_energy(state.displacement, state.time)
        gap = self.gap(state.displacement, state.time)
        return StepRecord(k, state.time, iterations, substeps, kinetic, potential,
                          kinetic + potential, time.process_time() - cpu,
                          time.perf_counter() - wall, gap, size)

    def run(self, displacement: torch.Tensor | None = None,
            velocity: torch.Tensor | None = None, *,
            on_frame: Callable[[float, SplineField], None] | None = None,
            on_checkpoint: Callable[[Checkpoint], None] | None = None,
            resume: Checkpoint | None = None) -> Trajectory:
        """Integrate from C₀ (None: the reference state) and V₀ (None: at rest) over
        `config.duration`, or on from `resume` (a `Checkpoint` of the same run: the same steps
        follow), by `solve_over` (one progress stage, a report per step); on_frame(time [s],
        field) at t = 0 and every `config.frame_times()`, then on_checkpoint(its `Checkpoint`)
        (from the loop's on_load_step callback)."""
        config = self.config
        if resume is None:
            resume = self.start(displacement, velocity)
        elif self.contact is not None:  # the check points and κ the steps reached
            self.contact.restore({"active": resume.active, "stiffness": resume.stiffness,
                                  "rounds": self.contact.rounds, "round": None})
        state, trajectory = resume.state, resume.trajectory

        def frame(state: Motion) -> None:
            trajectory.frames.append((state.time, state.displacement.clone()))
            if on_frame is not None:
                self.field.coefficients.copy_(state.displacement)
                on_frame(state.time, self.field)

        if resume.step == 0:
            frame(state)
        clock = TimeSteps(config, state, step=resume.step, size=resume.step_size,
                          easy=resume.easy)

        def solve(step, _start) -> StepRecord:  # one time step (halved inside: `advance`)
            cpu, wall, size = time.process_time(), time.perf_counter(), clock.size
            end, iterations, substeps = self.advance(clock.state, size)
            end = clock.after(end, iterations, substeps)
            record = self._record(clock.step, end, iterations, substeps, size, cpu, wall)
            trajectory.records.append(record)
            for name, u in self._probes(end.displacement, end.time).items():
                trajectory.probes[name].append(u)
            progress.report(min(config.steps, round(end.time / config.dt)), t=end.time,
                            E=record.total)
            return record

        def at_frame(_time: float) -> None:  # after a step that reached its output frame
            if clock.at_frame():
                frame(clock.state)
                if on_checkpoint is not None:
                    on_checkpoint(self._checkpoint(clock.step, clock.state, trajectory,
                                                   clock.h, clock.easy))

        with progress.stage(f"dynamics ({config.integrator}, {config.steps} steps of "
                            f"{config.dt:.3g} s{', adaptive' if clock.rule else ''})",
                            config.steps):
            solve_over(Stages(solve), (), first_step=resume.step,
                       callbacks=[Hook("on_load_step", at_frame)],
                       next_value=lambda _index, _last: clock.next())
        self.field.coefficients.copy_(clock.state.displacement)
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

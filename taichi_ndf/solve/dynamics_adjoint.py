"""Gradients through time: the discrete adjoint of the time steps (`taichi_ndf.solve.dynamics`)
with respect to one stiffness parameter θ of the material (e.g. `bending_stiffness` B [N·m]).

A step of h from the state (C, V, A) (coefficients (n, 3)) ends at the minimiser x = C' of
E(x) = ½ s (x − x*)ᵀ M (x − x*) + Π(x; θ), so g(x) = s M (x − x*) + f(x; θ) = 0 with
f = ∇Π. Both schemes are linear in the state apart from that solve (`StepMap`):
x* = t_C C + t_V V + t_A A, V' = Σ v_y y and A' = Σ a_y y over y = (x, C, V, A). For a
trajectory quantity J(C_0, …, C_N) with ∂J/∂C_k = W_k, backwards from (λ_C, λ_V, λ_A) =
(W_N, 0, 0) at the last state, per step:

    μ solves K μ = λ_C' + v_x λ_V' + a_x λ_A'    (K = s M + ∂f/∂x at x, EXACT blocks)
    dJ/dθ −= μᵀ ∂f/∂θ(x)
    λ_y = W + v_y λ_V' + a_y λ_A' + s t_y M μ     for y = C, V, A (W only for C);

and at t = 0, Newmark's A₀ (M A₀ = −f(C₀) − α M V₀) adds −λ_Aᵀ M⁻¹ ∂f/∂θ(C₀). K is the exact
Hessian of the step's incremental potential at its converged end (`exact_hessian`, as the
quasistatic sensitivities; not the projected one Newton steps with); ∂f/∂θ is the pull-back of
the shell energy's gradient at unit θ (Π is linear in each stiffness parameter,
`ShellEnergy.evaluate`'s per-sample stiffness). The states are recomputed by `record`, which
steps like `TimeStepper.run` but keeps every state and refuses a halved step; its fixed time
steps are the steps of the one continuation loop (`solve_over`, a step's value its end time
[s]), as `TimeStepper.run`'s.

Prescribed boundary motions (a scene's `[dynamics.motion]` μ(t), or handles on their own paths,
`solve.handle_paths.PathStepper`): u = g(t) + J C with the boundary's part g(t) given, stepped
by the same scheme (`Motion.boundary`: g, ġ, g̈, none of which depends on θ). The step's
equation is then g = s Jᵀ M (J x + g' − x*_u) + f(x; θ) = 0 with x*_u = J x* + (the scheme's
combination of g, ġ, g̈): the boundary's part is a constant of the derivatives, so the
recursion above is unchanged; what changes is that each step's K and ∂f/∂θ are taken with
the boundary where it stands at that step's end (`stepper._at(t)`), and `record` keeps the
boundary's states and polishes each step with its inertia target. Not covered:
stiffness-proportional damping (K₀ depends on C and θ), contact, wind, a custom per-sample
stiffness; these raise ValueError (`record` too: its polish has no barrier or drag).

A start that depends on θ (`rest_start`: C₀ the static equilibrium at t = 0, V₀ = 0): its
derivative (dC₀/dθ, dV₀/dθ) enters the tangent as its first state's and the adjoint as
dJ/dθ += λ_Cᵀ dC₀/dθ + λ_Vᵀ dV₀/dθ with λ at t = 0 (implicit Euler; Newmark's A₀ would
depend on C₀ too: refused). For C₀ = argmin Π(·; θ) at the boundary of t = 0,
dC₀/dθ = −K₀⁻¹ ∂f/∂θ(C₀) (K₀ the exact static Hessian): the implicit-function derivative.

Handle paths with unknowns q (`HandlePath.basis`, p columns): the boundary's part then
depends on q, g_k = U d(t_k; q) (U = `PathStepper.units`: g per unit handle displacement), and
the step's equation Jᵀ [s M (J x + g' − J x* − g*) + ∂Π/∂u(J x + g')] = 0, with g* the scheme's
target of the boundary's (g, ġ, g̈) (each linear in q, stepped by the same maps), gives per
step and column K dx = s M dx* − Jᵀ H U δd' + s Jᵀ M U δd* (H the step potential's exact
per-point blocks, inertia included; δd = dd/dq); the rest start's dC₀/dq = −K₀⁻¹ Jᵀ H₀ U δd(0).
`tangent` and `rest_start` then carry 1 + p columns (θ first); the observed positions move
by J dC/dq + U δd(t) besides (`inverse.material.trajectory_fit`). The adjoint stays θ's.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf.minimise.continuation import Stages, Step, solve_over
from taichi_ndf.minimise.minimisers import NewtonMinimiser, Phase, run_phases
from taichi_ndf.minimise.sensitivity import exact_blocks, exact_hessian, sensitivity
from taichi_ndf.objective.inertia import InertiaTerm
from taichi_ndf.problem.dynamics import StepMap, combine
from taichi_ndf.problem.loads import Loads
from taichi_ndf.shell.energy import ShellEnergy
from taichi_ndf.shell.hessian import flat_blocks
from taichi_ndf.solve.dynamics import DynamicsError, Motion, TimeStepper

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Start:
    """A run's start at a parameter θ: C₀ (n, 3) [m], V₀ (n, 3) [m/s] (None: 0) and
    derivative (dC₀/dθ, dV₀/dθ) (None: the start does not depend on θ)."""

    displacement: torch.Tensor
    velocity: torch.Tensor | None = None
    derivative: tuple[torch.Tensor, torch.Tensor] | None = None


def _check_steps(stepper: TimeStepper) -> None:
    """Refuse what the steps' potential here (`_step_potential`, `_step_hessian`) lacks."""
    if stepper.config.stiffness_damping:
        raise ValueError("dynamics adjoint: stiffness-proportional damping is not supported")
    if stepper.contact is not None:
        raise ValueError("dynamics adjoint: contact ([[obstacles]] or [self_contact]) is not "
                         "supported")
    if stepper.config.wind is not None:
        raise ValueError("dynamics adjoint: wind is not supported")


def _check(stepper: TimeStepper, parameter: str) -> None:
    _check_steps(stepper)
    if getattr(stepper.objective.shell, "stiffness", None) is not None:
        raise ValueError("dynamics adjoint: a per-sample stiffness is not supported")
    names = stepper.model.material.stiffness_names
    if parameter not in names:
        raise ValueError(f"dynamics adjoint: unknown stiffness parameter {parameter!r}; "
                         f"choose from {names}")


def record(stepper: TimeStepper, displacement: torch.Tensor | None = None,
           velocity: torch.Tensor | None = None, *, polish: int = 4) -> list[Motion]:
    """The states at t = 0, dt, …, steps × dt from C₀ and V₀ (None: rest, as `run`), each
    step one `TimeStepper.step` then at most `polish` plain Newton steps on its exact Hessian
    (`_polish`); DynamicsError where a step's Newton does not converge (the adjoint follows
    unhalved steps only)."""
    _check_steps(stepper)
    config = stepper.config
    first = stepper.start(displacement, velocity).state  # the run's own step 0 (a path's too)
    step = StepMap.of(config, config.dt)

    def solve(at: Step, start: Motion) -> Motion:  # one time step to at.value [s], polished
        end, solution = stepper.step(start, config.dt)
        if not solution.converged:
            raise DynamicsError(f"dynamics adjoint: step {at.index + 1} did not converge "
                                "(halved steps are not supported)")
        potential, linear = _step_potential(stepper, step, start, at.value)
        x = _polish(stepper, potential, linear, end.displacement, polish)
        velocity, acceleration = step.apply(x, start)
        return Motion(at.value, x, velocity, acceleration, end.boundary)

    def start(_at: Step, previous: Motion | None, _coarser) -> Motion:
        return first if previous is None else previous

    times = [k * config.dt for k in range(1, config.steps + 1)]
    (steps,) = solve_over(Stages(solve, start=start), times)
    return [first, *steps]


def _step_potential(stepper: TimeStepper, step: StepMap, start: Motion, time: float):
    """The incremental potential of the step from `start` that ends at `time` [s], and the
    linearisation with the boundary there (the inertia's target with the boundary's part as
    `TimeStepper.step` makes it)."""
    linear = stepper._at(time)
    target = combine(step.target, (start.displacement, start.velocity, start.acceleration))
    b = start.boundary
    boundary = None if b is None else combine(step.target, (b.displacement, b.velocity,
                                                            b.acceleration))
    inertia = InertiaTerm(stepper.density, step.scale, stepper._jets(linear, target, boundary))
    return (stepper.objective.with_terms(inertia).potential(stepper.config.load_factor(time)),
            linear)


def _polish(stepper: TimeStepper, potential, linear, x: torch.Tensor, limit: int
            ) -> torch.Tensor:
    """x moved by plain Newton steps x − K⁻¹ g of the potential on its linearisation while
    ‖g‖ falls (at most `limit`). Newton's line search on Π stops at Π's rounding floor, where
    x is known to about √ε only; the adjoint's g(x) = 0 and central differences of whole runs
    need x to the rounding of g."""

    def residual(x):
        return linear.gradient(potential(stepper.samples, linear.displacement(x), True)
                               .grad_u_jets)

    g = residual(x)
    for _ in range(limit):
        matrix = exact_hessian(linear, potential, x, fd_step=stepper.newton.fd_step)
        solved = linear.solve(matrix, g, 0.0)
        if solved is None:
            break
        trial = x + solved[0]
        g_trial = residual(trial)
        if not float(g_trial.norm()) < float(g.norm()):
            break
        x, g = trial, g_trial
    return x


def rest_start(stepper: TimeStepper, displacement: torch.Tensor, parameter: str, *,
               polish: int = 4) -> Start:
    """The start at rest: C₀ the static equilibrium of Π at t = 0 (the boundary there, the
    loads at λ(0)) that Newton reaches from `displacement` (n, 3) (the local minimum whose
    basin holds it, e.g. a fit to a video's first frame), polished as `record`'s steps;
    V₀ = 0; derivative (dC₀/dθ = −K₀⁻¹ ∂f/∂θ(C₀), 0) for the stiffness `parameter`, with
    a path's unknowns (n, 3, 1 + p) each: θ's column, then dC₀/dq (module docstring).
    DynamicsError where Newton does not converge; a warning where K₀ is not positive definite
    (a saddle, not a rest state)."""
    _check(stepper, parameter)
    load_factor = stepper.config.load_factor(0.0)
    linear = stepper._at(0.0)
    potential = stepper.objective.potential(load_factor)
    (solution,) = run_phases([Phase(
        NewtonMinimiser(stepper.newton, load_factor=load_factor, report=False),
        lambda: (linear, potential), lambda: displacement)])
    if not solution.converged:
        raise DynamicsError("rest start: the static equilibrium at t = 0 did not converge")
    x = _polish(stepper, potential, linear, solution.parameters, polish)
    matrix, blocks = exact_blocks(linear, potential, x, fd_step=stepper.newton.fd_step)
    rhs = force_derivative(stepper, parameter, x, 0.0)[..., None]
    path = getattr(stepper, "path", None)
    if path is not None and path.unknowns:
        moved = _pulled(stepper, linear, blocks) @ _tensor(path.derivative_at(0.0), x)
        rhs = torch.cat([rhs, moved], dim=-1)
    solved = sensitivity(matrix, rhs, stepper.linear.fixed)
    if not solved.definite:
        log.warning("rest start: the equilibrium's Hessian is not positive definite (a saddle)")
    derivative = solved.derivative if rhs.shape[-1] > 1 else solved.derivative[..., 0]
    return Start(x, torch.zeros_like(x), (derivative, torch.zeros_like(derivative)))


def _padded(columns: torch.Tensor, m: int) -> torch.Tensor:
    """(n, 3) or (n, 3, k) as (n, 3, m): the missing columns 0."""
    columns = columns if columns.dim() == 3 else columns[..., None]
    missing = columns.new_zeros(*columns.shape[:2], m - columns.shape[-1])
    return torch.cat([columns, missing], dim=-1)


def _tensor(array, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(array, dtype=like.dtype)


def _pulled(stepper: TimeStepper, linear, blocks: torch.Tensor | None) -> torch.Tensor:
    """Jᵀ H U (n, 3, 3H): the force per unit displacement of each handle coordinate
    (`PathStepper.units`) of the potential whose exact per-point blocks (N, 18, 18) at the
    linearisation's samples are `blocks`; None: the unit mass's, Jᵀ M U."""
    units = stepper.units(linear.samples.xi, linear.samples.r_jets.dtype)
    n, columns = units.shape[0], units.shape[-1]
    if blocks is None:
        term = InertiaTerm(stepper.density, 1.0, torch.zeros_like(units[..., 0]))
        pushed = [term.evaluate(linear.samples, units[..., k])[1] for k in range(columns)]
    else:
        hv = torch.einsum("nij,njk->nik", blocks, units.reshape(n, 18, columns))
        pushed = list(hv.reshape(n, 6, 3, columns).unbind(-1))
    return torch.stack([linear.gradient(v) for v in pushed], dim=-1)


def _mass_times(stepper: TimeStepper, coefficients: torch.Tensor, mass=None) -> torch.Tensor:
    """M P (n, 3[, m]) for coefficients P (n, 3[, m]) (held unknowns 0; M does not depend on
    the boundary); mass: M assembled (`_mass_matrix`), for many columns at once."""
    if coefficients.dim() == 3:
        if mass is None:
            return torch.stack([_mass_times(stepper, c) for c in coefficients.unbind(-1)], -1)
        columns = coefficients.reshape(mass.shape[0], -1).numpy()
        out = torch.from_numpy(np.asarray(mass @ columns)).reshape(coefficients.shape)
        if stepper.linear.fixed is not None:
            out.reshape(mass.shape[0], -1)[torch.from_numpy(stepper.linear.fixed)] = 0.0
        return out
    linear = stepper.linear
    term = InertiaTerm(stepper.density, 1.0, stepper.offset_of(linear))
    _, gradient = term.evaluate(stepper.samples, linear.displacement(coefficients))
    return linear.gradient(gradient)


def force_derivative(stepper: TimeStepper, parameter: str, displacement: torch.Tensor,
                     time: float = 0.0) -> torch.Tensor:
    """∂f/∂θ (n, 3) [N/unit of θ] at coefficients C and time t [s] (the boundary there): the
    gradient of Π's part that θ multiplies (the strain energy at unit θ, every other stiffness
    0, no loads)."""
    material = stepper.model.material
    samples = stepper.samples
    dtype = samples.r_jets.dtype
    unit = torch.zeros(len(samples), len(material.stiffness_names), dtype=dtype)
    unit[:, material.stiffness_names.index(parameter)] = 1.0
    unloaded = samples.with_point_force(torch.zeros_like(samples.point_force))
    linear = stepper._at(time)
    result = ShellEnergy(material, Loads()).evaluate(
        unloaded, linear.displacement(displacement), stiffness=unit)
    return linear.gradient(result.grad_u_jets)


def _step_hessian(stepper: TimeStepper, step: StepMap, end: Motion, *, path: bool = False):
    """K: the exact Hessian (sparse) of the step's incremental potential at its end (the
    boundary where it stands then); path: (K, Jᵀ H U (n, 3, 3H), `_pulled`)."""
    linear = stepper._at(end.time)
    u = linear.displacement(end.displacement)
    inertia = InertiaTerm(stepper.density, step.scale, u)  # K does not depend on x*
    potential = stepper.objective.with_terms(inertia).potential(
        stepper.config.load_factor(end.time))
    if not path:
        return exact_hessian(linear, potential, end.displacement,
                             fd_step=stepper.newton.fd_step)
    matrix, blocks = exact_blocks(linear, potential, end.displacement,
                                  fd_step=stepper.newton.fd_step)
    return matrix, _pulled(stepper, linear, blocks)


def _check_initial(stepper: TimeStepper, initial) -> None:
    if initial is not None and stepper.config.integrator == "newmark":
        raise ValueError("dynamics adjoint: a start that depends on the parameter is supported "
                         "with implicit Euler only (Newmark's A₀ depends on C₀)")


def gradient(stepper: TimeStepper, states: list[Motion], parameter: str,
             weights: dict[int, torch.Tensor],
             initial: tuple[torch.Tensor, torch.Tensor] | None = None) -> float:
    """dJ/dθ of a trajectory quantity J(C_0, …, C_N) over the states of `record`, weights
    {k: ∂J/∂C_k (n, 3)} (module docstring); θ a stiffness name of the model's material;
    initial: the start's (dC₀/dθ, dV₀/dθ) (`Start.derivative`; None: constant)."""
    _check(stepper, parameter)
    _check_initial(stepper, initial)
    config = stepper.config
    zeros = torch.zeros_like(states[0].displacement)
    step = StepMap.of(config, config.dt)
    lam_c = weights.get(len(states) - 1, zeros).clone()
    lam_v, lam_a = zeros.clone(), zeros.clone()
    total = 0.0
    for k in range(len(states) - 1, 0, -1):
        rhs = lam_c + step.velocity[0] * lam_v + step.acceleration[0] * lam_a
        matrix = _step_hessian(stepper, step, states[k])
        mu = -sensitivity(matrix, rhs[..., None], stepper.linear.fixed).derivative[..., 0]
        total -= float((mu * force_derivative(stepper, parameter, states[k].displacement,
                                                states[k].time)).sum())
        coupling = step.scale * _mass_times(stepper, mu)
        lam_c, lam_v, lam_a = (
            weights.get(k - 1, zeros) + step.velocity[1] * lam_v
            + step.acceleration[1] * lam_a + step.target[0] * coupling,
            step.velocity[2] * lam_v + step.acceleration[2] * lam_a + step.target[1] * coupling,
            step.velocity[3] * lam_v + step.acceleration[3] * lam_a + step.target[2] * coupling)
    if config.integrator == "newmark":
        total += float((lam_a * _initial_acceleration_derivative(
            stepper, parameter, states[0].displacement)).sum())
    if initial is not None:
        total += float((lam_c * initial[0]).sum() + (lam_v * initial[1]).sum())
    return total


def _mass_matrix(stepper: TimeStepper):
    """M (3n × 3n, sparse): the assembled mass matrix (the inertia's blocks at unit scale)."""
    linear = stepper.linear
    u = linear.displacement(torch.zeros_like(stepper.field.coefficients))
    term = InertiaTerm(stepper.density, 1.0, u)
    return linear.hessian(flat_blocks(term.hessian_blocks(stepper.samples, u)))


def _initial_acceleration_derivative(stepper: TimeStepper, parameter: str,
                                     displacement: torch.Tensor) -> torch.Tensor:
    """dA₀/dθ = −M⁻¹ ∂f/∂θ(C₀) (n, 3)."""
    force = force_derivative(stepper, parameter, displacement, 0.0)
    solved = stepper.linear.solve(_mass_matrix(stepper), force, 0.0)
    if solved is None:
        raise DynamicsError("the mass matrix could not be factorised")
    return solved[0]


def tangent(stepper: TimeStepper, states: list[Motion], parameter: str,
            initial: tuple[torch.Tensor, torch.Tensor] | None = None) -> list[torch.Tensor]:
    """dC_k/dθ (n, 3) for every state of `record` (k = 0 … N), forwards: per step
    K dx = s M dx* − ∂f/∂θ(x), dV' and dA' by the scheme's maps (the tangent of the steps: all
    the sensitivities a Gauss–Newton fit needs for one parameter; `gradient` is its adjoint);
    initial: the start's (dC₀/dθ, dV₀/dθ) (None: constant). A path with p unknowns
    (`HandlePath.basis`): (n, 3, 1 + p) per state, θ's column first (module docstring);
    initial's then (n, 3, 1 + p) each."""
    _check(stepper, parameter)
    _check_initial(stepper, initial)
    config = stepper.config
    step = StepMap.of(config, config.dt)
    path = getattr(stepper, "path", None)
    p = path.unknowns if path is not None else 0
    zeros = torch.zeros(*states[0].displacement.shape, 1 + p, dtype=torch.float64)
    d = (zeros, zeros, zeros.clone())
    if config.integrator == "newmark":
        d[2][..., 0] = _initial_acceleration_derivative(stepper, parameter,
                                                        states[0].displacement)
    if initial is not None:  # a start without q's columns does not move with q
        d = tuple(_padded(v, 1 + p) for v in initial) + (zeros,)
    if p:  # the boundary's (δd, δḋ, δd̈) (3H, p) by the scheme: the path's start, slope, 0
        b = (_tensor(path.derivative_at(0.0), zeros),
             _tensor(path.initial_velocity_derivative(), zeros),
             torch.zeros(3 * path.handles, p, dtype=zeros.dtype))
        mass_units = _pulled(stepper, stepper.linear, None)
    mass = _mass_matrix(stepper) if p else None  # many columns: one assembled M
    out = [d[0]]
    for end in states[1:]:
        moved = combine(step.target, d)
        rhs = -step.scale * _mass_times(stepper, moved, mass)
        rhs[..., 0] += force_derivative(stepper, parameter, end.displacement, end.time)
        if p:
            matrix, pulled = _step_hessian(stepper, step, end, path=True)
            now = _tensor(path.derivative_at(end.time), zeros)
            rhs[..., 1:] += pulled @ now - step.scale * (mass_units @ combine(step.target, b))
            y = (now, *b)
            b = (now, combine(step.velocity, y), combine(step.acceleration, y))
        else:
            matrix = _step_hessian(stepper, step, end)
        dx = sensitivity(matrix, rhs, stepper.linear.fixed).derivative
        y = (dx, *d)
        d = (dx, combine(step.velocity, y),
             combine(step.acceleration, y))
        out.append(dx)
    return out if p else [o[..., 0] for o in out]

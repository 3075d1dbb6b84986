"""Quasistatic solver: minimise the total potential energy Π over the field's weights.

Each iteration draws fresh stratified jittered samples, evaluates the field's jets, applies the
boundary conditions, evaluates Π and its gradient (Taichi autodiff), chains it back into the
weights (the field's hand-written adjoint) and takes an Adam step. Loads may be applied in
increments (continuation): each load factor is solved in turn, warm-started from the previous.

Optionally, last-layer Newton phases (`taichi_ndf.minimise.last_layer`) solve the output layer
exactly on a fixed sample set: at the start of each load step, every `newton_every` Adam
iterations and at the end of the step. Adam improves the features (hidden layers), Newton the
combination of them — first-order steps alone crawl on stiff shells.

At every monitor record a Π that climbed an order of magnitude above anything recorded at
the load factor sends the field and Adam's moments back to the best state and halves the
learning rate (`taichi_ndf.minimise.backoff`).

With `pseudo_time` the field takes the load factor t as an extra input and is trained over all
t at once (`taichi_ndf.problem.pseudo_time`): every area sample draws its own t in
[pseudo_time_start, λ] for the current load step λ, so several load steps act as a curriculum
that widens the range of t. The monitor reports Π at t = λ.

Roles: the operator (`problem.operator`) gives the jets and chains gradients back; the
objective gives Π and dΠ/du_jets; the minimisers (`minimise.minimisers`: one interface,
`Minimiser`) change the state (`minimise.state`); this module draws the sample sets and
solves a load step as a list of phases (`Solver.phases`), which the continuation loop calls
for each load step. Checkpoints and the divergence guard are callbacks (`minimise.callbacks`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from taichi_ndf import progress
from taichi_ndf.contact.hook import ContactHook
from taichi_ndf.field import NeuralField
from taichi_ndf.minimise.backoff import MAX_BACKOFFS, back_to_best, keep_if_best, should_back_off
from taichi_ndf.minimise.callbacks import DivergenceError, call
from taichi_ndf.minimise.continuation import Hook, Stages, Step, resume_point, solve_over
from taichi_ndf.minimise.last_layer import last_layer_config, output_linearisation
from taichi_ndf.minimise.linearisation import DenseLinearisation
from taichi_ndf.minimise.minimisers import (
    AdamMinimiser,
    Hooks,
    LBFGSMinimiser,
    MinimiseResult,
    OutputLayerNewton,
    Phase,
    adam_iteration,
    run_phases,
    value_and_gradient,
)
from taichi_ndf.minimise.state import MonitorRecord, State
from taichi_ndf.objective import Objective
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.pseudo_time import TIME_RANGE, conditioning, samples_over_time
from taichi_ndf.problem.sampling import SurfaceSamples, sample_surface
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.shell.energy import EnergyResult

__all__ = ["DivergenceError", "MonitorRecord", "SolveResult", "Solver", "SolverConfig"]

log = logging.getLogger(__name__)

# Where the last-layer Newton phases take their linearisation from: (samples, load factor) ->
# the output layer's `DenseLinearisation` there.
Linearise = Callable[[SurfaceSamples, float], DenseLinearisation]

# Seed offsets of the fixed sample sets, so that they differ from the training samples' stream.
MONITOR_SEED_OFFSET = 7919
NEWTON_SEED_OFFSET = 104729


@dataclass
class SolveResult:
    energy: float
    iterations: int
    wall_time: float
    history: list[MonitorRecord]
    probes: dict[str, list[float]]
    newton_steps: int = 0
    backoffs: int = 0  # learning-rate backoffs (`taichi_ndf.minimise.backoff`)


class Solver:
    """Minimises an objective (default: Π of the model) over a field's weights: sample sets,
    Adam / Newton / L-BFGS phases and the continuation over load steps."""

    def __init__(self, model: ShellModel, field: NeuralField, config: SolverConfig, *,
                 objective: Objective | None = None, state: State | None = None,
                 linearise: Linearise | None = None):
        """objective: what is minimised (default: the model's potential energy,
        `Objective.of_model`), e.g. with the work of an end moment added. state: where to
        start (default: `State.initial`; a restored one resumes). linearise(samples, load
        factor): the output layer's linearisation the last-layer Newton phases minimise over
        (the discretisation's, `SirenDiscretisation.linearisation`; default:
        `output_linearisation` of this solver's operator)."""
        self.operator = DisplacementOperator(field, model.boundary)
        self._linearise = linearise or (
            lambda samples, load_factor: output_linearisation(self.operator, samples,
                                                              load_factor))
        if config.newton_iterations and self.operator.frame:
            raise ValueError("the last-layer Newton phases (newton_iterations) do not support "
                             "a boundary frame; use Adam or the spline field")
        if config.pseudo_time:
            self.operator.refuse_free_pin("pseudo_time", ": the pin's value would differ per "
                                          "sample time")
        if config.pseudo_time and field.config.conditioning != (TIME_RANGE,):
            raise ValueError(f"a pseudo-time solve needs a field with the one conditioning "
                             f"input range {TIME_RANGE}, got {field.config.conditioning}")
        self.model = model
        self.objective = objective or Objective.of_model(model)
        self.field = field
        self.config = config
        self.state = state or State.initial(field, config.adam, config.seed)
        self._monitor = None
        self._newton_samples = None
        self._callbacks = ()
        self._t0 = time.perf_counter()  # the start of `run` (monitor records' wall time)
        self.contact = None  # with obstacles: the `ContactHook` every phase asks
        self.rejected_steps = 0  # Adam steps the contact filter rejected
        if model.contact is not None:
            if config.pseudo_time:
                raise ValueError("contact is not available with a pseudo-time field")
            if model.contact.has_friction:
                raise ValueError("obstacle friction is solved on the spline + projected-Newton "
                                 "path only ([field] type = \"spline\" or --field spline)")
            self.contact = ContactHook.of_model(model, field.parameters[0].dtype,
                                                both_ends=True)
            self.objective = self.objective.with_terms(self.contact.term)

    def energy_and_gradient(self, samples, load_factor: float, *, grad: bool = True,
                            times: torch.Tensor | None = None) -> EnergyResult:
        """Π [J] of the current field on given samples (the objective at the displacement
        operator's jets); fills the field's gradients if `grad`.

        times: the pseudo-time of each sample (N,) of a pseudo-time solve; default: t =
            load_factor at every sample (Π of the field's state at that load factor)."""
        if self.contact is not None:
            samples = self.contact.points.augment(samples)
        xi = samples.xi
        cond = None
        if self.config.pseudo_time:
            t = times if times is not None else torch.full_like(xi[:, 0], float(load_factor))
            cond = conditioning(t, len(xi), dtype=xi.dtype, device=xi.device)
        else:
            if times is not None:
                raise ValueError("per-sample times need a pseudo-time solve")
            t = load_factor
        u = self.operator.jets(xi, t=t, conditioning=cond)
        result = self.objective.evaluate(samples, u, t, grad=grad)
        if grad:
            self.operator.backward(result.grad_u_jets)
        return result

    def evaluator(self, samples, load_factor: float, times: torch.Tensor | None = None):
        """`evaluate(grad) -> Π` on fixed samples, the form the minimisers take."""
        def evaluate(grad: bool) -> float:
            return self.energy_and_gradient(samples, load_factor, grad=grad, times=times).total
        return evaluate

    def _samples(self, n: int, generator: torch.Generator):
        """n area samples and the point-load samples, with unscaled point forces (the
        objective applies the load factor)."""
        rt_dtype = self.field.parameters[0].dtype
        s = sample_surface(self.model.surface, n, self.model.loads, generator)
        return s.to(dtype=rt_dtype, device=self.field.parameters[0].device)

    def training_samples(self, n: int, load_factor: float, generator: torch.Generator):
        """Samples of one iteration (or of the L-BFGS polish) and their pseudo-times: in a
        pseudo-time solve each draws its t in [pseudo_time_start, load_factor], else None."""
        samples = self._samples(n, generator)
        if not self.config.pseudo_time:
            return samples, None
        return samples_over_time(samples, self.config.pseudo_time_start, load_factor,
                                 generator)

    def monitor_samples(self):
        """Fixed samples on which Π is monitored (the same at every load factor)."""
        if self._monitor is None:
            gen = torch.Generator().manual_seed(self.config.seed + MONITOR_SEED_OFFSET)
            self._monitor = self._samples(self.config.monitor_samples, gen)
        return self._monitor

    def newton_samples(self):
        """Fixed samples of the last-layer Newton phases (the same at every load factor)."""
        if self._newton_samples is None:
            gen = torch.Generator().manual_seed(self.config.seed + NEWTON_SEED_OFFSET)
            self._newton_samples = self._samples(self.config.newton_samples, gen)
        return self._newton_samples

    def newton(self, load_factor: float) -> None:
        """A last-layer Newton phase on the fixed Newton samples at this load factor."""
        run_phases([self._newton_phase(load_factor)])

    def _newton_phase(self, load_factor: float) -> Phase:
        """`OutputLayerNewton` on the fixed Newton samples (and contact's check points)."""
        def objective():
            samples = self.newton_samples()
            potential = self.objective.potential(load_factor)
            if self.contact is not None:
                samples = self.contact.points.augment(samples)
                # Π alone, without its terms' own Hessian blocks: with contact the phases'
                # blocks are central differences of the whole gradient
                potential = value_and_gradient(potential)
            return self._linearise(samples, load_factor), potential

        def after(result: MinimiseResult) -> None:
            self.state.newton_steps += result.steps
            self._refresh_contact(load_factor)
        newton = OutputLayerNewton(load_factor, last_layer_config(
            max_iterations=self.config.newton_iterations), contact=self.contact)
        return Phase(newton, objective, lambda: self.field, after=after)

    def probe_displacements(self, load_factor: float) -> dict[str, list[float]]:
        if not self.model.probes:
            return {}
        dtype = self.field.parameters[0].dtype
        xi = torch.tensor([p.xi for p in self.model.probes], dtype=dtype)
        cond = None
        if self.config.pseudo_time:
            cond = conditioning(load_factor, len(xi), dtype=dtype)
        u = self.operator.displacement(xi, t=load_factor, conditioning=cond)
        return {p.name: [float(v) for v in u[k]] for k, p in enumerate(self.model.probes)}

    # -- continuation over the load steps (`taichi_ndf.minimise.continuation`) ---------------------
    def run(self, *, callbacks=(), on_load_step=None) -> SolveResult:
        """Minimise Π for every load step from the state's; `callbacks`
        (`taichi_ndf.minimise.callbacks`: progress, checkpoints, the divergence guard) see every
        iteration, and `on_load_step(load_factor)` is called after each step."""
        cfg, state = self.config, self.state
        _, start_step = resume_point(state, len(cfg.load_steps))  # a finished run goes on
        self._t0 = time.perf_counter()
        self._callbacks = callbacks = tuple(callbacks)
        if self.contact is not None and state.iteration == 0 and state.newton_steps == 0:
            lam = cfg.load_steps[start_step]
            self.contact.feasible_start(self._displacement(lam), lam, self._zero_output_layer)
        if on_load_step is not None:
            callbacks = (*callbacks, Hook("on_load_step", on_load_step))
        solve_over(Stages(solve=self._solve_load_step, before_end=self._finished),
                   cfg.load_steps, first_step=start_step, callbacks=callbacks, subject=self)
        return SolveResult(energy=state.history[-1].energy, iterations=state.iteration,
                           wall_time=time.perf_counter() - self._t0, history=state.history,
                           probes=self.probe_displacements(cfg.load_steps[-1]),
                           newton_steps=state.newton_steps, backoffs=state.backoffs)

    def _solve_load_step(self, load_step: Step, _start=None) -> None:
        """One load step's phases from where the state stands, then a monitor record."""
        cfg, state = self.config, self.state
        step, lam = load_step.index, load_step.load_factor
        state.load_step = step
        self._refresh_contact(lam)
        run_phases(self.phases(load_step, max(state.iteration - step * cfg.iterations, 0)))
        newton = cfg.newton_iterations > 0
        recorded = state.history and state.history[-1].iteration == state.iteration
        if cfg.lbfgs_iterations or newton or not recorded:
            self._record(lam, state.optimiser.gradient_norm(), self._t0)
        log.info("load factor %.4g: Π = %.8g J after %d iterations", lam,
                 state.history[-1].energy, state.iteration)

    def phases(self, load_step: Step, done_in_step: int = 0) -> list[Phase]:
        """The minimisers of a load step with `done_in_step` Adam iterations done: last-layer
        Newton (with `newton_iterations`), Adam (with Newton every `newton_every`), Newton,
        the L-BFGS polish."""
        cfg, lam = self.config, load_step.load_factor
        newton = cfg.newton_iterations > 0
        phases = [self._newton_phase(lam)] if newton and done_in_step == 0 else []
        phases.append(self._adam_phase(load_step, done_in_step))
        if newton and cfg.iterations > 0:
            phases.append(self._newton_phase(lam))
        if cfg.lbfgs_iterations:
            phases.append(self._lbfgs_phase(lam))
        return phases

    def _adam_phase(self, load_step: Step, done_in_step: int) -> Phase:
        """Adam's iterations (`AdamMinimiser`, with the contact policy), each followed by a
        monitor record every `monitor_every`, on_iteration, progress, Newton phases."""
        cfg, state = self.config, self.state
        step, lam = load_step.index, load_step.load_factor
        newton, shown = cfg.newton_iterations > 0, {}

        def objective():
            if done_in_step == 0 and cfg.iterations > 0:  # the step's start: the first best
                keep_if_best(state, self.field, lam, self._monitor_energy(lam))
            return lambda: self.training_samples(cfg.samples, lam, state.generator)

        def iterated(gnorm: float) -> None:
            state.iteration += 1
            record = None
            if state.iteration % cfg.monitor_every == 0:
                record = self._record(lam, gnorm, self._t0)
                shown.update({"Π": record.energy, "‖∇Π‖": record.grad_norm})
            call(self._callbacks, "on_iteration", self, record)
            in_step = state.iteration - step * cfg.iterations
            progress.report(in_step, **shown)
            if newton and cfg.newton_every and in_step % cfg.newton_every == 0 \
                    and in_step < cfg.iterations:
                self.newton(lam)
        adam = AdamMinimiser(state.optimiser, cfg.iterations, first=done_in_step,
                             step=lambda drawn, check: self._adam_step(*drawn, lam, check))
        return Phase(adam, objective, hooks=Hooks(on_step=self._check_step,
                                                  on_iteration=iterated),
                     stage=(f"Adam, load {lam:.4g}", cfg.iterations))

    def _finished(self) -> None:
        self.state.load_step = len(self.config.load_steps)

    # -- contact: penetration filter and dense check ----------------------------------------------
    def _adam_step(self, samples, times, lam: float, guard) -> float:
        """One Adam step (`adam_iteration`, `guard(Π, ‖∇Π‖)` before it); with contact, the
        hook's policy (`ContactHook.accept`: on the step's area samples and the dense grid,
        halved until allowed, else undone and counted in `rejected_steps`). Returns ‖∇Π‖
        before the step."""
        evaluate = self.evaluator(samples, lam, times)
        if self.contact is None:
            return adam_iteration(self.state.optimiser, evaluate, check=guard)[1]
        contact, field = self.contact, self.field

        def positions() -> torch.Tensor:
            return contact.points.filter_positions(self._displacement(lam), samples)
        before = field.get_flat().clone()
        check = contact.check(positions(), lam)
        _, gnorm = adam_iteration(self.state.optimiser, evaluate, check=guard)
        if not contact.accept(check, before, field.get_flat().clone(), field.set_flat,
                              positions):
            self.rejected_steps += 1
        return gnorm

    def _displacement(self, lam: float):
        """u(ξ) (N, 3) of the current field at the load factor."""
        return lambda xi: self.operator.displacement(xi, t=lam)

    def _zero_output_layer(self) -> None:
        """The field's output layer set to zero (u = the prescribed motions only): the
        feasible start where the initial field touches an obstacle."""
        weight, bias = self.field.output_layer()
        with torch.no_grad():
            weight.zero_()
            bias.zero_()

    def _refresh_contact(self, lam: float) -> None:
        """Dense check (with contact): add the grid points that came within the activation
        distance."""
        if self.contact is not None:
            self.contact.refresh(self._displacement(lam), lam)

    def _check_step(self, energy: float, grad_norm: float) -> None:
        call(self._callbacks, "on_step", self, energy, grad_norm)

    def _record(self, lam: float, gnorm: float, t0: float) -> MonitorRecord:
        energy = self._monitor_energy(lam)
        if should_back_off(self.state, lam, energy):
            energy = self._back_off(lam, energy)
        call(self._callbacks, "on_record", self, energy, gnorm, lam)
        record = MonitorRecord(
            iteration=self.state.iteration, load_factor=lam, energy=energy, grad_norm=gnorm,
            learning_rate=self.state.optimiser.learning_rate,
            probes=self.probe_displacements(lam), wall_time=time.perf_counter() - t0)
        self.state.history.append(record)
        keep_if_best(self.state, self.field, lam, energy)
        return record

    def _monitor_energy(self, lam: float) -> float:
        return self.energy_and_gradient(self.monitor_samples(), lam, grad=False).total

    # -- learning-rate backoff (`taichi_ndf.minimise.backoff`) -------------------------------------
    def _back_off(self, lam: float, energy: float) -> float:
        """The field and Adam's moments back to the best state at this load factor, the
        learning rate halved; returns Π of the restored field on the monitor samples."""
        state, best = self.state, self.state.best
        back_to_best(state, self.field)
        self._refresh_contact(lam)
        restored = self._monitor_energy(lam)
        log.warning("Adam's Π climbed to %.6g J at iteration %d (best %.6g J at iteration %d, "
                    "load factor %g): back to that state, learning rate halved to %.3g "
                    "(backoff %d of at most %d)", energy, state.iteration, best.energy,
                    best.iteration, lam, state.optimiser.learning_rate, state.backoffs,
                    MAX_BACKOFFS)
        return restored

    def _lbfgs_phase(self, lam: float) -> Phase:
        """L-BFGS polish on a fixed, large sample set (of (ξ, t) in a pseudo-time solve)."""
        def objective():
            if self.config.pseudo_time:
                gen = torch.Generator().manual_seed(self.config.seed + MONITOR_SEED_OFFSET)
                samples, times = self.training_samples(self.config.monitor_samples, lam, gen)
            else:
                samples, times = self.monitor_samples(), None
            return self.evaluator(samples, lam, times)

        def after(result: MinimiseResult) -> None:
            call(self._callbacks, "on_polish", self, result.energy_before, result.energy)
            log.info("L-BFGS polish: Π %.8g -> %.8g J", result.energy_before, result.energy)
        return Phase(LBFGSMinimiser(self.config.lbfgs_iterations), objective,
                     lambda: self.field, after=after)

"""Quasistatic solver: minimise the total potential energy Π over the field's weights.

Each iteration draws fresh stratified jittered samples, evaluates the field's jets, applies the
boundary conditions, evaluates Π and its gradient (Taichi autodiff), chains it back into the
weights (the field's hand-written adjoint) and takes an Adam step. Loads may be applied in
increments (continuation): each load factor is solved in turn, warm-started from the previous.

Optionally, last-layer Newton phases (`taichi_ndf.newton`) solve the output layer exactly on a
fixed sample set: at the start of each load step, every `newton_every` Adam iterations and at
the end of the step. Adam improves the features (hidden layers), Newton the combination of
them — first-order steps alone crawl on stiff shells.

With `pseudo_time` the field takes the load factor t as an extra input and is trained over all
t at once (`taichi_ndf.pseudo_time`): every area sample draws its own t in
[pseudo_time_start, λ] for the current load step λ, so several load steps act as a curriculum
that widens the range of t. The monitor reports Π at t = λ.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from taichi_ndf.checkpoint import load_checkpoint, save_checkpoint
from taichi_ndf.field import NeuralField
from taichi_ndf.model import ShellModel
from taichi_ndf.newton import NewtonConfig, solve_last_layer
from taichi_ndf.objective import Objective
from taichi_ndf.operator import DisplacementOperator
from taichi_ndf.optim import Adam
from taichi_ndf.pseudo_time import TIME_RANGE, conditioning, samples_over_time
from taichi_ndf.sampling import sample_surface
from taichi_ndf.shell.energy import EnergyResult
from taichi_ndf.training import SolverConfig

__all__ = ["DivergenceError", "MonitorRecord", "SolveResult", "Solver", "SolverConfig"]

log = logging.getLogger(__name__)


BLOW_UP_FACTOR = 1e3
# Seed offsets of the fixed sample sets, so that they differ from the training samples' stream.
MONITOR_SEED_OFFSET = 7919
NEWTON_SEED_OFFSET = 104729


class DivergenceError(RuntimeError):
    """Training produced a non-finite energy or gradient; the last good state was kept."""


@dataclass
class MonitorRecord:
    """One row of the convergence history."""

    iteration: int  # counted over all load steps
    load_factor: float
    energy: float  # Π on the monitor samples [J]
    grad_norm: float  # ‖∂Π/∂weights‖ of the last training step
    learning_rate: float
    probes: dict[str, list[float]]  # displacement [m] at each probe
    wall_time: float  # seconds since the start of this run


@dataclass
class SolveResult:
    energy: float
    iterations: int
    wall_time: float
    history: list[MonitorRecord]
    probes: dict[str, list[float]]
    newton_steps: int = 0


class Solver:
    """Minimises Π of a model over a field's weights; checkpoints, resumes, guards NaNs."""

    def __init__(self, model: ShellModel, field: NeuralField, config: SolverConfig, *,
                 objective: Objective | None = None,
                 checkpoint_path: str | Path | None = None, checkpoint_extra: dict | None = None):
        """objective: what is minimised (default: the model's potential energy,
        `Objective.of_model`); e.g. with the work of an end moment added."""
        self.operator = DisplacementOperator(field, model.boundary)
        if config.pseudo_time:
            self.operator.refuse_free_pin("pseudo_time", ": the pin's value would differ per "
                                          "sample time")
        if config.pseudo_time and field.config.conditioning != (TIME_RANGE,):
            raise ValueError(f"a pseudo-time solve needs a field with the one conditioning "
                             f"input range {TIME_RANGE}, got {field.config.conditioning}")
        self.model = model
        self.objective = objective or Objective.of_model(model)
        self.checkpoint_extra = checkpoint_extra or {}
        self.field = field
        self.config = config
        self.checkpoint_path = Path(checkpoint_path) if checkpoint_path else None
        self.optimiser = Adam(field.parameters, field.gradients, config=config.adam)
        self.generator = torch.Generator().manual_seed(config.seed)
        self.iteration = 0
        self.newton_steps = 0
        self.history: list[MonitorRecord] = []
        self._good_state = field.get_flat().clone()
        self._monitor = {}
        self._newton_samples = {}

    # -- energy -------------------------------------------------------------------------------
    def energy_and_gradient(self, samples, load_factor: float, *, grad: bool = True,
                            times: torch.Tensor | None = None) -> EnergyResult:
        """Π [J] of the current field on given samples (the objective at the displacement
        operator's jets); fills the field's gradients if `grad`.

        times: the pseudo-time of each sample (N,) of a pseudo-time solve; default: t =
            load_factor at every sample (Π of the field's state at that load factor). A number
            load factor means the samples' point forces are already scaled by it (`_samples`)."""
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

    def _samples(self, n: int, load_factor: float, generator: torch.Generator):
        """n area samples (and the point-load samples) with their point forces scaled by the
        load factor; unscaled in a pseudo-time solve, where the energy scales them per
        sample."""
        rt_dtype = self.field.parameters[0].dtype
        factor = 1.0 if self.config.pseudo_time else load_factor
        s = sample_surface(self.model.surface, n, self.model.loads.scaled(factor), generator)
        return s.to(dtype=rt_dtype, device=self.field.parameters[0].device)

    def training_samples(self, n: int, load_factor: float, generator: torch.Generator):
        """Samples of one iteration (or of the L-BFGS polish) and their pseudo-times: in a
        pseudo-time solve each draws its t in [pseudo_time_start, load_factor], else None."""
        samples = self._samples(n, load_factor, generator)
        if not self.config.pseudo_time:
            return samples, None
        return samples_over_time(samples, self.config.pseudo_time_start, load_factor,
                                 generator)

    def monitor_samples(self, load_factor: float):
        """Fixed samples on which Π is monitored (the same at every t of a pseudo-time
        solve, whose samples do not depend on the load factor)."""
        key = 1.0 if self.config.pseudo_time else load_factor
        if key not in self._monitor:
            gen = torch.Generator().manual_seed(self.config.seed + MONITOR_SEED_OFFSET)
            self._monitor[key] = self._samples(self.config.monitor_samples, key, gen)
        return self._monitor[key]

    def newton_samples(self, load_factor: float):
        if load_factor not in self._newton_samples:
            gen = torch.Generator().manual_seed(self.config.seed + NEWTON_SEED_OFFSET)
            self._newton_samples[load_factor] = self._samples(self.config.newton_samples,
                                                              load_factor, gen)
        return self._newton_samples[load_factor]

    def newton(self, load_factor: float) -> None:
        """A last-layer Newton phase on the fixed Newton samples of this load factor."""
        samples = self.newton_samples(load_factor)
        potential = self.objective.potential(load_factor)
        result = solve_last_layer(self.field, self.model.boundary, potential, samples,
                                  load_factor,
                                  NewtonConfig(iterations=self.config.newton_iterations))
        self.newton_steps += result.steps

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

    # -- checkpoints ----------------------------------------------------------------------------
    def save(self, load_step: int) -> None:
        if self.checkpoint_path is None:
            return
        save_checkpoint(
            self.checkpoint_path, self.field, self.optimiser,
            extra={**self.checkpoint_extra, "iteration": self.iteration,
                   "load_step": load_step, "history": [asdict(h) for h in self.history],
                   "sampling_rng": self.generator.get_state()},
        )

    def resume(self) -> int:
        """Load the checkpoint; returns the load step to continue from."""
        if self.checkpoint_path is None or not self.checkpoint_path.exists():
            raise FileNotFoundError(f"no checkpoint to resume from at {self.checkpoint_path}")
        extra = load_checkpoint(self.checkpoint_path, self.field, optimiser=self.optimiser).extra
        self.iteration = int(extra["iteration"])
        self.history = [MonitorRecord(**h) for h in extra["history"]]
        if "sampling_rng" in extra:  # absent in checkpoints written before it was kept
            self.generator.set_state(extra["sampling_rng"])
        self._good_state = self.field.get_flat().clone()
        log.info("resumed from %s at iteration %d", self.checkpoint_path, self.iteration)
        # A finished run stores one past its last step; resumed (with more iterations) it goes
        # on in its last step.
        return min(int(extra["load_step"]), len(self.config.load_steps) - 1)

    # -- main loop ------------------------------------------------------------------------------
    def run(self, *, resume: bool = False, on_load_step=None) -> SolveResult:
        """Minimise Π for every load step; `on_load_step(load_factor)` is called after each."""
        cfg = self.config
        start_step = self.resume() if resume else 0
        t0 = time.perf_counter()
        total = cfg.iterations * len(cfg.load_steps)
        show = cfg.progress and sys.stderr.isatty()
        bar = tqdm(total=total, initial=min(self.iteration, total), disable=not show,
                   desc="Π minimisation", dynamic_ncols=True)
        energy = float("nan")
        for step in range(start_step, len(cfg.load_steps)):
            lam = cfg.load_steps[step]
            done_in_step = max(self.iteration - step * cfg.iterations, 0)
            newton = cfg.newton_iterations > 0
            if newton and done_in_step == 0:
                self.newton(lam)
            for _ in range(done_in_step, cfg.iterations):
                samples, times = self.training_samples(cfg.samples, lam, self.generator)
                res = self.energy_and_gradient(samples, lam, times=times)
                gnorm = self.optimiser.gradient_norm()
                if not (math.isfinite(res.total) and math.isfinite(gnorm)):
                    self._diverged(res.total, gnorm, step)
                self.optimiser.step()
                self.iteration += 1
                bar.update(1)
                if self.iteration % cfg.monitor_every == 0:
                    energy = self._record(lam, gnorm, t0, step)
                    bar.set_postfix(energy=f"{energy:.5g}", grad=f"{gnorm:.3g}")
                if cfg.checkpoint_every and self.iteration % cfg.checkpoint_every == 0:
                    self.save(step)
                in_step = self.iteration - step * cfg.iterations
                if newton and cfg.newton_every and in_step % cfg.newton_every == 0 \
                        and in_step < cfg.iterations:
                    self.newton(lam)
            if newton and cfg.iterations > 0:
                self.newton(lam)
            if cfg.lbfgs_iterations:
                self._lbfgs(lam, step)
            recorded = self.history and self.history[-1].iteration == self.iteration
            if cfg.lbfgs_iterations or newton or not recorded:
                self._record(lam, self.optimiser.gradient_norm(), t0, step)
            energy = self.history[-1].energy
            log.info("load factor %.4g: Π = %.8g J after %d iterations", lam, energy,
                     self.iteration)
            if on_load_step is not None:
                on_load_step(lam)
        bar.close()
        self.save(len(cfg.load_steps))
        return SolveResult(energy=energy, iterations=self.iteration,
                           wall_time=time.perf_counter() - t0, history=self.history,
                           probes=self.probe_displacements(cfg.load_steps[-1]),
                           newton_steps=self.newton_steps)

    def _record(self, lam: float, gnorm: float, t0: float, step: int) -> float:
        energy = self.energy_and_gradient(self.monitor_samples(lam), lam, grad=False).total
        if not math.isfinite(energy) or self._blown_up(energy, lam):
            self._diverged(energy, gnorm, step)
        self._good_state = self.field.get_flat().clone()
        self.history.append(MonitorRecord(
            iteration=self.iteration, load_factor=lam, energy=energy, grad_norm=gnorm,
            learning_rate=self.optimiser.learning_rate, probes=self.probe_displacements(lam),
            wall_time=time.perf_counter() - t0))
        return energy

    def _blown_up(self, energy: float, lam: float) -> bool:
        """Π far above anything seen at this load factor: a minimiser must not climb by
        orders of magnitude (1000× the largest magnitude recorded so far)."""
        seen = [h.energy for h in self.history if h.load_factor == lam]
        if not seen:
            return False
        return energy > seen[0] + BLOW_UP_FACTOR * max(abs(e) for e in seen)

    def _diverged(self, energy: float, gnorm: float, step: int):
        self.field.set_flat(self._good_state)
        where = f" (checkpoint {self.checkpoint_path})" if self.checkpoint_path else ""
        last = self.history[-1].iteration if self.history else 0
        raise DivergenceError(
            f"training diverged at iteration {self.iteration}: Π = {energy}, "
            f"‖∇Π‖ = {gnorm}; the field was reset to its last good state from iteration "
            f"{last}{where}. Lower the learning rate or the load step.")

    def _lbfgs(self, lam: float, step: int) -> None:
        """Deterministic L-BFGS polish on a fixed, large sample set (of (ξ, t) in a
        pseudo-time solve)."""
        if self.config.pseudo_time:
            gen = torch.Generator().manual_seed(self.config.seed + MONITOR_SEED_OFFSET)
            samples, times = self.training_samples(self.config.monitor_samples, lam, gen)
        else:
            samples, times = self.monitor_samples(lam), None
        flat = torch.nn.Parameter(self.field.get_flat().clone())
        # torch's default tolerances are absolute (1e-7 on the gradient, 1e-9 on Π) and stop at
        # once when Π is small; run the requested iterations instead.
        opt = torch.optim.LBFGS([flat], lr=1.0, max_iter=self.config.lbfgs_iterations,
                                history_size=20, line_search_fn="strong_wolfe",
                                tolerance_grad=0.0, tolerance_change=0.0)

        def closure():
            self.field.set_flat(flat.detach())
            res = self.energy_and_gradient(samples, lam, times=times)
            flat.grad = self.field.get_flat_gradient().clone()
            return torch.tensor(res.total, dtype=flat.dtype)

        before = self.energy_and_gradient(samples, lam, grad=False, times=times).total
        opt.step(closure)
        self.field.set_flat(flat.detach())
        after = self.energy_and_gradient(samples, lam, grad=False, times=times).total
        if not math.isfinite(after):
            self._diverged(after, float("nan"), step)
        log.info("L-BFGS polish: Π %.8g -> %.8g J", before, after)

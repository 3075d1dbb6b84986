"""A SIREN field trained by Adam (with last-layer Newton phases and an L-BFGS polish) on
samples drawn afresh every iteration: `Solver.run` over the load steps."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar

import torch

from taichi_ndf.discretise.protocol import OnLoadStep, Probes, ResultPart, Solution
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.minimise.checkpoint import read_checkpoint
from taichi_ndf.minimise.last_layer import output_linearisation
from taichi_ndf.minimise.linearisation import DenseLinearisation
from taichi_ndf.objective import Objective
from taichi_ndf.problem.field_types import SIREN, FieldType
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.run_size import contact_check_points
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.solve.output_scale import field_for_run
from taichi_ndf.solve.solver import Solver


class SirenDiscretisation:
    """A `FieldConfig` on a model: its parameters are the network's weights, its energy is
    evaluated on stratified samples drawn every Adam iteration (and on fixed monitor and
    Newton samples). objective: what is minimised (None: Π of the model); estimate: the
    scene's name of an output scale estimated at run start (`Scene.output_scale_estimate`;
    None: a number given); dtype: the field's (None: the runtime's)."""

    field_type: ClassVar[FieldType] = SIREN
    name: ClassVar[str] = SIREN.name

    def __init__(self, spec: FieldConfig, model: ShellModel, *,
                 objective: Objective | None = None, estimate: str | None = None,
                 dtype: torch.dtype | None = None):
        self.spec = spec
        self.model = model
        self.objective = objective
        self.estimate = estimate
        self.dtype = dtype
        self.field: NeuralField | None = None
        self.solver: Solver | None = None

    def _with(self, spec: FieldConfig) -> SirenDiscretisation:
        return SirenDiscretisation(spec, self.model, objective=self.objective,
                                   estimate=self.estimate, dtype=self.dtype)

    def uses_newton(self, config: SolverConfig) -> bool:
        return config.newton_iterations > 0

    def check_size(self, config: SolverConfig, *, itemsize: int = 4) -> None:
        SIREN.check_size(self.spec, config, itemsize, **contact_check_points(self.model.contact))

    def refined(self, levels: int) -> SirenDiscretisation:
        raise ValueError("--refine needs a spline field ([field] type = \"spline\" or "
                         "--field spline)")

    def with_displacement_unit(self, factor: float) -> SirenDiscretisation:
        """The output scale × factor: the network's outputs keep their size."""
        return self._with(dataclasses.replace(self.spec,
                                              output_scale=self.spec.output_scale * factor))

    def for_case(self, scene_solver: SolverConfig, quick_solver: SolverConfig, *,
                 quick: bool, solver: SolverConfig | None, iterations: int | None,
                 seed: int | None, levels: int) -> tuple[SirenDiscretisation, SolverConfig]:
        """solver (else the scene's quick or full settings) with `iterations` Adam iterations
        per load step and `seed` where given; `levels` has no meaning here."""
        config = solver or (quick_solver if quick else scene_solver)
        if iterations is not None:
            config = config.with_iterations(iterations)
        if seed is not None:
            config = dataclasses.replace(config, seed=seed)
        return self, config

    def start(self, config: SolverConfig, *, seed: int, resume_from: Path | None = None
              ) -> None:
        """A resumed run keeps the output scale it started with ("auto" is not estimated
        again); a fresh one estimates it where the scene asks (`field_for_run`)."""
        if resume_from is not None:
            stored = read_checkpoint(resume_from)["architecture"]
            spec = dataclasses.replace(self.spec, output_scale=stored.output_scale)
        else:
            spec = field_for_run(self.spec, self.estimate, self.model, config)
        self.field = NeuralField(spec, seed=seed, dtype=self.dtype)
        self.solver = Solver(self.model, self.field, config, objective=self.objective,
                             linearise=self.linearisation)
        if resume_from is not None:
            self.solver.state.restore(resume_from)

    def solve(self, config: SolverConfig, *, callbacks: Sequence[Any] = (),
              on_load_step: OnLoadStep | None = None,
              report: Callable[[str], None] | None = None) -> Solution:
        """`Solver.run`; on_load_step sees the live field after each load step."""
        run, field = self.solver, self.field
        step = None if on_load_step is None else (lambda t: on_load_step(t, field))
        result = run.run(callbacks=callbacks, on_load_step=step)
        convergence = {t: ([h.iteration for h in records], [h.probes for h in records])
                       for t in config.load_steps
                       for records in [[h for h in result.history if h.load_factor == t]]}
        return Solution(
            field=field, energy=result.energy, iterations=result.iterations,
            wall_time=result.wall_time, history=result.history, probes=result.probes,
            field_document=field.config.to_dict(), document={"backoffs": result.backoffs},
            contact=None if run.contact is None else run.contact.points,
            contact_counts={"rejected_steps": run.rejected_steps},
            convergence=convergence, adam_iterations=result.iterations,
            newton_steps=result.newton_steps, samples=config.samples,
            newton_samples=config.newton_samples if config.newton_iterations else 0,
            settings={"iterations_per_step": config.iterations, "samples": config.samples,
                      "load_steps": list(config.load_steps),
                      "lbfgs_iterations": config.lbfgs_iterations,
                      "newton_iterations": config.newton_iterations,
                      "newton_every": config.newton_every,
                      "newton_samples": config.newton_samples,
                      "learning_rate": config.adam.lr, "field": field.config.to_dict()})

    def check_solution(self, solution: Solution) -> None:
        """Adam's result is checked as it trains (the divergence guard, backoffs)."""

    def probes(self, field: NeuralField, load_factor: float) -> Probes:
        """field: the one being trained (`on_load_step` gives no other): read through the
        solver's operator (with a pseudo-time field, at t = load_factor)."""
        return self.solver.probe_displacements(load_factor)

    def energy_at(self, load_factor: float) -> float:
        """Π on the fixed monitor samples (with a pseudo-time field: its state at that t)."""
        run = self.solver
        return run.energy_and_gradient(run.monitor_samples(), load_factor, grad=False).total

    def evaluation_points(self) -> SurfaceSamples:
        return self.solver.newton_samples()

    def displacement(self, xi: torch.Tensor, load_factor: float) -> torch.Tensor:
        self._no_pseudo_time()
        return self.solver.operator.jets(xi, t=load_factor)

    def linearisation(self, samples: SurfaceSamples, load_factor: float
                      ) -> DenseLinearisation:
        """The output layer's (`output_linearisation`): what the solver's last-layer Newton
        phases minimise over."""
        self._no_pseudo_time()
        return output_linearisation(self.solver.operator, samples, load_factor)

    def _no_pseudo_time(self) -> None:
        if self.spec.pseudo_time:
            raise ValueError("a pseudo-time field's jets take its time input: use its "
                             "Solver (energy_and_gradient)")

    def result_parts(self, field: NeuralField) -> tuple[ResultPart, ...]:
        """One surface: the model with `field`."""
        return (ResultPart("", self.model, field),)

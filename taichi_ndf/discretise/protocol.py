"""What a discretisation of the displacement field is to the tools: the `Discretisation`
protocol and the `Solution` of one solve over the load steps.

A discretisation is one field type with what differs between field types: its parameters
and where the energy is evaluated (a SIREN's weights on samples drawn afresh every
iteration, a spline's coefficients on fixed Gauss points per knot span), the solve driver
that minimises over them on the one continuation loop (`Solver.run`: Adam with last-layer
Newton phases; `solve_spline`: projected Newton, coarse to fine), the field's state at run
start (an estimated output scale, or a checkpoint), refinement where it exists, the memory
it needs and the parts of the result that only it has. The tools (`simulate`, the
validation runner, `ndf-sim`) see only this protocol; `taichi_ndf.discretise.discretisation`
picks the class from the field specification, the one place that tells field types apart.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

import torch

from taichi_ndf.minimise.newton import Linearisation
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.problem.training import SolverConfig

# Probe displacements [m] by probe name, each (x, y, z).
Probes = dict[str, list[float]]
# Called after each solved load step with its load factor and the field at it (a spline:
# after every grid level, once per load step, coarse to fine).
OnLoadStep = Callable[[float, Any], None]


class SolveRefused(RuntimeError):
    """A solve ended without a result worth writing (the message says why)."""


@dataclass(frozen=True)
class ResultPart:
    """One surface of a run's result: a model (its reference surface, boundary conditions and
    probes) with the field solved on it, whose deformed mesh the run writes.
    name: "" for a run's one surface (mesh.obj); a panel's name for one of several
    (mesh_<name>.obj, probes named "<name>.<probe>"). seams: the seams between the parts'
    outline edges, (part a, edge number a, part b, edge number b, reversed) each, whose two
    sides the output meshes sample alike (`problem.outline_mesh.seam_fractions`)."""

    name: str
    model: Any
    field: Any
    seams: tuple[tuple[int, int, int, int, bool], ...] = ()


@dataclass
class Solution:
    """One solve of a discretisation over the load steps.

    field: the final field (its parameters at the last load factor; a spline: the finest grid).
    energy: Π [J] at the last load factor. iterations: Adam iterations, or projected-Newton
    iterations over all levels and load steps. wall_time: [s] of the solve. history: the
    monitor records (Adam) or the Newton iterations (`taichi_ndf.minimise.state`). probes:
    displacement [m] by name at the last load factor. field_document: result.json's resolved field.
    document: result.json's parts only this discretisation has (Adam: "backoffs"; spline:
    "levels", "load_steps", "refinement"), in their order. refinement: the Richardson study
    over the grids (None: one grid, or no grids). contact: the contact check points
    (`ContactPoints`) with obstacles, else None; contact_counts: result.json's counts of the
    contact solve. convergence: per load factor, the axis (Adam iterations or grid levels)
    and the probes along it. adam_iterations, newton_steps, samples, newton_samples: the
    validation table's counts; settings: its record of the solve's settings.
    """

    field: Any
    energy: float
    iterations: int
    wall_time: float
    history: list
    probes: Probes
    field_document: dict
    document: dict = field(default_factory=dict)
    refinement: dict | None = None
    contact: Any = None
    contact_counts: dict = field(default_factory=dict)
    convergence: dict[float, tuple[list[int], list[Probes]]] = field(default_factory=dict)
    adam_iterations: int = 0
    newton_steps: int = 0
    samples: int = 0
    newton_samples: int = 0
    settings: dict = field(default_factory=dict)


class Discretisation(Protocol):
    """A field type bound to a model (and optionally an objective other than Π of the model).
    Built cheaply (nothing solved, no runtime needed) so that tools can ask sizes and settings
    before a run starts; `start` then makes the field, `solve` minimises over it."""

    # Its field type (`taichi_ndf.problem.field_types`: the field and specification classes,
    # the checkpoint tag, the scene's default method and keys, the size check).
    field_type: ClassVar[Any]
    name: ClassVar[str]  # the field type as scenes and --field name it: "siren", "spline"
    spec: Any  # the field specification (`FieldConfig`, `SplinePlan`)
    # The dtype of the fields it makes, and so of its evaluation points and linearisations
    # (None: the runtime's): a caller working in its own precision whatever the run's (the
    # material fits' equilibria: float64) asks for it when building it
    # (`discretise.discretisation(..., dtype=)`).
    dtype: torch.dtype | None

    def uses_newton(self, config: SolverConfig) -> bool:
        """Whether a Newton method solves it with `config` (rigid motions then matter)."""

    def check_size(self, config: SolverConfig, *, itemsize: int = 4) -> None:
        """ValueError (one line with the estimate) where solving it with `config` needs more
        memory than the machine has (`taichi_ndf.problem.run_size`); itemsize: bytes per value."""

    def refined(self, levels: int) -> Discretisation:
        """The same on `levels` successively refined grids (ValueError where none exist)."""

    def with_displacement_unit(self, factor: float) -> Discretisation:
        """The same for displacements `factor` times larger (a linearised case)."""

    def for_case(self, scene_solver: SolverConfig, quick_solver: SolverConfig, *,
                 quick: bool, solver: SolverConfig | None, iterations: int | None,
                 seed: int | None, levels: int) -> tuple[Discretisation, SolverConfig]:
        """The discretisation and settings a validation case is solved with."""

    def start(self, config: SolverConfig, *, seed: int, resume_from: Path | None = None
              ) -> None:
        """Make the field and the state the solve starts from: fresh (a SIREN's output-scale
        estimate made here, `output_scale.field_for_run`), or the checkpoint's at
        `resume_from` (CheckpointError where it is not one of this field type)."""

    def solve(self, config: SolverConfig, *, callbacks: Sequence[Any] = (),
              on_load_step: OnLoadStep | None = None,
              report: Callable[[str], None] | None = None) -> Solution:
        """Minimise over the load steps from the started state; `callbacks`
        (`taichi_ndf.minimise.callbacks`) see every iteration; `report` takes one line per finished
        stage worth a line (a spline's grid levels) where `config.progress`.
        DivergenceError from the divergence guard."""

    def check_solution(self, solution: Solution) -> None:
        """SolveRefused where the result would not be worth writing; logs what is doubtful."""

    def probes(self, field: Any, load_factor: float) -> Probes:
        """The displacement [m] of every probe of the model, of `field` at a load factor."""

    def energy_at(self, load_factor: float) -> float:
        """Π [J] of the solved field at a load factor (a pseudo-time field's path)."""

    def result_parts(self, field: Any) -> tuple[ResultPart, ...]:
        """The surfaces a run writes of `field` (the solution's, or one `on_load_step` gave):
        one unnamed part (a single field on the model), or one named part per panel."""

    # What a solver written against the protocol minimises over (after `start`): the fixed
    # points where its Newton evaluates Π, the displacement jets of the current parameters,
    # and their linearisation about them.
    def evaluation_points(self) -> SurfaceSamples:
        """The fixed points of its Newton solve: a SIREN's last-layer Newton samples (its Adam
        iterations draw theirs afresh), a spline's Gauss points per knot span of its grid."""

    def displacement(self, xi: torch.Tensor, load_factor: float) -> torch.Tensor:
        """Displacement jets (N, 6, 3) [m] at ξ (N, 2) of the current parameters (those
        started from, after `solve` the solution's) at a load factor."""

    def linearisation(self, samples: SurfaceSamples, load_factor: float) -> Linearisation:
        """U(P) = U₀ + J P at `samples` about the current parameters
        (`taichi_ndf.minimise.newton.Linearisation`): a SIREN's output layer
        (`DenseLinearisation`, P the change of (W_out | b_out), (3, width + 1), from the
        current one), a spline's coefficients (`SplineLinearisation`, P the coefficients
        (n, 3), the boundary's held unknowns fixed)."""

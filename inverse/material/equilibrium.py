"""The forward model of the implicit-function estimates: the equilibrium of a model with the
unknowns set to θ on one discretisation of the displacement field, and its sensitivity to the
outer coordinates z (ln θ for positive unknowns, the value for signed ones).

`Equilibrium` is written once for every field type: the solves (from the reference state
through the load steps on the one continuation loop, `taichi_ndf.minimise.continuation.solve_over`;
warm-started from the current solution plus the first-order prediction; from a given start;
the first solution kept and reused), θ's loads and point forces on the samples, the
sensitivity dP*/dz = −K⁻¹ ∂g/∂z column by column from the unknowns' term gradients
(Π = Π_known + Σ_j θ_j T_j, `unknowns.term_gradients`, so ∂g/∂θ_j is the pull-back of
dT_j/du and a column is multiplied by θ_j for a positive unknown), and the observed positions
x(ξ) = X(ξ) + u(ξ). What differs between field types is a subclass, registered per field
type in `inverse.material.field_types` (`InverseFieldType.equilibrium`): its parameters P (a SIREN's
output layer on fixed features, `implicit.ImplicitEquilibrium`; a spline's coefficients,
`spline_equilibrium.SplineEquilibrium`),
its samples, its Newton over P, its K and pull-back, and u and du/dP at ξ. `forward_model`
(`inverse.material.forward_model`) picks the class from the field's configuration there.

Its interface to the outer fit (`outer_fit`): `solve(values, prediction=, from_reference=,
start=)`, `state()` / `set_state(state, values)`, `sensitivity()`, `predicted_change(sensitivity,
dz)`, `positions(ξ)`, `position_jets(ξ)`, `position_sensitivity(ξ, sensitivity)`, `model`,
`field`, `label`, `newton_steps`, `unconverged_solves`, `stable`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from inverse.material.unknowns import Unknown, apply, term_gradients
from taichi_ndf import jets
from taichi_ndf.minimise.continuation import Stages, solve_over
from taichi_ndf.objective import Objective
from taichi_ndf.problem.model import ShellModel

# The pull-back of dΠ/du_jets (N, 6, 3) at the samples to the parameters, and the solve of
# K dP = ∂g/∂z for the columns (one per unknown): (samples, u at them in the model's order,
# pull-back, solve), as `Equilibrium._linearised` gives them.
Linearised = tuple[Any, torch.Tensor, Callable[[torch.Tensor], torch.Tensor],
                   Callable[[list[torch.Tensor]], torch.Tensor]]


class Equilibrium:
    """The equilibrium of `model` with the unknowns set to θ on one discretisation, and its
    sensitivity dP*/dz (module docstring). boundary_length: the band width of the boundary
    conditions' vanishing factors (None: the model's); load_steps: the load factors of a
    solve from the reference state."""

    label: dict  # names the forward model in reports
    samples: Any  # `SurfaceSamples` with θ's point forces (the point loads' rows: point_rows)
    point_rows: Any

    def __init__(self, model: ShellModel, unknowns: list[Unknown], *,
                 boundary_length: float | None, load_steps: tuple[float, ...]):
        if boundary_length is not None:
            model = model.with_boundary_length(boundary_length)
        self.model = model
        self.unknowns = list(unknowns)
        self.load_steps = tuple(load_steps)
        self.values: np.ndarray | None = None  # θ of the current solution
        self.newton_steps = 0
        self.unconverged_solves = 0  # inner Newton solves stopped before their tolerance
        self.solve_time = 0.0
        self.stable = True  # K positive definite at the last sensitivity (where checked)
        self._first: tuple[np.ndarray, Any] | None = None

    # -- what a field type gives -------------------------------------------------------------
    def state(self) -> Any:
        """A copy of the parameters P."""
        raise NotImplementedError

    def _set_parameters(self, state: Any) -> None:
        raise NotImplementedError

    def _reference(self) -> Any:
        """P of the reference state (u = 0 where the boundary conditions allow)."""
        raise NotImplementedError

    def _shifted(self, prediction: torch.Tensor | None) -> Any:
        """P + prediction (a `predicted_change`), the start of a warm re-solve."""
        raise NotImplementedError

    def _minimise(self, values, potential, start: Any, load_factor: float, *,
                  warm: bool) -> Any:
        """P minimising `potential` (Π of θ = values at the load factor) from `start`; warm: a
        re-solve near the solution (its own iteration limit where the field has one)."""
        raise NotImplementedError

    def _linearised(self, potential) -> Linearised:
        """At the current solution (θ's `potential` at load 1): module docstring."""
        raise NotImplementedError

    def displacement_jets(self, xi: torch.Tensor) -> torch.Tensor:
        """Jets (N, 6, 3) [m] of the current displacement at ξ (N, 2) of the field's dtype."""
        raise NotImplementedError

    def predicted_change(self, sensitivity: torch.Tensor, dz: np.ndarray) -> torch.Tensor:
        """First-order change of P for a step dz (p,) in z."""
        raise NotImplementedError

    def position_sensitivity(self, xi: torch.Tensor, sensitivity: torch.Tensor
                             ) -> torch.Tensor:
        """dx/dz (N, 3, p) at ξ from dP*/dz (`sensitivity`): x is affine in P."""
        raise NotImplementedError

    @property
    def dtype(self) -> torch.dtype:
        return self.field.parameters[0].dtype

    # -- unknowns of this observation alone (e.g. its held points: `inverse.material.handles`)
    # The outer fit (`outer_fit.fit`) estimates them beside the shared θ; their columns follow
    # θ's in `sensitivity`, `predicted_change` and `position_sensitivity`. None here.
    local_scale = 1.0  # the normalised coordinate of a local unknown, in its unit

    @property
    def local_count(self) -> int:
        return 0

    def local_values(self) -> np.ndarray:
        return np.zeros(0)

    def set_local(self, values) -> None:
        if len(values):
            raise ValueError(f"{type(self).__name__} has no local unknowns")

    def _local_gradients(self) -> list[torch.Tensor]:
        """∂g/∂(local unknown) at the last `_linearised` point, one per local unknown."""
        return []

    # -- written once ---------------------------------------------------------------------------
    def set_state(self, state: Any, values) -> None:
        self._set_parameters(state)
        self.values = None if values is None else np.array(values, dtype=np.float64)

    def _potential(self, values, load_factor: float):
        """Π of θ at a load factor (the objective scales the loads); sets the samples'
        (unscaled) point forces to θ's."""
        loaded = apply(self.model, self.unknowns, values)
        if loaded.loads.point_loads:
            forces = self.samples.point_force.clone()
            forces[self.point_rows] = torch.tensor(
                [p.force for p in loaded.loads.point_loads], dtype=forces.dtype)
            self.samples = self.samples.with_point_force(forces)
        return Objective.of_model(loaded).potential(load_factor)

    def _solve_at(self, values, start: Any, load_factor: float, *, warm: bool) -> Any:
        return self._minimise(values, self._potential(values, load_factor), start, load_factor,
                              warm=warm)

    def solve(self, values, *, prediction: torch.Tensor | None = None,
              from_reference: bool = False, start: Any = None) -> int:
        """Solve for θ = values; returns the Newton steps taken. From `start` (parameters)
        at load 1 when given; else from the reference state through `load_steps` the first
        time (or with `from_reference`; the result kept and reused when asked for the same θ
        again); else warm-started from the current P* plus `prediction`."""
        values = np.array(values, dtype=np.float64)
        t0 = time.perf_counter()
        steps = self.newton_steps
        if start is not None:
            self._set_parameters(self._solve_at(values, start, 1.0, warm=False))
            self._first = (values, self.state())
        elif self._first is not None and (from_reference or self.values is None) and \
                np.array_equal(values, self._first[0]):
            self._set_parameters(self._first[1])
        elif self.values is None or from_reference:
            reference = self._reference()  # the first load step's start
            solution = solve_over(Stages(
                lambda step, begin: self._solve_at(values, begin, step.load_factor, warm=False),
                lambda step, previous, _coarser: reference if previous is None else previous),
                self.load_steps)[0][-1]
            self._set_parameters(solution)
            if self._first is None:
                self._first = (values, self.state())
        else:
            self._set_parameters(self._solve_at(values, self._shifted(prediction), 1.0,
                                                warm=True))
        self.values = values
        self.solve_time += time.perf_counter() - t0
        return self.newton_steps - steps

    def sensitivity(self) -> torch.Tensor:
        """dP*/dz at the current solution, the unknowns on the last axis: column j is
        −K⁻¹ ∂g/∂θ_j, times θ_j for a positive unknown (z_j = ln θ_j); the local unknowns'
        columns (−K⁻¹ ∂g/∂l) after θ's."""
        if self.values is None:
            raise RuntimeError("solve before asking for the sensitivity")
        samples, u, pull_back, solve = self._linearised(self._potential(self.values, 1.0))
        columns, _ = term_gradients(self.model, self.unknowns, samples, u)
        dg = []
        for unknown, value, column in zip(self.unknowns, self.values, columns, strict=True):
            g = pull_back(column)
            dg.append(g * float(value) if unknown.positive else g)
        return solve(dg + self._local_gradients())

    def position_jets(self, xi: torch.Tensor, z=None) -> torch.Tensor:
        """Jets (N, 6, 3) of the current equilibrium positions [m] (z: ignored, for the
        interface of `bilevel.closest_surface_points`)."""
        xi = xi.to(self.dtype)
        return self.model.surface.jets(xi) + self.displacement_jets(xi)

    def positions(self, xi: torch.Tensor, z=None) -> torch.Tensor:
        """Current equilibrium positions (N, 3) [m] at ξ (N, 2)."""
        return self.position_jets(xi)[:, jets.VALUE]

"""Forward model of the Newton estimate: the equilibrium on a spline field and its sensitivity.

For given unknowns θ the equilibrium coefficients C*(θ) of a B-spline displacement field
(`SplineField`) minimise Π(C; θ) on the span quadrature of its grid, by projected Newton
(`minimise.newton.minimise`): the first solve from the undeformed state through
`load_steps`, later ones warm-started from the previous C* moved by the first-order prediction
(dC*/dz) Δz, or from a given start (e.g. a coarser grid's solution prolonged).

Sensitivity: Π is linear in every unknown (Π = Π_known + Σ_j θ_j T_j, `unknowns`), so
∂g/∂θ_j = Assembly.gradient(dT_j/dU) (`term_gradients`: the same pull-back as the gradient) and
dC*/dθ_j = −K⁻¹ ∂g/∂θ_j with K of the exact blocks at C*, factorised once for all unknowns
(`minimise.sensitivity`). If K is not positive definite the equilibrium is unstable and
`stable` is False. In the outer coordinates z (ln θ for positive unknowns, the value for
signed ones) a column is multiplied by θ_j for a positive unknown. Observed positions
x(ξ) = X(ξ) + u(ξ) are affine in C, so dx/dz = J_obs dC*/dz exactly (the composition at ξ).
What is the same for every field type (the solves, θ's point forces, the sensitivity's
columns, the positions) is `inverse.material.equilibrium`.

Free handles (`free_handles`): the displacement of some of the model's handles offset by
local unknowns δ [m]; their columns dC*/dδ = −K⁻¹ Jᵀ H dU/dδ use the same exact per-sample
blocks H and the same factorisation of K (`inverse.material.handles`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np
import torch

from inverse.material.equilibrium import Equilibrium
from inverse.material.handles import (
    OFFSET_SCALE,
    check_free_handles,
    displaced,
    unit_displacements,
)
from inverse.material.unknowns import Unknown
from taichi_ndf import checks, jets, progress
from taichi_ndf.discretise import discretisation
from taichi_ndf.field import SplineConfig
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.linear_solve import LinearSolverConfig
from taichi_ndf.minimise.newton import NewtonConfig, coupled_blocks, minimise, point_blocks
from taichi_ndf.minimise.sensitivity import sensitivity
from taichi_ndf.objective.seam import seam_points
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.spline_grid import SplinePlan, auto_span_length, spans_for
from taichi_ndf.problem.training import SolverConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SplineModelConfig:
    """The spline forward model.

    spans: knot spans (n1, n2) of the coarsest grid; None: the project's grid rule
        (`spline_grid.auto_span_length` with the model's thickness and band).
    degree: 3 or 4. quadrature_points: Gauss points per span and direction (None: degree + 1).
    boundary_length: band width of the boundary conditions' vanishing factors, a fraction of
        the domain (None: the model's); a wide band keeps the grid rule's spans coarse.
    load_steps: load factors of the first solve from the undeformed state (the last is 1).
    newton_iterations: most projected-Newton iterations per solve (per load step).
    """

    spans: tuple[int, int] | None = None
    degree: int = 3
    quadrature_points: int | None = None
    boundary_length: float | None = 2.0
    load_steps: tuple[float, ...] = (0.25, 0.5, 0.75, 1.0)
    newton_iterations: int = 60

    def __post_init__(self):
        if self.spans is not None and (len(self.spans) != 2 or any(
                isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in self.spans)):
            raise ValueError(f"spans must be two positive integers or None, got {self.spans!r}")
        if self.degree not in (3, 4):
            raise ValueError(f"degree must be 3 or 4, got {self.degree!r}")
        q = self.quadrature_points
        if q is not None and (isinstance(q, bool) or not isinstance(q, int) or q < 1):
            raise ValueError(f"quadrature_points must be a positive integer or None, got {q!r}")
        if self.boundary_length is not None and not self.boundary_length > 0:
            raise ValueError(f"boundary_length must be positive or None, got "
                             f"{self.boundary_length!r}")
        checks.load_steps(self.load_steps)
        if isinstance(self.newton_iterations, bool) or self.newton_iterations < 1:
            raise ValueError(f"newton_iterations must be >= 1, got {self.newton_iterations!r}")

    def grid(self, model: ShellModel) -> SplineConfig:
        """The coarsest grid for a model (with this configuration's band)."""
        if self.boundary_length is not None:
            model = model.with_boundary_length(self.boundary_length)
        domain = model.surface.domain
        spans = self.spans or spans_for(model.surface, auto_span_length(
            model.surface, model.material.thickness, model.boundary.narrowest_band))
        return SplineConfig(spans=tuple(spans), degree=self.degree, domain=domain.bounds,
                            periodic=domain.periodic)


class SplineEquilibrium(Equilibrium):
    """The equilibrium of `model` with the unknowns set to θ on one spline grid, and dC*/dz:
    `Equilibrium` on a spline's coefficients C (n, 3).

    model: the observation's model (unknowns at their scene values); grid: the field's
    configuration (`SplineModelConfig.grid`, or a refinement of it); free_handles: indices of
    the model's `Handle` constraints whose displacement is offset by local unknowns (3 each,
    [m], world axes; `inverse.material.handles`)."""

    def __init__(self, model: ShellModel, unknowns: list[Unknown], config: SplineModelConfig,
                 grid: SplineConfig, *, free_handles: tuple[int, ...] = ()):
        super().__init__(model, unknowns, boundary_length=config.boundary_length,
                         load_steps=config.load_steps)
        model = self.model
        self.free_handles = check_free_handles(model.boundary, free_handles)
        self._held = model.boundary  # the handles at their stated displacement (offsets 0)
        self.offsets = np.zeros((len(self.free_handles), 3))
        self.local_scale = OFFSET_SCALE * math.sqrt(model.surface.domain.rectangle_area)
        self._units = None  # dU/dδ at the assembly's samples (`handles.unit_displacements`)
        self._local_dg: list[torch.Tensor] = []
        self.config = config
        self.label = {"spans": list(grid.spans), "degree": grid.degree}
        # the grid through the forward solve's discretisation (in float64 whatever the run's):
        # its field, its Gauss points and its linearisation builder with the direct solve
        spline = discretisation(SplinePlan(grid, quadrature_points=config.quadrature_points),
                                model, dtype=torch.float64)
        spline.start(SolverConfig(method="newton"), seed=0)
        self.field = spline.field
        self.grid = spline.linearise(self.field, LinearSolverConfig(kind="direct"))
        self.operator = self.grid.operator
        original = spline.evaluation_points()
        self.assembly = self.grid.assemble(original)
        self.fixed = self.grid.fixed
        # the assembly's row of each original sample (`Assembly.order` is the inverse):
        # term_gradients and the point forces index the original order (the quadrature, its
        # point loads last, then the seams' own points)
        self._model_order = torch.argsort(self.assembly.order)
        end = len(original) - seam_points(model.terms)
        self.point_rows = self._model_order[end - len(model.loads.point_loads):end]
        self.newton = NewtonConfig(max_iterations=config.newton_iterations)
        self.coefficients = torch.zeros(grid.num_coefficients, 3, dtype=torch.float64)

    @classmethod
    def of_field(cls, spec: SplineConfig, model: ShellModel, unknowns: list[Unknown],
                 config: SplineModelConfig, *, seed: int = 0) -> SplineEquilibrium:
        """On the grid `spec` (seed: no meaning here)."""
        return cls(model, unknowns, config, spec)

    # -- the free handles' offsets δ (k, 3) [m]: local unknowns ---------------------------------
    @property
    def local_count(self) -> int:
        return 3 * len(self.free_handles)

    def local_values(self) -> np.ndarray:
        return self.offsets.reshape(-1).copy()

    def set_local(self, values) -> None:
        """Move the free handles to their stated displacement plus `values` (3k,) [m]: the
        model's conditions and the operator follow; the solution is not re-solved."""
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (self.local_count,):
            raise ValueError(f"need {self.local_count} handle offsets, got {values.shape}")
        if not self.local_count:
            return
        self.offsets = values.reshape(-1, 3).copy()
        boundary = displaced(self._held, self.free_handles, self.offsets)
        self.model = dataclasses.replace(self.model, boundary=boundary)
        self.grid.boundary = boundary
        self.grid.operator = self.operator = DisplacementOperator(self.field, boundary)
        self._first = None  # a kept first solution belongs to the old offsets

    # -- the coefficients C ---------------------------------------------------------------------
    @property
    def samples(self):
        """The assembly's samples (in its order)."""
        return self.assembly.samples

    @samples.setter
    def samples(self, samples) -> None:
        self.assembly.samples = samples

    def state(self) -> torch.Tensor:
        return self.coefficients.clone()

    def _set_parameters(self, state: torch.Tensor) -> None:
        self.coefficients = state.clone()

    def _reference(self) -> torch.Tensor:
        return torch.zeros_like(self.coefficients)

    def _shifted(self, prediction: torch.Tensor | None) -> torch.Tensor:
        return self.coefficients if prediction is None else self.coefficients + prediction

    def predicted_change(self, sensitivity: torch.Tensor, dz: np.ndarray) -> torch.Tensor:
        """First-order change of the state (n, 3) for a step dz (p,) in the outer coordinates."""
        return torch.einsum("ncj,j->nc", sensitivity, torch.from_numpy(dz))

    def _minimise(self, values, potential, start: torch.Tensor, load_factor: float, *,
                  warm: bool) -> torch.Tensor:
        """Projected Newton from `start` (warm or not: at most `newton_iterations`)."""
        with progress.stage(f"equilibrium {self.label}, load {load_factor:.3g}",
                            self.newton.max_iterations):
            linearisation = self.grid.linearisation(load_factor)
            solution = minimise(linearisation, potential, start, self.newton,
                                load_factor=load_factor)
        self.newton_steps += len(solution.history)
        if not solution.converged:
            self.unconverged_solves += 1
            log.warning("spline equilibrium %s: Newton did not converge at θ = %s (load %.3g)",
                        self.label, np.asarray(values).tolist(), load_factor)
        return solution.parameters

    def _linearised(self, potential):
        """K of the exact blocks at C*, factorised once for all unknowns; sets `stable`."""
        linearisation = self.grid.linearisation(1.0)
        u_assembly = linearisation.displacement(self.coefficients)
        blocks = point_blocks(linearisation, potential, self.coefficients, u_assembly,
                              self.newton.fd_step)  # the exact blocks (not projected)
        couplings = coupled_blocks(potential, linearisation.samples, u_assembly)
        matrix = linearisation.hessian(blocks, couplings)
        self._local_dg = self._handle_gradients(blocks, couplings)
        samples = self.assembly.samples
        order = self._model_order
        u = self.assembly.displacement(self.coefficients)
        in_order = type(samples)(samples.xi[order], samples.r_jets[order], samples.weight[order],
                                 samples.point_force[order])

        def pull_back(column: torch.Tensor) -> torch.Tensor:
            back = torch.empty_like(column)
            back[order] = column
            return self.assembly.gradient(back)

        def solve(dg: list[torch.Tensor]) -> torch.Tensor:
            result = sensitivity(matrix, torch.stack(dg, dim=-1), self.fixed)
            if not result.definite and self.stable:
                log.warning("spline equilibrium %s at θ = %s: K is not positive definite — "
                            "the equilibrium is unstable", self.label, self.values.tolist())
            self.stable = result.definite
            return result.derivative

        return in_order, u[order], pull_back, solve

    def _handle_gradients(self, blocks: torch.Tensor, couplings) -> list[torch.Tensor]:
        """∂g/∂δ = Jᵀ H dU/dδ per free-handle coordinate (`inverse.material.handles`), H the
        exact per-sample blocks (N, 18, 18) at the solution (the assembly's sample order)."""
        if not self.local_count:
            return []
        if couplings is not None:
            raise NotImplementedError("free handles with pair couplings in the Hessian")
        if self._units is None:
            self._units = unit_displacements(self._held, self.free_handles,
                                             self.assembly.samples.xi)
        n = self._units.shape[0]
        flat = self._units.reshape(n, 18, self.local_count)
        hv = torch.einsum("nij,njk->nik", blocks, flat).reshape(n, 6, 3, self.local_count)
        return [self.assembly.gradient(hv[..., k]) for k in range(self.local_count)]

    def _local_gradients(self) -> list[torch.Tensor]:
        dg, self._local_dg = self._local_dg, []
        return dg

    def fitted_state(self, xi: torch.Tensor, points: torch.Tensor, *,
                     ridge: float = 1e-10) -> torch.Tensor:
        """Coefficients (n, 3) whose positions at ξ (N, 2) fit observed `points` (N, 3) [m]
        in least squares (a start for a first solve next to an observed shape, on its branch):
        u is affine in C per component, so one ridge-regularised normal-equation solve per
        component (ridge relative to the mean diagonal)."""
        xi = xi.to(torch.float64)
        at = self.grid.at_points(xi, 1.0)
        if at.pin is not None:
            raise ValueError("fitted_state does not support a free pin")
        target = self.operator.to_frame(points.to(torch.float64)
                                        - self.model.surface.jets(xi)[:, jets.VALUE])
        target = target - at.offset[:, jets.VALUE]
        n = self.coefficients.shape[0]
        rows = torch.arange(len(xi)).repeat_interleave(at.index.shape[1])
        state = torch.zeros_like(self.coefficients)
        for c in range(3):
            a = torch.zeros(len(xi), n, dtype=torch.float64)
            a.index_put_((rows, at.index.reshape(-1)),
                         at.jacobian.component(c)[:, jets.VALUE].reshape(-1), accumulate=True)
            normal = a.T @ a
            normal += ridge * float(normal.diagonal().mean()) * torch.eye(n, dtype=normal.dtype)
            state[:, c] = torch.linalg.solve(normal, a.T @ target[:, c])
        if self.fixed is not None:
            state.view(-1)[torch.as_tensor(self.fixed)] = 0.0
        return state

    # -- observation space ----------------------------------------------------------------------
    def displacement_jets(self, xi: torch.Tensor) -> torch.Tensor:
        return displacement_at(self.operator, xi, self.coefficients, 1.0)

    def position_sensitivity(self, xi: torch.Tensor, sensitivity: torch.Tensor) -> torch.Tensor:
        """dx/dz (N, 3, p) at ξ from dC*/dz (`sensitivity`): x is affine in C."""
        at = self.grid.at_points(xi.to(torch.float64), 1.0)
        local = sensitivity[at.index]  # (N, k, 3, p)
        out = torch.stack([torch.einsum("na,naj->nj", at.jacobian.component(c)[:, jets.VALUE],
                                        local[:, :, c]) for c in range(3)], dim=1)
        if at.pin is not None:
            out = out + torch.einsum("cna,acj->ncj", at.pin[:, :, jets.VALUE],
                                     sensitivity[at.pin_index])
        # components along the boundary frame's axes -> world (vectors on the last axis)
        out = self.operator.to_world(out.transpose(1, 2)).transpose(1, 2)
        if self.local_count:  # a free handle moves x through the prescribed part too
            units = unit_displacements(self._held, self.free_handles, xi.to(torch.float64))
            out[:, :, -self.local_count:] += units[:, jets.VALUE]
        return out

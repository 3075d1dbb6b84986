"""Shape-from-template on a SIREN displacement field, frame by frame by Adam: the SIREN's part
of the one reconstruction (`inverse.sft.reconstruct.FrameReconstructor`).

u is a SIREN ``NeuralField`` on the template's UV rectangle whose zero output layer makes u ≡ 0
(the template) before the first frame. Frame t > 0 starts from frame t − 1's weights (warm
start; optionally first fitted to an initial guess such as the baseline's mesh, `fit_to`) and
minimises, with Adam on a cosine schedule,

    L(u) = E_data(u) + w_phys · Π_int(u) / E_ref

E_data the frame's data terms (`inverse.sft.least_squares`: value and gradient with respect to
u at their points; Adam follows the gradient of the value it computes, so the silhouette's
slope is the bilinear sample of the distance image's central differences, "interpolant"), Π_int
the objective's ``ShellEnergyTerm`` on Monte-Carlo samples of the template redrawn every step
(`sample_surface`); both enter the displacement operator's ``backward`` in one batch of jets.

Sequential warm starts rather than one field over (ξ, t): each step then costs as much as one
frame, the cost per frame does not grow with the sequence, and a frame is done before the next
one is read (the frame loop: `inverse.sft.sequential`, shared with the spline field).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from inverse.sft.least_squares import LeastSquaresData
from inverse.sft.sequential import FrameSolve
from inverse.sft.settings import ReconstructionConfig
from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.geometry import MeshSurface
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.optim import Adam, AdamConfig
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.shell.materials import LinearIsotropic


class SirenFrameField:
    """The SIREN's part of the frame fit (`inverse.sft.sequential.FrameField`): the field
    (output scale a fraction of √A, A the template's area), its prior on `energy_samples`
    samples redrawn every Adam step, and Adam over the network's weights."""

    slope = "interpolant"  # Adam: the slope of the value it computes

    def __init__(self, surface: MeshSurface, conditions: BoundaryConditions | None,
                 config: ReconstructionConfig, *, mean_edge: float, material: LinearIsotropic,
                 energy_reference: float):
        self.config = cfg = config
        self.surface = surface
        self.mean_edge = mean_edge
        tri = surface.vertices.numpy()[surface.faces.numpy()]
        area = float((0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                           axis=1)).sum())
        self.field = NeuralField(
            FieldConfig(width=cfg.width, hidden_layers=cfg.hidden_layers, omega0=cfg.omega0,
                        domain=surface.domain.bounds,
                        output_scale=cfg.output_scale * math.sqrt(area)),
            seed=cfg.seed)
        # A zero output layer makes u ≡ 0 (the template) before the first frame is fitted.
        for p in self.field.output_layer():
            p.zero_()
        self.dtype = self.field.dtype
        self.prior = Objective(ShellEnergyTerm(material, Loads()))
        self.energy_reference = energy_reference
        self.operator = DisplacementOperator(self.field, conditions)
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.data_xi = None

    def displacement(self, xi: torch.Tensor) -> torch.Tensor:
        """u (N, 3) [m] at ξ (N, 2): the value channel of the jets that Adam's steps evaluate
        (`DisplacementOperator.displacement` differs from it by rounding, ~1e-17 m in f64)."""
        return self.operator.jets(xi)[:, jets.VALUE]

    def rows(self, blocks: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """The data points after each step's energy samples; the terms see the data rows only
        (numbered from 0, block after block)."""
        self.data_xi = torch.cat(list(blocks))
        rows, first = [], 0
        for xi in blocks:
            rows.append(torch.arange(first, first + len(xi)))
            first += len(xi)
        return rows

    def solve(self, terms: Sequence[LeastSquaresData]) -> FrameSolve:
        """`steps` Adam steps; the loss terms are those of the last step's evaluation."""
        cfg = self.config
        lam = cfg.physics_weight / self.energy_reference
        optimiser = Adam(self.field.parameters, self.field.gradients, config=AdamConfig(
            lr=cfg.lr, schedule="cosine", total_steps=cfg.steps, min_lr=cfg.min_lr))
        at_data, parts = None, {}
        for _ in range(cfg.steps):
            samples = sample_surface(self.surface, cfg.energy_samples, generator=self.generator,
                                     dtype=self.dtype)
            n_energy = len(samples)
            u_jets = self.operator.jets(torch.cat([samples.xi, self.data_xi]))
            grad = torch.zeros_like(u_jets, dtype=torch.float64)
            at_data = u_jets[n_energy:].double()
            _, grad[n_energy:] = terms[0].evaluate(None, at_data)
            for term in terms[1:]:
                grad[n_energy:] += term.evaluate(None, at_data)[1]
            if lam > 0:
                result = self.prior.evaluate(samples, u_jets[:n_energy])
                grad[:n_energy] = lam * result.grad_u_jets.double()
                parts["energy"] = result.internal / self.energy_reference
            self.operator.backward(grad)
            optimiser.step()
        return FrameSolve(at_data, parts, cfg.steps)

    def fit_to(self, xi: torch.Tensor, target: torch.Tensor) -> None:
        """Fit u at ξ (n, 2) to `target` (n, 3) [m] (least squares, `init_steps` Adam steps
        on the same schedule as a frame's)."""
        cfg = self.config
        if not cfg.init_steps:
            return
        optimiser = Adam(self.field.parameters, self.field.gradients, config=AdamConfig(
            lr=cfg.lr, schedule="cosine", total_steps=cfg.init_steps, min_lr=cfg.min_lr))
        for _ in range(cfg.init_steps):
            u_jets = self.operator.jets(xi)
            grad = torch.zeros_like(u_jets, dtype=torch.float64)
            difference = u_jets[:, jets.VALUE].double() - target
            grad[:, jets.VALUE] = 2.0 * difference / (len(target) * self.mean_edge**2)
            self.operator.backward(grad)
            optimiser.step()

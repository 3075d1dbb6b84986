"""Physics-regularised shape-from-template: a neural deformation field fitted frame by frame.

Each frame's surface is x(ξ) = X(ξ) + u(ξ) on the template's reference surface (ξ = the
template's UVs; X the template itself, piecewise linear for data and output, its C² spline fit
``MeshSurface`` for the energy), with u a SIREN ``NeuralField``. Frame 0 is the template (the
input contract gives it). Frame t > 0 starts from frame t − 1's weights (warm start; optionally
first fitted to an initial guess such as the baseline's mesh) and minimises, with Adam,

    L(u) = Σ_i c_i ρ(‖π(x(ξ_i)) − p_i‖) / Σ_i c_i                 robust reprojection [px²]
         + w_sil · mean_v D(π(x(ξ_v)))²                            silhouette [px²] (with masks)
         + w_phys · Π_int(u) / E_ref                                 Kirchhoff–Love prior
         + w_temp · mean_v ‖x_t(ξ_v) − 2 x_{t−1}(ξ_v) + x_{t−2}(ξ_v)‖² / h²   smooth motion

with (ξ_i, p_i, c_i) the tracked surface points, pixels and confidences, π the pinhole
projection, ρ the Huber penalty (quadratic up to ``huber_px``), ξ_v the template vertices' UVs,
D the distance [px] to the mask (0 inside), Π_int the internal energy of a fixed linear
isotropic material (Monte-Carlo samples redrawn every step), h the template's mean edge length.

Choice of λ = w_phys / E_ref: E_ref = B / 2 is the bending energy of the template bent to uniform
curvature 1/√A (A its area, B the bending stiffness), so Π_int / E_ref is dimensionless and does
not depend on the stiffness scale: the prior is fixed by ν, the thickness h (D / B = 12 / h²) and
the one number w_phys, chosen once on a tuning sequence and never per sequence.

Sequential warm starts rather than one field over (ξ, t): each step then costs as much as one
frame, the cost per frame does not grow with the sequence, and a frame is done before the next
one is read (the frame loop: `inverse.sft.sequential`, shared with the spline field). Pinned
vertices are exact: u = φ N with ``PinnedPoint`` conditions at their UVs. Gradients: the data
terms are the spline fit's (`inverse.sft.least_squares`, analytic value and gradient with
respect to u at their points; the silhouette's slope is the bilinear sample of the distance
image's central differences), the prior the objective's ``ShellEnergyTerm``; both enter the
displacement operator's ``backward`` in one batch of jets.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
import torch

from inverse.sft.inputs import Template, mean_edge_length
from inverse.sft.sequential import (
    DataWeights,
    FittedFrame,
    FrameData,
)
from inverse.sft.settings import ReconstructionConfig
from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import PinnedPoint
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.geometry import MeshSurface
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.optim import Adam, AdamConfig
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.shell.materials import preset

log = logging.getLogger(__name__)


class FieldReconstructor:
    """Holds the field, the reference surface, the prior and the per-frame optimisation (a
    `inverse.sft.sequential.FrameFit`, without the outline term).

    initial: per-frame initial guesses of the vertices [m] (n, 3) (e.g. the baseline's) that
    each frame's field is first fitted to, or None."""

    def __init__(
        self,
        template: Template,
        *,
        pinned: np.ndarray | None = None,
        initial: Sequence[np.ndarray] | None = None,
        config: ReconstructionConfig | None = None,
    ):
        self.config = cfg = config or ReconstructionConfig()
        self.weights = DataWeights(cfg.huber_px, cfg.temporal_weight, cfg.silhouette_weight)
        self.template = template
        self.initial = initial
        self.surface = MeshSurface(template.vertices, template.faces, template.uvs,
                                   name="template")
        tri = template.vertices[template.faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        self.area = float(area.sum())
        self.mean_edge = mean_edge_length(template.vertices, template.faces)
        self.field = NeuralField(
            FieldConfig(width=cfg.width, hidden_layers=cfg.hidden_layers, omega0=cfg.omega0,
                        domain=self.surface.domain.bounds,
                        output_scale=cfg.output_scale * math.sqrt(self.area)),
            seed=cfg.seed,
        )
        # A zero output layer makes u ≡ 0 (the template) before the first frame is fitted.
        for p in self.field.output_layer():
            p.zero_()
        self.ftype = self.field.dtype
        material = preset(cfg.material)
        self.prior = Objective(ShellEnergyTerm(material, Loads()))
        self.energy_reference = 0.5 * material.bending_stiffness
        conditions = None
        if pinned is not None and len(pinned):
            points = [PinnedPoint(xi=tuple(float(c) for c in template.uvs[i])) for i in pinned]
            conditions = BoundaryConditions(points, self.surface.domain)
        self.operator = DisplacementOperator(self.field, conditions)
        self.vertex_xi = torch.from_numpy(template.uvs).to(self.ftype)
        self.rest = torch.from_numpy(template.vertices)
        self.generator = torch.Generator().manual_seed(cfg.seed)

    # -- field evaluation ------------------------------------------------------------------

    def vertices(self) -> np.ndarray:
        """Current surface at the template vertices [m], shape (n, 3), template order."""
        u = self.operator.jets(self.vertex_xi)[:, jets.VALUE].double()
        return (self.rest + u).numpy()

    # -- one frame ---------------------------------------------------------------------------

    def fit_frame(self, frame: FrameData) -> FittedFrame:
        """One frame's vertices, its final loss terms (at the last step) and Adam steps."""
        cfg = self.config
        if self.initial is not None and cfg.init_steps:
            self._fit_to(self.initial[frame.index])
        track_xi = frame.track_xi.to(self.ftype)
        n_tracks, n_vertices = len(track_xi), len(self.vertex_xi)
        # Adam follows the gradient of the value it computes: the interpolant's own slope.
        data = frame.data_term(torch.arange(n_tracks),
                               torch.arange(n_tracks, n_tracks + n_vertices), slope="interpolant")
        lam = cfg.physics_weight / self.energy_reference

        optimiser = Adam(self.field.parameters, self.field.gradients, config=AdamConfig(
            lr=cfg.lr, schedule="cosine", total_steps=cfg.steps, min_lr=cfg.min_lr))
        parts: dict[str, float] = {}
        for step in range(cfg.steps):
            samples = sample_surface(self.surface, cfg.energy_samples, generator=self.generator,
                                     dtype=self.ftype)
            n_energy = len(samples)
            xi = torch.cat([samples.xi, track_xi, self.vertex_xi])
            u_jets = self.operator.jets(xi)
            grad = torch.zeros_like(u_jets, dtype=torch.float64)

            at_data = u_jets[n_energy:].double()
            _, grad[n_energy:] = data.evaluate(None, at_data)
            if step == cfg.steps - 1:
                parts = data.parts(at_data)
            if lam > 0:
                result = self.prior.evaluate(samples, u_jets[:n_energy])
                grad[:n_energy] = lam * result.grad_u_jets.double()
                parts["energy"] = result.internal / self.energy_reference
            self.operator.backward(grad)
            optimiser.step()
        return FittedFrame(self.vertices(), parts, cfg.steps)

    def _fit_to(self, target: np.ndarray) -> None:
        """Fit u at the template vertices to target − template (least squares, Adam)."""
        cfg = self.config
        goal = torch.from_numpy(np.asarray(target) - self.template.vertices)
        optimiser = Adam(self.field.parameters, self.field.gradients, config=AdamConfig(
            lr=cfg.lr, schedule="cosine", total_steps=cfg.init_steps, min_lr=cfg.min_lr))
        for _ in range(cfg.init_steps):
            u_jets = self.operator.jets(self.vertex_xi)
            grad = torch.zeros_like(u_jets, dtype=torch.float64)
            difference = u_jets[:, jets.VALUE].double() - goal
            grad[:, jets.VALUE] = 2.0 * difference / (len(goal) * self.mean_edge**2)
            self.operator.backward(grad)
            optimiser.step()


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
one is read. Pinned vertices are exact: u = φ N with ``PinnedPoint`` conditions at their UVs.
Gradients: the data terms (`inverse.sft.data_terms`) by torch autograd with respect to u at
their points, the prior by the objective's ``ShellEnergyTerm``; both enter the displacement
operator's ``backward`` in one batch of jets.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.data_terms import (
    DataTerms,
    MotionTerm,
    ReprojectionTerm,
    SilhouetteTerm,
    silhouette_distance,
)
from inverse.sft.inputs import Camera, Template, mean_edge_length
from inverse.sft.settings import ReconstructionConfig
from taichi_ndf import jets, progress
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import PinnedPoint
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.geometry import MeshSurface
from taichi_ndf.loads import Loads
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.operator import DisplacementOperator
from taichi_ndf.optim import Adam, AdamConfig
from taichi_ndf.sampling import sample_surface
from taichi_ndf.shell.materials import preset

log = logging.getLogger(__name__)


@dataclass
class ReconstructionResult:
    """Vertices per frame [m] (n, 3), template order; seconds per frame; final loss terms."""

    vertices: list[np.ndarray]
    seconds: list[float]
    losses: list[dict[str, float]] = field(default_factory=list)


class FieldReconstructor:
    """Holds the field, the reference surface, the prior and the per-frame optimisation."""

    def __init__(
        self,
        template: Template,
        camera: Camera,
        *,
        pinned: np.ndarray | None = None,
        config: ReconstructionConfig | None = None,
    ):
        self.config = cfg = config or ReconstructionConfig()
        self.template = template
        self.camera = camera
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

    def fit_frame(
        self,
        correspondences: FrameCorrespondences,
        history: Sequence[np.ndarray],
        *,
        mask: np.ndarray | None = None,
        initial: np.ndarray | None = None,
    ) -> tuple[np.ndarray, dict[str, float]]:
        """Vertices [m] (n, 3) of one frame and its final loss terms.

        history: the previous one or two frames' vertices (latest last), for the motion term;
        initial: an initial guess of this frame's vertices (e.g. the baseline's), or None.
        """
        cfg = self.config
        if initial is not None and cfg.init_steps:
            self._fit_to(initial)
        faces = self.template.faces[correspondences.face]
        bary = torch.from_numpy(correspondences.bary)
        track_xi = (bary[:, :, None] * torch.from_numpy(self.template.uvs[faces])).sum(1)
        track_rest = (bary[:, :, None] * self.rest[torch.from_numpy(faces)]).sum(1)
        previous = torch.from_numpy(history[-1])
        before = torch.from_numpy(history[-2]) if len(history) > 1 else previous
        n_tracks = len(track_xi)
        tracks, vertices = slice(0, n_tracks), slice(n_tracks, None)
        terms = [
            ("reprojection", ReprojectionTerm(
                track_rest, torch.from_numpy(correspondences.xy),
                torch.from_numpy(correspondences.confidence), self.camera, cfg.huber_px),
             1.0, tracks),
            ("motion", MotionTerm(self.rest, 2.0 * previous - before, self.mean_edge),
             cfg.temporal_weight, vertices)]
        if mask is not None and cfg.silhouette_weight > 0:
            terms.append(("silhouette",
                          SilhouetteTerm(self.rest, silhouette_distance(mask), self.camera),
                          cfg.silhouette_weight, vertices))
        data = DataTerms(terms)
        lam = cfg.physics_weight / self.energy_reference

        optimiser = Adam(self.field.parameters, self.field.gradients, config=AdamConfig(
            lr=cfg.lr, schedule="cosine", total_steps=cfg.steps, min_lr=cfg.min_lr))
        parts: dict[str, float] = {}
        for _ in range(cfg.steps):
            samples = sample_surface(self.surface, cfg.energy_samples, generator=self.generator,
                                     dtype=self.ftype)
            n_energy = len(samples)
            xi = torch.cat([samples.xi, track_xi.to(self.ftype), self.vertex_xi])
            u_jets = self.operator.jets(xi)
            grad = torch.zeros_like(u_jets, dtype=torch.float64)

            _, grad[n_energy:, jets.VALUE], parts = data.evaluate(
                u_jets[n_energy:, jets.VALUE].double())
            if lam > 0:
                result = self.prior.evaluate(samples, u_jets[:n_energy])
                grad[:n_energy] = lam * result.grad_u_jets.double()
                parts["energy"] = result.internal / self.energy_reference
            self.operator.backward(grad)
            optimiser.step()
        return self.vertices(), parts

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


def reconstruct(
    template: Template,
    camera: Camera,
    correspondences: Sequence[FrameCorrespondences],
    *,
    masks: Sequence[np.ndarray] | None = None,
    pinned: np.ndarray | None = None,
    initial: Sequence[np.ndarray] | None = None,
    config: ReconstructionConfig | None = None,
) -> ReconstructionResult:
    """Vertices for every frame (frame 0 = template), fitted frame by frame with warm starts.

    masks: per-frame silhouettes (bool (h, w)) or None; pinned: vertex indices held at their
    template positions; initial: per-frame initial guesses (e.g. the baseline's vertices).
    """
    solver = FieldReconstructor(template, camera, pinned=pinned, config=config)
    vertices = [template.vertices.copy()]
    seconds, losses = [0.0], [{}]
    for i in progress.counted(range(1, len(correspondences)), "SfT reconstruction, frames"):
        start = time.perf_counter()
        fitted, terms = solver.fit_frame(
            correspondences[i], vertices[-2:],
            mask=None if masks is None else masks[i],
            initial=None if initial is None else initial[i],
        )
        seconds.append(time.perf_counter() - start)
        vertices.append(fitted)
        losses.append(terms)
        log.debug("frame %d: %.2f s, %s", i, seconds[-1], terms)
    log.info("reconstruction: %d frames, %.2f s per frame", len(vertices),
             np.mean(seconds[1:]) if len(seconds) > 1 else 0.0)
    return ReconstructionResult(vertices=vertices, seconds=seconds, losses=losses)

"""Per-frame baseline reconstruction: reprojection least squares + inextensibility + smoothness.

No physics: the classic template-based baseline, used to initialise the physics-regularised
reconstruction and as the reference it has to beat. For frame t > 0 the vertices V (n, 3) [m,
camera coordinates] minimise, warm-started from frame t − 1,

    E(V) = Σ_i c_i ρ(‖π(P_i(V)) − x_i‖) / Σ_i c_i                       reprojection [px²]
         + w_inext · mean_edges ((ℓ_e(V) − L_e) / L_e)²                 inextensibility
         + w_smooth · mean_vertices ‖(Δ(V − V_{t−1}))_v‖² / h²          smooth motion

with P_i = Σ_k bary_ik V[faces[face_i, k]] the tracked surface points, π the pinhole projection,
x_i [px] the tracked pixels, c_i their confidences, ρ the Huber penalty (r² up to ``huber_px``,
then linear), L_e the template's edge lengths, Δ the uniform graph Laplacian (vertex minus the
mean of its neighbours) and h the template's mean edge length. The inextensibility term fixes the
monocular depth/scale ambiguity; the smoothness term propagates motion into parts without
tracks (occluded or textureless) and damps noise. Pinned vertices stay at their template
positions. Frame 0 is the template itself (the input contract gives it for frame 0).

Solver: Levenberg–Marquardt on the Gauss–Newton normal equations (Huber by iteratively
reweighted least squares), assembled from analytic per-residual Jacobian blocks and solved
densely (torch Cholesky). Dense normal equations cost 72 n² bytes (n = 1000 vertices: 72 MB), so
templates are limited to ``MAX_VERTICES``; a few iterations converge where first-order methods
(L-BFGS) still crawl along the soft bending modes after hundreds.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.inputs import Camera, Template, mean_edge_length, mesh_edges
from taichi_ndf import progress

log = logging.getLogger(__name__)

MAX_VERTICES = 5000
# Depth [m] below which projected points are clamped.
MIN_DEPTH = 1e-9


@dataclass(frozen=True)
class BaselineConfig:
    """Weights and solver settings of the baseline.

    inextensibility_weight: w_inext, in px² per unit mean squared relative edge-length change
    (1e4: a 1 % stretch of every edge costs as much as 1 px of reprojection error everywhere);
    smoothness_weight: w_smooth, px² per unit mean squared Laplacian of the frame-to-frame
    motion measured in mean edge lengths; huber_px: reprojection error [px] beyond which the
    penalty grows linearly; max_iterations: Levenberg–Marquardt iterations per frame;
    tolerance: stop when an accepted step lowers E by less than this fraction.
    """

    inextensibility_weight: float = 1e4
    smoothness_weight: float = 30.0
    huber_px: float = 2.0
    max_iterations: int = 30
    tolerance: float = 1e-4

    def __post_init__(self):
        for name in ("inextensibility_weight", "smoothness_weight"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.huber_px <= 0:
            raise ValueError(f"huber_px must be positive, got {self.huber_px}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if self.tolerance <= 0:
            raise ValueError(f"tolerance must be positive, got {self.tolerance}")


@dataclass(frozen=True)
class BaselineResult:
    """Reconstructed vertices per frame [m] (n, 3), solver iterations and seconds per frame."""

    vertices: list[np.ndarray]
    iterations: list[int]
    seconds: list[float]


def uniform_laplacian(n: int, edges: np.ndarray) -> np.ndarray:
    """Dense uniform graph Laplacian Δ = I − D⁻¹A of a mesh with n vertices, shape (n, n)."""
    adjacency = np.zeros((n, n))
    adjacency[edges[:, 0], edges[:, 1]] = 1.0
    adjacency[edges[:, 1], edges[:, 0]] = 1.0
    degree = adjacency.sum(axis=1)
    return np.eye(n) - adjacency / np.maximum(degree, 1.0)[:, None]


class BaselineReconstructor:
    """Fits one frame at a time; holds the template's edges, rest lengths and smoothness term."""

    def __init__(
        self,
        template: Template,
        camera: Camera,
        *,
        pinned: np.ndarray | None = None,
        config: BaselineConfig | None = None,
    ):
        n = len(template.vertices)
        if n > MAX_VERTICES:
            raise ValueError(
                f"baseline: template has {n} vertices, more than MAX_VERTICES = {MAX_VERTICES} "
                "that the dense normal equations allow; decimate the template"
            )
        self.template = template
        self.camera = camera
        self.config = config or BaselineConfig()
        self.edges = mesh_edges(template.faces)
        rest = template.vertices[self.edges[:, 0]] - template.vertices[self.edges[:, 1]]
        self.rest_length = np.linalg.norm(rest, axis=1)
        mean_edge = mean_edge_length(template.vertices, template.faces)
        laplacian = uniform_laplacian(n, self.edges)
        # E_smooth = w/(n h²) Σ_v |Δ(V − V_prev)|_v² is quadratic: its Hessian (halved) is fixed.
        block = self.config.smoothness_weight / (n * mean_edge**2) * (laplacian.T @ laplacian)
        self.smooth_hessian = np.kron(block, np.eye(3))
        free = np.ones(n, bool)
        if pinned is not None and len(pinned):
            free[np.asarray(pinned)] = False
        self.free_dofs = np.nonzero(np.repeat(free, 3))[0]
        self.pinned = ~free

    def energy(
        self, vertices: np.ndarray, correspondences: FrameCorrespondences, previous: np.ndarray
    ) -> float:
        """E(V) of the module docstring [px²]."""
        residual, weight, huber = self._reprojection(vertices, correspondences)[:3]
        r = np.linalg.norm(residual, axis=1)
        delta = self.config.huber_px
        rho = np.where(huber, 2.0 * delta * r - delta**2, r**2)
        strain = self._strain(vertices)[0]
        motion = (vertices - previous).reshape(-1)
        return float(
            (weight * rho).sum()
            + self.config.inextensibility_weight * (strain**2).mean()
            + motion @ self.smooth_hessian @ motion
        )

    def normal_equations(
        self, vertices: np.ndarray, correspondences: FrameCorrespondences, previous: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Gauss–Newton H (3n, 3n) and gradient g (3n,), both halved: ∇E = 2 g, ∇²E ≈ 2 H.

        Huber is linearised by IRLS: residuals beyond huber_px get weight huber_px / |r|.
        """
        size = 3 * len(vertices)
        residual, weight, huber, jac, dofs = self._reprojection(vertices, correspondences)
        r = np.linalg.norm(residual, axis=1)
        weight = weight * np.where(huber, self.config.huber_px / np.maximum(r, 1e-300), 1.0)
        blocks = [(jac, residual, weight, dofs)]
        strain, strain_jac, strain_dofs = self._strain(vertices)
        w_inext = self.config.inextensibility_weight / len(strain)
        blocks.append((strain_jac, strain[:, None], np.full(len(strain), w_inext), strain_dofs))

        hessian = self.smooth_hessian.copy()
        gradient = self.smooth_hessian @ (vertices - previous).reshape(-1)
        for jac_b, res_b, w_b, dofs_b in blocks:
            # jac_b (m, rows, k), res_b (m, rows), w_b (m,), dofs_b (m, k)
            jtj = np.einsum("m,mri,mrj->mij", w_b, jac_b, jac_b)
            jtr = np.einsum("m,mri,mr->mi", w_b, jac_b, res_b)
            flat = (dofs_b[:, :, None] * size + dofs_b[:, None, :]).reshape(-1)
            hessian += np.bincount(flat, jtj.reshape(-1), minlength=size * size).reshape(size, size)
            gradient += np.bincount(dofs_b.reshape(-1), jtr.reshape(-1), minlength=size)
        return hessian, gradient

    def fit(
        self, correspondences: FrameCorrespondences, initial: np.ndarray, previous: np.ndarray
    ) -> tuple[np.ndarray, int]:
        """Vertices [m] (n, 3) of one frame, started at ``initial``; and the iterations used.

        previous: the previous frame's vertices, the reference of the smoothness term.
        """
        cfg = self.config
        x = np.array(initial, dtype=np.float64)
        x[self.pinned] = self.template.vertices[self.pinned]
        energy = self.energy(x, correspondences, previous)
        damping = 1e-4
        free = torch.from_numpy(self.free_dofs)
        iterations = 0
        while iterations < cfg.max_iterations:
            iterations += 1
            hessian, gradient = self.normal_equations(x, correspondences, previous)
            h = torch.from_numpy(hessian)[free][:, free]
            g = torch.from_numpy(gradient)[free]
            diagonal = torch.diagonal(h).clone()
            while True:
                step = np.zeros(x.size)
                step[self.free_dofs] = -_solve_spd(h + torch.diag(damping * diagonal), g)
                candidate = x + step.reshape(x.shape)
                new_energy = self.energy(candidate, correspondences, previous)
                if new_energy <= energy or damping > 1e8:
                    break
                damping *= 10.0
            if new_energy > energy:
                break
            decrease = energy - new_energy
            x, energy = candidate, new_energy
            damping = max(damping / 10.0, 1e-9)
            if decrease <= cfg.tolerance * max(energy, 1e-300):
                break
        return x, iterations

    def _reprojection(self, vertices: np.ndarray, corr: FrameCorrespondences):
        """Residuals (m, 2) [px], normalised confidences (m,), beyond-Huber flags (m,),
        Jacobian blocks (m, 2, 9) and their dofs (m, 9)."""
        corners = self.template.faces[corr.face]  # (m, 3)
        points = np.einsum("mk,mkd->md", corr.bary, vertices[corners])
        projected = self.camera.project(points, min_depth=MIN_DEPTH)
        residual = projected - corr.xy
        weight = corr.confidence / max(corr.confidence.sum(), 1e-300)
        huber = np.linalg.norm(residual, axis=1) > self.config.huber_px
        d_proj = self.camera.projection_jacobian(points, min_depth=MIN_DEPTH)
        jac = (d_proj[:, :, None, :] * corr.bary[:, None, :, None]).reshape(-1, 2, 9)
        dofs = (3 * corners[:, :, None] + np.arange(3)).reshape(-1, 9)
        return residual, weight, huber, jac, dofs

    def _strain(self, vertices: np.ndarray):
        """Relative edge-length changes (e,), their Jacobian blocks (e, 1, 6) and dofs (e, 6)."""
        a, b = self.edges[:, 0], self.edges[:, 1]
        d = vertices[a] - vertices[b]
        length = np.linalg.norm(d, axis=1)
        strain = (length - self.rest_length) / self.rest_length
        unit = d / (np.maximum(length, 1e-300) * self.rest_length)[:, None]
        jac = np.concatenate([unit, -unit], axis=1)[:, None, :]
        dofs = np.concatenate([3 * a[:, None] + np.arange(3), 3 * b[:, None] + np.arange(3)], 1)
        return strain, jac, dofs


def _solve_spd(matrix: torch.Tensor, rhs: torch.Tensor) -> np.ndarray:
    """Solve a symmetric positive definite system by Cholesky (LU if it is not quite SPD)."""
    factor, info = torch.linalg.cholesky_ex(matrix)
    if int(info) == 0:
        return torch.cholesky_solve(rhs[:, None], factor)[:, 0].numpy()
    return torch.linalg.solve(matrix, rhs).numpy()


def reconstruct_baseline(
    template: Template,
    camera: Camera,
    correspondences: Sequence[FrameCorrespondences],
    *,
    pinned: np.ndarray | None = None,
    config: BaselineConfig | None = None,
) -> BaselineResult:
    """Baseline vertices for every frame (frame 0 = template), warm-started frame to frame."""
    solver = BaselineReconstructor(template, camera, pinned=pinned, config=config)
    vertices = [template.vertices.copy()]
    iterations, seconds = [0], [0.0]
    for i in progress.counted(range(1, len(correspondences)), "SfT baseline, frames"):
        start = time.perf_counter()
        fitted, n_iter = solver.fit(correspondences[i], vertices[-1], vertices[-1])
        seconds.append(time.perf_counter() - start)
        vertices.append(fitted)
        iterations.append(n_iter)
        log.debug("frame %d: %d L-BFGS iterations, %.2f s", i, n_iter, seconds[-1])
    log.info(
        "baseline: %d frames, %.2f s per frame, %.0f iterations per frame",
        len(vertices), np.mean(seconds[1:]) if len(seconds) > 1 else 0.0,
        np.mean(iterations[1:]) if len(iterations) > 1 else 0.0,
    )
    return BaselineResult(vertices=vertices, iterations=iterations, seconds=seconds)

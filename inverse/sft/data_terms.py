"""The data terms of the physics-regularised SfT fit (`inverse.sft.reconstruct`): robust
reprojection of tracked points, smooth motion and silhouette of the template vertices.

Each term is a function of the displacement u (n, 3) [m] at its own points (tracked surface
points or template vertices), differentiable with torch autograd; `DataTerms` sums them with
their weights on their rows of one batch of displacements and gives the value and its gradient
with respect to those displacements (what the displacement operator's backward takes, in the
jets' value channel). The shell prior is the objective's `ShellEnergyTerm`
(`taichi_ndf.objective`).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from inverse.sft.camera import Camera

# Depth [m] below which projected points are clamped (a bad step must not divide by ~0).
MIN_DEPTH = 1e-6


class ReprojectionTerm:
    """Σ_i c_i ρ(‖π(X_i + u_i) − p_i‖) / Σ_i c_i [px²]: X_i (n, 3) [m] the tracked points on the
    template, p_i (n, 2) [px] where they are seen, c_i (n,) their confidences, ρ the Huber
    penalty (quadratic up to huber_px [px])."""

    def __init__(self, rest: torch.Tensor, target: torch.Tensor, confidence: torch.Tensor,
                 camera: Camera, huber_px: float):
        self.rest = rest
        self.target = target
        self.weight = confidence / confidence.sum().clamp_min(1e-300)
        self.camera = camera
        self.huber_px = huber_px

    def value(self, u: torch.Tensor) -> torch.Tensor:
        residual = self.camera.project(self.rest + u, min_depth=MIN_DEPTH) - self.target
        return (self.weight * huber(residual, self.huber_px)).sum()


class MotionTerm:
    """mean_v ‖X_v + u_v − x̂_v‖² / h² (dimensionless): the vertices' distance to their
    predicted positions x̂ (n, 3) [m] (constant velocity from the previous frames), in mean
    edge lengths h [m]."""

    def __init__(self, rest: torch.Tensor, predicted: torch.Tensor, mean_edge: float):
        self.rest = rest
        self.predicted = predicted
        self.mean_edge = mean_edge

    def value(self, u: torch.Tensor) -> torch.Tensor:
        return ((self.rest + u - self.predicted) ** 2).sum(1).mean() / self.mean_edge**2


class SilhouetteTerm:
    """mean_v D(π(X_v + u_v))² [px²]: D the distance [px] outside the silhouette (0 inside),
    `silhouette_residual` of the `silhouette_distance` image (h, w)."""

    def __init__(self, rest: torch.Tensor, distance: torch.Tensor, camera: Camera):
        self.rest = rest
        self.distance = distance
        self.camera = camera

    def value(self, u: torch.Tensor) -> torch.Tensor:
        pixels = self.camera.project(self.rest + u, min_depth=MIN_DEPTH)
        return (silhouette_residual(self.distance, pixels) ** 2).mean()


class DataTerms:
    """Σ_k w_k T_k(u[rows_k]) over named terms, each on its rows of the displacements.

    terms: (name, term, weight, rows) with rows a slice of the batch."""

    def __init__(self, terms: list[tuple[str, object, float, slice]]):
        self.terms = terms

    def evaluate(self, u: torch.Tensor) -> tuple[float, torch.Tensor, dict[str, float]]:
        """The weighted sum [px²] at displacements u (m, 3) [m] (float64), its gradient (m, 3)
        and each term's unweighted value."""
        u = u.detach().requires_grad_(True)
        loss = None
        parts = {}
        for name, term, weight, rows in self.terms:
            value = term.value(u[rows])
            parts[name] = value.item()
            weighted = weight * value  # exact for weight 1
            loss = weighted if loss is None else loss + weighted
        (grad,) = torch.autograd.grad(loss, u)
        return loss.item(), grad, parts


def huber(residual: torch.Tensor, delta: float) -> torch.Tensor:
    """Huber penalty (n,) [px²] of residuals (n, 2) [px]: r² up to δ, 2δr − δ² beyond."""
    r = torch.sqrt((residual**2).sum(dim=1) + 1e-24)
    return torch.where(r <= delta, r**2, 2.0 * delta * r - delta**2)


def bilinear_differentiable(image: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """Bilinear samples (n,) of an (h, w) image at pixels xy (n, 2), clamped to the image;
    differentiable in xy (torch; `inverse.sft.image.bilinear` samples numpy images fast)."""
    h, w = image.shape
    x = xy[:, 0].clamp(0, w - 1.001)
    y = xy[:, 1].clamp(0, h - 1.001)
    x0, y0 = x.detach().floor().long(), y.detach().floor().long()
    fx, fy = x - x0, y - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx
    bottom = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def silhouette_distance(mask: np.ndarray) -> torch.Tensor:
    """Signed distance [px] of every pixel centre to the silhouette's outline, float64 (h, w):
    positive outside the mask, negative on it. The outline runs half-way between the centres of
    mask and non-mask pixels (centres at integer coordinates, as the renderer's; a mask pixel
    is one at least half covered), so a point on the true outline samples ≈ 0 bilinearly.
    (The distance to the nearest mask pixel centre, 0 on the mask, samples ≈ 0.5 px there: it
    charged every outline vertex of the true surface and pulled the outline inwards.)"""
    mask = np.asarray(mask, dtype=bool)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return torch.from_numpy(np.where(mask, 0.5 - inside, outside - 0.5).astype(np.float64))


def silhouette_residual(distance: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """Distance [px] (n,) of pixels xy (n, 2) outside the silhouette (0 inside): the
    `silhouette_distance` image sampled bilinearly, clamped at 0 (differentiable)."""
    return bilinear_differentiable(distance, xy).clamp_min(0.0)

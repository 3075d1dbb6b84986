"""The mask as a signed distance image, sampled differentiably at projected points: what the
silhouette and outline terms of `inverse.sft.least_squares` and the outline allowance of
`inverse.sft.outline` measure, and the silhouette's own allowance from frame 0."""

from __future__ import annotations

import cv2
import numpy as np
import torch


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


def silhouette_residual(distance: torch.Tensor, xy: torch.Tensor,
                        allowance: torch.Tensor | None = None) -> torch.Tensor:
    """Distance [px] (n,) of pixels xy (n, 2) outside the silhouette (0 inside): the
    `silhouette_distance` image sampled bilinearly, less `allowance` (n,) [px] ≥ 0 where given,
    clamped at 0 (differentiable)."""
    d = bilinear_differentiable(distance, xy)
    return (d if allowance is None else d - allowance).clamp_min(0.0)


def silhouette_allowance(distance: torch.Tensor, xy: np.ndarray, rows: np.ndarray
                         ) -> np.ndarray:
    """(n,) [px]: how far outside the silhouette of frame 0 (`distance` D₀ (h, w): frame 0's
    mask as its `silhouette_distance`) the points at pixels xy (n, 2) of frame 0 lie,
    max(0, D₀), at the points selected by `rows` (bool (n,): the template's border vertices);
    0 elsewhere. Frame 0 is the template, right by construction: where its outline lies
    outside the mask, the mask and the template disagree there, and the silhouette term
    tolerates that much (`least_squares`)."""
    depth = bilinear_differentiable(distance, torch.from_numpy(
        np.asarray(xy, dtype=np.float64))).numpy()
    return np.where(rows, np.maximum(depth, 0.0), 0.0)


def faded_allowance(allowance: np.ndarray, first: np.ndarray, previous: np.ndarray,
                    fade_px: float) -> np.ndarray:
    """(n,) [px]: a `silhouette_allowance` (n,) faded as each vertex moves away from where
    frame 0 saw it, a_v · max(0, 1 − ‖p_v − p_v⁰‖ / fade_px) with p_v⁰ its pixel in frame 0
    (`first` (n, 2)) and p_v in the previous frame (`previous` (n, 2)): the allowance measures
    where the mask and the template disagree in frame 0's pose, so a vertex that has moved
    `fade_px` [px] or more keeps none (an unobserved corner drifting out is not tolerated)."""
    moved = np.linalg.norm(np.asarray(previous) - np.asarray(first), axis=1)
    return np.asarray(allowance) * np.clip(1.0 - moved / fade_px, 0.0, 1.0)

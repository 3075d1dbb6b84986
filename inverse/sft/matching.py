"""Texture ↔ image correspondences of the SfT tracker: SIFT matches of a frame to the
texture, local affine maps between matched point sets, and patch agreement (NCC) under such
a map.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from inverse.sft.image import bilinear, signed_area, to_gray
from inverse.sft.inputs import Camera, Template
from inverse.sft.surface import uv_locator

log = logging.getLogger(__name__)


class TextureMatcher:
    """SIFT features of the texture and their template surface points."""

    def __init__(self, template: Template, texture: np.ndarray, *, ratio: float):
        self.ratio = ratio
        self.sift = cv2.SIFT_create()
        self.matcher = cv2.BFMatcher(cv2.NORM_L2)
        h, w = texture.shape[:2]
        self.chart = uv_locator(template, w, h)
        keypoints, descriptors = self.sift.detectAndCompute(to_gray(texture), None)
        xy = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)
        face, bary = self.chart.locate(xy)
        on_sheet = face >= 0
        self.texture_xy = xy[on_sheet]
        self.face, self.bary = face[on_sheet], bary[on_sheet]
        self.descriptors = descriptors[on_sheet] if descriptors is not None else None
        log.info("texture: %d SIFT features on the template's UV chart", len(self.face))

    def match(self, gray: np.ndarray, region: np.ndarray | None) -> tuple[np.ndarray, ...]:
        """Ratio-test matches of an image to the texture.

        Returns image xy (k, 2), texture xy (k, 2), face (k,), bary (k, 3) of matched features.
        """
        empty = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 3)))
        if self.descriptors is None or len(self.descriptors) < 2:
            return empty
        mask = None if region is None else region.astype(np.uint8) * 255
        keypoints, descriptors = self.sift.detectAndCompute(gray, mask)
        if descriptors is None or len(keypoints) == 0:
            return empty
        pairs = self.matcher.knnMatch(descriptors, self.descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < self.ratio * p[1].distance]
        if not good:
            return empty
        query = np.array([m.queryIdx for m in good])
        train = np.array([m.trainIdx for m in good])
        image_xy = np.array([keypoints[i].pt for i in query], dtype=np.float64)
        return image_xy, self.texture_xy[train], self.face[train], self.bary[train]


def prefiltered_texture(texture: np.ndarray, template: Template, camera: Camera,
                        texture_corners: np.ndarray) -> np.ndarray:
    """Grey float32 texture blurred to roughly the image's resolution (for patch comparison):
    σ from the ratio of the template's texture-pixel area (texture_corners (V, 2)) to its
    projected area in the frame-0 image."""
    projected = camera.project(template.vertices)
    tri_img = projected[template.faces]
    tri_tex = texture_corners[template.faces]
    area_img = np.abs(signed_area(tri_img)).sum()
    area_tex = np.abs(signed_area(tri_tex)).sum()
    scale = np.sqrt(area_tex / max(area_img, 1e-12))
    sigma = max(0.5 * scale, 0.5)
    return cv2.GaussianBlur(to_gray(texture).astype(np.float32), (0, 0), sigma)


def patch_ncc(image_gray: np.ndarray, texture_gray: np.ndarray, image_xy: np.ndarray,
              texture_xy: np.ndarray, jacobian: np.ndarray, radius: int) -> np.ndarray:
    """NCC (n,) between (2 radius + 1)² image patches around image_xy (n, 2) and texture
    patches around texture_xy (n, 2) mapped by the local affine maps' linear parts jacobian
    (n, 2, 2) (d texture / d image); −1 where a patch is flat. texture_gray: float32."""
    r = radius
    offsets = np.stack(np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1)), -1)
    offsets = offsets.reshape(-1, 2).astype(np.float64)
    img_pts = image_xy[:, None, :] + offsets[None]
    tex_pts = texture_xy[:, None, :] + np.einsum("nij,kj->nki", jacobian, offsets)
    a = bilinear(image_gray.astype(np.float32), img_pts)
    b = bilinear(texture_gray, tex_pts)
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    den = np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1))
    return np.where(den > 0, (a * b).sum(axis=1) / np.maximum(den, 1e-12), -1.0)


def pairwise_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (m, n) between 2D points a (m, 2) and b (n, 2): the values of
    ``np.linalg.norm(a[:, None] - b[None], axis=2)`` bit for bit, without its (m, n, 2)
    temporary (4x faster on R1's ~1500 tracks)."""
    dx, dy = a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]
    return np.sqrt(dx * dx + dy * dy)


def local_affine(
    source, target, query, neighbours, radius, *, with_jacobian=False, exclude_self=False
):
    """Predict target positions of query points by affine fits to their nearest source points.

    source, target: matched 2D points (n, 2); query: (m, 2) in source space. Each query uses its
    ``neighbours`` nearest source points, all within ``radius``; with exclude_self the queries
    are the source points themselves and each leaves itself out. Returns predictions (m, 2), a
    validity mask (m,) and, if asked, the affine maps' linear parts (m, 2, 2) (d target / d source).
    """
    m = len(query)
    d = pairwise_distances(query, source)
    if exclude_self:
        np.fill_diagonal(d, np.inf)
    k = min(neighbours, len(source) - int(exclude_self))
    nearest = np.argpartition(d, k - 1, axis=1)[:, :k]
    within = np.take_along_axis(d, nearest, axis=1).max(axis=1) <= radius
    x = source[nearest] - query[:, None, :]
    design = np.concatenate([x, np.ones((m, k, 1))], axis=2)
    normal = np.einsum("mki,mkj->mij", design, design)
    rhs = np.einsum("mki,mkj->mij", design, target[nearest])
    # Collinear neighbours leave the affine map undetermined: compare the smallest eigenvalue
    # of the neighbours' spread with its largest.
    spread = np.linalg.eigvalsh(np.einsum("mki,mkj->mij", x - x.mean(1, keepdims=True),
                                          x - x.mean(1, keepdims=True)))
    well_posed = (k >= 3) & (spread[:, 0] > 1e-3 * np.maximum(spread[:, 1], 1e-300))
    normal[~well_posed] = np.eye(3)
    coef = np.linalg.solve(normal, rhs)  # (m, 3, 2): rows d/dx, d/dy, value at the query
    prediction = coef[:, 2, :]
    ok = within & well_posed
    if with_jacobian:
        return prediction, ok, np.transpose(coef[:, :2, :], (0, 2, 1))
    return prediction, ok

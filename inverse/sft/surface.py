"""Points on the template surface, named by (face, barycentric), found from 2D positions.

A surface point is the triangle ``face`` and barycentric weights ``bary`` (3 numbers summing to
1) of its corners; its 3D position in any frame is ``bary @ vertices[faces[face]]``, so it follows
the mesh whatever the deformation. A :class:`SurfaceLocator` finds the surface point under a 2D
position for a piecewise-linear 2D image of the mesh: the UV chart drawn in texture pixels, or
the mesh projected by the camera (perspective-correct, front-most surface only).
"""

from __future__ import annotations

import numpy as np

from inverse.sft.inputs import Camera, Template
from taichi_ndf.render import rasterize, uv_to_texture_pixels

# A query counts as inside a triangle down to this barycentric value (edges shared by two
# triangles, round-off).
_INSIDE_TOLERANCE = 1e-6


def surface_positions(
    vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray
) -> np.ndarray:
    """3D positions [m], shape (n, 3), of surface points (face (n,), bary (n, 3))."""
    return np.einsum("nk,nkd->nd", bary, vertices[faces[face]])


class SurfaceLocator:
    """Finds (face, barycentric) of 2D query points in a 2D drawing of the mesh.

    corners: 2D position of every vertex in the drawing [px], shape (V, 2); faces: (F, 3);
    face_image: index of the triangle seen at each pixel (-1 for none), shape (H, W), pixel
    centres at integers; depth: per-vertex depth [m], shape (V,), for perspective-correct
    barycentrics of a camera projection, or None for an affine drawing (the UV chart).
    """

    def __init__(
        self,
        corners: np.ndarray,
        faces: np.ndarray,
        face_image: np.ndarray,
        *,
        depth: np.ndarray | None = None,
    ):
        self.corners = np.asarray(corners, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.face_image = face_image
        self.depth = None if depth is None else np.asarray(depth, dtype=np.float64)

    def locate(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Surface points under query positions [px], shape (n, 2).

        Only the triangles seen at the 3x3 pixel centres around a query are tried, so a point on
    a triangle thinner than a pixel that covers none of them (seen edge-on) is not found.
    Returns face (n,) int64, -1 where no triangle contains the point, and barycentrics
        (n, 3) with respect to the face's corners in the order of ``faces``.
        """
        query = np.asarray(query, dtype=np.float64).reshape(-1, 2)
        h, w = self.face_image.shape
        # The triangle seen at the nearest pixel may miss a point near an edge: try the 3x3
        # neighbourhood and keep the triangle that contains the point most clearly.
        cols = np.rint(query[:, 0]).astype(np.int64)[:, None] + np.array([-1, 0, 1] * 3)
        rows = np.rint(query[:, 1]).astype(np.int64)[:, None] + np.repeat([-1, 0, 1], 3)
        on_image = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        candidate = np.where(
            on_image, self.face_image[rows.clip(0, h - 1), cols.clip(0, w - 1)], -1
        )
        screen = _barycentric(self.corners[self.faces[candidate.clip(0)]], query[:, None, :])
        score = np.where(candidate >= 0, screen.min(axis=2), -np.inf)
        best = score.argmax(axis=1)
        n = np.arange(len(query))
        face = np.where(score[n, best] >= -_INSIDE_TOLERANCE, candidate[n, best], -1)
        bary = np.clip(screen[n, best], 0.0, 1.0)
        if self.depth is not None:
            # Screen-space weights are affine in the image; w_k / z_k are affine in 3D.
            bary = bary / self.depth[self.faces[face.clip(0)]]
        bary = bary / bary.sum(axis=1, keepdims=True)
        bary[face < 0] = 0.0
        return face, bary


def uv_locator(template: Template, texture_width: int, texture_height: int) -> SurfaceLocator:
    """Locator for texture pixel positions (x right, y down, texel centres at integers)."""
    corners = uv_to_texture_pixels(template.uvs, texture_width, texture_height)
    # The UV chart drawn as a flat mesh at unit depth through an identity camera.
    flat = np.column_stack([corners, np.ones(len(corners))])
    raster = rasterize(flat, template.faces, np.eye(3), texture_width, texture_height)
    return SurfaceLocator(corners, template.faces, raster.face_id)


def view_locator(vertices: np.ndarray, faces: np.ndarray, camera: Camera) -> SurfaceLocator:
    """Locator for image pixels of the mesh (camera coordinates [m]) seen by the camera.

    Only the front-most surface is found (z-buffer); pixels not covered give face -1.
    """
    raster = rasterize(vertices, faces, camera.K, camera.width, camera.height)
    return SurfaceLocator(camera.project(vertices), faces, raster.face_id, depth=vertices[:, 2])


def _barycentric(tri: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Affine barycentrics of 2D points in 2D triangles; tri (..., 3, 2), point (..., 2)."""
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    v0, v1, v2 = b - a, c - a, point - a
    den = v0[..., 0] * v1[..., 1] - v1[..., 0] * v0[..., 1]
    degenerate = np.abs(den) < 1e-300
    den = np.where(degenerate, 1.0, den)
    l1 = (v2[..., 0] * v1[..., 1] - v1[..., 0] * v2[..., 1]) / den
    l2 = (v0[..., 0] * v2[..., 1] - v2[..., 0] * v0[..., 1]) / den
    bary = np.stack([1.0 - l1 - l2, l1, l2], axis=-1)
    bary[degenerate] = -1.0  # degenerate triangles contain nothing
    return bary

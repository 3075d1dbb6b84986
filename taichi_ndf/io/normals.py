"""Vertex normals of triangle meshes."""

import numpy as np

__all__ = ["vertex_normals"]


def vertex_normals(
    vertices: np.ndarray, faces: np.ndarray, *, canonical: np.ndarray | None = None
) -> np.ndarray:
    """Area-weighted unit vertex normals, shape (V, 3).

    vertices: positions, shape (V, 3); faces: triangles, shape (F, 3) (orientation sets the sign).
    canonical: optional (V,) index of the vertex each vertex coincides with (see
        `taichi_ndf.io.GridMesh`); coinciding vertices share one normal, averaged across a seam.
    Vertices that touch no triangle of non-zero area get a zero vector.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    corners = vertices[faces]
    # The cross product's length is twice the triangle's area: summing it weights by area.
    face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    owner = faces if canonical is None else np.asarray(canonical, dtype=np.int64)[faces]
    summed = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(summed, owner[:, k], face_normal)
    if canonical is not None:
        summed = summed[canonical]
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    return np.divide(summed, length, out=np.zeros_like(summed), where=length > 0)

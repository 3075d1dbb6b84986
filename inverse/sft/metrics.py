"""Accuracy of a reconstructed mesh sequence against ground truth, with a fixed protocol.

The protocol (``PROTOCOL``) is part of every result so numbers are never quoted without it:
- e3D: per frame ‖V − V_gt‖_F / ‖V_gt‖_F over all vertices (camera coordinates, no alignment),
  mean over frames; e3D_procrustes: the same after the similarity transform (scale, rotation,
  translation) that best aligns V to V_gt (Umeyama), per frame.
- chamfer ×1e4: per frame, mean squared distance [m²] from each of N area-uniform surface samples
  of the prediction to the nearest sample of the ground truth, plus the same the other way
  (N fixed, sample positions drawn with a fixed seed), ×1e4, mean over frames.
- normal error: per frame, mean over vertices of the angle [deg] between area-weighted vertex
  normals of prediction and ground truth (same vertex order; orientation from the face winding),
  mean over frames.
- reprojection error: per frame, mean over vertices of the pixel distance between the
  projections of predicted and ground-truth vertices, mean over frames (needs the camera).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from inverse.sft.inputs import Camera
from taichi_ndf import progress
from taichi_ndf.io import vertex_normals

CHAMFER_SAMPLES = 10_000
CHAMFER_SEED = 0
CHAMFER_SCALE = 1e4

PROTOCOL = (
    "e3D = mean over frames of ||V - V_gt||_F / ||V_gt||_F (camera coordinates, no alignment); "
    "e3D_procrustes = same after per-frame similarity Procrustes; "
    f"chamfer x1e4 = mean sq. NN distance [m^2] pred->gt + gt->pred over {CHAMFER_SAMPLES} "
    f"area-uniform surface samples per mesh (seed {CHAMFER_SEED}), x1e4, mean over frames; "
    "normal error = mean angle [deg] between area-weighted vertex normals, mean over vertices "
    "and frames; reprojection = mean pixel distance between projected predicted and true "
    "vertices, mean over vertices and frames"
)


def relative_error(pred: np.ndarray, gt: np.ndarray) -> float:
    """‖pred − gt‖_F / ‖gt‖_F for vertex arrays [m], shape (n, 3)."""
    _check_same_vertices(pred, gt)
    return float(np.linalg.norm(pred - gt) / np.linalg.norm(gt))


def similarity_align(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """pred [m], shape (n, 3), moved by the similarity transform that best fits gt (Umeyama)."""
    _check_same_vertices(pred, gt)
    mu_p, mu_g = pred.mean(axis=0), gt.mean(axis=0)
    p, g = pred - mu_p, gt - mu_g
    u, s, vt = np.linalg.svd(g.T @ p / len(pred))
    d = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[2] = -1.0
    rotation = u @ np.diag(d) @ vt
    scale = float((s * d).sum() / (p**2).sum(axis=1).mean())
    return scale * p @ rotation.T + mu_g


def surface_samples(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    count: int = CHAMFER_SAMPLES,
    seed: int = CHAMFER_SEED,
) -> np.ndarray:
    """count points [m], shape (count, 3), uniform by area on the mesh, deterministic by seed."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    face = rng.choice(len(faces), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    # Square-root warping makes (1 - s, s (1 - r2), s r2) uniform on the triangle.
    s = np.sqrt(r1)
    bary = np.stack([1.0 - s, s * (1.0 - r2), s * r2], axis=1)
    return np.einsum("nk,nkd->nd", bary, tri[face])


def chamfer(
    pred_vertices: np.ndarray,
    pred_faces: np.ndarray,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray,
    *,
    count: int = CHAMFER_SAMPLES,
    seed: int = CHAMFER_SEED,
) -> float:
    """Symmetric chamfer distance [m²] (not scaled): mean sq. NN distance both ways, summed."""
    a = surface_samples(pred_vertices, pred_faces, count=count, seed=seed)
    b = surface_samples(gt_vertices, gt_faces, count=count, seed=seed)
    return float(nearest_sq_distances(a, b).mean() + nearest_sq_distances(b, a).mean())


def nearest_sq_distances(query: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact squared distance from each query (m, 3) to its nearest point (n, 3), shape (m,)
    (a k-d tree, ``scipy.spatial.cKDTree``)."""
    distance, _ = cKDTree(points).query(query, k=1)
    return distance**2


def normal_error_deg(pred: np.ndarray, gt: np.ndarray, faces: np.ndarray) -> float:
    """Mean angle [deg] between vertex normals of pred and gt (same connectivity)."""
    _check_same_vertices(pred, gt)
    cos = np.sum(vertex_normals(pred, faces) * vertex_normals(gt, faces), axis=1)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).mean())


def reprojection_error_px(pred: np.ndarray, gt: np.ndarray, camera: Camera) -> float:
    """Mean pixel distance between the projections of pred and gt vertices (camera frame)."""
    _check_same_vertices(pred, gt)
    return float(np.linalg.norm(camera.project(pred) - camera.project(gt), axis=1).mean())


@dataclass(frozen=True)
class SequenceMetrics:
    """Per-frame errors (arrays of length n_frames) and their means, with the protocol."""

    e3d: np.ndarray
    e3d_procrustes: np.ndarray
    chamfer_x1e4: np.ndarray
    normal_deg: np.ndarray
    reprojection_px: np.ndarray | None
    protocol: str = field(default=PROTOCOL)

    def summary(self) -> dict:
        """Means over frames, the frame count and the protocol, as a JSON-ready dict."""
        out = {
            "frames": int(len(self.e3d)),
            "e3d": float(self.e3d.mean()),
            "e3d_procrustes": float(self.e3d_procrustes.mean()),
            "chamfer_x1e4": float(self.chamfer_x1e4.mean()),
            "normal_deg": float(self.normal_deg.mean()),
            "reprojection_px": (
                None if self.reprojection_px is None else float(self.reprojection_px.mean())
            ),
        }
        out["protocol"] = self.protocol
        return out

    def per_frame(self) -> dict:
        """Per-frame values as JSON-ready lists."""
        out = {
            "e3d": self.e3d.tolist(),
            "e3d_procrustes": self.e3d_procrustes.tolist(),
            "chamfer_x1e4": self.chamfer_x1e4.tolist(),
            "normal_deg": self.normal_deg.tolist(),
        }
        if self.reprojection_px is not None:
            out["reprojection_px"] = self.reprojection_px.tolist()
        return out


def evaluate_sequence(
    pred: Sequence[np.ndarray],
    gt: Sequence[np.ndarray],
    faces: np.ndarray,
    *,
    camera: Camera | None = None,
    gt_faces: np.ndarray | None = None,
) -> SequenceMetrics:
    """Metrics of predicted vertex arrays against ground truth, frame by frame.

    pred, gt: per-frame vertices [m], shape (n, 3) each, same vertex order; faces: (m, 3)
    connectivity of the prediction (and of the ground truth unless gt_faces is given).
    """
    if len(pred) != len(gt) or len(pred) == 0:
        raise ValueError(f"need the same non-zero number of frames, got {len(pred)} and {len(gt)}")
    gt_faces = faces if gt_faces is None else gt_faces
    rows = []
    with progress.stage(f"metrics of {len(pred)} frames", len(pred)):
        for i, (p, g) in enumerate(zip(pred, gt, strict=True)):
            rows.append((
                relative_error(p, g),
                relative_error(similarity_align(p, g), g),
                CHAMFER_SCALE * chamfer(p, faces, g, gt_faces),
                normal_error_deg(p, g, faces),
                reprojection_error_px(p, g, camera) if camera is not None else np.nan,
            ))
            progress.report(i + 1)
    cols = np.array(rows).T
    return SequenceMetrics(
        e3d=cols[0], e3d_procrustes=cols[1], chamfer_x1e4=cols[2], normal_deg=cols[3],
        reprojection_px=cols[4] if camera is not None else None,
    )


def _check_same_vertices(pred: np.ndarray, gt: np.ndarray) -> None:
    if pred.shape != gt.shape:
        raise ValueError(
            f"prediction and ground truth need the same vertex order and count, got shapes "
            f"{pred.shape} and {gt.shape}"
        )

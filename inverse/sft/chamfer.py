"""The field's chamfer protocol against ground-truth point clouds (real captures, e.g. φ-SfT).

Written from its definition (φ-SfT's evaluation, also used by PGSfT, NSfT and Thin-Shell-SfT),
per frame: sample the reconstructed surface uniformly by area with as many points as the
ground-truth cloud has (seeded); chamfer = mean over the samples of the squared distance to the
nearest cloud point + mean over the cloud points of the squared distance to the nearest sample,
in m² (reported ×1e4, i.e. cm²). Quads are split along their 0–2 diagonal. Nearest neighbours
are exact (``scipy.spatial.cKDTree``). Beside it: the largest distance from a reconstructed
vertex to the cloud [m], which shows run-away vertices the mean hides.

Clouds are ``.npy`` arrays (N, 3) or ``.ply`` point clouds (faces, if any, are ignored),
metres, in the reconstruction's coordinates (camera coordinates for ``ndf-sft``).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from inverse.sft.errors import InputError, existing_path
from inverse.sft.metrics import CHAMFER_SCALE, CHAMFER_SEED, nearest_sq_distances, surface_samples
from taichi_ndf import progress

CLOUD_SUFFIXES = (".npy", ".ply")

CLOUD_PROTOCOL = (
    "chamfer x1e4 (field protocol, point-cloud ground truth) = per frame, mean sq. NN distance "
    "[m^2] from as many area-uniform samples of the reconstruction as the cloud has points "
    f"(seed {CHAMFER_SEED}) to the cloud + mean sq. NN distance from the cloud to the samples, "
    "x1e4, mean over frames; max vertex distance = largest distance [m] from a reconstructed "
    "vertex to its nearest cloud point"
)


def triangulated(faces: np.ndarray) -> np.ndarray:
    """Triangles (F, 3) as they are, quads (F, 4) split into (0, 1, 2) and (0, 2, 3)."""
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] not in (3, 4):
        raise ValueError(f"faces must be triangles (F, 3) or quads (F, 4), got {faces.shape}")
    if faces.shape[1] == 3:
        return faces
    return np.concatenate([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]])


def chamfer_to_cloud(
    vertices: np.ndarray, faces: np.ndarray, cloud: np.ndarray, *, seed: int = CHAMFER_SEED
) -> float:
    """The field's chamfer distance [m²] (not scaled) of a surface to a point cloud.

    vertices [m], shape (V, 3); faces: triangles (F, 3) or quads (F, 4); cloud [m], shape
    (N, 3). The surface is sampled with N area-uniform points drawn with `seed`.
    """
    cloud = _checked_cloud(cloud)
    samples = surface_samples(np.asarray(vertices, float), triangulated(faces),
                              count=len(cloud), seed=seed)
    return float(nearest_sq_distances(samples, cloud).mean()
                 + nearest_sq_distances(cloud, samples).mean())


def max_vertex_distance(vertices: np.ndarray, cloud: np.ndarray) -> float:
    """Largest distance [m] from a vertex (V, 3) to its nearest point of the cloud (N, 3)."""
    return float(np.sqrt(nearest_sq_distances(np.asarray(vertices, float),
                                              _checked_cloud(cloud)).max()))


def load_point_cloud(path: str | Path) -> np.ndarray:
    """A ground-truth point cloud [m], shape (N, 3), float64, from ``.npy`` or ``.ply``."""
    path = existing_path(path, "point cloud")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            points = np.load(path, allow_pickle=False)
        elif suffix == ".ply":
            import trimesh

            points = np.asarray(trimesh.load(path, process=False).vertices)
        else:
            raise InputError(f"point cloud {path}: expected {CLOUD_SUFFIXES}")
    except (OSError, ValueError) as err:
        if isinstance(err, InputError):
            raise
        raise InputError(f"point cloud {path}: cannot be read ({err})") from None
    try:
        return _checked_cloud(points)
    except ValueError as err:
        raise InputError(f"point cloud {path}: {err}") from None


def cloud_files(folder: str | Path) -> list[Path]:
    """The ``.npy`` / ``.ply`` files of a folder in frame order (last group of digits of the
    name, else the name); InputError if there are none."""
    folder = existing_path(folder, "point-cloud folder")
    files = [p for p in folder.iterdir() if p.suffix.lower() in CLOUD_SUFFIXES]
    if not files:
        raise InputError(f"{folder}: contains no point clouds {CLOUD_SUFFIXES}")

    def natural(p: Path):
        return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]

    return sorted(files, key=natural)


def is_cloud_folder(folder: str | Path) -> bool:
    """Whether a folder holds point clouds (``.npy`` / ``.ply`` without faces) rather than
    meshes: any ``.npy`` file, or ``.ply`` files whose first one has no faces."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    names = [p for p in folder.iterdir() if p.suffix.lower() in (".npy", ".ply", ".obj")]
    if any(p.suffix.lower() == ".npy" for p in names):
        return True
    plys = sorted(p for p in names if p.suffix.lower() == ".ply")
    return bool(plys) and not any(p.suffix.lower() == ".obj" for p in names) and \
        _ply_face_count(plys[0]) == 0


@dataclass(frozen=True)
class CloudMetrics:
    """Per-frame field chamfer ×1e4 and largest vertex-to-cloud distance [m], with the
    protocol."""

    chamfer_x1e4: np.ndarray
    max_vertex_distance: np.ndarray
    protocol: str = field(default=CLOUD_PROTOCOL)

    def summary(self) -> dict:
        """Mean, worst frame and largest vertex distance, JSON-ready."""
        worst = int(np.argmax(self.chamfer_x1e4))
        return {
            "frames": int(len(self.chamfer_x1e4)),
            "chamfer_x1e4": float(self.chamfer_x1e4.mean()),
            "chamfer_x1e4_worst": float(self.chamfer_x1e4[worst]),
            "worst_frame": worst,
            "max_vertex_distance_m": float(self.max_vertex_distance.max()),
            "max_vertex_distance_frame": int(np.argmax(self.max_vertex_distance)),
            "protocol": self.protocol,
        }

    def per_frame(self) -> dict:
        """Per-frame values as JSON-ready lists."""
        return {"chamfer_x1e4": self.chamfer_x1e4.tolist(),
                "max_vertex_distance_m": self.max_vertex_distance.tolist()}


def evaluate_against_clouds(
    pred: Sequence[np.ndarray], faces: np.ndarray, clouds: Sequence[np.ndarray],
    *, seed: int = CHAMFER_SEED,
) -> CloudMetrics:
    """Field chamfer and largest vertex distance of each frame's vertices (V, 3) [m] with
    `faces` (triangles or quads) against that frame's cloud (N_t, 3) [m]."""
    if len(pred) != len(clouds) or len(pred) == 0:
        raise ValueError(f"need the same non-zero number of frames and clouds, got {len(pred)} "
                         f"and {len(clouds)}")
    rows = []
    with progress.stage(f"chamfer of {len(pred)} frames against their clouds", len(pred)):
        for i, (v, c) in enumerate(zip(pred, clouds, strict=True)):
            rows.append((CHAMFER_SCALE * chamfer_to_cloud(v, faces, c, seed=seed),
                         max_vertex_distance(v, c)))
            progress.report(i + 1)
    cols = np.array(rows).T
    return CloudMetrics(chamfer_x1e4=cols[0], max_vertex_distance=cols[1])


def _checked_cloud(points) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ValueError(f"a point cloud must have shape (N, 3), N > 0, got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("point cloud contains NaN or infinity")
    return points


def _ply_face_count(path: Path) -> int:
    """The face count of a PLY header (0 when it declares no faces)."""
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("ascii", "replace").strip()
            if line.startswith("element face"):
                return int(line.split()[2])
            if line == "end_header":
                return 0
    return 0

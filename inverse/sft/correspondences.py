"""What the SfT tracker hands on: template surface points seen at image pixels, per frame,
the tracker's stage timings, and how far the tracked points leave parts of the sheet
unobserved (`track_gaps`, a per-frame confidence)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class FrameCorrespondences:
    """Template surface points seen at image pixels in one frame.

    face: template triangle, shape (n,), int64; bary: barycentrics in that triangle, (n, 3);
    xy: pixel position (x right, y down, pixel centres at integers), (n, 2); confidence: (n,)
    in (0, 1]; track_id: identity of the track across frames, (n,), int64.
    """

    face: np.ndarray
    bary: np.ndarray
    xy: np.ndarray
    confidence: np.ndarray
    track_id: np.ndarray

    def __len__(self) -> int:
        return len(self.face)


@dataclass
class TrackingTimings:
    """Wall time [s] per frame of the tracker's stages."""

    per_frame: list[float] = field(default_factory=list)
    matching: float = 0.0
    flow: float = 0.0
    seeding: float = 0.0


def track_gaps(vertices: np.ndarray, faces: np.ndarray, seen: FrameCorrespondences,
               mean_edge: float) -> np.ndarray:
    """How far each template vertex lies from the nearest tracked surface point of one frame,
    on the template (3-D distance between template positions), in units of the template's
    mean edge length `mean_edge` [m]; shape (n,). Inf for every vertex when nothing is seen.

    A frame's confidence: where this exceeds the field's knot span (`span_edges`), the fit
    has no image point under that part's own coefficients, so its shape there is the prior's
    continuation of the seen parts, not a measurement (on φ-SfT's R1 the free edge in frames
    34–49, where the reconstruction is up to 48 mm off the cloud; benchmarks/RESULTS.md)."""
    if len(seen) == 0:
        return np.full(len(vertices), np.inf)
    points = np.einsum("nk,nkd->nd", seen.bary, vertices[faces[seen.face]])
    distance, _ = cKDTree(points).query(vertices)
    return distance / mean_edge

"""What the SfT tracker hands on: template surface points seen at image pixels, per frame,
and the tracker's stage timings."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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

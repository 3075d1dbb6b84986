"""Re-found texture points carried forward as tracks: evidence that accumulates over frames.

The guided search (`inverse.sft.guided`) re-finds a lost texture point in frame t by matching
the template's texture, warped by the predicted triangle, near the reconstruction's
prediction. A part of the sheet that turns away foreshortens and blurs, and the texture stops
matching it long before the image stops showing it; the image of frame t − 1 where the point
was seen does still match it (the same blur, nearly the same view). So each re-found point
becomes a track: from the frame where it was accepted it is followed frame to frame by
pyramidal Lucas–Kanade, checked forward–backward, and dropped when the check fails
(fb ≥ `fb_threshold`, the tracker's limit), when it leaves the image or the eroded mask, or
when the sparse tracker holds a point within `gap_edges` mean edges of it on the template (the
same rule that decides which points the guided search looks for). Its confidence in a frame is
exp(−(fb / fb_threshold)²), a sparse track's rule. A point that is carried is not searched
again; one that is dropped may be re-found by the search later. Opt-in
(`GuidedConfig.carry`): on R1 and on the synthetic study it measured worse than re-searching
every frame (benchmarks/RESULTS.md, R1 section, wip-sft6).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.image import eroded, inside, sample_mask, to_gray


@dataclass(frozen=True)
class CarryConfig:
    """Lucas–Kanade window [px] and pyramid levels, forward–backward limit [px], distance kept
    from the mask's outline [px]: the sparse tracker's (`TrackerConfig`) values."""

    lk_window: int = 21
    lk_levels: int = 3
    fb_threshold: float = 0.5
    mask_margin: int = 4

    def __post_init__(self):
        if self.lk_window < 3 or self.lk_levels < 0:
            raise ValueError(f"need lk_window >= 3 and lk_levels >= 0, got {self.lk_window}, "
                             f"{self.lk_levels}")
        if not 0 < self.fb_threshold < np.inf or self.mask_margin < 0:
            raise ValueError("need a finite positive fb_threshold and mask_margin >= 0")


class CarriedTracks:
    """The re-found points followed so far, with the frame index they were last seen in.

    ``advance(t, frames, masks)`` follows them from frame t − 1 into frame t (all are dropped
    when they were not seen in t − 1); ``add(t, found)`` starts tracks at the points accepted
    in frame t; ``current()`` the points of the last frame as correspondences.
    """

    def __init__(self, config: CarryConfig | None = None):
        self.config = config or CarryConfig()
        self.frame = -1
        self.points = _empty()

    def __len__(self) -> int:
        return len(self.points)

    def advance(self, t: int, frames, masks=None) -> None:
        """Follow the carried points from frame t − 1 into frame t (frames: BGR or grey uint8
        images; masks: bool (h, w) per frame or None); drop those that fail."""
        if self.frame != t - 1 or len(self.points) == 0:
            self.points, self.frame = _empty(), t
            return
        cfg = self.config
        before, now = to_gray(frames[t - 1]), to_gray(frames[t])
        params = dict(winSize=(cfg.lk_window, cfg.lk_window), maxLevel=cfg.lk_levels,
                      criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        p0 = self.points.xy.astype(np.float32).reshape(-1, 1, 2)
        p1, ok_f, _ = cv2.calcOpticalFlowPyrLK(before, now, p0, None, **params)
        back, ok_b, _ = cv2.calcOpticalFlowPyrLK(now, before, p1, None, **params)
        p1 = p1.reshape(-1, 2).astype(np.float64)
        fb = np.linalg.norm(back.reshape(-1, 2) - self.points.xy, axis=1)
        keep = (ok_f.ravel() == 1) & (ok_b.ravel() == 1) & (fb < cfg.fb_threshold)
        keep &= inside(p1, now.shape, margin=cfg.lk_window / 2)
        if masks is not None:
            keep &= sample_mask(eroded(masks[t], cfg.mask_margin), p1)
        p = self.points
        self.points = FrameCorrespondences(
            p.face[keep], p.bary[keep], p1[keep],
            np.exp(-((fb[keep] / cfg.fb_threshold) ** 2)), p.track_id[keep])
        self.frame = t

    def drop_near(self, carried_rest: np.ndarray, tracked_rest: np.ndarray,
                  distance: float) -> None:
        """Drop the carried points whose template positions `carried_rest` (m, 3) [m] lie
        within `distance` [m] of a tracked point's `tracked_rest` (k, 3) [m]."""
        if len(self.points) == 0 or len(tracked_rest) == 0:
            return
        gap, _ = cKDTree(tracked_rest).query(carried_rest)
        self._keep(gap > distance)

    def add(self, t: int, found: FrameCorrespondences) -> None:
        """Start tracks at the points `found` in frame t (after `advance(t, ...)`)."""
        if self.frame != t:
            self.points, self.frame = _empty(), t
        fresh = ~np.isin(found.track_id, self.points.track_id)
        self.points = FrameCorrespondences(
            *(np.concatenate([getattr(self.points, name), getattr(found, name)[fresh]])
              for name in ("face", "bary", "xy", "confidence", "track_id")))

    def current(self) -> FrameCorrespondences:
        """The carried points as seen in the last frame."""
        return self.points

    def _keep(self, keep: np.ndarray) -> None:
        p = self.points
        self.points = FrameCorrespondences(p.face[keep], p.bary[keep], p.xy[keep],
                                           p.confidence[keep], p.track_id[keep])


def _empty() -> FrameCorrespondences:
    return FrameCorrespondences(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2)),
                                np.zeros(0), np.zeros(0, np.int64))

"""The parameters of the frame-by-frame tracker (`inverse.sft.tracking`), validated on
construction."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TrackerConfig:
    """Tracking parameters (pixels are image pixels unless stated).

    max_tracks / min_tracks: corners are seeded up to max_tracks when fewer than min_tracks
    remain; min_distance: minimum spacing of tracks [px]; corner_quality: Shi–Tomasi quality
    level; lk_window, lk_levels: Lucas–Kanade window [px] and pyramid levels; fb_threshold:
    forward–backward error limit [px]; rematch_every: frames between texture re-matches (0:
    never); match_ratio: Lowe ratio test; match_tolerance: texture match vs predicted position
    [px]; drift_tolerance: track vs fresh matches [px]; outlier_tolerance: track vs the local
    map of its neighbours [px]; neighbours: tracks in a local affine fit;
    neighbour_radius: farthest neighbour allowed [px]; patch_radius: half size of the NCC patch
    [px]; min_ncc: NCC a seeded corner needs; seed_confidence: base confidence of seeds;
    mask_margin: distance kept from the mask or silhouette boundary [px].
    """

    max_tracks: int = 800
    min_tracks: int = 500
    min_distance: float = 7.0
    corner_quality: float = 0.01
    lk_window: int = 21
    lk_levels: int = 3
    fb_threshold: float = 0.5
    rematch_every: int = 5
    match_ratio: float = 0.75
    match_tolerance: float = 3.0
    drift_tolerance: float = 1.5
    outlier_tolerance: float = 2.0
    neighbours: int = 8
    neighbour_radius: float = 45.0
    patch_radius: int = 6
    min_ncc: float = 0.8
    seed_confidence: float = 0.5
    mask_margin: int = 4

    def __post_init__(self):
        if not 0 < self.min_tracks <= self.max_tracks:
            raise ValueError(
                f"need 0 < min_tracks <= max_tracks, got {self.min_tracks}, {self.max_tracks}"
            )
        for name in ("min_distance", "fb_threshold", "match_tolerance", "drift_tolerance",
                     "outlier_tolerance", "neighbour_radius"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.rematch_every < 0:
            raise ValueError(f"rematch_every must be >= 0, got {self.rematch_every}")
        if not 0 < self.match_ratio < 1:
            raise ValueError(f"match_ratio must be in (0, 1), got {self.match_ratio}")
        if self.neighbours < 3:
            raise ValueError(f"neighbours must be >= 3 for an affine fit, got {self.neighbours}")
        if not 0 < self.seed_confidence <= 1:
            raise ValueError(f"seed_confidence must be in (0, 1], got {self.seed_confidence}")

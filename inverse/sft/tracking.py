"""Correspondences between template surface points and image pixels, frame by frame.

Pipeline (all OpenCV, pixel centres at integer coordinates):
1. Frame 0. SIFT features of the texture are matched to frame 0 (Lowe ratio test); each texture
   keypoint is a template surface point through the UV chart. Because the template is given in
   camera coordinates for frame 0, its projection predicts where each match must be: matches
   farther than ``match_tolerance`` from the prediction are rejected (a geometric check that
   holds for curved templates, where a single homography would not). Shi–Tomasi corners inside
   the template's silhouette are added, their surface points read from the projected template.
2. Every next frame. Pyramidal Lucas–Kanade forward and backward; tracks whose forward–backward
   error exceeds ``fb_threshold`` or that leave the image (or the mask) are dropped.
3. Every ``rematch_every`` frames the frame is matched to the texture again: fresh matches are
   checked against where the current tracks say they should be (local affine map from texture
   to image), existing tracks that disagree with the fresh matches by more than
   ``drift_tolerance`` are dropped as drifted, agreeing ones are marked verified, and fresh
   matches are added as new tracks.
4. When fewer than ``min_tracks`` remain, new corners are seeded: each gets its texture
   position from a local affine fit to neighbouring tracks (image → texture), and is kept only
   if its image patch agrees with the texture there (normalised cross-correlation), which
   rejects corners on the back side of the sheet or on the background.

Per-track confidence in (0, 1]: the track's base (1 for texture matches and template-located
corners, ``seed_confidence`` for seeded corners until a re-match verifies them) times
exp(-(fb / fb_threshold)²) with fb the current frame's forward–backward error [px].
The parameters are `TrackerConfig` (`inverse.sft.tracking_config`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import cv2
import numpy as np

from inverse.sft.correspondences import FrameCorrespondences, TrackingTimings
from inverse.sft.image import contrast_normalised, eroded, inside, sample_mask, to_gray
from inverse.sft.inputs import Camera, Template
from inverse.sft.matching import (
    TextureMatcher,
    local_affine,
    pairwise_distances,
    patch_ncc,
    prefiltered_texture,
)
from inverse.sft.surface import surface_positions, view_locator
from inverse.sft.tracking_config import TrackerConfig
from taichi_ndf import progress
from taichi_ndf.render import uv_to_texture_pixels

log = logging.getLogger(__name__)


class Tracker:
    """Stateful tracker: ``start`` on frame 0, then ``step`` on each next frame.

    template: frame-0 mesh in camera coordinates with UVs; texture: BGR uint8; camera: pinhole.
    """

    def __init__(
        self,
        template: Template,
        texture: np.ndarray,
        camera: Camera,
        *,
        config: TrackerConfig | None = None,
    ):
        self.template = template
        self.camera = camera
        self.config = config or TrackerConfig()
        self.matcher = TextureMatcher(template, texture, ratio=self.config.match_ratio)
        h, w = texture.shape[:2]
        self.texture_corners = uv_to_texture_pixels(template.uvs, w, h)
        self.texture_gray = prefiltered_texture(texture, template, camera, self.texture_corners)
        self.timings = TrackingTimings()
        self._next_id = 0
        self._frame_index = -1
        self._flow_image: np.ndarray | None = None
        self._reset_tracks()

    def start(self, frame: np.ndarray, mask: np.ndarray | None = None) -> FrameCorrespondences:
        """Correspondences in frame 0 (texture registration plus template-located corners)."""
        start = time.perf_counter()
        self._reset_tracks()
        self._frame_index = 0
        gray = to_gray(frame)
        view = view_locator(self.template.vertices, self.template.faces, self.camera)
        silhouette = view.face_image >= 0
        region = self._region(silhouette if mask is None else mask & silhouette)

        # Corners located on the projected template are exact when the template is; they come
        # first, texture matches fill the gaps.
        t0 = time.perf_counter()
        corners = self._new_corners(gray, region, self.config.max_tracks)
        face, bary = view.locate(corners)
        found = face >= 0
        self._add(face[found], bary[found], corners[found], base=1.0)
        self.timings.seeding += time.perf_counter() - t0

        t0 = time.perf_counter()
        image_xy, _, face, bary = self.matcher.match(gray, region)
        predicted = self.camera.project(
            surface_positions(self.template.vertices, self.template.faces, face, bary)
        )
        error = np.linalg.norm(predicted - image_xy, axis=1)
        good = error < self.config.match_tolerance
        if good.sum() < 10:
            raise RuntimeError(
                f"frame 0: only {int(good.sum())} of {len(error)} texture matches agree with the "
                f"projected template within {self.config.match_tolerance} px; is the template in "
                "camera coordinates of frame 0 and the texture the right one?"
            )
        log.info(
            "frame 0: %d of %d texture matches within %.1f px of the projected template "
            "(median %.2f px)", good.sum(), len(error), self.config.match_tolerance,
            np.median(error[good]),
        )
        fresh = good & self._far_from_tracks(image_xy)
        self._add(face[fresh], bary[fresh], image_xy[fresh], base=1.0)
        self.timings.matching += time.perf_counter() - t0

        self._flow_image = contrast_normalised(gray)
        self.timings.per_frame.append(time.perf_counter() - start)
        return self.correspondences()

    def step(self, frame: np.ndarray, mask: np.ndarray | None = None) -> FrameCorrespondences:
        """Track into the next frame, re-match and re-seed as configured."""
        if self._flow_image is None:
            raise RuntimeError("call start() on frame 0 before step()")
        start = time.perf_counter()
        self._frame_index += 1
        gray = to_gray(frame)
        cfg = self.config

        t0 = time.perf_counter()
        flow_image = contrast_normalised(gray)
        self._flow(self._flow_image, flow_image, mask)
        self.timings.flow += time.perf_counter() - t0

        region = self._region(mask if mask is not None else self._track_hull(gray.shape))
        if cfg.rematch_every and self._frame_index % cfg.rematch_every == 0:
            t0 = time.perf_counter()
            self._rematch(gray, region)
            self.timings.matching += time.perf_counter() - t0
        if len(self.face) < cfg.min_tracks:
            t0 = time.perf_counter()
            self._seed(gray, region)
            self.timings.seeding += time.perf_counter() - t0

        self._flow_image = flow_image
        self.timings.per_frame.append(time.perf_counter() - start)
        return self.correspondences()

    def correspondences(self) -> FrameCorrespondences:
        """The current tracks as correspondences (copies)."""
        return FrameCorrespondences(
            face=self.face.copy(), bary=self.bary.copy(), xy=self.xy.copy(),
            confidence=self.base * np.exp(-((self.fb / self.config.fb_threshold) ** 2)),
            track_id=self.track_id.copy(),
        )

    # -- stages ----------------------------------------------------------------------------

    def _flow(self, previous: np.ndarray, current: np.ndarray, mask: np.ndarray | None) -> None:
        if len(self.face) == 0:
            return
        cfg = self.config
        params = dict(
            winSize=(cfg.lk_window, cfg.lk_window), maxLevel=cfg.lk_levels,
            criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
        )
        p0 = self.xy.astype(np.float32).reshape(-1, 1, 2)
        p1, ok_forward, _ = cv2.calcOpticalFlowPyrLK(previous, current, p0, None, **params)
        p0_back, ok_backward, _ = cv2.calcOpticalFlowPyrLK(current, previous, p1, None, **params)
        p1 = p1.reshape(-1, 2).astype(np.float64)
        fb = np.linalg.norm(p0_back.reshape(-1, 2) - self.xy, axis=1)
        keep = (ok_forward.ravel() == 1) & (ok_backward.ravel() == 1) & (fb < cfg.fb_threshold)
        keep &= inside(p1, current.shape, margin=cfg.lk_window / 2)
        if mask is not None:
            keep &= sample_mask(self._region(mask), p1)
        self.xy = p1
        self.fb = fb
        self._keep(keep)
        self._keep(self._separate())
        self._keep(self._consistent())

    def _separate(self) -> np.ndarray:
        """Drop the younger of two tracks that converged to within min_distance / 4.

        Tracks pile up where the sheet turns away from the camera; piled-up tracks carry no
        extra information and often one of them has slid.
        """
        d = pairwise_distances(self.xy, self.xy)
        younger = self.track_id[:, None] > self.track_id[None, :]
        return ~np.any((d < self.config.min_distance / 4) & younger, axis=1)

    def _consistent(self) -> np.ndarray:
        """Tracks whose texture position agrees with their image neighbours' (leave one out).

        A track that slid onto an occluding part of the sheet, or off it, still passes the
        forward–backward check but sits among neighbours showing other texture.
        """
        cfg = self.config
        n = len(self.xy)
        if n <= cfg.neighbours:
            return np.ones(n, bool)
        texture_xy = self._texture_xy()
        predicted, ok, jacobian = local_affine(
            self.xy, texture_xy, self.xy, cfg.neighbours, cfg.neighbour_radius,
            with_jacobian=True, exclude_self=True,
        )
        # Texture residual mapped back to image pixels through the local map.
        det = np.linalg.det(jacobian)
        ok &= np.abs(det) > 1e-9
        jacobian[~ok] = np.eye(2)
        residual = np.linalg.solve(jacobian, (texture_xy - predicted)[..., None])[..., 0]
        bad = ok & (np.linalg.norm(residual, axis=1) > cfg.outlier_tolerance)
        return ~bad

    def _rematch(self, gray: np.ndarray, region: np.ndarray) -> None:
        cfg = self.config
        image_xy, texture_xy, face, bary = self.matcher.match(gray, region)
        if len(image_xy) == 0 or len(self.face) < cfg.neighbours:
            return
        # Fresh matches must agree with where the current tracks put that texture point.
        predicted, ok = local_affine(
            self._texture_xy(), self.xy, texture_xy, cfg.neighbours,
            cfg.neighbour_radius * self._texture_scale(),
        )
        agree = ok & (np.linalg.norm(predicted - image_xy, axis=1) < cfg.match_tolerance)
        image_xy, texture_xy = image_xy[agree], texture_xy[agree]
        face, bary = face[agree], bary[agree]
        if len(image_xy) < cfg.neighbours:
            return
        # Existing tracks must agree with the fresh matches around them: else they drifted.
        check, ok = local_affine(
            texture_xy, image_xy, self._texture_xy(), cfg.neighbours,
            cfg.neighbour_radius * self._texture_scale(),
        )
        distance = np.linalg.norm(check - self.xy, axis=1)
        drifted = ok & (distance > cfg.drift_tolerance)
        self.base = np.where(ok & ~drifted, 1.0, self.base)
        self._keep(~drifted)
        # Fresh matches away from existing tracks become new tracks.
        fresh = self._far_from_tracks(image_xy)
        self._add(face[fresh], bary[fresh], image_xy[fresh], base=1.0)
        log.debug(
            "frame %d: %d texture matches agree, %d drifted tracks dropped, %d added",
            self._frame_index, len(image_xy), int(drifted.sum()), int(fresh.sum()),
        )

    def _seed(self, gray: np.ndarray, region: np.ndarray) -> None:
        cfg = self.config
        if len(self.face) < cfg.neighbours:
            return
        corners = self._new_corners(gray, region, cfg.max_tracks - len(self.face))
        if len(corners) == 0:
            return
        texture_xy, ok, jacobian = local_affine(
            self.xy, self._texture_xy(), corners, cfg.neighbours, cfg.neighbour_radius,
            with_jacobian=True,
        )
        ok &= patch_ncc(gray, self.texture_gray, corners, texture_xy, jacobian,
                         cfg.patch_radius) >= cfg.min_ncc
        face, bary = self.matcher.chart.locate(texture_xy[ok])
        on_sheet = face >= 0
        self._add(face[on_sheet], bary[on_sheet], corners[ok][on_sheet], base=cfg.seed_confidence)
        log.debug("frame %d: seeded %d of %d corners", self._frame_index, on_sheet.sum(),
                  len(corners))

    # -- helpers ---------------------------------------------------------------------------

    def _reset_tracks(self) -> None:
        self.face = np.zeros(0, np.int64)
        self.bary = np.zeros((0, 3))
        self.xy = np.zeros((0, 2))
        self.base = np.zeros(0)
        self.fb = np.zeros(0)
        self.track_id = np.zeros(0, np.int64)

    def _add(self, face, bary, xy, *, base: float) -> None:
        n = len(face)
        self.face = np.concatenate([self.face, face])
        self.bary = np.concatenate([self.bary, bary])
        self.xy = np.concatenate([self.xy, xy])
        self.base = np.concatenate([self.base, np.full(n, base)])
        self.fb = np.concatenate([self.fb, np.zeros(n)])
        self.track_id = np.concatenate([self.track_id, self._next_id + np.arange(n)])
        self._next_id += n

    def _keep(self, keep: np.ndarray) -> None:
        for name in ("face", "bary", "xy", "base", "fb", "track_id"):
            setattr(self, name, getattr(self, name)[keep])

    def _texture_xy(self) -> np.ndarray:
        """Texture pixel position of every track's surface point, shape (n, 2)."""
        corners = self.texture_corners[self.template.faces[self.face]]
        return np.einsum("nk,nkd->nd", self.bary, corners)

    def _texture_scale(self) -> float:
        """Texture pixels per image pixel, estimated from the current tracks."""
        tex, img = self._texture_xy(), self.xy
        if len(tex) < 3:
            return 1.0
        spread = np.sqrt(np.linalg.det(np.cov(tex.T)) / max(np.linalg.det(np.cov(img.T)), 1e-12))
        return float(np.sqrt(spread))

    def _region(self, mask: np.ndarray) -> np.ndarray:
        """Mask shrunk by mask_margin so corners and tracks keep off its boundary."""
        return eroded(mask, self.config.mask_margin)

    def _track_hull(self, shape: tuple[int, int]) -> np.ndarray:
        hull = np.zeros(shape, np.uint8)
        if len(self.xy) >= 3:
            points = cv2.convexHull(np.round(self.xy).astype(np.int32))
            cv2.fillConvexPoly(hull, points, 1)
        return hull > 0

    def _new_corners(self, gray: np.ndarray, region: np.ndarray, count: int) -> np.ndarray:
        """Shi–Tomasi corners (subpixel) in region, at least min_distance from existing tracks."""
        if count <= 0:
            return np.zeros((0, 2))
        free = region.astype(np.uint8)
        radius = int(np.ceil(self.config.min_distance))
        for x, y in np.round(self.xy).astype(int):
            cv2.circle(free, (int(x), int(y)), radius, 0, -1)
        corners = cv2.goodFeaturesToTrack(
            gray, maxCorners=count, qualityLevel=self.config.corner_quality,
            minDistance=self.config.min_distance, mask=free,
        )
        if corners is None:
            return np.zeros((0, 2))
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (5, 5), (-1, -1), criteria)
        return corners.reshape(-1, 2).astype(np.float64)

    def _far_from_tracks(self, xy: np.ndarray) -> np.ndarray:
        if len(self.xy) == 0:
            return np.ones(len(xy), bool)
        d = pairwise_distances(xy, self.xy).min(axis=1)
        return d >= self.config.min_distance


def track_sequence(
    frames: Sequence[np.ndarray],
    template: Template,
    texture: np.ndarray,
    camera: Camera,
    *,
    masks: Sequence[np.ndarray] | None = None,
    config: TrackerConfig | None = None,
) -> tuple[list[FrameCorrespondences], TrackingTimings]:
    """Correspondences for every frame, and the tracker's timings."""
    tracker = Tracker(template, texture, camera, config=config)
    out = []
    for i, frame in progress.counted(enumerate(frames), "SfT tracking, frames", len(frames)):
        mask = None if masks is None else masks[i]
        out.append(tracker.start(frame, mask) if i == 0 else tracker.step(frame, mask))
    log.info(
        "tracked %d frames: %.0f correspondences per frame on average, %.3f s per frame",
        len(out), np.mean([len(c) for c in out]), np.mean(tracker.timings.per_frame),
    )
    return out, tracker.timings

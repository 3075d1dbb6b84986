"""Dense correspondences from optical flow: the surface seen in the last frame, carried into the
next by OpenCV's DIS flow, forward–backward checked.

The sparse tracks (`inverse.sft.tracking`) sit on corners; between them, and near the outline
where corners are dropped, nothing tells the fit where the sheet went. Dense flow fills that in.
For frame t the surface points are those the last reconstruction x_{t−1} shows on a pixel grid
(z-buffered: hidden parts of a fold give none, so occlusion is handled by the mesh itself);
each is carried by the forward flow F (t−1 → t) and kept only if the backward flow B (t → t−1)
brings it back: ‖q − (q + F(q) + B(q + F(q)))‖ < ``fb_threshold``. Its correspondence is
(face, barycentric) of the surface point with the pixel q + F(q) at frame t.

Work stays on the sheet and resolution-independent: both frames are cropped to the projected
mesh's bounding box (plus ``margin_px``) and that crop is scaled so its longer side is at most
``working_px`` pixels. Grid spacing and the forward–backward threshold are stated in pixels of
the full image. The images are contrast-normalised first (`inverse.sft.image`), which keeps the
flow's brightness constancy under illumination drift.

Errors of x_{t−1} in the image are carried along but do not accumulate: the sparse tracks,
re-matched to the texture, hold the fit to the texture, the flow adds where the sheet moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from inverse.sft.camera import Camera
from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.image import bilinear, contrast_normalised, eroded, sample_mask, to_gray
from inverse.sft.surface import SurfaceLocator
from taichi_ndf.render import rasterize

# Track ids of flow points start here (sparse tracks count up from 0).
FLOW_TRACK_ID = 1 << 40


@dataclass(frozen=True)
class FlowConfig:
    """Dense-flow correspondences.

    spacing_px: grid spacing of the carried points [full-image px]; fb_threshold: largest
    forward–backward error [full-image px]; working_px: longest side of the working crop [px]
    (the crop is downscaled to it, never upscaled); margin_px: margin around the projected mesh
    [full-image px]; confidence: confidence of a flow point at zero forward–backward error (the
    sparse tracks have 1), scaled by exp(−(fb / fb_threshold)²) like them; mask_margin: distance
    kept from the mask's outline at frame t [full-image px].
    """

    spacing_px: float = 8.0
    fb_threshold: float = 1.0
    working_px: int = 640
    margin_px: int = 32
    confidence: float = 0.5
    mask_margin: int = 2

    def __post_init__(self):
        for name in ("spacing_px", "fb_threshold", "confidence"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and positive, got {getattr(self, name)}")
        if self.working_px < 32:
            raise ValueError(f"working_px must be >= 32, got {self.working_px}")
        if self.margin_px < 0 or self.mask_margin < 0:
            raise ValueError("margin_px and mask_margin must be >= 0")
        if self.confidence > 1:
            raise ValueError(f"confidence must be in (0, 1], got {self.confidence}")


class DenseFlow:
    """Flow correspondences frame by frame: ``correspondences(t, vertices_{t−1})``.

    frames: BGR or grey uint8 images (h, w[, 3]); faces: the template's triangles (F, 3);
    masks: bool (h, w) per frame or None.
    """

    def __init__(self, frames, camera: Camera, faces: np.ndarray, *, masks=None,
                 config: FlowConfig | None = None):
        self.frames = frames
        self.masks = masks
        self.camera = camera
        self.faces = np.asarray(faces, dtype=np.int64)
        self.config = config or FlowConfig()
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)

    def correspondences(self, t: int, previous: np.ndarray) -> FrameCorrespondences:
        """Surface points of the mesh `previous` (vertices of frame t − 1 [m], (V, 3)) seen in
        frame t − 1, carried into frame t; empty when the mesh is off the image."""
        cfg = self.config
        cam = self.camera
        pixels = cam.project(previous)
        box = _crop_box(pixels, cfg.margin_px, cam.width, cam.height)
        if box is None:
            return _empty()
        x0, y0, x1, y1 = box
        scale = min(1.0, cfg.working_px / max(x1 - x0, y1 - y0))
        size = (max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale)))
        before = self._working(t - 1, box, size)
        after = self._working(t, box, size)
        forward = self._dis.calc(before, after, None)
        backward = self._dis.calc(after, before, None)

        # The mesh in the working crop: pixel centres at integers in both, so a full-image
        # pixel p maps to (p − x0 + ½) · s − ½.
        K = cam.K.copy()
        K[:2] *= scale
        K[0, 2] += (0.5 - x0) * scale - 0.5
        K[1, 2] += (0.5 - y0) * scale - 0.5
        raster = rasterize(previous, self.faces, K, size[0], size[1])
        corners = (pixels - [x0, y0] + 0.5) * scale - 0.5
        locator = SurfaceLocator(corners, self.faces, raster.face_id, depth=previous[:, 2])

        step = cfg.spacing_px * scale
        gx, gy = np.meshgrid(np.arange(step / 2, size[0] - 1, step),
                             np.arange(step / 2, size[1] - 1, step))
        query = np.column_stack([gx.ravel(), gy.ravel()])
        face, bary = locator.locate(query)
        seen = face >= 0
        if self.masks is not None:
            seen &= sample_mask(self.masks[t - 1], _full(query, box, scale))
        query, face, bary = query[seen], face[seen], bary[seen]

        moved = query + _sample_flow(forward, query)
        back = moved + _sample_flow(backward, moved)
        fb = np.linalg.norm(back - query, axis=1) / scale
        target = _full(moved, box, scale)
        keep = fb < cfg.fb_threshold
        keep &= (target[:, 0] >= 0) & (target[:, 0] <= cam.width - 1)
        keep &= (target[:, 1] >= 0) & (target[:, 1] <= cam.height - 1)
        if self.masks is not None:
            keep &= sample_mask(eroded(self.masks[t], cfg.mask_margin), target)
        n = int(keep.sum())
        return FrameCorrespondences(
            face=face[keep], bary=bary[keep], xy=target[keep],
            confidence=cfg.confidence * np.exp(-((fb[keep] / cfg.fb_threshold) ** 2)),
            track_id=FLOW_TRACK_ID + np.arange(n, dtype=np.int64))

    def _working(self, t: int, box, size) -> np.ndarray:
        x0, y0, x1, y1 = box
        crop = to_gray(self.frames[t])[y0:y1, x0:x1]
        if size != (x1 - x0, y1 - y0):
            crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
        return contrast_normalised(crop)



def merged(sparse: FrameCorrespondences, dense: FrameCorrespondences) -> FrameCorrespondences:
    """The sparse tracks followed by the flow points, one set of correspondences."""
    return FrameCorrespondences(
        *(np.concatenate([getattr(sparse, name), getattr(dense, name)])
          for name in ("face", "bary", "xy", "confidence", "track_id")))


def _crop_box(pixels: np.ndarray, margin: int, width: int, height: int):
    """Integer box (x0, y0, x1, y1), end exclusive, around the finite pixels, in the image."""
    finite = pixels[np.isfinite(pixels).all(axis=1)]
    if len(finite) == 0:
        return None
    x0 = max(0, int(math.floor(finite[:, 0].min())) - margin)
    y0 = max(0, int(math.floor(finite[:, 1].min())) - margin)
    x1 = min(width, int(math.ceil(finite[:, 0].max())) + margin + 1)
    y1 = min(height, int(math.ceil(finite[:, 1].max())) + margin + 1)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    return x0, y0, x1, y1


def _full(points: np.ndarray, box, scale: float) -> np.ndarray:
    """Working-crop pixels (n, 2) → full-image pixels."""
    return (points + 0.5) / scale - 0.5 + [box[0], box[1]]


def _sample_flow(flow: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The flow field (h, w, 2) bilinearly sampled at points (n, 2) [px], (n, 2)."""
    return np.column_stack([bilinear(np.ascontiguousarray(flow[..., k]), points)
                            for k in range(2)]).astype(np.float64)


def _empty() -> FrameCorrespondences:
    return FrameCorrespondences(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2)),
                                np.zeros(0), np.zeros(0, np.int64))

"""Texture points re-found where the reconstruction predicts them: tracking guided by the fit.

The sparse tracker (`inverse.sft.tracking`) loses the parts of the sheet that bend fast, and a
global descriptor match cannot bring them back when the print repeats (every square of a
checkerboard matches every other). The reconstruction knows roughly where each lost point is:
for frame t the constant-velocity prediction x̂ = 2 x_{t−1} − x_{t−2} of the mesh (the motion
term's) projects each template point to a pixel p̂. Within a few pixels of p̂ the repeat is
gone, so a local search decides.

Per frame t, for the template's texture corners (Shi–Tomasi corners of the texture on its UV
chart) that no tracked point of frame t lies near on the template (farther than `gap_edges`
mean edge lengths: lost or never found):
1. p̂ from x̂, shifted by the median pixel error of x̂ at the k template-nearest tracked
   points of frame t (where the tracker says the prediction is off); skipped when off the
   eroded mask, hidden behind another part of x̂ (z-buffer), or seen so obliquely that the
   local map stretches more than `max_stretch`;
2. the texture around the point is warped into the image by the affine map that x̂'s triangle
   induces (texture → image through the camera), a (2 r + 1)² patch; frame and texture are
   both smoothed by `match_sigma` (a moving sheet's frames are blurrier than its texture);
3. normalised cross-correlation of that patch over a window of radius R around p̂, R =
   `window_sigmas` × the median distance of those tracked errors from their median (the
   prediction's own uncertainty there), clamped to [`min_window`, `max_window`]; a peak on
   the window's edge (the correlation still rising out of it) is searched once more in the
   widest window;
4. accepted when the peak is high (NCC ≥ `min_ncc`), not on the window's edge, distinct (no
   other local maximum farther than `peak_separation` reaches `peak_ratio` × the peak: the
   window holds one match, not two repeats) and stable: Lucas–Kanade from the warped patch to
   the frame, started at the peak, and back, returns within `fb_threshold` (the tracker's
   limit) and stays within `peak_separation` of the peak.

An accepted point's confidence is exp(−(fb / fb_threshold)²) like a track's. By default the
points are correspondences of frame t only, re-searched every frame from the newest
prediction. With `carry` an accepted point becomes a track (`inverse.sft.carried`): followed
frame to frame by Lucas–Kanade from the image where it was accepted, forward–backward checked,
dropped when it fails or leaves the mask; a carried point is not searched again, and its pixel
error, like a tracked point's, sets the windows of the candidates near it. `carry` is off:
measured worse on R1 and on the synthetic study (benchmarks/RESULTS.md, R1, wip-sft6).
`stats` keeps per frame how many were searched and accepted, and why the others were not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from inverse.sft.camera import Camera
from inverse.sft.carried import CarriedTracks, CarryConfig
from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.flow import merged
from inverse.sft.image import bilinear, eroded, sample_mask, signed_area, to_gray
from inverse.sft.inputs import Template, mean_edge_length
from inverse.sft.matching import prefiltered_texture
from inverse.sft.surface import surface_positions, uv_locator
from taichi_ndf.render import rasterize, uv_to_texture_pixels

# Track ids of guided points start here (sparse tracks count up from 0, flow points from 2^40).
GUIDED_TRACK_ID = 1 << 41


@dataclass(frozen=True)
class GuidedConfig:
    """The guided search (pixels are image pixels).

    patch_radius: half size of the compared patch [px] (10: the tracker's 21 px Lucas–Kanade
    window); min_window / max_window: smallest / largest search radius [px] (2: the
    reconstruction's own sub-pixel-to-pixel error; 8: beyond that a constant-velocity
    prediction is no longer a guide, and a wider window lets a repeat in); window_sigmas:
    search radius in prediction errors (3, a three-sigma bound); neighbours: tracked points
    whose prediction error sets the window; min_ncc: peak correlation needed (0.8, the
    tracker's for seeded corners); peak_ratio: largest second peak relative to the first (0.8:
    with a perfect first peak the second stays below what a match needs); peak_separation:
    how far [px] a second peak must lie from the first (2: the correlation peak's own width
    at the image's resolution); fb_threshold: forward–backward limit [px] (0.5, the
    tracker's); gap_edges: a texture point is searched when no tracked point lies within this
    many template mean edge lengths (1: nearer, the tracks already pin its knot span);
    max_stretch: largest ratio of the local map's singular values (4: a patch seen at more
    than ~75° from the normal); max_points: texture points searched per frame, farthest from
    the tracks first; mask_margin: distance kept from the mask's outline [px] (the tracker's);
    corner_spacing: spacing of the texture corners [image px at frame 0] (the tracker's
    min_distance); match_sigma: smoothing of both images before matching [image px] (1.5:
    about the motion blur of a sheet that moves a few px per frame; R1's whipping strip keeps
    0.7 of frame 0's Laplacian energy); carry: follow accepted points into the next frames
    as tracks (`inverse.sft.carried`, the tracker's Lucas–Kanade settings; off: measured worse
    on R1's largest distance and on the synthetic roll and corner sequences).
    """

    patch_radius: int = 10
    min_window: float = 2.0
    max_window: float = 8.0
    window_sigmas: float = 3.0
    neighbours: int = 8
    min_ncc: float = 0.8
    peak_ratio: float = 0.8
    peak_separation: float = 2.0
    fb_threshold: float = 0.5
    gap_edges: float = 1.0
    max_stretch: float = 4.0
    max_points: int = 400
    mask_margin: int = 4
    corner_spacing: float = 7.0
    match_sigma: float = 1.5
    carry: bool = False

    def __post_init__(self):
        if self.patch_radius < 2:
            raise ValueError(f"patch_radius must be >= 2, got {self.patch_radius}")
        if not 0 < self.min_window <= self.max_window < math.inf:
            raise ValueError("need 0 < min_window <= max_window (finite), got "
                             f"{self.min_window}, {self.max_window}")
        for name in ("window_sigmas", "peak_separation", "fb_threshold", "gap_edges",
                     "corner_spacing", "match_sigma"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and positive, got {getattr(self, name)}")
        if not 0 < self.min_ncc < 1 or not 0 < self.peak_ratio < 1:
            raise ValueError("min_ncc and peak_ratio must be in (0, 1)")
        if self.max_stretch < 1 or self.neighbours < 1 or self.max_points < 1:
            raise ValueError("need max_stretch >= 1, neighbours >= 1, max_points >= 1")
        if self.mask_margin < 0:
            raise ValueError(f"mask_margin must be >= 0, got {self.mask_margin}")


# Why a candidate was not searched, and why a searched one was not accepted (in test order).
SKIPS = ("off_mask", "hidden", "oblique")
REJECTIONS = ("low_peak", "edge", "ambiguous", "forward_backward")


class GuidedSearch:
    """Guided correspondences frame by frame: ``correspondences(t, history, tracked)``.

    frames: BGR or grey uint8 images (h, w[, 3]) in `camera`'s pixels; template: frame 0's mesh
    with UVs; texture: BGR or grey uint8; masks: bool (h, w) per frame or None.
    """

    def __init__(self, frames, camera: Camera, template: Template, texture: np.ndarray, *,
                 masks=None, config: GuidedConfig | None = None):
        self.frames = frames
        self.masks = masks
        self.camera = camera
        self.template = template
        self.config = config or GuidedConfig()
        self.mean_edge = mean_edge_length(template.vertices, template.faces)
        h, w = texture.shape[:2]
        self.texture_corners = uv_to_texture_pixels(template.uvs, w, h)
        scale = _texture_scale(template, camera, self.texture_corners)
        self.texture_gray = cv2.GaussianBlur(
            prefiltered_texture(texture, template, camera, self.texture_corners), (0, 0),
            self.config.match_sigma * scale)
        self.face, self.bary, self.texture_xy = self._texture_points(texture, scale)
        self.rest = surface_positions(template.vertices, template.faces, self.face, self.bary)
        self.carried = CarriedTracks(CarryConfig(fb_threshold=self.config.fb_threshold,
                                                 mask_margin=self.config.mask_margin))
        self.stats: dict[int, dict[str, int]] = {}

    def _texture_points(self, texture: np.ndarray, scale: float):
        """Shi–Tomasi corners of the texture on the UV chart (scale: texture px per image
        px): face, bary, texture xy."""
        gray = to_gray(texture)
        chart = uv_locator(self.template, gray.shape[1], gray.shape[0])
        on_chart = (chart.face_image >= 0).astype(np.uint8)
        corners = cv2.goodFeaturesToTrack(
            gray, maxCorners=20000, qualityLevel=0.01,
            minDistance=self.config.corner_spacing * scale, mask=on_chart)
        xy = np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2).astype(np.float64)
        face, bary = chart.locate(xy)
        keep = face >= 0
        return face[keep], bary[keep], xy[keep]

    def correspondences(self, t: int, history: list[np.ndarray],
                        tracked: FrameCorrespondences) -> FrameCorrespondences:
        """Texture points of frame t away from the `tracked` points: with `carry` those
        carried from frame t − 1, plus those re-found near where `history` (the vertices [m]
        of the frames before t, last one last) predicts them."""
        if not self.config.carry:
            return self._search(t, history, tracked)
        self.carried.advance(t, self.frames, self.masks)
        if len(tracked) and len(self.carried):  # the tracker has them again: no need
            carried = self.carried.current()
            self.carried.drop_near(
                surface_positions(self.template.vertices, self.template.faces, carried.face,
                                  carried.bary),
                surface_positions(self.template.vertices, self.template.faces, tracked.face,
                                  tracked.bary), self.config.gap_edges * self.mean_edge)
        carried = self.carried.current()
        found = self._search(t, history, tracked, carried)
        self.stats[t]["carried"] = len(carried)
        self.carried.add(t, found)
        return self.carried.current()

    def _search(self, t: int, history: list[np.ndarray], tracked: FrameCorrespondences,
                carried: FrameCorrespondences | None = None) -> FrameCorrespondences:
        """Texture points re-found in frame t near where `history` predicts them, away from
        the `tracked` points, other than those `carried` (whose errors, with the tracked
        points', set the windows)."""
        cfg = self.config
        stats = dict.fromkeys(("candidates", *SKIPS, "searched", "widened", "accepted",
                               *REJECTIONS), 0)
        self.stats[t] = stats
        previous = history[-1]
        predicted = 2.0 * previous - history[-2] if len(history) > 1 else previous
        faces = self.template.faces

        # Lost or never found: far (on the template) from every tracked point of frame t.
        if len(tracked):
            track_rest = surface_positions(self.template.vertices, faces, tracked.face,
                                           tracked.bary)
            gap, _ = cKDTree(track_rest).query(self.rest)
        else:
            gap = np.full(len(self.rest), np.inf)
        order = np.argsort(-gap)
        order = order[gap[order] > cfg.gap_edges * self.mean_edge]
        if carried is not None and len(carried):
            order = order[~np.isin(GUIDED_TRACK_ID + order, carried.track_id)]
            tracked = merged(tracked, carried)
            track_rest = surface_positions(self.template.vertices, faces, tracked.face,
                                           tracked.bary)
        order = order[:cfg.max_points]
        stats["candidates"] = len(order)
        if len(order) == 0:
            return _empty()

        cam = self.camera
        points = surface_positions(predicted, faces, self.face[order], self.bary[order])
        pixel = cam.project(points)
        shift, window = self._windows(predicted, tracked, track_rest if len(tracked) else None,
                                      order)
        pixel = pixel + shift
        reach = cfg.patch_radius + np.ceil(window) + 2
        on_image = np.isfinite(pixel).all(1) & (points[:, 2] > 0)
        pixel = np.where(on_image[:, None], pixel, -1e9)
        on_image &= (pixel[:, 0] >= reach) & (pixel[:, 0] <= cam.width - 1 - reach)
        on_image &= (pixel[:, 1] >= reach) & (pixel[:, 1] <= cam.height - 1 - reach)
        if self.masks is not None:
            on_image &= sample_mask(eroded(self.masks[t], cfg.mask_margin), pixel)
        raster = rasterize(predicted, faces, cam.K, cam.width, cam.height)
        col = np.clip(np.rint(pixel[:, 0]), 0, cam.width - 1).astype(int)
        row = np.clip(np.rint(pixel[:, 1]), 0, cam.height - 1).astype(int)
        # Hidden: another part of the predicted sheet lies in front by more than an edge.
        visible = raster.depth[row, col] > points[:, 2] - self.mean_edge
        jacobian = self._texture_map(predicted, order)
        singular = np.linalg.svd(jacobian, compute_uv=False)
        frontal = singular[:, 1] > 1e-9
        frontal &= singular[:, 0] <= cfg.max_stretch * np.maximum(singular[:, 1], 1e-300)
        stats["off_mask"] = int((~on_image).sum())
        stats["hidden"] = int((on_image & ~visible).sum())
        stats["oblique"] = int((on_image & visible & ~frontal).sum())
        ok = on_image & visible & frontal
        chosen = np.flatnonzero(ok)
        stats["searched"] = len(chosen)
        if len(chosen) == 0:
            return _empty()

        gray = cv2.GaussianBlur(to_gray(self.frames[t]).astype(np.float32), (0, 0),
                                cfg.match_sigma)
        found, fb = [], []
        for k in chosen:
            result = search(gray, self.texture_gray, pixel[k], self.texture_xy[order[k]],
                            jacobian[k], int(np.ceil(window[k])), cfg)
            if result == "edge" and window[k] < cfg.max_window:
                # The correlation rises out of the window: search the widest one once.
                stats["widened"] += 1
                result = search(gray, self.texture_gray, pixel[k], self.texture_xy[order[k]],
                                jacobian[k], int(np.ceil(cfg.max_window)), cfg)
            if isinstance(result, str):
                stats[result] += 1
                continue
            found.append((k, result[0]))
            fb.append(result[1])
        stats["accepted"] = len(found)
        if not found:
            return _empty()
        index = np.array([k for k, _ in found])
        fb = np.array(fb)
        return FrameCorrespondences(
            face=self.face[order[index]], bary=self.bary[order[index]],
            xy=np.array([xy for _, xy in found]),
            confidence=np.exp(-((fb / cfg.fb_threshold) ** 2)),
            track_id=GUIDED_TRACK_ID + order[index].astype(np.int64))

    def _windows(self, predicted: np.ndarray, tracked: FrameCorrespondences,
                 track_rest: np.ndarray | None, order: np.ndarray):
        """Where the tracked points say the prediction is off, per candidate: the median
        offset [px] (n, 2) of the pixel error of x̂ at its template-nearest tracked points
        (added to the prediction), and the search radius [px] (n,): window_sigmas × the median
        distance of those errors from that offset, clamped."""
        cfg = self.config
        if track_rest is None or len(tracked) == 0:
            return np.zeros((len(order), 2)), np.full(len(order), cfg.max_window)
        at = self.camera.project(surface_positions(predicted, self.template.faces,
                                                   tracked.face, tracked.bary))
        error = tracked.xy - at
        k = min(cfg.neighbours, len(tracked))
        _, near = cKDTree(track_rest).query(self.rest[order], k=k)
        near = np.asarray(near).reshape(len(order), k)
        shift = np.median(error[near], axis=1)
        spread = np.median(np.linalg.norm(error[near] - shift[:, None], axis=2), axis=1)
        return shift, np.clip(cfg.window_sigmas * spread, cfg.min_window, cfg.max_window)

    def _texture_map(self, predicted: np.ndarray, order: np.ndarray) -> np.ndarray:
        """d texture / d image (n, 2, 2) of each candidate's triangle under the projection of
        the predicted mesh (affine per triangle)."""
        tri = self.template.faces[self.face[order]]
        img = self.camera.project(predicted[tri.reshape(-1)]).reshape(-1, 3, 2)
        tex = self.texture_corners[tri]
        e_img = np.stack([img[:, 1] - img[:, 0], img[:, 2] - img[:, 0]], axis=2)
        e_tex = np.stack([tex[:, 1] - tex[:, 0], tex[:, 2] - tex[:, 0]], axis=2)
        det = np.linalg.det(e_img)
        e_img[np.abs(det) < 1e-12] = np.eye(2)
        out = e_tex @ np.linalg.inv(e_img)
        out[np.abs(det) < 1e-12] = 0.0
        return out


def search(gray: np.ndarray, texture_gray: np.ndarray, predicted: np.ndarray,
           texture_xy: np.ndarray, jacobian: np.ndarray, radius: int,
           config: GuidedConfig) -> tuple[np.ndarray, float] | str:
    """One texture point searched in a grey float32 image within `radius` [px] of the
    `predicted` pixel (2,): the texture (float32) around `texture_xy` (2,) warped into the
    image by d texture / d image `jacobian` (2, 2). Returns (pixel (2,), forward–backward
    error [px]) or why it was rejected (one of `REJECTIONS`)."""
    r, R = config.patch_radius, radius
    half = R + r
    grid = np.stack(np.meshgrid(np.arange(-half, half + 1), np.arange(-half, half + 1)), -1)
    grid = grid.astype(np.float64)
    image = bilinear(gray, predicted + grid)
    warped = bilinear(texture_gray, texture_xy + grid @ jacobian.T)
    patch = warped[R:R + 2 * r + 1, R:R + 2 * r + 1]
    if patch.std() < 1e-3 or image.std() < 1e-3:
        return "low_peak"
    score = cv2.matchTemplate(image, np.ascontiguousarray(patch), cv2.TM_CCOEFF_NORMED)
    peak = np.unravel_index(int(np.argmax(score)), score.shape)
    best = float(score[peak])
    if best < config.min_ncc:
        return "low_peak"
    if min(peak) == 0 or max(peak) == 2 * R:
        return "edge"  # the correlation still rises out of the window: no peak inside it
    # The second peak: the highest other local maximum (a repeat), not the first peak's own
    # flank, which a smooth texture keeps high for pixels around it.
    rows, cols = np.indices(score.shape)
    maxima = score >= cv2.dilate(score, np.ones((3, 3), np.uint8))
    maxima &= np.hypot(rows - peak[0], cols - peak[1]) > config.peak_separation
    if maxima.any() and score[maxima].max() >= config.peak_ratio * best:
        return "ambiguous"
    # Lucas–Kanade from the warped texture to the image, started at the peak, and back.
    a, b = _normalised(warped), _normalised(image)
    centre = np.array([[[half, half]]], np.float32)
    start = np.array([[[half + peak[1] - R, half + peak[0] - R]]], np.float32)
    params = dict(winSize=(2 * r + 1, 2 * r + 1), maxLevel=0,
                  criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    forward, ok_f, _ = cv2.calcOpticalFlowPyrLK(a, b, centre, start.copy(),
                                                flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
    back, ok_b, _ = cv2.calcOpticalFlowPyrLK(b, a, forward, centre.copy(),
                                             flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
    fb = float(np.linalg.norm(back - centre))
    moved = float(np.linalg.norm(forward - start))
    if not (ok_f.all() and ok_b.all()) or fb >= config.fb_threshold \
            or moved > config.peak_separation:
        return "forward_backward"
    return predicted + forward.reshape(2).astype(np.float64) - half, fb


def _normalised(patch: np.ndarray) -> np.ndarray:
    """A float patch as 8-bit with zero mean and a fixed spread (NCC-like for Lucas–Kanade)."""
    p = (patch - patch.mean()) / max(float(patch.std()), 1e-6)
    return np.clip(128.0 + 40.0 * p, 0, 255).astype(np.uint8)


def _texture_scale(template: Template, camera: Camera, texture_corners: np.ndarray) -> float:
    """Texture pixels per image pixel of frame 0 (the template's areas, square-rooted)."""
    faces = template.faces
    img = np.abs(signed_area(camera.project(template.vertices)[faces])).sum()
    tex = np.abs(signed_area(texture_corners[faces])).sum()
    return float(np.sqrt(tex / max(img, 1e-12)))


def _empty() -> FrameCorrespondences:
    return FrameCorrespondences(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2)),
                                np.zeros(0), np.zeros(0, np.int64))

"""A direct photometric data term: the template's texture, carried by the current surface, compared
with the frame at every textured point, not only at the corners the tracker keeps.

Points: a square grid of texture pixels over the UV chart, about `points` of them (the cost of
a frame grows with their number, not with the image's resolution), kept 2σ inside the chart's
outline (the blur there mixes in what lies beside the sheet), each a surface point (face,
barycentric) with its template position X_k [m]. Images:
the texture and each frame in grey, blurred by σ (a coarse pyramid level: the term's reach is a
few σ), then contrast-normalised over 4σ (`normalised`: zero local mean, unit local spread, so
a slowly varying gain and offset — the lighting of a moving sheet — do not count). Per frame

    E_photo(u) = w_photo / m · Σ_k ρ((I_t(π(X_k + u_k)) − T_k) / g)                  [px²]

over the m points visible at the start of the frame (on the previous frame's surface: projected
inside the mask eroded by 2σ, facing the camera as in frame 0, and not behind another part of
the sheet by more than a mean edge in its z-buffer), with T_k the
texture level at point k, I_t the frame's level sampled bilinearly, ρ the Huber penalty of
`least_squares.huber` (quadratic up to δ [px]) and g the rms slope [1/px] of frame 0's level
at the points: a residual of one unit is the intensity change of a 1 px shift, so E_photo is
in the reprojection term's units (px²) and w_photo = 1 weighs the mean photometric error as
the mean reprojection error. Gauss–Newton as the silhouette's: the residual's row is
∇I_t · dπ/dx / g (the bilinear sample of the level's central differences), Huber by IRLS.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from inverse.sft.camera import Camera
from inverse.sft.image import bilinear, eroded, sample_mask, signed_area, to_gray
from inverse.sft.inputs import Template, mean_edge_length
from inverse.sft.least_squares import COMPONENTS, MIN_DEPTH, huber
from inverse.sft.silhouette import bilinear_differentiable
from inverse.sft.surface import surface_positions, uv_locator
from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.render import rasterize, uv_to_texture_pixels

log = logging.getLogger(__name__)

# Contrast normalisation window, in units of the level's blur σ.
NORMALISATION_SIGMAS = 4.0
# Points closer than this many σ to the chart's outline or the mask's are not used.
BORDER_SIGMAS = 2.0


def normalised(gray: np.ndarray, sigma: float) -> np.ndarray:
    """A grey image (h, w) blurred by σ [px] and contrast-normalised over NORMALISATION_SIGMAS σ:
    zero local mean, unit local spread, float32."""
    g = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), sigma)
    window = NORMALISATION_SIGMAS * sigma
    detail = g - cv2.GaussianBlur(g, (0, 0), window)
    spread = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), window))
    return detail / (spread + 1e-3 * max(float(spread.max()), 1e-6))


@dataclass(frozen=True)
class PhotometricFrame:
    """What one frame's photometric term needs: the visible points' indices among the
    evidence's points (m,), their UVs ξ (m, 2), template positions (m, 3) [m] and texture
    values (m,); the frame's level (h, w) and its central
    differences d/dx, d/dy (h, w); 1/g [px]; the weight w_photo and Huber δ [px]."""

    index: np.ndarray
    xi: torch.Tensor
    rest: torch.Tensor
    target: torch.Tensor
    image: torch.Tensor
    slope: tuple[torch.Tensor, torch.Tensor]
    inverse_slope: float
    weight: float
    huber_px: float

    def term(self, camera: Camera, rows: torch.Tensor) -> PhotometricTerm:
        """The term on a batch of points whose rows `rows` (m,) (int64) are these points."""
        return PhotometricTerm(camera, rows, self)


class PhotometricEvidence:
    """The sequence's photometric points and levels: ``frame(t, previous)`` per frame.

    frames: BGR or grey uint8 (h, w[, 3]) in `camera`'s pixels; template: frame 0's mesh with
    UVs; texture: BGR or grey uint8; masks: bool (h, w) per frame or None; sigma: the level's
    blur [frame px]; points: about how many points; weight: w_photo; huber_px: δ [px]."""

    def __init__(self, frames, camera: Camera, template: Template, texture: np.ndarray, *,
                 masks=None, sigma: float = 2.0, points: int = 4096, weight: float = 1.0,
                 huber_px: float = 2.0):
        if not (sigma > 0 and weight >= 0 and huber_px > 0 and points >= 1):
            raise ValueError(f"need sigma > 0, weight >= 0, huber_px > 0; got {sigma}, "
                             f"{weight}, {huber_px}")
        self.frames, self.masks, self.camera = frames, masks, camera
        self.template, self.sigma = template, sigma
        self.mean_edge = mean_edge_length(template.vertices, faces := template.faces)
        self.weight, self.huber_px = weight, huber_px
        gray = to_gray(texture)
        h, w = gray.shape
        corners = uv_to_texture_pixels(template.uvs, w, h)
        image_area = np.abs(signed_area(camera.project(template.vertices)[faces])).sum()
        scale = float(np.sqrt(np.abs(signed_area(corners[faces])).sum() / max(image_area, 1e-12)))
        level = normalised(gray, sigma * scale)
        chart = uv_locator(template, w, h)
        inner = eroded(chart.face_image >= 0, int(np.ceil(BORDER_SIGMAS * sigma * scale)))
        step = float(np.sqrt(inner.sum() / points))
        xs, ys = np.meshgrid(np.arange(0.0, w, step), np.arange(0.0, h, step))
        xy = np.column_stack([xs.ravel(), ys.ravel()])
        xy = xy[sample_mask(inner, xy)]
        self.face, self.bary = chart.locate(xy)
        keep = self.face >= 0
        self.face, self.bary, xy = self.face[keep], self.bary[keep], xy[keep]
        self.target = bilinear(level, xy).astype(np.float64)
        self.xi = np.einsum("nk,nkd->nd", self.bary, template.uvs[faces[self.face]])
        self.rest = surface_positions(template.vertices, faces, self.face, self.bary)
        self._front = self._facing(template.vertices)
        # g: the rms slope of frame 0's level at the points (a 1 px shift's intensity change)
        first = self._level(0)
        pixels = camera.project(self.rest)
        gx, gy = np.gradient(first)
        self.slope_rms = float(np.sqrt(np.mean(bilinear(gx, pixels) ** 2
                                               + bilinear(gy, pixels) ** 2)))
        log.info("photometric term: %d points, level σ %.1f px, rms slope %.3f per px",
                 len(self.rest), sigma, self.slope_rms)

    def _level(self, t: int) -> np.ndarray:
        return normalised(to_gray(self.frames[t]), self.sigma)

    def _facing(self, vertices: np.ndarray) -> np.ndarray:
        """The sign (n,) of each point's face normal against its viewing ray."""
        tri = vertices[self.template.faces[self.face]]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        centre = tri.mean(axis=1)
        return np.sign(np.einsum("nd,nd->n", normal, centre))

    def frame(self, t: int, previous: np.ndarray) -> PhotometricFrame:
        """Frame t's term data, the visible points chosen on `previous` (n, 3) [m] (the
        surface the frame's fit starts from)."""
        level = self._level(t)
        at = surface_positions(previous, self.template.faces, self.face, self.bary)
        pixels = self.camera.project(at)
        if self.masks is not None:
            region = eroded(self.masks[t], int(np.ceil(BORDER_SIGMAS * self.sigma)))
        else:
            region = np.zeros(level.shape, bool)
            margin = int(np.ceil(BORDER_SIGMAS * self.sigma))
            region[margin:-margin, margin:-margin] = True
        visible = sample_mask(region, pixels) & (self._facing(previous) == self._front)
        # Hidden: another part of the sheet lies in front by more than a mean edge.
        raster = rasterize(previous, self.template.faces, self.camera.K, *level.shape[::-1])
        col = np.clip(np.rint(pixels[:, 0]), 0, level.shape[1] - 1).astype(int)
        row = np.clip(np.rint(pixels[:, 1]), 0, level.shape[0] - 1).astype(int)
        visible &= raster.depth[row, col] > at[:, 2] - self.mean_edge
        gy, gx = np.gradient(level.astype(np.float64))
        idx = np.nonzero(visible)[0]
        return PhotometricFrame(
            index=idx, xi=torch.from_numpy(self.xi[idx]), rest=torch.from_numpy(self.rest[idx]),
            target=torch.from_numpy(self.target[idx]),
            image=torch.from_numpy(level.astype(np.float64)),
            slope=(torch.from_numpy(gx), torch.from_numpy(gy)),
            inverse_slope=1.0 / max(self.slope_rms, 1e-12), weight=self.weight,
            huber_px=self.huber_px)


def photometric_evidence(config, frames, camera: Camera, template: Template,
                         texture: np.ndarray, *, masks=None) -> PhotometricEvidence | None:
    """The evidence that the frame-fit settings `config` ask for: with photometric_weight > 0
    (a `SplinePriorConfig`: its σ, points, weight and the reprojection's Huber δ); None where
    the weight is 0 (the settings of a fit without the term declare 0)."""
    if config.photometric_weight <= 0:
        return None
    return PhotometricEvidence(frames, camera, template, texture, masks=masks,
                               sigma=config.photometric_sigma,
                               points=config.photometric_points,
                               weight=config.photometric_weight, huber_px=config.huber_px)


class PhotometricTerm:
    """E_photo at rows `rows` of a sample set (the `Term` protocol plus Gauss–Newton
    `hessian_blocks`), float64."""

    def __init__(self, camera: Camera, rows: torch.Tensor, data: PhotometricFrame):
        self.camera, self.rows, self.data = camera, rows, data
        self.scale = data.weight / max(len(rows), 1)

    def _residual(self, u: torch.Tensor):
        d = self.data
        points = d.rest + u[self.rows]
        pixels = self.camera.project(points, min_depth=MIN_DEPTH)
        r = (bilinear_differentiable(d.image, pixels) - d.target) * d.inverse_slope
        return points, pixels, r

    def parts(self, u_jets: torch.Tensor) -> dict[str, float]:
        """The mean squared residual [px²-equivalent] and the number of points."""
        _, _, r = self._residual(u_jets[:, jets.VALUE].double())
        return {"photometric": float((r**2).mean()) if len(r) else 0.0,
                "photometric_points": float(len(r))}

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float = 1.0, *, grad: bool = True):
        value, gradient, _ = self._evaluate(u_jets, grad=grad, blocks=False)
        return value, gradient

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float = 1.0, *, steps: torch.Tensor) -> torch.Tensor:
        return self._evaluate(u_jets, grad=False, blocks=True)[2]

    def _evaluate(self, u_jets: torch.Tensor, *, grad: bool, blocks: bool):
        dtype, n = u_jets.dtype, u_jets.shape[0]
        u = u_jets[:, jets.VALUE].double()
        d = self.data
        points, pixels, r = self._residual(u)
        residual = r[:, None]
        value = self.scale * huber(residual, d.huber_px).sum()
        full_grad = full_blocks = None
        if grad or blocks:
            image_slope = torch.stack([bilinear_differentiable(g, pixels) for g in d.slope], 1)
            row = d.inverse_slope * torch.einsum(
                "nr,nri->ni", image_slope,
                self.camera.projection_jacobian(points, min_depth=MIN_DEPTH))
            a = r.abs()
            irls = 2.0 * self.scale * torch.where(
                a <= d.huber_px, torch.ones_like(a), d.huber_px / a.clamp_min(1e-300))
        if grad:
            full_grad = torch.zeros(n, jets.CHANNELS, COMPONENTS, dtype=dtype)
            full_grad[self.rows, jets.VALUE] = (irls[:, None] * r[:, None] * row).to(dtype)
        if blocks:
            full_blocks = torch.zeros(n, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS,
                                      dtype=dtype)
            full_blocks[self.rows, jets.VALUE, :, jets.VALUE, :] = (
                irls[:, None, None] * row[:, :, None] * row[:, None, :]).to(dtype)
        return float(value), full_grad, full_blocks

"""Pixel-level helpers of the SfT tracker: grey and contrast-normalised images, bilinear
samples at any number of points, masks and pixel-space triangle areas.

Pixel centres at integer coordinates, x right, y down.
"""

from __future__ import annotations

import cv2
import numpy as np

# Window [px] of the local contrast normalisation of the images Lucas–Kanade sees.
CONTRAST_SIGMA = 8.0
# Points per cv2.remap call: its maps must have fewer than SHRT_MAX = 32767 columns.
REMAP_COLUMNS = 32000


def to_gray(image: np.ndarray) -> np.ndarray:
    """Grey 8-bit image of a BGR (h, w, 3) or grey (h, w) one."""
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def contrast_normalised(gray: np.ndarray) -> np.ndarray:
    """Local contrast normalisation (8-bit): removes slowly varying gain and offset.

    Lucas–Kanade assumes constant brightness; under illumination drift it is biased by a
    fraction of a pixel per frame, which accumulates along a track.
    """
    g = gray.astype(np.float32)
    detail = g - cv2.GaussianBlur(g, (0, 0), CONTRAST_SIGMA)
    spread = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), CONTRAST_SIGMA)) + 1.0
    return np.clip(128.0 + 40.0 * detail / spread, 0, 255).astype(np.uint8)


def inside(xy: np.ndarray, shape: tuple[int, ...], *, margin: float) -> np.ndarray:
    """Whether pixels xy (n, 2) lie at least `margin` [px] inside an image of `shape`, (n,)."""
    h, w = shape[:2]
    return (
        (xy[:, 0] >= margin) & (xy[:, 0] <= w - 1 - margin)
        & (xy[:, 1] >= margin) & (xy[:, 1] <= h - 1 - margin)
    )


def eroded(mask: np.ndarray, margin: int) -> np.ndarray:
    """The mask (bool (h, w)) shrunk by `margin` [px] (an elliptic kernel), bool; as it is
    for margin <= 0."""
    if margin <= 0:
        return np.asarray(mask, dtype=bool)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
    return cv2.erode(np.asarray(mask, dtype=np.uint8), kernel) > 0


def sample_mask(mask: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The mask's value (n,) at the nearest pixel of each of xy (n, 2), clamped to the image."""
    h, w = mask.shape
    col = np.clip(np.rint(xy[:, 0]).astype(int), 0, w - 1)
    row = np.clip(np.rint(xy[:, 1]).astype(int), 0, h - 1)
    return mask[row, col]


def signed_area(tri: np.ndarray) -> np.ndarray:
    """Signed areas (n,) [px²] of 2-D triangles (n, 3, 2), positive counter-clockwise in x, y."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    return 0.5 * (ab[:, 0] * ac[:, 1] - ac[:, 0] * ab[:, 1])


def bilinear(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 image (h, w) at points (..., 2) [px], shape (...); the
    border replicated. Any number of points: OpenCV's remap takes maps of fewer than
    SHRT_MAX columns, so the points go in rows of `REMAP_COLUMNS`."""
    shape = points.shape[:-1]
    coords = points.reshape(-1, 2).astype(np.float32)
    out = np.empty(len(coords), dtype=np.float32)
    for start in range(0, len(coords), REMAP_COLUMNS):
        chunk = coords[None, start:start + REMAP_COLUMNS]
        out[start:start + chunk.shape[1]] = cv2.remap(
            image, chunk[..., 0], chunk[..., 1], cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE).reshape(-1)
    return out.reshape(shape)

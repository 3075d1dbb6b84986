"""Textured rendering of a mesh seen by a pinhole camera (synthetic video frames)."""

import numpy as np

from taichi_ndf.render.raster import downsample, interpolate, rasterize

__all__ = ["render_textured", "uv_to_texture_pixels"]


def uv_to_texture_pixels(uvs: np.ndarray, texture_width: int, texture_height: int) -> np.ndarray:
    """Texture pixel coordinates (x right, y down, texel centres at integers) of UVs (..., 2).

    UV convention (OBJ/OpenGL): u runs left to right and v bottom to top over the whole image,
    (0, 0) is the bottom-left corner of the bottom-left texel and (1, 1) the top-right corner of
    the top-right texel.
    """
    uvs = np.asarray(uvs, dtype=np.float64)
    x = uvs[..., 0] * texture_width - 0.5
    y = (1.0 - uvs[..., 1]) * texture_height - 0.5
    return np.stack([x, y], axis=-1)


def texture_pixels_to_uv(pixels: np.ndarray, texture_width: int,
                         texture_height: int) -> np.ndarray:
    """UVs (..., 2) of texture pixel coordinates (..., 2): the inverse of
    `uv_to_texture_pixels` (same conventions)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    u = (pixels[..., 0] + 0.5) / texture_width
    v = 1.0 - (pixels[..., 1] + 0.5) / texture_height
    return np.stack([u, v], axis=-1)


def render_textured(
    points_cam: np.ndarray,
    faces: np.ndarray,
    uvs: np.ndarray,
    texture: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    supersample: int = 2,
    background: np.ndarray | float | tuple | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render a textured mesh (camera convention of `taichi_ndf.render.raster`).

    points_cam: vertex positions in camera coordinates, shape (V, 3).
    faces: triangles, shape (F, 3).
    uvs: per-vertex texture coordinates (convention of `uv_to_texture_pixels`), shape (V, 2).
    texture: image, shape (h, w) or (h, w, C), any dtype; sampled bilinearly, edges clamped.
    K: intrinsics (3, 3); width, height: output size [pixels].
    supersample: sub-pixels per pixel along each axis (antialiasing of edges and texture).
    background: image of the output size with the texture's channels, or a scalar / per-channel
        colour; None is black.

    Returns (image, mask): the image has the texture's dtype and channels, shape (height, width[,
    C]); the silhouette mask is bool (height, width), True where the mesh covers at least half of
    the pixel.
    """
    import cv2  # on first use: not on ndf-sim's solve path (issue 28)

    texture = np.asarray(texture)
    uvs = np.asarray(uvs, dtype=np.float64)
    if uvs.shape != (len(points_cam), 2):
        raise ValueError(f"uvs must have shape ({len(points_cam)}, 2), got {uvs.shape}")
    if texture.ndim not in (2, 3):
        raise ValueError(f"texture must have shape (h, w) or (h, w, C), got {texture.shape}")

    raster = rasterize(points_cam, faces, K, width, height, supersample=supersample)
    tex_px = interpolate(raster, uv_to_texture_pixels(uvs, texture.shape[1], texture.shape[0]))
    sampled = cv2.remap(
        texture.astype(np.float32),
        tex_px[..., 0].astype(np.float32),
        tex_px[..., 1].astype(np.float32),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    covered = raster.mask.astype(np.float32)
    if sampled.ndim == 3:
        covered = covered[..., None]
    # Composite at output resolution: box filter of (texture x coverage) plus the background
    # weighted by what the mesh leaves uncovered, which is exact for a box-filtered render.
    coverage = downsample(covered, raster.supersample)
    foreground = downsample(sampled * covered, raster.supersample)
    image = foreground + _background(background, foreground.shape) * (1.0 - coverage)

    if np.issubdtype(texture.dtype, np.integer):
        info = np.iinfo(texture.dtype)
        image = np.clip(np.rint(image), info.min, info.max)
    mask = coverage.reshape(height, width) >= 0.5
    return image.astype(texture.dtype), mask


def _background(background, shape) -> np.ndarray:
    """Background as float32 of the output image's shape (H, W[, C])."""
    if background is None:
        return np.zeros(shape, dtype=np.float32)
    value = np.asarray(background, dtype=np.float32)
    if value.ndim >= 2 and value.shape != shape:
        raise ValueError(f"background image must have shape {shape}, got {value.shape}")
    try:
        return np.broadcast_to(value, shape)
    except ValueError:
        raise ValueError(f"background {value} does not fit an image of shape {shape}") from None

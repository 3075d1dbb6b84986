"""Z-buffered triangle rasteriser (numpy), OpenCV camera convention.

Convention (the same as OpenCV's pinhole model):
- camera axes: x right, y down, z forward (points in front of the camera have Z > 0);
- a camera-space point (X, Y, Z) projects to the pixel coordinates (u, v) = K @ (X/Z, Y/Z, 1);
- pixel centres are at integer coordinates: the pixel in column i and row j of an image is
  sampled at (u, v) = (i, j), and covers [i - 1/2, i + 1/2] x [j - 1/2, j + 1/2].

With ``supersample = s`` every pixel is sampled at an s x s grid of sub-pixel centres, i.e. the
raster is ``(s * height, s * width)`` with the sub-pixel (i', j') sampled at
((i' + 1/2) / s - 1/2, (j' + 1/2) / s - 1/2) in output pixel coordinates; `downsample`
box-filters such a raster back to the output size.
"""

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Raster",
    "rasterize",
    "interpolate",
    "interpolate_covered",
    "downsample",
    "supersampled_intrinsics",
]

# Candidate (triangle, pixel) pairs handled at once: small chunks keep the work arrays (~20 MB)
# cache- and allocator-friendly, measured 3x faster than 4M-candidate chunks.
_CHUNK_CANDIDATES = 1 << 18
# Barycentric tolerance so that pixels on an edge shared by two triangles are never missed.
_EDGE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Raster:
    """What each pixel of a rasterised image sees.

    depth: camera-space Z of the visible surface (units of the input points), shape (H, W);
        ``inf`` where no triangle covers the pixel.
    face_id: index into ``faces`` of the visible triangle, shape (H, W), int64; -1 where empty.
    bary: perspective-correct barycentric coordinates of the visible point with respect to the
        three vertices of ``faces[face_id]``, shape (H, W, 3); 0 where empty.
    faces: the triangles that were rasterised, vertex indices, shape (F, 3).
    supersample: sub-pixels per output pixel along each axis (H, W are s times the output size).
    """

    depth: np.ndarray
    face_id: np.ndarray
    bary: np.ndarray
    faces: np.ndarray
    supersample: int

    @property
    def mask(self) -> np.ndarray:
        """Pixels covered by a triangle, bool (H, W)."""
        return self.face_id >= 0


def supersampled_intrinsics(K: np.ndarray, supersample: int) -> np.ndarray:
    """Intrinsics of the s-times finer sub-pixel grid described in the module docstring."""
    s = float(supersample)
    to_fine = np.array([[s, 0.0, (s - 1.0) / 2.0], [0.0, s, (s - 1.0) / 2.0], [0.0, 0.0, 1.0]])
    return to_fine @ np.asarray(K, dtype=np.float64)


def rasterize(
    points_cam: np.ndarray,
    faces: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    supersample: int = 1,
    near: float = 1e-6,
) -> Raster:
    """Rasterise a triangle mesh seen by a pinhole camera, keeping the nearest surface per pixel.

    points_cam: vertex positions in camera coordinates (x right, y down, z forward), shape (V, 3).
    faces: vertex indices of the triangles, shape (F, 3); both orientations are drawn.
    K: camera intrinsics, shape (3, 3).
    width, height: output image size [pixels]; the raster is ``supersample`` times larger.
    near: triangles with any vertex at Z <= near (or not finite) are dropped, not clipped.
    """
    points = np.asarray(points_cam, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points_cam must have shape (V, 3), got {points.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {faces.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(points)):
        raise ValueError(f"faces index vertices outside [0, {len(points)})")
    if np.shape(K) != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {np.shape(K)}")
    if int(supersample) != supersample or supersample < 1:
        raise ValueError(f"supersample must be a positive integer, got {supersample}")
    if width < 1 or height < 1:
        raise ValueError(f"width and height must be positive, got {width} x {height}")

    s = int(supersample)
    fine_w, fine_h = s * int(width), s * int(height)
    depth = np.full(fine_h * fine_w, np.inf)
    face_id = np.full(fine_h * fine_w, -1, dtype=np.int64)
    bary = np.zeros((fine_h * fine_w, 3))

    z = points[:, 2]
    usable = np.all(np.isfinite(points), axis=1) & (z > near)
    visible_faces = np.nonzero(np.all(usable[faces], axis=1))[0]
    if len(visible_faces):
        tri = faces[visible_faces]
        projected = points @ supersampled_intrinsics(K, s).T
        with np.errstate(divide="ignore", invalid="ignore"):
            pixel = projected[:, :2] / projected[:, 2:3]
        _rasterize_projected(
            pixel[tri], z[tri], visible_faces, fine_w, fine_h, depth, face_id, bary
        )

    return Raster(
        depth=depth.reshape(fine_h, fine_w),
        face_id=face_id.reshape(fine_h, fine_w),
        bary=bary.reshape(fine_h, fine_w, 3),
        faces=faces,
        supersample=s,
    )


def _rasterize_projected(corner_px, corner_z, face_index, width, height, depth, face_id, bary):
    """Scan-convert triangles given by pixel corners (F, 3, 2) and depths (F, 3) into the buffers.

    Works on every (triangle, pixel in its bounding box) pair at once, chunked to bound memory.
    """
    x, y = corner_px[..., 0], corner_px[..., 1]
    # Twice the signed screen area; its sign is the orientation, which is not culled.
    area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    # Bounding boxes of sub-pixel centres; clip before casting, projections near Z = 0 are huge.
    x_lo = np.ceil(np.clip(x.min(axis=1), -1.0, width) - _EDGE_TOLERANCE).astype(np.int64)
    x_hi = np.floor(np.clip(x.max(axis=1), -1.0, width) + _EDGE_TOLERANCE).astype(np.int64)
    y_lo = np.ceil(np.clip(y.min(axis=1), -1.0, height) - _EDGE_TOLERANCE).astype(np.int64)
    y_hi = np.floor(np.clip(y.max(axis=1), -1.0, height) + _EDGE_TOLERANCE).astype(np.int64)
    x_lo, y_lo = np.maximum(x_lo, 0), np.maximum(y_lo, 0)
    x_hi, y_hi = np.minimum(x_hi, width - 1), np.minimum(y_hi, height - 1)
    keep = (np.abs(area2) > 1e-12) & (x_lo <= x_hi) & (y_lo <= y_hi)
    if not keep.any():
        return
    x, y, corner_z, area2 = x[keep], y[keep], corner_z[keep], area2[keep]
    face_index, x_lo, x_hi, y_lo, y_hi = (a[keep] for a in (face_index, x_lo, x_hi, y_lo, y_hi))

    # Screen-space barycentrics are affine in the pixel position: w_k = a_k u + b_k v + c_k.
    coeff = np.empty((len(x), 2, 3))
    for k in range(2):
        i, j = (k + 1) % 3, (k + 2) % 3
        coeff[:, k, 0] = (y[:, i] - y[:, j]) / area2
        coeff[:, k, 1] = (x[:, j] - x[:, i]) / area2
        coeff[:, k, 2] = (x[:, i] * y[:, j] - x[:, j] * y[:, i]) / area2
    inverse_z = 1.0 / corner_z

    box_w = x_hi - x_lo + 1
    counts = box_w * (y_hi - y_lo + 1)
    ends = np.cumsum(counts)
    start = 0
    while start < len(counts):
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + _CHUNK_CANDIDATES, side="right")), start + 1)
        sl = slice(start, stop)
        start = stop

        n = counts[sl]
        owner = np.repeat(np.arange(len(n)), n)
        offset = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        bw = box_w[sl][owner]
        px = (x_lo[sl][owner] + offset % bw).astype(np.float64)
        py = (y_lo[sl][owner] + offset // bw).astype(np.float64)
        c = coeff[sl][owner]
        w0 = c[:, 0, 0] * px + c[:, 0, 1] * py + c[:, 0, 2]
        w1 = c[:, 1, 0] * px + c[:, 1, 1] * py + c[:, 1, 2]
        w2 = 1.0 - w0 - w1
        inside = (w0 >= -_EDGE_TOLERANCE) & (w1 >= -_EDGE_TOLERANCE) & (w2 >= -_EDGE_TOLERANCE)
        owner, px, py = owner[inside], px[inside], py[inside]
        screen = np.stack([w0[inside], w1[inside], w2[inside]], axis=1)
        if not len(owner):
            continue

        # Perspective correction: barycentrics are affine in screen space for (w_k / z_k).
        weighted = screen * inverse_z[sl][owner]
        point_depth = 1.0 / weighted.sum(axis=1)
        point_bary = np.clip(weighted * point_depth[:, None], 0.0, 1.0)
        pix = py.astype(np.int64) * width + px.astype(np.int64)

        # Z-buffer: the depth buffer takes the minimum over this chunk and earlier ones; the
        # candidates that reach it are visible (on exact ties the last one written wins).
        np.minimum.at(depth, pix, point_depth)
        best = np.nonzero(point_depth == depth[pix])[0]
        face_id[pix[best]] = face_index[sl][owner[best]]
        bary[pix[best]] = point_bary[best]


def interpolate(raster: Raster, vertex_attributes: np.ndarray, *, fill: float = 0.0) -> np.ndarray:
    """Per-pixel value of a per-vertex attribute, interpolated perspective-correctly.

    vertex_attributes: shape (V, C) or (V,). Returns (H, W, C) or (H, W) float64 with ``fill``
    where no triangle covers the pixel.
    """
    values = np.asarray(vertex_attributes, dtype=np.float64)
    pixel_index, covered_values = interpolate_covered(raster, values.reshape(len(values), -1))
    h, w = raster.face_id.shape
    out = np.full((h * w, covered_values.shape[1]), float(fill))
    out[pixel_index] = covered_values
    return out.reshape((h, w) + values.shape[1:])


def interpolate_covered(
    raster: Raster, vertex_attributes: np.ndarray, where: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Like `interpolate`, only at covered pixels (saves memory on large supersampled rasters).

    vertex_attributes: shape (V, C). where: bool (H * W,), the covered pixels wanted (default
    all covered ones). Returns the pixels' flat indices into H * W, shape (M,), and their
    interpolated values, shape (M, C).
    """
    values = np.asarray(vertex_attributes, dtype=np.float64)
    pixel_index = np.nonzero(raster.face_id.ravel() >= 0 if where is None else where)[0]
    corners = raster.faces[raster.face_id.ravel()[pixel_index]]
    weights = raster.bary.reshape(-1, 3)[pixel_index]
    return pixel_index, np.einsum("mk,mkc->mc", weights, values[corners])


def downsample(image: np.ndarray, supersample: int) -> np.ndarray:
    """Box-filter an s-times supersampled image (H s, W s, ...) to (H, W, ...), keeping dtype."""
    s = int(supersample)
    if s == 1:
        return image
    h, w = image.shape[0] // s, image.shape[1] // s
    if image.shape[0] != h * s or image.shape[1] != w * s:
        raise ValueError(f"image shape {image.shape[:2]} is not a multiple of {s}")
    blocks = image.reshape(h, s, w, s, *image.shape[2:])
    if image.dtype == np.uint8 and s * s * 255 <= np.iinfo(np.uint16).max:
        # exact integer sums (the float64 mean's sum is exact for these too): the same result
        # without a float64 copy of the supersampled image
        mean = blocks.sum(axis=3, dtype=np.uint16).sum(axis=1, dtype=np.uint16) / (s * s)
    else:
        mean = blocks.astype(np.float64).mean(axis=(1, 3))
    if np.issubdtype(image.dtype, np.integer):
        info = np.iinfo(image.dtype)
        return np.clip(np.rint(mean), info.min, info.max).astype(image.dtype)
    return mean.astype(image.dtype)

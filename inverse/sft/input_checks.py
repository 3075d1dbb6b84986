"""Checks that shape-from-template inputs fit together, run before any expensive work.

Each measures one thing on frame 0 and the template:
- ``silhouette_iou``: how well the template's projected silhouette covers the sheet's mask
  (a template in other axes than the camera's projects off the sheet or off the image);
- ``in_view_fraction``: the share of template vertices that project inside the image;
- ``uv_texture_ncc``: whether the texture, mapped through the template's UVs, looks like
  frame 0 where the template projects (normalised cross-correlation of small patches);
- ``check_template_in_view``, ``check_uvs_match_texture``, ``check_cloud_in_camera_frame``:
  the same as refusals, raising :class:`InputError` with one line that names the problem.
Thresholds are measured on φ-SfT's R1 and the synthetic sequences (``docs/sft.md`` §1).
"""

from __future__ import annotations

import cv2
import numpy as np

from inverse.sft.camera import Camera
from inverse.sft.errors import InputError
from inverse.sft.image import to_gray
from inverse.sft.inputs import Template
from inverse.sft.matching import patch_ncc, prefiltered_texture
from inverse.sft.metrics import nearest_sq_distances
from taichi_ndf.render import uv_to_texture_pixels

# The silhouette is drawn at this fraction of the camera's resolution (a 1920 x 1080 frame:
# 480 x 270), enough to tell a fitting template from one in other axes.
SILHOUETTE_SCALE = 0.25
# Refuse below these (measured values in docs/sft.md §1).
MIN_SILHOUETTE_IOU = 0.5
MIN_IN_VIEW_FRACTION = 0.9
MIN_UV_NCC = 0.5
# Patches for the UV check: half-width [px] in frame 0, at most this many, textured ones only
# (grey-level spread above MIN_PATCH_SPREAD of 255).
NCC_RADIUS = 7
NCC_PATCHES = 400
MIN_PATCH_SPREAD = 4.0
# A cloud in the camera's frame has its median template-vertex distance below this share of
# the template's diagonal.
MAX_CLOUD_OFFSET = 0.1


def silhouette(vertices: np.ndarray, faces: np.ndarray, camera: Camera) -> np.ndarray:
    """The template's projected silhouette at SILHOUETTE_SCALE, bool (h', w'); vertices in
    camera coordinates [m] (V, 3) with z > 0, triangles (F, 3)."""
    w, h = _scaled_size(camera)
    pixels = (camera.project(vertices) + 0.5) * SILHOUETTE_SCALE - 0.5
    image = np.zeros((h, w), np.uint8)
    shift = 4
    polygons = np.rint(pixels[faces] * (1 << shift)).astype(np.int32)
    # Far-off projections overflow OpenCV's fixed-point coordinates: clip them to a band
    # around the image, which keeps what falls inside.
    polygons = np.clip(polygons, -(w + h) << shift, 2 * (w + h) << shift)
    cv2.fillPoly(image, list(polygons), 1, cv2.LINE_8, shift)
    return image.astype(bool)


def silhouette_iou(vertices: np.ndarray, faces: np.ndarray, camera: Camera,
                   mask: np.ndarray) -> float:
    """Intersection over union of the template's silhouette and the mask (h, w) bool."""
    w, h = _scaled_size(camera)
    small = cv2.resize(mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_AREA) > 0
    drawn = silhouette(vertices, faces, camera)
    union = np.count_nonzero(drawn | small)
    return float(np.count_nonzero(drawn & small) / union) if union else 0.0


def in_view_fraction(vertices: np.ndarray, camera: Camera) -> float:
    """Share of the vertices (V, 3) [m] in front of the camera that project inside the image."""
    front = vertices[:, 2] > 0
    if not front.any():
        return 0.0
    xy = camera.project(vertices[front])
    inside = (xy[:, 0] >= -0.5) & (xy[:, 0] <= camera.width - 0.5) \
        & (xy[:, 1] >= -0.5) & (xy[:, 1] <= camera.height - 0.5)
    return float(np.count_nonzero(inside) / len(vertices))


def uv_texture_ncc(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                   texture: np.ndarray, frame: np.ndarray, camera: Camera,
                   mask: np.ndarray | None = None) -> tuple[float, int]:
    """Median NCC of frame-0 patches and the texture mapped onto them through the UVs.

    At the centroids of (up to NCC_PATCHES, evenly spread) triangles that project inside the
    image (and the mask), a (2 NCC_RADIUS + 1)² patch of frame 0 is compared with the texture
    under the triangle's affine image → texture map; untextured patches are skipped. Returns
    the median NCC and the number of patches compared (0: nothing to compare, NCC nan).
    """
    tri_img = camera.project(vertices)[faces]
    tri_tex = uv_to_texture_pixels(uvs, texture.shape[1], texture.shape[0])[faces]
    centre_img, centre_tex = tri_img.mean(axis=1), tri_tex.mean(axis=1)
    edges_img = np.stack([tri_img[:, 1] - tri_img[:, 0], tri_img[:, 2] - tri_img[:, 0]], -1)
    edges_tex = np.stack([tri_tex[:, 1] - tri_tex[:, 0], tri_tex[:, 2] - tri_tex[:, 0]], -1)
    det = np.linalg.det(edges_img)
    r = NCC_RADIUS
    ok = (np.abs(det) > 1.0) & (centre_img[:, 0] > r + 1) & (centre_img[:, 1] > r + 1) \
        & (centre_img[:, 0] < camera.width - r - 2) & (centre_img[:, 1] < camera.height - r - 2)
    if mask is not None:
        col, row = np.rint(centre_img.clip(0)).astype(int).T
        ok[ok] = mask[row[ok], col[ok]]
    index = np.flatnonzero(ok)
    if len(index) == 0:
        return float("nan"), 0
    gray = to_gray(frame).astype(np.float32)
    spread = np.array([gray[int(y) - r:int(y) + r + 1, int(x) - r:int(x) + r + 1].std()
                       for x, y in centre_img[index]])
    index = index[spread > MIN_PATCH_SPREAD]
    if len(index) == 0:
        return float("nan"), 0
    index = index[np.linspace(0, len(index) - 1, min(NCC_PATCHES, len(index))).astype(int)]
    jacobian = edges_tex[index] @ np.linalg.inv(edges_img[index])
    template = Template(vertices=vertices, faces=faces, uvs=uvs)
    texture_gray = prefiltered_texture(texture, template, camera,
                                       uv_to_texture_pixels(uvs, texture.shape[1],
                                                            texture.shape[0]))
    ncc = patch_ncc(gray, texture_gray, centre_img[index], centre_tex[index], jacobian, r)
    return float(np.median(ncc)), int(len(index))


def check_template_in_view(vertices: np.ndarray, faces: np.ndarray, camera: Camera,
                           mask: np.ndarray | None, *, what: str = "template") -> None:
    """InputError unless the template projects inside the image (and onto mask 0)."""
    if not np.all(np.isfinite(vertices)):
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        raise InputError(f"{what}: vertices {bad[:5].tolist()} are not finite (NaN or inf)")
    share = in_view_fraction(vertices, camera)
    if share < MIN_IN_VIEW_FRACTION:
        raise InputError(
            f"{what}: only {100 * share:.0f} % of its vertices project inside the "
            f"{camera.width}x{camera.height} image (need {100 * MIN_IN_VIEW_FRACTION:.0f} %): "
            "not in this camera's coordinates (OpenCV axes: x right, y down, z forward)?")
    if mask is not None:
        iou = silhouette_iou(vertices, faces, camera, mask)
        if iou < MIN_SILHOUETTE_IOU:
            raise InputError(
                f"{what}: its projected silhouette overlaps mask 0 by IoU {iou:.2f} (need "
                f"{MIN_SILHOUETTE_IOU}): not in this camera's coordinates, or not frame 0's shape")


def check_uvs_match_texture(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                            texture: np.ndarray, frame: np.ndarray, camera: Camera,
                            mask: np.ndarray | None, *, what: str = "template UVs") -> float:
    """InputError when the texture mapped through the UVs does not look like frame 0; returns
    the median patch NCC (nan when frame 0 has no textured patch under the template)."""
    ncc, count = uv_texture_ncc(vertices, faces, uvs, texture, frame, camera, mask)
    if count and ncc < MIN_UV_NCC:
        flip = _fitting_flip(vertices, faces, uvs, texture, frame, camera, mask)
        hint = (f"the template's axes look flipped: with {flip[0]} the texture matches "
                f"(NCC {flip[1]:.2f}); give the template in OpenCV camera axes" if flip else
                "re-derive the UVs by projecting the template into frame 0, or give frame 0's "
                "texture")
        raise InputError(
            f"{what}: the texture mapped through them does not match frame 0 (median patch "
            f"NCC {ncc:.2f} over {count} patches, need {MIN_UV_NCC}); {hint}")
    return ncc


def _fitting_flip(vertices, faces, uvs, texture, frame, camera, mask):
    """(name, NCC) of the best sign flip of the template's axes (z kept positive) under which
    the texture matches frame 0, or None."""
    best = None
    for signs, name in (((-1, -1, 1), "x and y negated"), ((-1, 1, 1), "x negated"),
                        ((1, -1, 1), "y negated")):
        flipped = vertices * signs
        if in_view_fraction(flipped, camera) < MIN_IN_VIEW_FRACTION:
            continue
        ncc, count = uv_texture_ncc(flipped, faces, uvs, texture, frame, camera, mask)
        if count and ncc >= MIN_UV_NCC and (best is None or ncc > best[1]):
            best = (name, ncc)
    return best


def check_cloud_in_camera_frame(vertices: np.ndarray, cloud: np.ndarray, *,
                                what: str = "point cloud 0") -> float:
    """InputError when ground-truth cloud 0 (N, 3) [m] is not where the template (frame 0's
    shape, camera coordinates) is; returns the median vertex-to-cloud distance [m]."""
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    median = float(np.sqrt(np.median(nearest_sq_distances(vertices, cloud))))
    if median > MAX_CLOUD_OFFSET * diagonal:
        raise InputError(
            f"{what}: the template's vertices are {1000 * median:.0f} mm (median) from it, "
            f"{median / diagonal:.2f} of the template's size (need <= {MAX_CLOUD_OFFSET}): the "
            "clouds are not in the camera's coordinates of frame 0")
    return median


def _scaled_size(camera: Camera) -> tuple[int, int]:
    return (max(1, round(camera.width * SILHOUETTE_SCALE)),
            max(1, round(camera.height * SILHOUETTE_SCALE)))

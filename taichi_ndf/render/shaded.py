"""Shaded renders of a surface mesh, optionally coloured by a per-vertex scalar."""

import cv2
import numpy as np

from taichi_ndf.io.normals import vertex_normals
from taichi_ndf.render.camera import Camera, frame_mesh, widest_azimuth
from taichi_ndf.render.raster import downsample, interpolate_covered, rasterize

__all__ = ["render_shaded", "colormap", "colour_bar", "colour_range", "vertex_scalars",
           "lambert_intensity", "welded_normals",
           "BACKGROUND_BGR", "SURFACE_BGR"]

BACKGROUND_BGR = (235, 235, 235)
SURFACE_BGR = np.array([205.0, 150.0, 95.0])  # steel blue
_MISSING_BGR = np.array([128.0, 128.0, 128.0])  # scalar is NaN
_TEXT_BGR = (40, 40, 40)
_AMBIENT = 0.3
# Light direction in camera axes (x right, y down, z forward): from above-left, behind the viewer.
_TOWARD_LIGHT = np.array([-0.4, -0.6, -1.0]) / np.linalg.norm([-0.4, -0.6, -1.0])
_VIRIDIS = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)[:, 0]


def colormap(values: np.ndarray, value_range: tuple[float, float]) -> np.ndarray:
    """Viridis BGR colours in [0, 255] (float) of ``values`` over ``value_range``; NaN is grey."""
    lo, hi = value_range
    span = hi - lo if hi > lo else 1.0
    t = np.clip((np.asarray(values, dtype=np.float64) - lo) / span, 0.0, 1.0)
    finite = np.isfinite(t)
    index = np.rint(np.where(finite, t, 0.0) * 255).astype(np.int64)
    return np.where(finite[..., None], _VIRIDIS[index].astype(np.float64), _MISSING_BGR)


def render_shaded(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    scalars: np.ndarray | None = None,
    camera: Camera | None = None,
    width: int = 800,
    height: int = 600,
    scalar_label: str = "",
    scalar_range: tuple[float, float] | None = None,
    supersample: int = 3,
) -> np.ndarray:
    """Render a surface with Lambert + ambient shading (both sides lit), as uint8 BGR (H, W, 3).

    vertices: world positions [m], shape (V, 3); faces: triangles (F, 3).
    scalars: optional per-vertex values (V,) shown with the viridis colour map and a colour bar
        (labelled ``scalar_label``) on the right; ``scalar_range`` defaults to their finite range.
    camera: defaults to `frame_mesh` (looking down at 30 degrees, z up) from `widest_azimuth`
        (a diagonal unless another side shows the surface larger).
    supersample: sub-pixels per pixel along each axis, for antialiased edges.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if scalars is not None:
        scalars = vertex_scalars(scalars, len(vertices))
        scalar_range = scalar_range or colour_range(scalars)
        bar = colour_bar(scalar_range, scalar_label, height)
        view_width = width - bar.shape[1]
        if view_width < 16:
            raise ValueError(f"width {width} leaves no room for the image beside the colour bar")
    else:
        view_width = width

    if camera is None:
        camera = frame_mesh(vertices, width=view_width, height=height,
                            azimuth_deg=widest_azimuth(vertices, faces))
    points_cam = camera.to_camera(vertices)
    raster = rasterize(
        points_cam,
        faces,
        camera.intrinsics(view_width, height),
        view_width,
        height,
        supersample=supersample,
    )
    normals = welded_normals(vertices, faces) @ camera.rotation.T
    attributes = [normals, points_cam] + ([] if scalars is None else [scalars[:, None]])
    pixel_index, per_pixel = interpolate_covered(raster, np.concatenate(attributes, axis=1))
    intensity = lambert_intensity(per_pixel[:, 0:3], per_pixel[:, 3:6])
    base = SURFACE_BGR if scalars is None else colormap(per_pixel[:, 6], scalar_range)

    fine_h, fine_w = raster.face_id.shape
    fine = np.empty((fine_h * fine_w, 3), dtype=np.uint8)
    fine[:] = BACKGROUND_BGR
    fine[pixel_index] = np.clip(np.rint(base * intensity[:, None]), 0, 255)
    image = downsample(fine.reshape(fine_h, fine_w, 3), raster.supersample)
    if scalars is not None:
        image = np.concatenate([image, bar], axis=1)
    return image


def vertex_scalars(scalars, count: int) -> np.ndarray:
    """Per-vertex values as float64 (count,), checked."""
    scalars = np.asarray(scalars, dtype=np.float64)
    if scalars.shape != (count,):
        raise ValueError(f"scalars must have shape ({count},), got {scalars.shape}")
    return scalars


def colour_range(values: np.ndarray, percentiles=(0.0, 100.0)) -> tuple[float, float]:
    """The values at the ends of the colour map: these percentiles of the finite values (their
    minimum and maximum by default), (0, 1) when there is none."""
    finite = values[np.isfinite(values)]
    if not len(finite):
        return 0.0, 1.0
    lo, hi = np.percentile(finite, percentiles)
    return float(lo), float(hi)


def welded_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Vertex normals (V, 3) in which vertices at the same position share their normal, so
    duplicated seams shade smoothly."""
    _, canonical = np.unique(
        np.round(vertices / _weld_tolerance(vertices)), axis=0, return_inverse=True
    )
    return vertex_normals(vertices, faces, canonical=canonical.ravel())


def lambert_intensity(normal: np.ndarray, view_ray: np.ndarray) -> np.ndarray:
    """Ambient + Lambert brightness in [0, 1] (M,) of points with normals (M, 3) seen along
    view rays (M, 3), both in camera axes; two-sided (normals turned towards the viewer)."""
    facing = np.sign(np.einsum("mc,mc->m", normal, view_ray))
    normal = normal * -np.where(facing == 0, 1.0, facing)[:, None]
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    return _AMBIENT + (1.0 - _AMBIENT) * np.clip(normal @ _TOWARD_LIGHT, 0.0, 1.0)


def _weld_tolerance(vertices: np.ndarray) -> float:
    """Positions closer than this (relative to the mesh size) count as the same point."""
    finite = vertices[np.all(np.isfinite(vertices), axis=1)]
    extent = np.ptp(finite, axis=0).max() if len(finite) else 0.0
    return 1e-9 * extent if extent > 0 else 1.0


def colour_bar(value_range, label: str, height: int) -> np.ndarray:
    """A panel (height, w, 3) with a vertical viridis bar, its end and middle values, a label."""
    font, scale, thickness = cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1
    lo, hi = value_range
    ticks = [(hi, 0.0), (0.5 * (lo + hi), 0.5), (lo, 1.0)]
    texts = [f"{value:.3g}" for value, _ in ticks]
    text_w = max(cv2.getTextSize(t, font, scale, thickness)[0][0] for t in texts)
    label_w = cv2.getTextSize(label, font, scale, thickness)[0][0] if label else 0
    bar_w, pad = 16, 10
    panel_w = max(pad + bar_w + 6 + text_w + pad, label_w + 2 * pad)
    panel = np.full((height, panel_w, 3), BACKGROUND_BGR, dtype=np.uint8)

    top, bottom = int(0.2 * height), int(0.8 * height)
    fraction = np.linspace(1.0, 0.0, bottom - top)
    column = colormap(lo + fraction * (hi - lo), (lo, hi)).astype(np.uint8)
    panel[top:bottom, pad : pad + bar_w] = column[:, None, :]
    cv2.rectangle(panel, (pad, top), (pad + bar_w - 1, bottom - 1), _TEXT_BGR, 1)
    for text, (_, position) in zip(texts, ticks, strict=True):
        y = int(round(top + position * (bottom - 1 - top)))
        cv2.putText(
            panel, text, (pad + bar_w + 6, y + 5), font, scale, _TEXT_BGR, thickness, cv2.LINE_AA
        )
    if label:
        cv2.putText(panel, label, (pad, top - 12), font, scale, _TEXT_BGR, thickness, cv2.LINE_AA)
    return panel

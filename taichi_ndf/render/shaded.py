"""Shaded renders of a surface mesh, optionally coloured by a per-vertex scalar."""

import numpy as np

from taichi_ndf.io.normals import vertex_normals
from taichi_ndf.render.camera import Camera, frame_mesh, widest_azimuth
from taichi_ndf.render.colour import colormap, colour_bar, colour_range, colour_scale
from taichi_ndf.render.raster import downsample, interpolate_covered, rasterize

__all__ = ["render_shaded", "colormap", "colour_bar", "colour_range", "vertex_scalars",
           "lambert_intensity", "welded_normals",
           "BACKGROUND_BGR", "SURFACE_BGR"]

BACKGROUND_BGR = (235, 235, 235)
SURFACE_BGR = np.array([205.0, 150.0, 95.0])  # steel blue
# Soft studio lighting, directions towards the lights in camera axes (x right, y down,
# z forward): a key light from above-left behind the viewer with a wrapped falloff (the
# terminator a soft gradient, not a hard edge), a dim fill from the right, and an ambient
# term brighter for surfaces facing up (a sky) than down. The weights sum to 1 (full light).
_KEY = np.array([-0.4, -0.6, -1.0]) / np.linalg.norm([-0.4, -0.6, -1.0])
_FILL = np.array([0.7, -0.1, -1.0]) / np.linalg.norm([0.7, -0.1, -1.0])
_KEY_WEIGHT, _FILL_WEIGHT, _AMBIENT, _SKY = 0.55, 0.15, 0.22, 0.08
_WRAP = 0.35  # key light reaches this far (in n·l) behind the terminator


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
        (labelled ``scalar_label``) on the right; ``scalar_range`` defaults to their 1st to
        99th percentile (`colour_scale`; the bar states what lies beyond).
    camera: defaults to `frame_mesh` (looking down at 30 degrees, z up) from `widest_azimuth`
        (a diagonal unless another side shows the surface larger).
    supersample: sub-pixels per pixel along each axis, for antialiased edges.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if scalars is not None:
        scalars = vertex_scalars(scalars, len(vertices))
        scalar_range = colour_scale(scalars, value_range=scalar_range)
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


def welded_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Vertex normals (V, 3) in which vertices at the same position share their normal, so
    duplicated seams shade smoothly."""
    _, canonical = np.unique(
        np.round(vertices / _weld_tolerance(vertices)), axis=0, return_inverse=True
    )
    return vertex_normals(vertices, faces, canonical=canonical.ravel())


def lambert_intensity(normal: np.ndarray, view_ray: np.ndarray) -> np.ndarray:
    """Soft diffuse brightness in [0, 1] (M,) of points with normals (M, 3) seen along view
    rays (M, 3), both in camera axes: wrapped key light, fill light, sky-tinted ambient
    (module constants); two-sided (normals turned towards the viewer)."""
    facing = np.sign(np.einsum("mc,mc->m", normal, view_ray))
    normal = normal * -np.where(facing == 0, 1.0, facing)[:, None]
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    key = np.clip((normal @ _KEY + _WRAP) / (1.0 + _WRAP), 0.0, 1.0)
    fill = np.clip(normal @ _FILL, 0.0, 1.0)
    sky = 0.5 * (1.0 - normal[:, 1])  # 1 facing up (camera -y), 0 facing down
    return _AMBIENT + _SKY * sky + _KEY_WEIGHT * key + _FILL_WEIGHT * fill


def _weld_tolerance(vertices: np.ndarray) -> float:
    """Positions closer than this (relative to the mesh size) count as the same point."""
    finite = vertices[np.all(np.isfinite(vertices), axis=1)]
    extent = np.ptp(finite, axis=0).max() if len(finite) else 0.0
    return 1e-9 * extent if extent > 0 else 1.0

"""Figures of a result: the coloured surface from one or more named views, obstacles in grey, a
soft shadow on the ground below, one colour bar with units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_ndf.render.camera import frame_mesh, ground_axes, widest_azimuth
from taichi_ndf.render.colour import (
    ROBUST_PERCENTILES,
    ColourScale,
    colormap,
    colour_bar,
    colour_scale,
)
from taichi_ndf.render.legend import Legend, legend_panel
from taichi_ndf.render.raster import downsample, interpolate_covered, rasterize
from taichi_ndf.render.shaded import (
    BACKGROUND_BGR,
    SURFACE_BGR,
    lambert_intensity,
    vertex_scalars,
    welded_normals,
)

__all__ = ["VIEWS", "RANGE_PERCENTILES", "VIEW_ASPECT", "Obstacle", "render_figure",
           "fitted_width", "shadow_points"]

# Named views: (elevation above the ground [deg], azimuth around up [deg]) for `frame_mesh`
# (azimuth 0 looks from the world axis least aligned with up; with z up that is +x). The
# three-quarter view's azimuth None: `widest_azimuth` of the surface, the diagonal -45 unless
# another side shows the shape at least 10 % larger (a sheet hanging in a vertical plane).
VIEWS = {"iso": (30.0, None), "front": (8.0, -90.0), "side": (8.0, 0.0), "top": (89.99, -90.0)}

RANGE_PERCENTILES = ROBUST_PERCENTILES  # default colour range of the scalars
VIEW_ASPECT = (0.5, 4.0 / 3.0)  # width / height of a view fitted to its shape (width=None)
# `frame_mesh`'s margin: the fraction of the half field of view left free on the tighter side
# (at 600 pixels 24 rows; a label's 46 rows need `label_rows`).
FRAME_MARGIN = 0.08
OBSTACLE_BGR = np.array([160.0, 160.0, 160.0])
_SHADOW_DARKNESS = 0.35  # fraction of the background's brightness a full shadow removes
# Direction towards the light, in the ground frame (east, north, up): high, slightly to the side.
_LIGHT_TILT = np.array([0.25, 0.35, 1.0])


@dataclass(frozen=True)
class Obstacle:
    """A rigid mesh drawn in grey beside the result: vertices [m] (V, 3), faces (F, 3)."""

    vertices: np.ndarray
    faces: np.ndarray


def shadow_points(points: np.ndarray, up, ground_height: float) -> np.ndarray:
    """Points (N, 3) projected along the light onto the ground plane {x . up = ground_height}."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    east, north = ground_axes(up)
    light = _LIGHT_TILT[0] * east + _LIGHT_TILT[1] * north + _LIGHT_TILT[2] * up
    light /= np.linalg.norm(light)
    height = points @ up - ground_height
    return points - (height / (light @ up))[:, None] * light[None, :]


def soft_shadow(coverage: np.ndarray, sigma: float, supersample: int) -> np.ndarray:
    """The shadow's coverage (fine_h, fine_w) of the supersampled image blurred by a Gaussian
    of `sigma` fine pixels: at the output resolution (area-averaged, sigma / supersample) and
    back up bilinearly: 0.011 instead of 0.3-0.5 s CPU at 1800 x 2400 fine pixels, within 0.02
    of the full-resolution blur (under 2 grey levels of 255 at the shadow's depth; the napkin's
    render.png changed by 1 level in 0.13 % of its pixels)."""
    import cv2  # on first use: not on ndf-sim's solve path (issue 28)

    fine_h, fine_w = coverage.shape
    coarse = cv2.resize(coverage.astype(np.float32), (fine_w // supersample,
                        fine_h // supersample), interpolation=cv2.INTER_AREA)
    blurred = cv2.GaussianBlur(coarse, (0, 0), sigma / supersample)
    return cv2.resize(blurred, (fine_w, fine_h), interpolation=cv2.INTER_LINEAR).astype(
        np.float64)


def render_figure(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    scalars: np.ndarray | None = None,
    scalar_label: str = "",
    scalar_range: tuple[float, float] | None = None,
    obstacles: tuple[Obstacle, ...] = (),
    views: tuple[str, ...] = ("iso",),
    up=(0.0, 0.0, 1.0),
    width: int | None = 800,
    height: int = 600,
    shadow: bool = True,
    supersample: int = 3,
    frame_points: np.ndarray | None = None,
    azimuth_deg: float | None = None,
    legend: Legend | None = None,
    label_rows: int = 0,
) -> np.ndarray:
    """The surface (V, 3) [m] with faces (F, 3) side by side from each of `views` (names in
    VIEWS), uint8 BGR (height, width, 3).

    width: of the whole image, shared equally by the views; None: each view as wide as the
        framed shape's extent needs (its width-to-height ratio, clipped to VIEW_ASPECT), so a
        tall hanging sheet is not a narrow strip in a wide frame.

    scalars: per-vertex values (V,) coloured with viridis and shown on a colour bar labelled
        `scalar_label` (give the units); without them the surface is steel blue.
    scalar_range: the values at the ends of the colour map; by default the 1st and 99th
        percentiles (a singular point, such as a pinned corner, then does not wash out the rest;
        values beyond are drawn in the end colours, and the colour bar states how many and
        their extremes); a ColourScale is used as it is, its colour bar stating what it
        states (a video's frames: the scale of all of them, one bar drawn once).
    obstacles: rigid meshes drawn in grey (they cast shadows too).
    up: the world direction shown upwards (against gravity); the ground plane lies just below
        the lowest point of the surface and the obstacles, normal to it.
    frame_points: points (N, 3) [m] the camera frames and the ground lies below, instead of
        the surface and obstacles (frames of a video: all of its frames, so the camera stays);
    azimuth_deg: the azimuth of every view (default: each view's own, `widest_azimuth` for
        the three-quarter view).
    legend: the scalars are category indices (0, 1, ...: a garment's panels), each drawn in
        its colour of the categorical palette and named in a legend (titled `scalar_label`)
        instead of the colour bar; scalar_range is then unused.
    label_rows: pixels at the top of the image kept free of the framed shape, for a label
        written there afterwards (`trajectory.put_label`): the framing's margin is widened to
        at least this many rows on every side (default FRAME_MARGIN of the half height).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    unknown = [v for v in views if v not in VIEWS]
    if not views or unknown:
        raise ValueError(f"views must be some of {', '.join(VIEWS)}, got {list(views)}")
    if not 0 <= label_rows < height // 2:
        raise ValueError(f"label_rows must be in [0, {height // 2}), got {label_rows}")
    margin = max(FRAME_MARGIN, 2.0 * label_rows / height)
    bar = None
    if scalars is not None:
        scalars = vertex_scalars(scalars, len(vertices))
        if legend is not None:
            bar = legend_panel(legend, height, title=scalar_label)
        else:
            if not isinstance(scalar_range, ColourScale):
                scalar_range = colour_scale(scalars, RANGE_PERCENTILES,
                                            value_range=scalar_range)
            bar = colour_bar(scalar_range, scalar_label, height)
    bar_width = 0 if bar is None else bar.shape[1]
    if width is not None and ((width - bar_width) // len(views) < 16 or height < 16):
        raise ValueError(f"a {width}x{height} image leaves no room for {len(views)} view(s)"
                         + ("" if bar is None else " and the colour bar"))

    # One triangle soup: part 0 the surface, 1 the obstacles, 2 the shadow (depth only).
    parts = [(vertices, faces, 0)] + [(np.asarray(o.vertices, dtype=np.float64),
                                       np.asarray(o.faces, dtype=np.int64), 1) for o in obstacles]
    solid = np.concatenate([p[0] for p in parts])
    if frame_points is not None:
        solid = np.asarray(frame_points, dtype=np.float64).reshape(-1, 3)
    size = max(float(np.ptp(solid, axis=0).max()), 1e-9)
    ground = float((solid @ up).min()) - 0.02 * size
    if shadow:
        parts += [(shadow_points(p[0], up, ground + 1e-3 * size), p[1], 2) for p in parts]
    offsets = np.cumsum([0] + [len(p[0]) for p in parts])
    all_points = np.concatenate([p[0] for p in parts])
    framed = all_points if frame_points is None else np.concatenate(
        [solid, shadow_points(solid, up, ground) if shadow else solid[:0]])
    all_faces = np.concatenate([p[1] + o for p, o in zip(parts, offsets, strict=False)])
    face_part = np.concatenate([np.full(len(p[1]), p[2]) for p in parts])
    vertex_scalar = np.full(len(all_points), np.nan)
    if scalars is not None:
        vertex_scalar[: len(vertices)] = scalars
    normals = welded_normals(all_points, all_faces)

    pictures = []
    for view in views:
        elevation, azimuth = VIEWS[view]
        azimuth = azimuth if azimuth_deg is None else azimuth_deg
        if azimuth is None:
            azimuth = widest_azimuth(vertices, faces, up=up, elevation_deg=elevation)
        if width is None:
            view_width = fitted_width(framed, height, up=up, elevation_deg=elevation,
                                      azimuth_deg=azimuth)
        else:
            view_width = (width - bar_width) // len(views)
        camera = frame_mesh(framed, width=view_width, height=height, up=tuple(up),
                            elevation_deg=elevation, azimuth_deg=azimuth, margin=margin)
        points_cam = camera.to_camera(all_points)
        raster = rasterize(points_cam, all_faces, camera.intrinsics(view_width, height),
                           view_width, height, supersample=supersample)
        fine_h, fine_w = raster.face_id.shape
        face_id = raster.face_id.ravel()
        covered = face_id >= 0
        covered[covered] = face_part[face_id[covered]] != 2  # the shadow needs coverage only
        attributes = np.concatenate([normals @ camera.rotation.T, points_cam,
                                     vertex_scalar[:, None]], axis=1)
        lit_index, per_pixel = interpolate_covered(raster, attributes, covered)
        part = face_part[face_id[lit_index]]
        intensity = lambert_intensity(per_pixel[:, 0:3], per_pixel[:, 3:6])
        if scalars is None:
            base = np.broadcast_to(SURFACE_BGR, (len(lit_index), 3))
        elif legend is not None:
            base = legend.colour_of(per_pixel[:, 6])
        else:
            base = colormap(per_pixel[:, 6], scalar_range)
        base = np.where((part == 1)[:, None], OBSTACLE_BGR, base)

        shade = (face_id >= 0) & ~covered
        shade = soft_shadow(shade.reshape(fine_h, fine_w), 0.01 * fine_h,
                            raster.supersample).ravel()
        # Background darkened by the shadow, then the lit pixels; rounded to uint8 in place.
        shade *= -_SHADOW_DARKNESS
        shade += 1.0
        fine = np.empty((fine_h * fine_w, 3))
        np.multiply(shade[:, None], np.asarray(BACKGROUND_BGR, dtype=np.float64)[None, :],
                    out=fine)
        base *= intensity[:, None]
        fine[lit_index] = base
        np.rint(fine, out=fine)
        np.clip(fine, 0, 255, out=fine)
        pictures.append(downsample(fine.astype(np.uint8).reshape(fine_h, fine_w, 3),
                                   raster.supersample))
    image = np.concatenate(pictures + ([] if bar is None else [bar]), axis=1)
    if width is not None and image.shape[1] < width:  # the integer division left a few columns
        pad = np.full((height, width - image.shape[1], 3), BACKGROUND_BGR, dtype=np.uint8)
        image = np.concatenate([image, pad], axis=1)
    return image


def fitted_width(points: np.ndarray, height: int, **view) -> int:
    """Width [pixels] of a view `height` pixels high that the points (N, 3) [m], framed by
    `frame_mesh` from `view` (up, elevation_deg, azimuth_deg), fill as they fill the height:
    their projected width-to-height ratio, clipped to VIEW_ASPECT."""
    camera = frame_mesh(points, width=height, height=height, **view)
    projected = camera.to_camera(points)
    projected = projected[:, :2] / projected[:, 2:3]
    extent = np.ptp(projected, axis=0)
    ratio = extent[0] / max(extent[1], 1e-12)
    lo, hi = VIEW_ASPECT
    return int(round(height * min(max(ratio, lo), hi)))

"""Pictures of meshes and runs: z-buffered rasteriser, textured and shaded renders, plots, video.

Camera convention (OpenCV): x right, y down, z forward; pixel (u, v) = K @ (X/Z, Y/Z, 1) with
pixel centres at integer coordinates. See `taichi_ndf.render.raster`.
"""

from taichi_ndf.render.camera import Camera, frame_mesh, widest_azimuth
from taichi_ndf.render.image_file import save_png
from taichi_ndf.render.plot import plot_curves
from taichi_ndf.render.raster import (
    Raster,
    downsample,
    interpolate,
    interpolate_covered,
    rasterize,
    supersampled_intrinsics,
)
from taichi_ndf.render.shaded import colormap, render_shaded
from taichi_ndf.render.textured import (
    render_textured,
    texture_pixels_to_uv,
    uv_to_texture_pixels,
)
from taichi_ndf.render.video import count_video_frames, write_video

__all__ = [
    "Raster",
    "rasterize",
    "interpolate",
    "interpolate_covered",
    "downsample",
    "supersampled_intrinsics",
    "render_textured",
    "texture_pixels_to_uv",
    "uv_to_texture_pixels",
    "Camera",
    "frame_mesh",
    "widest_azimuth",
    "render_shaded",
    "colormap",
    "plot_curves",
    "save_png",
    "write_video",
    "count_video_frames",
]

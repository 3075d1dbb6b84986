"""Rasteriser, textured and shaded renders, plots, PNG and video files."""

import cv2
import numpy as np
import pytest

from taichi_ndf.io import grid_mesh
from taichi_ndf.render import (
    Camera,
    count_video_frames,
    downsample,
    frame_mesh,
    interpolate,
    plot_curves,
    rasterize,
    render_shaded,
    render_textured,
    save_png,
    write_video,
)
from taichi_ndf.render.shaded import BACKGROUND_BGR
from taichi_ndf.render.video import video_info

K = np.array([[200.0, 0.0, 159.5], [0.0, 200.0, 119.5], [0.0, 0.0, 1.0]])
W, H = 320, 240


def tilted_plane(n=8, tilt_deg=60.0, size=1.0, depth=3.0):
    """A square grid rotated about the camera's x axis by tilt_deg, centred at Z = depth."""
    grid = grid_mesh(((-size, size), (-size, size)), n)
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    local = np.column_stack([grid.xi[:, 0], grid.xi[:, 1], np.zeros(len(grid.xi))])
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    points = local @ rotation.T + [0.0, 0.0, depth]
    normal = rotation[:, 2]
    return points, grid.faces, grid.uv, normal, normal @ [0.0, 0.0, depth]


def pixel_rays(width, height, k=K):
    """Camera-space ray directions with Z = 1 through every pixel centre, shape (H, W, 3)."""
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    pixels = np.stack([u, v, np.ones_like(u)], axis=-1)
    return pixels @ np.linalg.inv(k).T


def test_triangle_coverage_matches_projected_area():
    corners = np.array([[-0.61, -0.33, 2.0], [0.52, -0.47, 2.0], [0.13, 0.58, 2.0]])
    projected = corners @ K.T
    p = projected[:, :2] / projected[:, 2:]
    (x0, y0), (x1, y1), (x2, y2) = p
    area = 0.5 * abs((x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0))
    for supersample in (1, 4):
        raster = rasterize(corners, [[0, 1, 2]], K, W, H, supersample=supersample)
        assert raster.depth.shape == (H * supersample, W * supersample)
        covered = raster.mask.sum() / supersample**2
        assert covered == pytest.approx(area, rel=0.02 / supersample)
        assert np.all(raster.depth[raster.mask] == pytest.approx(2.0))
        assert np.all(np.isinf(raster.depth[~raster.mask]))
        assert np.all(raster.face_id[~raster.mask] == -1)


def test_pixel_aligned_quad_is_covered_exactly():
    # Edges at half-integer pixel coordinates: pixel centres 110..209 x 70..169 are inside.
    quad = np.array([[-0.5, -0.5, 2.0], [0.5, -0.5, 2.0], [0.5, 0.5, 2.0], [-0.5, 0.5, 2.0]])
    k = np.array([[200.0, 0.0, 159.5], [0.0, 200.0, 119.5], [0.0, 0.0, 1.0]])
    raster = rasterize(quad, [[0, 1, 2], [0, 2, 3]], k, W, H)
    expected = np.zeros((H, W), dtype=bool)
    expected[70:170, 110:210] = True
    assert np.array_equal(raster.mask, expected)


def test_mesh_has_no_cracks_between_triangles():
    # A tilted grid filling the view, and a fronto-parallel one whose edges run exactly through
    # pixel centres (rows, columns and diagonals), where rounding decides coverage.
    points, faces, _, _, _ = tilted_plane(n=23, tilt_deg=20.0, size=6.0, depth=3.0)
    assert rasterize(points, faces, K, W, H).mask.all()
    grid = grid_mesh(((-10.0, 330.0), (-10.0, 250.0)), (34, 26))
    pixels = np.column_stack([grid.xi, np.ones(len(grid.xi))])
    points = 2.0 * pixels @ np.linalg.inv(K).T
    raster = rasterize(points, grid.faces, K, W, H)
    assert raster.mask.all()
    assert np.allclose(raster.depth, 2.0)


def test_depth_and_perspective_correct_interpolation_on_tilted_plane():
    points, faces, _, normal, offset = tilted_plane(size=1.5)
    raster = rasterize(points, faces, K, W, H)
    rays = pixel_rays(W, H)
    expected_depth = offset / (rays @ normal)
    mask = raster.mask
    assert mask.sum() > 0.2 * W * H
    assert np.abs(raster.depth[mask] - expected_depth[mask]).max() < 1e-9
    # Position is linear on the plane: interpolation must give the ray's intersection exactly.
    position = interpolate(raster, points)
    assert np.abs(position[mask] - (expected_depth[..., None] * rays)[mask]).max() < 1e-9
    assert np.allclose(raster.bary[mask].sum(axis=-1), 1.0)


def test_nearest_surface_wins_regardless_of_order():
    quad = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    near, far = quad + [0.3, 0.0, 2.0], quad + [-0.3, 0.0, 3.0]
    points = np.concatenate([near, far])
    near_faces, far_faces = [[0, 1, 2], [0, 2, 3]], [[4, 5, 6], [4, 6, 7]]
    for faces, near_ids in ((near_faces + far_faces, {0, 1}), (far_faces + near_faces, {2, 3})):
        raster = rasterize(points, faces, K, W, H)
        centre = raster.face_id[H // 2, W // 2]
        assert centre in near_ids
        assert raster.depth[H // 2, W // 2] == pytest.approx(2.0)
        # Left of the near quad only the far quad is seen.
        left = raster.face_id[H // 2, 80]
        assert left >= 0 and left not in near_ids


def test_triangles_behind_or_across_the_camera_are_culled():
    behind = np.array([[-1.0, -1.0, -2.0], [1.0, -1.0, -2.0], [0.0, 1.0, -2.0]])
    across = np.array([[-1.0, -1.0, -2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]])
    for corners in (behind, across):
        assert not rasterize(corners, [[0, 1, 2]], K, W, H).mask.any()


def test_textured_render_samples_the_texture_perspective_correctly():
    points, faces, uvs, normal, offset = tilted_plane(n=1, tilt_deg=65.0)
    # Texel i holds 250 u at its centre, so bilinear sampling shows 250 u at every pixel.
    texture = np.tile(250.0 * (np.arange(256) + 0.5) / 256, (64, 1)).astype(np.float32)
    image, mask = render_textured(points, faces, uvs, texture, K, W, H, supersample=1)
    rays = pixel_rays(W, H)
    hit = (offset / (rays @ normal))[..., None] * rays
    expected_u = (hit[..., 0] + 1.0) / 2.0  # the plane's x is 2u - 1
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert inner.sum() > 1000
    assert np.abs(image[inner] / 250.0 - expected_u[inner]).max() < 0.005

    # The tilt makes this test sensitive: interpolating u affinely in screen space within each
    # triangle (no perspective correction) would be off by much more than the tolerance.
    raster = rasterize(points, faces, K, W, H)
    v, u = np.nonzero(inner)
    design = np.column_stack([u, v, np.ones_like(u)]).astype(float)
    for face in range(len(faces)):
        mine = raster.face_id[v, u] == face
        coeffs, *_ = np.linalg.lstsq(design[mine], expected_u[v, u][mine], rcond=None)
        assert np.abs(design[mine] @ coeffs - expected_u[v, u][mine]).max() > 0.02


def test_textured_render_mask_background_and_dtype():
    quad = np.array([[-0.5, -0.5, 2.0], [0.5, -0.5, 2.0], [0.5, 0.5, 2.0], [-0.5, 0.5, 2.0]])
    uvs = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    texture = np.zeros((32, 32, 3), dtype=np.uint8)
    texture[:] = (10, 200, 30)
    image, mask = render_textured(
        quad, [[0, 1, 2], [0, 2, 3]], uvs, texture, K, W, H, supersample=3, background=(255, 0, 0)
    )
    assert image.dtype == np.uint8 and image.shape == (H, W, 3)
    assert mask.sum() == 100 * 100
    assert np.all(image[mask] == (10, 200, 30))
    assert np.all(image[~mask] == (255, 0, 0))


def test_downsample_is_a_box_filter():
    fine = np.arange(36, dtype=np.float64).reshape(6, 6)
    coarse = downsample(fine, 3)
    assert coarse.shape == (2, 2)
    assert coarse[0, 0] == pytest.approx(fine[:3, :3].mean())


def test_frame_mesh_fits_and_centres_the_mesh():
    points, faces, _, _, _ = tilted_plane(n=4)
    camera = frame_mesh(points, width=400, height=300)
    rotation = camera.rotation
    assert np.allclose(rotation @ rotation.T, np.eye(3)) and np.linalg.det(rotation) > 0
    projected = camera.to_camera(points) @ camera.intrinsics(400, 300).T
    pixel = projected[:, :2] / projected[:, 2:]
    lo, hi = pixel.min(axis=0), pixel.max(axis=0)
    assert np.all(lo >= 0) and np.all(hi <= [399, 299])
    assert np.abs((lo + hi) / 2 - [199.5, 149.5]).max() < 2.0
    assert max((hi - lo) / [399, 299]) > 0.8  # fills the tighter direction
    # World up (+z) points up in the image (towards smaller v).
    up_point = Camera(eye=(3, 0, 0), target=(0, 0, 0)).to_camera([[0.0, 0.0, 1.0]])
    assert up_point[0, 1] < 0


def test_shaded_render_covers_the_mesh():
    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 16)
    x, y = grid.xi[:, 0], grid.xi[:, 1]
    vertices = np.column_stack([x, y, -0.3 * (1 - x) * (1 - y) ** 2])
    camera = frame_mesh(vertices, width=200, height=150)
    image = render_shaded(vertices, grid.faces, camera=camera, width=200, height=150)
    assert image.shape == (150, 200, 3) and image.dtype == np.uint8
    painted = np.any(image != BACKGROUND_BGR, axis=-1)
    raster = rasterize(
        camera.to_camera(vertices), grid.faces, camera.intrinsics(200, 150), 200, 150
    )
    assert raster.mask.mean() > 0.2
    # Antialiased edges differ by at most a one-pixel rim.
    assert abs(painted.sum() - raster.mask.sum()) < 0.1 * raster.mask.sum()
    assert np.all(painted[cv2.erode(raster.mask.astype(np.uint8), np.ones((3, 3))) > 0])
    assert image[painted].std() > 1.0  # shading varies over the curved sheet


def test_shaded_render_with_scalars_has_colour_bar():
    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 8)
    vertices = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
    image = render_shaded(
        vertices, grid.faces, scalars=grid.xi[:, 0], scalar_label="strain", width=320, height=200
    )
    assert image.shape == (200, 320, 3)
    painted = image[np.any(image != BACKGROUND_BGR, axis=-1)]
    distinct = np.unique(painted // 32, axis=0)
    assert len(distinct) > 8  # many colours of the map, not one flat colour
    with pytest.raises(ValueError, match="scalars"):
        render_shaded(vertices, grid.faces, scalars=np.zeros(3))


def test_plot_curves_draws_axes_curves_and_legend():
    x = np.arange(100)
    series = {"energy": (x, 1.0 + np.exp(-x / 10)), "gradient": (x, np.exp(-x / 20))}
    for log_y in (False, True):
        image = plot_curves(
            series,
            title="Convergence",
            xlabel="iteration",
            ylabel="J",
            log_y=log_y,
            width=400,
            height=300,
        )
        assert image.shape == (300, 400, 3) and image.dtype == np.uint8
        assert np.mean(image < 128) > 0.01
        blue = np.all(image == (180, 119, 31), axis=-1).sum()  # first palette colour
        assert blue > 100
    # Non-positive and non-finite values are dropped, not an error.
    image = plot_curves(
        {"a": ([0, 1, 2], [-1.0, np.nan, 3.0])}, title="t", xlabel="x", ylabel="y", log_y=True
    )
    assert image.shape == (500, 800, 3)


def test_plot_curves_integer_axis_gets_integer_ticks_and_markers():
    from taichi_ndf.render.plot import integer_axis

    assert integer_axis([0, 1, 2, 3]) and not integer_axis([0, 0.5, 1])
    assert not integer_axis(np.arange(100))  # an iteration axis is not marked point by point
    image = plot_curves({"Π per level": ([0, 1, 2], [-1.2, -1.25, -1.26])}, title="levels",
                        xlabel="grid level", ylabel=r"$\Pi$ [J]", width=400, height=300)
    blue = np.all(np.abs(image.astype(int) - (180, 119, 31)) < 8, axis=-1)
    # a marker is a filled disc: some rows hold a run of >= 7 blue pixels (a 1.8 px line not)
    runs = [np.diff(np.flatnonzero(np.diff(np.r_[0, row, 0]))).max(initial=0)
            for row in blue.astype(int)]
    assert max(runs[::1]) >= 7


def test_save_png_round_trip(tmp_path):
    image = (np.random.default_rng(0).random((20, 30, 3)) * 255).astype(np.uint8)
    save_png(tmp_path / "a.png", image)
    assert np.array_equal(cv2.imread(str(tmp_path / "a.png")), image)
    with pytest.raises(ValueError, match="uint8"):
        save_png(tmp_path / "b.png", image.astype(np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


def test_video_round_trip_is_h264(tmp_path):
    frames = [np.full((48, 63, 3), 8 * k, dtype=np.uint8) for k in range(12)]
    assert write_video(tmp_path / "v.mp4", iter(frames), fps=10) == 12
    assert count_video_frames(tmp_path / "v.mp4") == 12
    info = video_info(tmp_path / "v.mp4")
    assert info["codec"].startswith("h264") and info["size"] == (64, 48)  # odd width padded
    assert info["fps"] == pytest.approx(10.0)
    capture = cv2.VideoCapture(str(tmp_path / "v.mp4"))  # OpenCV (the SfT reader) decodes it
    ok, first = capture.read()
    capture.release()
    assert ok and first.shape == (48, 64, 3)
    with pytest.raises(ValueError, match="frame 1"):
        write_video(tmp_path / "w.mp4", [frames[0], np.zeros((10, 10, 3), np.uint8)], fps=10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def test_video_without_imageio_ffmpeg_says_what_is_missing(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails
    with pytest.raises(RuntimeError, match="H.264 video needs imageio-ffmpeg"):
        write_video(tmp_path / "v.mp4", [np.zeros((8, 8, 3), np.uint8)], fps=4)
    assert not list(tmp_path.iterdir())

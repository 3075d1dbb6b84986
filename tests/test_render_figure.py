"""Figures of a run (render/figure.py) and `ndf-render`: views, ground shadow, obstacles, colour
bar, bad input."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from taichi_ndf.cli import render
from taichi_ndf.io import grid_mesh, write_obj, write_ply
from taichi_ndf.io.run_files import read_run
from taichi_ndf.render.figure import Obstacle, render_figure
from taichi_ndf.render.shaded import BACKGROUND_BGR, colour_bar


def sheet(n: int = 12):
    """A 1 m sheet over the ground, bent up along x; vertices (V, 3), faces, uv."""
    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), n)
    x, y = grid.xi[:, 0], grid.xi[:, 1]
    return np.stack([x, y, 0.3 * x * x], axis=1), grid.faces, grid.uv


def fake_run(path: Path, *, frames: int = 0, obstacle: bool = False) -> Path:
    """A run directory as ndf-sim writes it (without the checkpoint), from `sheet`."""
    vertices, faces, uv = sheet()
    reference = vertices * [1.0, 1.0, 0.0]
    bending = 0.6 * vertices[:, 0]
    write_obj(path / "mesh.obj", vertices, faces, uvs=uv)
    write_obj(path / "reference.obj", reference, faces, uvs=uv)
    write_ply(path / "mesh.ply", vertices, faces, uvs=uv, vertex_scalars={
        "membrane_strain": 0.01 * vertices[:, 1], "bending_strain": bending,
        "energy_density": bending ** 2})
    factors = [(k + 1) / frames for k in range(frames)]
    for k, t in enumerate(factors):
        write_obj(path / "trajectory" / f"step_{k:03d}.obj", reference + t * (vertices - reference),
                  faces, uvs=uv)
    if obstacle:
        write_obj(path / "obstacles" / "block.obj",
                  [[0.2, 0.2, 0.5], [0.4, 0.2, 0.5], [0.2, 0.4, 0.5], [0.2, 0.2, 0.7]],
                  np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    (path / "probes.json").write_text(json.dumps({"tip": {
        "xi": [1.0, 1.0], "reference": [1.0, 1.0, 0.0], "displacement": [0.0, 0.0, 0.3]}}))
    (path / "result.json").write_text(json.dumps({
        "scene": "sheet", "history": [{"iteration": i, "energy": -1.0 + 0.5 ** i}
                                      for i in range(5)],
        "trajectory": {"load_factors": factors} if frames else None,
        "resolved": {"scene_file": {"loads": {"gravity": [0.0, 0.0, -9.81]}}}}))
    return path


def is_background(image: np.ndarray) -> np.ndarray:
    return np.all(image == BACKGROUND_BGR, axis=-1)


def test_shadow_lies_on_the_ground_below_the_sheet():
    vertices, faces, _ = sheet()
    with_shadow = render_figure(vertices, faces, width=320, height=240)
    without = render_figure(vertices, faces, width=320, height=240, shadow=False)
    surface = ~is_background(without)
    grey = with_shadow.astype(int)
    shadow = (~surface) & (grey.max(axis=-1) < BACKGROUND_BGR[0] - 20) \
        & (np.ptp(grey, axis=-1) == 0)
    assert shadow.sum() > 0.02 * shadow.size  # a visible soft grey area beside the sheet
    rows = np.nonzero(shadow.any(axis=1))[0]
    assert rows.mean() > np.nonzero(surface.any(axis=1))[0].mean()  # below it in the image


def test_views_colour_bar_and_obstacles():
    vertices, faces, _ = sheet()
    block = Obstacle(np.array([[0.2, 0.2, 0.5], [0.4, 0.2, 0.5], [0.2, 0.4, 0.5],
                               [0.2, 0.2, 0.7]]), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2],
                                                            [1, 2, 3]]))
    scalars = vertices[:, 0]
    image = render_figure(vertices, faces, scalars=scalars, scalar_label="|kappa| [1/m]",
                          obstacles=(block,), views=("iso", "top"), width=600, height=240,
                          shadow=False)
    assert image.shape == (240, 600, 3)
    view = (600 - colour_bar((0.0, 1.0), "|kappa| [1/m]", 240).shape[1]) // 2
    grey = (np.ptp(image.astype(int), axis=-1) < 4) & ~is_background(image)
    assert grey[:, :view].sum() > 100 and grey[:, view:2 * view].sum() > 100  # in both views
    coloured = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)[..., 1] > 80
    assert coloured[:, :view].sum() > 2000 and coloured[:, view:2 * view].sum() > 2000
    assert coloured[:, 2 * view:].sum() > 500  # the colour bar
    with pytest.raises(ValueError, match="views must be some of"):
        render_figure(vertices, faces, views=("oblique",))


def test_read_run_and_quantities(tmp_path):
    run = read_run(fake_run(tmp_path, frames=3, obstacle=True))
    assert run.name == "sheet" and len(run.frames) == 3 and len(run.obstacles) == 1
    assert [f.load_factor for f in run.frames] == pytest.approx([1 / 3, 2 / 3, 1.0])
    np.testing.assert_allclose(run.up, [0, 0, 1])
    np.testing.assert_allclose(run.quantity("displacement"), run.deformed[:, 2], atol=1e-8)
    np.testing.assert_allclose(run.probes[0].deformed, [1.0, 1.0, 0.3])
    assert run.available() == ["displacement", "membrane_strain", "bending_strain",
                               "energy_density"]
    with pytest.raises(ValueError, match="unknown quantity"):
        run.quantity("stress")


def test_scene_views_option_is_checked(tmp_path):
    from test_cli import SMALL_NAPKIN

    from taichi_ndf.scene.reader import parse_scene
    from taichi_ndf.scene.schema import SceneError

    def views(text):
        document = tomllib.loads(SMALL_NAPKIN.format(lr=1e-3).replace(
            "resolution = [16, 16]", f"resolution = [16, 16]\nviews = {text}"))
        return parse_scene(document, base_dir=tmp_path).output.views

    assert views('["front", "top"]') == ("front", "top")
    with pytest.raises(SceneError, match="output.views"):
        views('["oblique"]')


def test_render_cli(tmp_path, capsys):
    run = fake_run(tmp_path / "run", obstacle=True)
    out = tmp_path / "picture.png"
    assert render.main([str(run), "--view", "front", "iso", "--colour", "displacement",
                        "--size", "500x200", "--out", str(out)]) == 0
    image = cv2.imread(str(out))
    assert image.shape == (200, 500, 3) and (~is_background(image)).mean() > 0.1
    assert render.main([str(run)]) == 0
    assert (run / "render_iso_bending_strain.png").is_file()
    assert render.main([str(run)]) == 2  # exists
    assert "--overwrite" in capsys.readouterr().err
    assert render.main([str(tmp_path), "--out", str(tmp_path / "x.png")]) == 2
    assert "no result.json" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        render.main([str(run), "--size", "big"])
    assert stop.value.code == 2 and "WIDTHxHEIGHT" in capsys.readouterr().err


def hanging_sheet(n: int = 12):
    """A 1 m sheet hanging flat in the vertical plane x + y = 0 (normal (1, 1, 0) / √2): the
    fixed diagonal view (azimuth -45°) sees it edge-on."""
    grid = grid_mesh(((-0.5, 0.5), (0.0, 1.0)), n)
    s, depth = grid.xi[:, 0], grid.xi[:, 1]
    return np.stack([s / np.sqrt(2.0), -s / np.sqrt(2.0), -depth], axis=1), grid.faces


def test_default_view_faces_a_hanging_sheet_and_keeps_it_in_frame():
    from taichi_ndf.render.camera import frame_mesh, widest_azimuth
    from taichi_ndf.render.raster import rasterize

    vertices, faces = hanging_sheet()
    azimuth = widest_azimuth(vertices, faces)
    assert abs((azimuth - 45.0 + 90.0) % 180.0 - 90.0) <= 30.0  # near the face's normal

    def covered(camera, size=64):
        return rasterize(camera.to_camera(vertices), faces, camera.intrinsics(size, size),
                         size, size).mask.mean()

    edge_on = covered(frame_mesh(vertices, width=64, height=64, azimuth_deg=-45.0))
    chosen = covered(frame_mesh(vertices, width=64, height=64, azimuth_deg=azimuth))
    assert edge_on < 0.1 < 0.3 < chosen  # the old fixed view: a sliver

    image = render_figure(vertices, faces, width=None, height=240, shadow=False)
    surface = ~is_background(image)
    assert surface.mean() > 0.3  # not a sliver in its frame
    border = np.concatenate([surface[0], surface[-1], surface[:, 0], surface[:, -1]])
    assert not border.any()  # the whole sheet inside the picture, with a margin
    # A level sheet looks alike from everywhere: the preferred diagonal stays.
    level, level_faces, _ = sheet()
    assert widest_azimuth(level * [1.0, 1.0, 0.0], level_faces) == -45.0


def test_fitted_width_follows_the_shape():
    vertices, faces = hanging_sheet()
    tall = vertices * [0.3, 0.3, 1.0]
    image = render_figure(tall, faces, width=None, height=300, shadow=False)
    assert 150 <= image.shape[1] < 300  # narrower than square, never below half the height
    wide, wide_faces, _ = sheet()
    image = render_figure(wide * [3.0, 1.0, 1.0], wide_faces, width=None, height=300)
    assert image.shape[1] == 400  # 4:3 at most


def test_label_rows_keep_the_surface_out_of_the_label():
    """A hanging sheet fills the picture's height: with the default margin it reaches into
    the rows that put_label's boxed label covers (the flag's top corner was hidden under
    "t = 2.00 s", docs/gallery/dynamics_flag_wind.png); label_rows keeps them free."""
    from taichi_ndf.render.trajectory import LABEL_ROWS, put_label

    vertices, faces = hanging_sheet()
    plain = render_figure(vertices, faces, width=None, height=600, shadow=False)
    assert (~is_background(plain[:LABEL_ROWS])).any()  # the surface reaches under the label
    image = render_figure(vertices, faces, width=None, height=600, shadow=False,
                          label_rows=LABEL_ROWS)
    surface = ~is_background(image)
    assert not surface[:LABEL_ROWS].any() and surface.mean() > 0.25
    labelled = image.copy()
    put_label(labelled, "t = 2.00 s", boxed=True)
    changed = np.nonzero(np.any(labelled != image, axis=-1).any(axis=1))[0]
    assert changed.max() < LABEL_ROWS  # the label and its box lie in those rows
    with pytest.raises(ValueError, match="label_rows"):
        render_figure(vertices, faces, width=None, height=60, label_rows=30)

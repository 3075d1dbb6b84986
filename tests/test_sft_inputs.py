"""Shape-from-template input contract: loading, conventions, and refusal of malformed inputs."""

import json
import re

import cv2
import numpy as np
import pytest

from inverse.sft.camera import camera_from_json
from inverse.sft.inputs import (
    Camera,
    InputError,
    load_camera,
    load_inputs,
    load_template,
    read_frames,
)
from taichi_ndf.io import grid_mesh, write_obj

WIDTH, HEIGHT = 80, 60
CAMERA = {"fx": 100.0, "fy": 100.0, "cx": 39.5, "cy": 29.5, "width": WIDTH, "height": HEIGHT}


@pytest.fixture
def inputs_dir(tmp_path):
    """A valid set of inputs: 3 frames, camera, template, texture, masks, pins."""
    rng = np.random.default_rng(0)
    (tmp_path / "frames").mkdir()
    (tmp_path / "masks").mkdir()
    for i in (0, 1, 10):  # natural order: 0, 1, 10 (not 0, 10, 1)
        cv2.imwrite(str(tmp_path / "frames" / f"f{i}.png"),
                    np.full((HEIGHT, WIDTH, 3), 10 * i, np.uint8))
        cv2.imwrite(str(tmp_path / "masks" / f"m{i}.png"), np.full((HEIGHT, WIDTH), 255, np.uint8))
    (tmp_path / "camera.json").write_text(json.dumps(CAMERA))
    grid = grid_mesh(((-0.1, 0.1), (-0.05, 0.05)), (4, 2))
    vertices = np.column_stack([grid.xi, np.full(len(grid.xi), 0.5)])
    write_obj(tmp_path / "template.obj", vertices, grid.faces, uvs=grid.uv)
    cv2.imwrite(str(tmp_path / "texture.png"), rng.integers(0, 255, (32, 64, 3), dtype=np.uint8))
    (tmp_path / "pins.json").write_text("[0, 4]")
    return tmp_path


def load(d, **changes):
    paths = dict(frames=d / "frames", camera=d / "camera.json", template=d / "template.obj",
                 texture=d / "texture.png", masks=d / "masks", pinned=d / "pins.json")
    paths.update(changes)
    return load_inputs(**paths)


def test_valid_inputs_load_in_natural_order(inputs_dir):
    inputs = load(inputs_dir)
    assert [int(f[0, 0, 0]) for f in inputs.frames] == [0, 10, 100]
    assert inputs.camera.size == (WIDTH, HEIGHT)
    assert inputs.template.vertices.shape == (15, 3) and inputs.template.uvs.shape == (15, 2)
    assert len(inputs.masks) == 3 and inputs.masks[0].dtype == bool and inputs.masks[0].all()
    np.testing.assert_array_equal(inputs.pinned, [0, 4])


def test_camera_projection_follows_opencv(inputs_dir):
    camera = load_camera(inputs_dir / "camera.json")
    np.testing.assert_allclose(camera.project(np.array([[0.0, 0.0, 2.0], [0.1, -0.2, 1.0]])),
                               [[39.5, 29.5], [49.5, 9.5]])
    points = np.array([[0.1, 0.2, 1.0]])
    expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, None)
    np.testing.assert_allclose(camera.project(points), expected.reshape(-1, 2))


def test_extrinsics_move_the_template_into_camera_coordinates(inputs_dir):
    angle = 0.3
    R = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    t = [0.0, 0.1, 0.2]
    (inputs_dir / "camera.json").write_text(json.dumps({**CAMERA, "R": R, "t": t}))
    camera = load_camera(inputs_dir / "camera.json")
    world = load_template(inputs_dir / "template.obj").vertices
    moved = load_template(inputs_dir / "template.obj", camera=camera).vertices
    np.testing.assert_allclose(moved, world @ np.array(R).T + t)
    np.testing.assert_allclose(camera.to_world(moved), world, atol=1e-12)


def test_zero_distortion_leaves_frames_unchanged(inputs_dir):
    (inputs_dir / "camera.json").write_text(json.dumps({**CAMERA, "dist": [0, 0, 0, 0, 0]}))
    inputs = load(inputs_dir)
    assert inputs.camera.dist == (0.0, 0.0, 0.0, 0.0, 0.0)
    assert [int(f[30, 40, 0]) for f in inputs.frames] == [0, 10, 100]


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({k: v for k, v in CAMERA.items() if k != "fx"}, "missing key(s) ['fx']"),
        ({**CAMERA, "focal": 3.0}, "unknown key(s) ['focal']"),
        ({**CAMERA, "fy": -1.0}, "camera fy"),
        ({**CAMERA, "width": 80.5}, "camera width must be a positive integer"),
        ({**CAMERA, "dist": [0.1, 0.0]}, "5 coefficients"),
        ({**CAMERA, "R": np.eye(3).tolist()}, "both R and t"),
        ({**CAMERA, "R": (2 * np.eye(3)).tolist(), "t": [0, 0, 0]}, "rotation matrix"),
        ({**CAMERA, "cx": "centre"}, "cx must be a number"),
    ],
)
def test_bad_camera_json_is_refused(data, message):
    with pytest.raises(InputError, match=re.escape(message)):
        camera_from_json(data)


def test_camera_must_be_valid_json(tmp_path):
    (tmp_path / "camera.json").write_text("{fx: 1")
    with pytest.raises(InputError, match="not valid JSON"):
        load_camera(tmp_path / "camera.json")


def test_missing_file_is_named(inputs_dir):
    with pytest.raises(InputError, match=r"texture image .*nope.png: missing file"):
        load(inputs_dir, texture=inputs_dir / "nope.png")
    with pytest.raises(InputError, match="camera file .*: missing file"):
        load(inputs_dir, camera=inputs_dir / "cam.json")


def test_image_size_must_match_camera(inputs_dir):
    cv2.imwrite(str(inputs_dir / "frames" / "f1.png"), np.zeros((HEIGHT, WIDTH + 2, 3), np.uint8))
    with pytest.raises(InputError, match="frame 1: image size 82x60 differs from the camera"):
        load(inputs_dir)


def test_mask_count_must_match_frames(inputs_dir):
    (inputs_dir / "masks" / "m10.png").unlink()
    with pytest.raises(InputError, match="2 masks for 3 frames"):
        load(inputs_dir)


def test_template_without_uvs_is_refused(inputs_dir):
    grid = grid_mesh(((0, 1), (0, 1)), 2)
    write_obj(inputs_dir / "plain.obj", np.column_stack([grid.xi, np.ones(9)]), grid.faces)
    with pytest.raises(InputError, match="has no UV"):
        load(inputs_dir, template=inputs_dir / "plain.obj")


def test_template_with_uv_seams_is_refused(tmp_path):
    (tmp_path / "seam.obj").write_text(
        "v 0 0 1\nv 1 0 1\nv 0 1 1\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\nf 1/4 2/2 3/3\n"
    )
    with pytest.raises(InputError, match="line 8 uses texture index 4 for vertex 1"):
        load_template(tmp_path / "seam.obj")


def test_template_behind_the_camera_is_refused(tmp_path):
    grid = grid_mesh(((0, 1), (0, 1)), 1)
    write_obj(tmp_path / "behind.obj", np.column_stack([grid.xi, -np.ones(4)]), grid.faces,
              uvs=grid.uv)
    with pytest.raises(InputError, match="z <= 0"):
        load_template(tmp_path / "behind.obj")


def test_unreadable_video_and_zero_frames_are_refused(tmp_path):
    (tmp_path / "clip.mp4").write_bytes(b"this is not a video")
    with pytest.raises(InputError, match="unreadable video"):
        read_frames(tmp_path / "clip.mp4")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="zero frames"):
        read_frames(tmp_path / "empty")


def test_unreadable_image_is_named(inputs_dir):
    (inputs_dir / "frames" / "f1.png").write_bytes(b"garbage")
    with pytest.raises(InputError, match=r"frame .*f1.png: unreadable image"):
        load(inputs_dir)


def test_pinned_indices_must_exist(inputs_dir):
    with pytest.raises(InputError, match=r"indices \[15\] out of range \[0, 15\)"):
        load(inputs_dir, pinned=[3, 15])
    (inputs_dir / "pins.txt").write_text("1 2 x")
    with pytest.raises(InputError, match="expected a list of integers"):
        load(inputs_dir, pinned=inputs_dir / "pins.txt")


def test_camera_round_trips_through_json():
    camera = Camera(fx=500.0, fy=510.0, cx=320.0, cy=240.0, width=640, height=480,
                    dist=(0.1, 0.0, 0.0, 0.0, 0.0), rotation=tuple(map(tuple, np.eye(3))),
                    translation=(0.0, 0.0, 1.0))
    assert camera_from_json(json.loads(json.dumps(camera.to_json()))) == camera

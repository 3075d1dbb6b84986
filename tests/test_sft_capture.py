"""The capture importer (φ-SfT / PGSfT layout) on a tiny synthetic capture written by the test,
with the template in that layout's own axes (x and y negated) and UVs that do not fit."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from inverse.cli import sft
from inverse.cli.sft_options import pinned_option
from inverse.sft.camera import write_camera
from inverse.sft.capture import load_capture, projected_uvs
from inverse.sft.chamfer import chamfer_to_cloud, max_vertex_distance, triangulated
from inverse.sft.errors import InputError
from inverse.sft.metrics import surface_samples
from inverse.sft.synth import SynthConfig, generate
from taichi_ndf.io import write_obj

FRAMES = 3
PGSFT_AXES = np.array([-1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def sequence():
    return generate(SynthConfig(sequence="roll", frames=FRAMES, image_size=(320, 240),
                                focal=300.0, texture_size=(256, 192), cells=(14, 10),
                                supersample=1))


def write_capture(seq, folder, *, axes=PGSFT_AXES, cloud_axes=(1.0, 1.0, 1.0), pinned=None,
                  template=None):
    """seq in the capture layout: frames/, masks/, template/*.obj (axes flipped, UVs that do
    not fit), camera.json, ground_truth/ clouds (camera coordinates unless cloud_axes)."""
    for name in ("frames", "masks", "template", "ground_truth"):
        (folder / name).mkdir(parents=True)
    for i in range(FRAMES):
        cv2.imwrite(str(folder / "frames" / f"rgb_{i:03d}.png"), seq.frames[i])
        cv2.imwrite(str(folder / "masks" / f"mask_{i:03d}.png"),
                    seq.masks[i].astype(np.uint8) * 255)
        cloud = surface_samples(seq.vertices[i], seq.faces, count=3000, seed=10 + i)
        np.save(folder / "ground_truth" / f"point_cloud_{i:03d}.npy",
                (cloud * cloud_axes).astype(np.float32))
    vertices = seq.vertices[0] * axes if template is None else template
    write_obj(folder / "template" / "0_quad.obj", vertices, seq.faces, uvs=seq.uvs[::-1])
    write_camera(seq.camera, folder / "camera.json")
    if pinned is not None:
        (folder / "pinned.json").write_text(json.dumps(pinned))
    return folder


def test_the_template_axes_are_found_and_uvs_rederived_from_frame_0(sequence, tmp_path):
    capture = load_capture(write_capture(sequence, tmp_path))
    assert capture.axes == (-1, -1, 1)
    t = capture.inputs.template
    np.testing.assert_allclose(t.vertices, sequence.vertices[0], atol=1e-9)
    np.testing.assert_allclose(t.uvs, projected_uvs(t.vertices, sequence.camera))
    assert capture.inputs.texture is capture.inputs.frames[0]
    assert capture.inputs.pinned is None and capture.ground_truth == tmp_path / "ground_truth"
    text = " | ".join(capture.conventions)
    assert "negate x and y" in text and "UVs re-derived" in text and "held vertices: none" in text


def test_projected_uvs_follow_the_texel_centre_convention(sequence):
    cam = sequence.camera
    # A point on the optical axis projects to (cx, cy): UV ((cx + ½)/W, 1 − (cy + ½)/H).
    uv = projected_uvs(np.array([[0.0, 0.0, 1.0]]), cam)
    np.testing.assert_allclose(uv, [[(cam.cx + 0.5) / cam.width,
                                     1 - (cam.cy + 0.5) / cam.height]])


def test_pinned_file_is_read_and_an_option_overrides_it(sequence, tmp_path):
    folder = write_capture(sequence, tmp_path, pinned=[0, 5])
    assert load_capture(folder).inputs.pinned.tolist() == [0, 5]
    capture = load_capture(folder, pinned=[1, 2, 3])
    assert capture.inputs.pinned.tolist() == [1, 2, 3]
    assert "given as an option" in capture.conventions[3]


def test_a_template_that_fits_no_axes_is_refused(sequence, tmp_path):
    moved = sequence.vertices[0] + [0.5, 0.0, 0.0]  # off the sheet in every convention
    with pytest.raises(InputError, match="no axis convention projects it onto mask 0"):
        load_capture(write_capture(sequence, tmp_path, template=moved))


def test_clouds_in_another_frame_are_refused(sequence, tmp_path):
    folder = write_capture(sequence, tmp_path, cloud_axes=PGSFT_AXES)
    with pytest.raises(InputError, match="point cloud point_cloud_000.npy: .* not in the "
                                         "camera's coordinates"):
        load_capture(folder)


def nan_vertex(obj, index):
    """Rewrite vertex `index` of an OBJ file as (nan, nan, nan)."""
    lines = obj.read_text().splitlines()
    row = [i for i, line in enumerate(lines) if line.startswith("v ")][index]
    lines[row] = "v nan nan nan"
    obj.write_text("\n".join(lines) + "\n")


def test_a_nan_template_vertex_is_named(sequence, tmp_path):
    folder = write_capture(sequence, tmp_path)
    nan_vertex(folder / "template" / "0_quad.obj", 4)
    with pytest.raises(InputError, match=r"vertices \[4\] are not finite"):
        load_capture(folder)


def test_ndf_sft_reads_a_capture_and_scores_against_its_clouds(sequence, tmp_path, capsys):
    folder = write_capture(sequence, tmp_path / "capture")
    out = tmp_path / "out"
    code = sft.main(["--capture", str(folder), "--out", str(out), "--method", "baseline",
                     "--threads", "1"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "capture: template axes: negate x and y" in printed
    assert "chamfer x1e4 (field protocol) mean" in printed
    result = json.loads((out / "result.json").read_text())
    assert result["pinned"] is None
    assert any("UVs re-derived" in line for line in result["conventions"])
    m = result["metrics"]
    assert m["frames"] == FRAMES and "point-cloud ground truth" in m["protocol"]
    # Frame 0 is the template itself: its chamfer is that of the true surface (sampling only).
    cloud = np.load(folder / "ground_truth" / "point_cloud_000.npy")
    truth = 1e4 * chamfer_to_cloud(sequence.vertices[0], sequence.faces, cloud)
    assert result["metrics_per_frame"]["chamfer_x1e4"][0] == pytest.approx(truth, rel=1e-6)
    distances = result["metrics_per_frame"]["max_vertex_distance_m"]
    assert distances[0] == pytest.approx(max_vertex_distance(sequence.vertices[0], cloud),
                                         rel=1e-6)
    assert m["max_vertex_distance_m"] == max(distances)
    confidence = result["confidence"]
    assert len(confidence["unobserved_vertices"]) == FRAMES
    assert confidence["largest_gap_mean_edges"][0] < confidence["reach_mean_edges"]
    assert "confidence: " in printed


def test_capture_and_contract_options_are_not_mixed(sequence, tmp_path, capsys):
    folder = write_capture(sequence, tmp_path / "capture")
    code = sft.main(["--capture", str(folder), "--frames", str(folder / "frames"),
                     "--out", str(tmp_path / "out")])
    assert code == 2
    assert "--capture replaces --frames" in capsys.readouterr().err
    code = sft.main(["--frames", str(folder / "frames"), "--out", str(tmp_path / "out")])
    assert code == 2
    assert "missing --camera, --template, --texture" in capsys.readouterr().err


def test_pinned_option_takes_a_list_or_a_file():
    assert pinned_option("0,992") == [0, 992]
    assert pinned_option("pins.json") == Path("pins.json")


def test_triangulated_quads_cover_the_same_area():
    quads = np.array([[0, 1, 2, 3]])
    assert triangulated(quads).tolist() == [[0, 1, 2], [0, 2, 3]]


R1 = Path("/work/shared/data/phi_sft_r1")


@pytest.mark.slow
@pytest.mark.skipif(not R1.is_dir(), reason="φ-SfT's R1 capture is not on this machine")
def test_phi_sft_r1_reads_with_the_measured_conventions():
    capture = load_capture(R1)
    assert capture.axes == (-1, -1, 1)  # the README's finding, found by the tool
    cloud = np.load(R1 / "ground_truth" / "point_cloud_000.npy")
    t = capture.inputs.template
    # The README's value for frame 0 alone: 0.19.
    assert 1e4 * chamfer_to_cloud(t.vertices, t.faces, cloud) == pytest.approx(0.19, abs=0.01)

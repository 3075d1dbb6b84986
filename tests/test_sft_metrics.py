"""SfT metrics on cases with known answers, and the ndf-sft-eval command line."""

import json

import numpy as np
import pytest

from inverse.cli import sft_eval
from inverse.sft.camera import write_camera
from inverse.sft.deformations import rotation_xyz
from inverse.sft.metrics import (
    CHAMFER_SCALE,
    PROTOCOL,
    chamfer,
    evaluate_sequence,
    nearest_sq_distances,
    normal_error_deg,
    relative_error,
    similarity_align,
    surface_samples,
)
from inverse.sft.synth import default_camera, flat_sheet
from taichi_ndf.io import write_obj

DEPTH = 0.5


def flat(cells=(12, 9)):
    """Fronto-parallel flat sheet at depth DEPTH: vertices (n, 3), faces."""
    points, faces, _ = flat_sheet((0.28, 0.21), cells)
    return np.column_stack([points, np.full(len(points), DEPTH)]), faces


def test_identical_meshes_score_zero():
    v, f = flat()
    m = evaluate_sequence([v, v], [v, v], f, camera=default_camera())
    for values in (m.e3d, m.e3d_procrustes, m.chamfer_x1e4, m.normal_deg, m.reprojection_px):
        np.testing.assert_allclose(values, 0.0, atol=1e-12)
    summary = m.summary()
    assert summary["frames"] == 2 and summary["protocol"] == PROTOCOL


def test_offset_along_the_normal_gives_known_values():
    v, f = flat()
    d = 0.01
    moved = v + [0.0, 0.0, d]
    m = evaluate_sequence([moved], [v], f)
    np.testing.assert_allclose(m.e3d[0], d * np.sqrt(len(v)) / np.linalg.norm(v), rtol=1e-12)
    np.testing.assert_allclose(m.e3d_procrustes[0], 0.0, atol=1e-12)  # a translation
    # Samples are the same barycentric draws on both meshes: every nearest neighbour is the
    # translated twin at distance d, both ways.
    np.testing.assert_allclose(m.chamfer_x1e4[0], CHAMFER_SCALE * 2 * d**2, rtol=1e-9)
    np.testing.assert_allclose(m.normal_deg[0], 0.0, atol=1e-9)


def test_sideways_offset_gives_known_reprojection_error():
    v, f = flat()
    camera = default_camera()
    m = evaluate_sequence([v + [0.002, 0.0, 0.0]], [v], f, camera=camera)
    np.testing.assert_allclose(m.reprojection_px[0], camera.fx * 0.002 / DEPTH, rtol=1e-12)


def test_rotation_gives_its_angle_as_normal_error_and_procrustes_removes_it():
    v, f = flat()
    centre = v.mean(axis=0)
    rotated = (v - centre) @ rotation_xyz(0.0, np.radians(12.0), 0.0).T + centre
    np.testing.assert_allclose(normal_error_deg(rotated, v, f), 12.0, rtol=1e-9)
    scaled = 1.3 * rotated + [0.1, -0.2, 0.3]
    np.testing.assert_allclose(similarity_align(scaled, v), v, atol=1e-12)
    np.testing.assert_allclose(relative_error(1.1 * v, v), 0.1, rtol=1e-12)


def test_surface_samples_are_deterministic_and_area_uniform():
    v, f = flat()
    a = surface_samples(v, f, count=20000, seed=5)
    np.testing.assert_array_equal(a, surface_samples(v, f, count=20000, seed=5))
    assert not np.array_equal(a, surface_samples(v, f, count=20000, seed=6))
    # Uniform on the rectangle: a quarter of the samples in each quadrant.
    quadrant = (a[:, 0] > 0).astype(int) * 2 + (a[:, 1] > 0)
    np.testing.assert_allclose(np.bincount(quadrant) / len(a), 0.25, atol=0.01)


def test_nearest_neighbours_are_exact():
    rng = np.random.default_rng(2)
    points = rng.normal(size=(700, 3))
    query = np.concatenate([rng.normal(size=(300, 3)), [[40.0, 0.0, 0.0]]])  # one far away
    expected = ((query[:, None, :] - points[None, :, :]) ** 2).sum(axis=2).min(axis=1)
    np.testing.assert_allclose(nearest_sq_distances(query, points), expected,
                               rtol=1e-12)


def test_chamfer_sees_a_bump():
    v, f = flat()
    bumped = v.copy()
    bumped[:, 2] -= 0.02 * np.exp(-(v[:, 0] ** 2 + v[:, 1] ** 2) / 0.05**2)
    assert chamfer(bumped, f, v, f) > 1e-6 > chamfer(v, f, v, f)


def test_mismatched_inputs_are_refused():
    v, f = flat()
    with pytest.raises(ValueError, match="same vertex order"):
        relative_error(v[:-1], v)
    with pytest.raises(ValueError, match="same non-zero number of frames"):
        evaluate_sequence([v], [v, v], f)


@pytest.fixture
def mesh_folders(tmp_path):
    v, f = flat()
    for name in ("000000", "000001"):
        write_obj(tmp_path / "gt" / f"{name}.obj", v, f)
    write_obj(tmp_path / "pred" / "000000.obj", v, f)
    write_obj(tmp_path / "pred" / "000001.obj", v + [0.0, 0.0, 0.01], f)
    write_camera(default_camera(), tmp_path / "camera.json")
    return tmp_path


def test_eval_command_line_reports_metrics_and_protocol(mesh_folders, capsys):
    d = mesh_folders
    code = sft_eval.main(["--pred", str(d / "pred"), "--gt", str(d / "gt"),
                          "--camera", str(d / "camera.json"), "--json", str(d / "m.json")])
    assert code == 0
    out = capsys.readouterr().out
    assert "e3d" in out and "protocol: e3D = mean over frames" in out
    report = json.loads((d / "m.json").read_text())
    assert report["frames"] == ["000000", "000001"]
    np.testing.assert_allclose(report["per_frame"]["chamfer_x1e4"],
                               [0.0, CHAMFER_SCALE * 2 * 0.01**2], rtol=1e-6, atol=1e-12)
    assert report["summary"]["protocol"] == PROTOCOL
    assert report["summary"]["reprojection_px"] > 0


def test_eval_command_line_refuses_unmatched_names(mesh_folders, capsys):
    (mesh_folders / "pred" / "000001.obj").rename(mesh_folders / "pred" / "frame2.obj")
    code = sft_eval.main(["--pred", str(mesh_folders / "pred"), "--gt", str(mesh_folders / "gt")])
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "paired by frame number" in err
    assert "missing predictions [1]" in err and "without ground truth [2]" in err


def test_eval_pairs_frames_by_number_and_says_so(mesh_folders, capsys):
    """ndf-sft writes 000000.obj…, other tools 0000.obj…: the same frames."""
    gt = mesh_folders / "gt"
    for name in ("000000", "000001"):
        (gt / f"{name}.obj").rename(gt / f"{name[2:]}.obj")
    code = sft_eval.main(["--pred", str(mesh_folders / "pred"), "--gt", str(gt),
                          "--json", str(mesh_folders / "m.json")])
    assert code == 0
    out = capsys.readouterr().out
    assert "paired 2 frames by frame number: 000000.obj <-> 0000.obj ... 000001.obj <-> " \
        "0001.obj" in out
    report = json.loads((mesh_folders / "m.json").read_text())
    assert report["pairs"] == [["000000.obj", "0000.obj"], ["000001.obj", "0001.obj"]]
    # The second frame is the offset one whichever way it is named.
    assert report["per_frame"]["chamfer_x1e4"][1] > 0 == report["per_frame"]["chamfer_x1e4"][0]


def test_eval_pairs_by_file_name_without_frame_numbers(mesh_folders, capsys):
    for folder in ("pred", "gt"):
        d = mesh_folders / folder
        (d / "000000.obj").rename(d / "first.obj")
        (d / "000001.obj").rename(d / "second.obj")
    code = sft_eval.main(["--pred", str(mesh_folders / "pred"), "--gt", str(mesh_folders / "gt")])
    assert code == 0
    assert "paired 2 frames by file name" in capsys.readouterr().out

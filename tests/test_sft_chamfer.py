"""The field's chamfer protocol against point clouds, on cases with hand-computable answers."""

import json

import numpy as np
import pytest
import trimesh

from inverse.sft.chamfer import (
    CLOUD_PROTOCOL,
    chamfer_to_cloud,
    cloud_files,
    evaluate_against_clouds,
    is_cloud_folder,
    load_point_cloud,
    max_vertex_distance,
    triangulated,
)
from inverse.sft.errors import InputError
from inverse.sft.metrics import surface_samples


def unit_square(cells=4, depth=1.0):
    """[0, 1]² at z = depth as a grid of quads: vertices (n, 3), quads (m, 4)."""
    t = np.linspace(0.0, 1.0, cells + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, depth)])
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a = (i * (cells + 1) + j).ravel()
    quads = np.column_stack([a, a + cells + 1, a + cells + 2, a + 1])
    return vertices, quads


def test_a_cloud_offset_along_the_normal_gives_twice_the_squared_offset():
    v, q = unit_square()
    d = 0.003
    # The cloud is the surface's own samples (same count and seed) moved by d along the normal:
    # every nearest neighbour is the twin at distance d, both ways.
    cloud = surface_samples(v, triangulated(q), count=5000, seed=0) + [0.0, 0.0, d]
    np.testing.assert_allclose(chamfer_to_cloud(v, q, cloud, seed=0), 2 * d**2, rtol=1e-9)
    assert chamfer_to_cloud(v, q, cloud, seed=1) > 2 * d**2  # other samples: not twins


def test_quads_and_their_triangles_score_the_same():
    v, q = unit_square()
    cloud = np.random.default_rng(0).random((3000, 3))
    assert chamfer_to_cloud(v, q, cloud) == chamfer_to_cloud(v, triangulated(q), cloud)


def test_a_cloud_covering_half_the_surface_adds_the_uncovered_half():
    v, q = unit_square(depth=0.0)
    s = np.linspace(0.0, 1.0, 401)
    x, y = np.meshgrid(s[s <= 0.5], s, indexing="ij")
    cloud = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    # Samples with x > 1/2 are (x - 1/2) from the cloud: ∫_{1/2}^{1} (x - 1/2)² dx = 1/24; the
    # cloud → samples term is of the order of the sample spacing squared (~1e-5).
    value = chamfer_to_cloud(v, q, cloud)
    assert abs(value - 1 / 24) < 0.002


def test_max_vertex_distance_finds_the_run_away_vertex():
    v, q = unit_square(depth=0.0)
    cloud = v.copy()
    moved = v.copy()
    moved[7] += [0.0, 0.0, 0.391]
    assert max_vertex_distance(moved, cloud) == pytest.approx(0.391)
    assert max_vertex_distance(v, cloud) == 0.0


def test_sequence_summary_names_mean_worst_frame_and_largest_distance():
    v, q = unit_square()
    clouds = [surface_samples(v, triangulated(q), count=2000, seed=0) + [0, 0, d]
              for d in (0.001, 0.004, 0.002)]
    m = evaluate_against_clouds([v, v, v], q, clouds)
    s = m.summary()
    np.testing.assert_allclose(m.chamfer_x1e4, 1e4 * 2 * np.array([1, 16, 4]) * 1e-6, rtol=1e-6)
    assert s["worst_frame"] == 1 and s["frames"] == 3 and s["protocol"] == CLOUD_PROTOCOL
    assert s["chamfer_x1e4_worst"] == pytest.approx(0.32)
    # Same in-plane gaps in every frame, so the largest offset gives the largest distance.
    assert np.all(m.max_vertex_distance > [0.001, 0.004, 0.002])
    assert s["max_vertex_distance_frame"] == 1
    assert s["max_vertex_distance_m"] == m.max_vertex_distance.max()
    with pytest.raises(ValueError, match="same non-zero number"):
        evaluate_against_clouds([v], q, clouds)


def test_clouds_load_from_npy_and_ply_and_bad_ones_are_named(tmp_path):
    points = np.random.default_rng(1).random((50, 3))
    np.save(tmp_path / "point_cloud_000.npy", points.astype(np.float32))
    trimesh.PointCloud(points).export(tmp_path / "point_cloud_001.ply")
    np.testing.assert_allclose(load_point_cloud(tmp_path / "point_cloud_000.npy"), points,
                               rtol=1e-6)
    np.testing.assert_allclose(load_point_cloud(tmp_path / "point_cloud_001.ply"), points)
    assert [p.name for p in cloud_files(tmp_path)] == ["point_cloud_000.npy",
                                                       "point_cloud_001.ply"]
    assert is_cloud_folder(tmp_path)
    np.save(tmp_path / "flat.npy", points[:, :2])
    with pytest.raises(InputError, match=r"flat.npy: a point cloud must have shape \(N, 3\)"):
        load_point_cloud(tmp_path / "flat.npy")
    bad = points.copy()
    bad[3, 1] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(InputError, match="nan.npy: point cloud contains NaN"):
        load_point_cloud(tmp_path / "nan.npy")
    with pytest.raises(InputError, match="missing"):
        load_point_cloud(tmp_path / "absent.npy")


def test_a_folder_of_meshes_is_not_a_cloud_folder(tmp_path):
    v, q = unit_square()
    trimesh.Trimesh(v, triangulated(q), process=False).export(tmp_path / "000000.ply")
    assert not is_cloud_folder(tmp_path)
    (tmp_path / "empty").mkdir()
    assert not is_cloud_folder(tmp_path / "empty")
    with pytest.raises(InputError, match="no point clouds"):
        cloud_files(tmp_path / "empty")


def test_eval_command_line_scores_meshes_against_clouds(tmp_path, capsys):
    from inverse.cli import sft_eval
    from taichi_ndf.io import write_obj

    v, q = unit_square()
    faces = triangulated(q)
    for i, d in enumerate((0.001, 0.003)):
        write_obj(tmp_path / "pred" / f"{i:06d}.obj", v, faces)
        (tmp_path / "gt").mkdir(exist_ok=True)
        np.save(tmp_path / "gt" / f"point_cloud_{i:03d}.npy",
                surface_samples(v, faces, count=1000, seed=0) + [0, 0, d])
    code = sft_eval.main(["--pred", str(tmp_path / "pred"), "--gt", str(tmp_path / "gt"),
                          "--json", str(tmp_path / "e.json")])
    printed = capsys.readouterr().out
    assert code == 0
    assert "paired 2 frames by frame number: 000000.obj <-> point_cloud_000.npy" in printed
    report = json.loads((tmp_path / "e.json").read_text())
    np.testing.assert_allclose(report["per_frame"]["chamfer_x1e4"], [0.02, 0.18], rtol=1e-6)
    assert report["summary"]["worst_frame"] == 1
    np.save(tmp_path / "gt" / "point_cloud_002.npy", np.zeros((5, 3)))
    assert sft_eval.main(["--pred", str(tmp_path / "pred"), "--gt", str(tmp_path / "gt")]) == 2
    assert "missing predictions [2]" in capsys.readouterr().err

"""Parameter grids, vertex normals, OBJ/PLY files and run directories."""

import json

import numpy as np
import pytest

from taichi_ndf.io import (
    OutputDir,
    atomic_path,
    grid_mesh,
    read_mesh,
    vertex_normals,
    write_obj,
    write_ply,
)


def cylinder(cells=(24, 6), radius=0.3):
    grid = grid_mesh(((0.0, 2 * np.pi), (0.0, 1.0)), cells, periodic=(True, False))
    phi, z = grid.xi[:, 0], grid.xi[:, 1]
    return grid, np.column_stack([radius * np.cos(phi), radius * np.sin(phi), z])


def test_grid_layout_orientation_and_uvs():
    grid = grid_mesh(((-1.0, 3.0), (0.0, 2.0)), (4, 2))
    assert grid.xi.shape == (15, 2) and grid.faces.shape == (16, 3) and grid.cells == (4, 2)
    assert np.array_equal(grid.xi.reshape(3, 5, 2)[0, :, 0], [-1.0, 0.0, 1.0, 2.0, 3.0])
    assert np.array_equal(grid.xi.reshape(3, 5, 2)[:, 0, 1], [0.0, 1.0, 2.0])
    assert np.allclose(grid.uv, (grid.xi - [-1.0, 0.0]) / [4.0, 2.0])
    corners = grid.xi[grid.faces]
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    signed_area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert np.allclose(signed_area, 0.5)  # counter-clockwise, tiling the 8 unit cells
    assert np.array_equal(grid.canonical, np.arange(15))


def test_grids_with_dividing_resolutions_share_vertices():
    coarse = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 32).xi
    fine = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 256).xi.reshape(257, 257, 2)
    assert np.allclose(fine[::8, ::8].reshape(-1, 2), coarse, atol=1e-15)


def test_periodic_seam_is_duplicated_and_welded_in_normals():
    grid, vertices = cylinder()
    seam = np.nonzero(grid.canonical != np.arange(len(vertices)))[0]
    assert len(seam) == 7  # last column, one per row
    assert np.allclose(grid.xi[seam, 0], 2 * np.pi)
    assert np.allclose(vertices[seam], vertices[grid.canonical[seam]])
    welded = vertex_normals(vertices, grid.faces, canonical=grid.canonical)
    radial = np.column_stack([vertices[:, :2], np.zeros(len(vertices))]) / 0.3
    interior_rows = (grid.xi[:, 1] > 0) & (grid.xi[:, 1] < 1)
    # Faces are counter-clockwise in (phi, z): normals point along r_phi x r_z = outwards.
    assert np.abs(welded[interior_rows] - radial[interior_rows]).max() < 1e-12
    one_sided = vertex_normals(vertices, grid.faces)
    assert np.abs(one_sided[seam] - radial[seam]).max() > 0.05


def test_vertex_normals_are_area_weighted():
    # A big triangle in the z = 0 plane and a small one in the x = 0 plane share vertex 0.
    vertices = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 3, 4]])
    normal = vertex_normals(vertices, faces)[0]
    expected = np.array([1.0, 0.0, 16.0])  # cross products: 2 x area x unit normal
    assert np.allclose(normal, expected / np.linalg.norm(expected))


@pytest.mark.parametrize("with_uvs, with_normals", [(False, False), (True, False), (True, True)])
def test_obj_round_trip_keeps_order_and_uvs(tmp_path, with_uvs, with_normals):
    grid, vertices = cylinder()
    permutation = np.random.default_rng(1).permutation(len(vertices))
    vertices, uvs = vertices[permutation], grid.uv[permutation]
    faces = np.argsort(permutation)[grid.faces]
    normals = vertex_normals(vertices, faces)
    path = tmp_path / "mesh.obj"
    write_obj(
        path,
        vertices,
        faces,
        uvs=uvs if with_uvs else None,
        normals=normals if with_normals else None,
    )
    mesh = read_mesh(path)
    assert np.allclose(mesh.vertices, vertices, atol=1e-8)
    assert np.array_equal(mesh.faces, faces)
    if with_uvs:
        assert np.allclose(mesh.uvs, uvs, atol=1e-8)
    else:
        assert mesh.uvs is None


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip_keeps_order_uvs_and_scalars(tmp_path, binary):
    grid, vertices = cylinder()
    scalars = {
        "membrane_strain": np.linspace(-1e-3, 1e-3, len(vertices)),
        "bending_strain": np.cos(grid.xi[:, 0]),
        "energy_density": np.arange(len(vertices), dtype=float),
    }
    path = tmp_path / "mesh.ply"
    write_ply(path, vertices, grid.faces, uvs=grid.uv, vertex_scalars=scalars, binary=binary)
    mesh = read_mesh(path)
    assert np.allclose(mesh.vertices, vertices, rtol=1e-6, atol=1e-7)
    assert np.array_equal(mesh.faces, grid.faces)
    assert np.allclose(mesh.uvs, grid.uv, atol=1e-7)
    assert set(mesh.vertex_scalars) == set(scalars)
    for name, values in scalars.items():
        assert np.allclose(mesh.vertex_scalars[name], values, rtol=1e-6, atol=1e-9)


def test_mesh_writers_validate_their_inputs(tmp_path):
    grid, vertices = cylinder()
    with pytest.raises(ValueError, match="energy_density"):
        write_ply(
            tmp_path / "a.ply", vertices, grid.faces, vertex_scalars={"energy_density": np.zeros(3)}
        )
    with pytest.raises(ValueError, match="uvs"):
        write_obj(tmp_path / "a.obj", vertices, grid.faces, uvs=grid.uv[:5])
    with pytest.raises(ValueError, match="NaN"):
        write_obj(tmp_path / "a.obj", np.full_like(vertices, np.nan), grid.faces)
    with pytest.raises(FileNotFoundError):
        read_mesh(tmp_path / "missing.obj")
    assert list(tmp_path.iterdir()) == []


def test_output_dir_refuses_non_empty_directory(tmp_path):
    run = OutputDir(tmp_path / "runs" / "a")
    assert run.path.is_dir()
    run.release()
    OutputDir(tmp_path / "runs" / "a").release()  # empty: reusable
    run.write_json("result.json", {"energy": 1.5})
    with pytest.raises(FileExistsError, match="not empty"):
        OutputDir(tmp_path / "runs" / "a")
    again = OutputDir(tmp_path / "runs" / "a", overwrite=True)
    again.write_json("result.json", {"energy": 2.5})
    assert json.loads(again.file("result.json").read_text()) == {"energy": 2.5}
    assert again.file("frames/0001.obj").parent.is_dir()
    with pytest.raises(ValueError, match="inside the run"):
        again.file("../escape.txt")
    with pytest.raises(ValueError):
        again.write_json("bad.json", {"energy": float("nan")})
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError, match="not a directory"):
        OutputDir(tmp_path / "file")


def test_atomic_path_leaves_target_untouched_on_error(tmp_path):
    target = tmp_path / "mesh.obj"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as temporary:
            assert temporary.suffix == ".obj" and temporary.parent == tmp_path
            temporary.write_text("half")
            raise RuntimeError("writer failed")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["mesh.obj"]

"""Meshes and files out: parameter grids, OBJ/PLY, vertex normals, run directories."""

from taichi_ndf.io.grid import GridMesh, grid_mesh
from taichi_ndf.io.mesh_files import MeshData, read_mesh, write_obj, write_ply
from taichi_ndf.io.normals import vertex_normals
from taichi_ndf.io.output_dir import OutputDir, atomic_path, incomplete_path, staged_run

__all__ = [
    "GridMesh",
    "grid_mesh",
    "MeshData",
    "read_mesh",
    "write_obj",
    "write_ply",
    "vertex_normals",
    "OutputDir",
    "atomic_path",
    "incomplete_path",
    "staged_run",
]

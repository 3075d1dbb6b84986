"""A finished run directory read back: the files `ndf-sim` wrote, for export, viewing, renders.

Reads (no Taichi, no field evaluation): mesh.obj (deformed positions, UVs, faces), mesh.ply
(per-vertex strains and energy density), reference.obj (the undeformed surface), probes.json,
trajectory/step_*.obj with the load factors and history of result.json, and obstacles/*.obj
(obstacle meshes of a scene that has them; none of the shipped scenes has one yet).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from taichi_ndf.io.mesh_files import MeshData, read_mesh

__all__ = ["QUANTITIES", "Frame", "Probe", "RunFiles", "read_run", "up_direction"]

# Colourable per-vertex quantities: name -> label with units (colour bars, viewer, USD docs).
QUANTITIES = {
    "displacement": "|u| [m]",
    "membrane_strain": "|ε| [–]",
    "bending_strain": "|κ| [1/m]",
    "energy_density": "Ψ [J/m²]",
}


@dataclass(frozen=True)
class Frame:
    """One trajectory frame: its load factor (or pseudo-time) and deformed positions (V, 3) [m]."""

    load_factor: float
    vertices: np.ndarray


@dataclass(frozen=True)
class Probe:
    """A named probe: reference position and displacement at the end of the run, (3,) [m]."""

    name: str
    reference: np.ndarray
    displacement: np.ndarray

    @property
    def deformed(self) -> np.ndarray:
        return self.reference + self.displacement


@dataclass(frozen=True)
class RunFiles:
    """What a run directory holds.

    deformed: final positions (V, 3) [m], as in mesh.obj; faces (F, 3); uv (V, 2);
    reference: undeformed positions (V, 3) or None (runs written before reference.obj existed);
    scalars: per-vertex quantities of mesh.ply by name (V,); frames: the trajectory, in order
    (empty without one); history: (iterations, Π [J]) of the monitor; up: unit vector against
    gravity (z without gravity); obstacles: meshes of the scene's obstacles, named in
    obstacle_names (their scene names: the stems of obstacles/<name>.obj).
    """

    path: Path
    name: str
    deformed: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    reference: np.ndarray | None
    scalars: dict[str, np.ndarray]
    frames: tuple[Frame, ...]
    history: tuple[np.ndarray, np.ndarray]
    probes: tuple[Probe, ...]
    up: np.ndarray
    obstacles: tuple[MeshData, ...] = field(default_factory=tuple)
    obstacle_names: tuple[str, ...] = field(default_factory=tuple)

    def quantity(self, name: str) -> np.ndarray:
        """Per-vertex values (V,) of one of QUANTITIES."""
        if name not in QUANTITIES:
            raise ValueError(f"unknown quantity {name!r}; choose from {', '.join(QUANTITIES)}")
        if name == "displacement":
            if self.reference is None:
                raise ValueError(f"{self.path} has no reference.obj, so no displacement")
            return np.linalg.norm(self.deformed - self.reference, axis=1)
        if name not in self.scalars:
            raise ValueError(f"{self.path / 'mesh.ply'} holds no {name}")
        return self.scalars[name]

    def available(self) -> list[str]:
        """The QUANTITIES this run can show."""
        return [q for q in QUANTITIES if q in self.scalars
                or (q == "displacement" and self.reference is not None)]


def up_direction(gravity) -> np.ndarray:
    """The direction shown upwards: against gravity, or world z without gravity."""
    g = np.asarray(gravity if gravity is not None else (0.0, 0.0, 0.0), dtype=np.float64)
    length = np.linalg.norm(g)
    return -g / length if length > 0 else np.array([0.0, 0.0, 1.0])


def read_run(path: str | os.PathLike) -> RunFiles:
    """Read a run directory written by `ndf-sim`; raises FileNotFoundError or ValueError (the
    message names the file) when it is not one."""
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"run directory not found: {path}")
    result_path = path / "result.json"
    if not result_path.is_file():
        raise FileNotFoundError(f"{path} holds no result.json; it is not a finished ndf-sim run")
    try:
        result = json.loads(result_path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{result_path} is not valid JSON: {err}") from err
    mesh = read_mesh(path / "mesh.obj")
    scalars = read_mesh(path / "mesh.ply").vertex_scalars if (path / "mesh.ply").is_file() else {}
    reference = None
    if (path / "reference.obj").is_file():
        reference = _same_topology(read_mesh(path / "reference.obj"), mesh, "reference.obj")
    frame_files = sorted((path / "trajectory").glob("step_*.obj"))
    factors = (result.get("trajectory") or {}).get("load_factors", [])
    if len(factors) != len(frame_files):
        raise ValueError(f"{path}: {len(frame_files)} trajectory/step_*.obj files but "
                         f"{len(factors)} load factors in result.json")
    frames = tuple(Frame(float(t), _same_topology(read_mesh(f), mesh, f.name))
                   for t, f in zip(factors, frame_files, strict=True))
    history = result.get("history", [])
    gravity = result.get("resolved", {}).get("scene_file", {}).get("loads", {}).get("gravity")
    obstacle_files = sorted((path / "obstacles").glob("*.obj"))
    return RunFiles(
        path=path, name=str(result.get("scene", path.name)), deformed=mesh.vertices,
        faces=mesh.faces, uv=mesh.uvs, reference=reference, scalars=scalars, frames=frames,
        history=(np.array([h["iteration"] for h in history], dtype=np.float64),
                 np.array([h["energy"] for h in history], dtype=np.float64)),
        probes=_read_probes(path / "probes.json"), up=up_direction(gravity),
        obstacles=tuple(read_mesh(f) for f in obstacle_files),
        obstacle_names=tuple(f.stem for f in obstacle_files))


def _same_topology(other: MeshData, mesh: MeshData, name: str) -> np.ndarray:
    if other.vertices.shape != mesh.vertices.shape or not np.array_equal(other.faces, mesh.faces):
        raise ValueError(f"{name} does not have the vertices and faces of mesh.obj")
    return other.vertices


def _read_probes(path: Path) -> tuple[Probe, ...]:
    if not path.is_file():
        return ()
    document = json.loads(path.read_text())
    return tuple(Probe(name, np.asarray(p["reference"], dtype=np.float64),
                       np.asarray(p["displacement"], dtype=np.float64))
                 for name, p in document.items())

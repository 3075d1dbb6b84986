"""A finished run directory read back: the files `ndf-sim` wrote, for export, viewing, renders.

Reads (no Taichi, no field evaluation): mesh.obj (deformed positions, UVs, faces), mesh.ply
(per-vertex strains and energy density), reference.obj (the undeformed surface), probes.json,
trajectory/step_*.obj with the load factors, history and per-load-step probes of result.json,
and obstacles/*.obj (obstacle meshes of a scene that has them).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from taichi_ndf.io.mesh_files import MeshData, read_mesh

__all__ = ["QUANTITIES", "Frame", "Probe", "RunFiles", "garment_panels", "read_run",
           "up_direction"]

# Colourable per-vertex quantities: name -> label with units (colour bars, viewer, USD docs).
QUANTITIES = {
    "displacement": "|u| [m]",
    "membrane_strain": "|ε| [–]",
    "bending_strain": "|κ| [1/m]",
    "energy_density": "Ψ [J/m²]",
}


@dataclass(frozen=True)
class Frame:
    """One trajectory frame: its load factor (or pseudo-time), deformed positions (V, 3) [m]
    and, where result.json records them for this load step (the spline path's `load_steps`),
    the probes' displacements (3,) [m] by name."""

    load_factor: float
    vertices: np.ndarray
    probes: dict[str, np.ndarray] | None = None


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
    (empty without one); history: (iterations, Π [J]) of the monitor; decrements: the Newton
    decrement λ² [J] of each history row (projected Newton; empty for Adam runs); up: unit
    vector against gravity (z without gravity); obstacles: meshes of the scene's obstacles,
    named in obstacle_names (their scene names: the stems of obstacles/<name>.obj).
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
    decrements: np.ndarray = field(default_factory=lambda: np.zeros(0))
    time_rate: float | None = None  # a dynamic run's output frames per second [1/s], or None

    def probe_positions(self, index: int | None = None) -> tuple[np.ndarray, bool]:
        """Deformed positions (P, 3) [m] of the probes in trajectory frame `index` (None or the
        last frame: the final state) and whether they are the solver's values.

        The final state's come from probes.json, a load step's from result.json where it
        records them (`Frame.probes`); otherwise they are interpolated on the frame's mesh
        (linear on the triangle that holds the probe's reference position, so off by the
        mesh's interpolation error, of order h² times the curvature)."""
        if index is None or index == len(self.frames) - 1 or not self.probes:
            return np.array([p.deformed for p in self.probes]).reshape(-1, 3), True
        frame = self.frames[index]
        if frame.probes is not None and all(p.name in frame.probes for p in self.probes):
            return np.array([p.reference + frame.probes[p.name] for p in self.probes]), True
        if self.reference is None:
            raise ValueError(f"{self.path} has no reference.obj to place the probes on")
        places = [_on_mesh(self.reference, self.faces, p.reference) for p in self.probes]
        return np.array([weights @ frame.vertices[self.faces[face]]
                         for face, weights in places]), False

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
    step_probes = {float(s["load_factor"]): s.get("probes")
                   for s in result.get("load_steps") or [] if "load_factor" in s}
    frames = tuple(Frame(float(t), _same_topology(read_mesh(f), mesh, f.name),
                         _displacements(step_probes.get(float(t))))
                   for t, f in zip(factors, frame_files, strict=True))
    history = result.get("history", [])
    gravity = result.get("resolved", {}).get("scene_file", {}).get("loads", {}).get("gravity")
    obstacle_files = sorted((path / "obstacles").glob("*.obj"))
    rate = None  # a dynamic run: its frames' times [s] as load factors, a frame every 1/rate s
    if (result.get("trajectory") or {}).get("source") == "dynamics" and len(factors) > 1:
        rate = 1.0 / (float(factors[1]) - float(factors[0]))
    return RunFiles(
        path=path, name=str(result.get("scene", path.name)), deformed=mesh.vertices,
        faces=mesh.faces, uv=mesh.uvs, reference=reference, scalars=scalars, frames=frames,
        history=(np.array([h["iteration"] for h in history], dtype=np.float64),
                 np.array([h["energy"] for h in history], dtype=np.float64)),
        probes=_read_probes(path / "probes.json"), up=up_direction(gravity),
        obstacles=tuple(read_mesh(f) for f in obstacle_files),
        obstacle_names=tuple(f.stem for f in obstacle_files),
        decrements=np.array([h["decrement"] for h in history]
                            if all("decrement" in h for h in history) else [], dtype=np.float64),
        time_rate=rate)


def garment_panels(path: str | os.PathLike) -> list[str] | None:
    """The panels' names of the garment run in directory `path` (its result.json's scene has
    [[panels]]), or None where `path` holds no garment run (or no readable result.json)."""
    try:
        result = json.loads((Path(path) / "result.json").read_text())
    except (OSError, json.JSONDecodeError):
        return None
    panels = result.get("resolved", {}).get("scene_file", {}).get("panels")
    if not isinstance(panels, list):
        return None
    return [str(p.get("name", "?")) if isinstance(p, dict) else "?" for p in panels]


def _displacements(probes: dict | None) -> dict[str, np.ndarray] | None:
    if not isinstance(probes, dict):
        return None
    return {name: np.asarray(u, dtype=np.float64) for name, u in probes.items()}


def _on_mesh(vertices: np.ndarray, faces: np.ndarray, point: np.ndarray
             ) -> tuple[int, np.ndarray]:
    """The triangle of the mesh (vertices (V, 3), faces (F, 3)) nearest to `point` (3,) that
    holds its projection, and the barycentric weights (3,) of that projection; the nearest
    vertex (weight 1) when no triangle holds it."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    e1, e2, d = b - a, c - a, point - a
    d11, d12, d22 = (np.einsum("ij,ij->i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    p1, p2 = np.einsum("ij,ij->i", d, e1), np.einsum("ij,ij->i", d, e2)
    det = d11 * d22 - d12 ** 2
    ok = det > 1e-30 * np.maximum(d11 * d22, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(ok, (d22 * p1 - d12 * p2) / det, -1.0)
        w = np.where(ok, (d11 * p2 - d12 * p1) / det, -1.0)
    u = 1.0 - v - w
    inside = ok & (np.minimum(np.minimum(u, v), w) >= -1e-6)
    if not inside.any():
        nearest = int(np.argmin(np.linalg.norm(vertices - point, axis=1)))
        face = int(np.nonzero((faces == nearest).any(axis=1))[0][0])
        return face, (faces[face] == nearest).astype(np.float64)
    projected = a + v[:, None] * e1 + w[:, None] * e2
    distance = np.where(inside, np.linalg.norm(point - projected, axis=1), np.inf)
    face = int(np.argmin(distance))
    weights = np.clip([u[face], v[face], w[face]], 0.0, None)
    return face, weights / weights.sum()


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

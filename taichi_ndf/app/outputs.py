"""What a run leaves behind: deformed meshes with strain and energy, renders, plots, JSON.

The field is continuous, so the exported mesh is an evaluation on any grid of surface
coordinates (or on a template mesh's own vertices); memory stays bounded by evaluating in
chunks.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf import jets, progress
from taichi_ndf.contact.config import contact_summary, write_obstacles
from taichi_ndf.io import grid_mesh, write_obj, write_ply
from taichi_ndf.io.output_dir import OutputDir
from taichi_ndf.io.run_files import QUANTITIES, up_direction
from taichi_ndf.objective import ShellEnergyTerm
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.outline_mesh import conforming_mesh
from taichi_ndf.problem.pseudo_time import conditioning
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.render import save_png, write_video
from taichi_ndf.render.figure import Obstacle, render_figure
from taichi_ndf.shell.kinematics import strains

log = logging.getLogger(__name__)

CHUNK = 8192  # samples per jets evaluation when exporting (bounds the field's tape memory)
# Grid cells per coordinate (256² points) of the clearance to the obstacles in result.json.
CONTACT_GRID = (255, 255)


class ExportError(ValueError):
    """An exported mesh holds non-finite values (the run's result cannot be trusted)."""


@dataclass
class DeformedMesh:
    """A triangle mesh of the deformed surface.

    xi: surface coordinates of the vertices (V, 2); reference, deformed: positions [m] (V, 3);
    faces (F, 3); uv: texture coordinates (V, 2); per-vertex scalars: membrane_strain (norm of
    ε in the reference metric, dimensionless), bending_strain (norm of κ, [1/m]),
    energy_density Ψ [J/m²].
    """

    xi: np.ndarray
    reference: np.ndarray
    deformed: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    membrane_strain: np.ndarray
    bending_strain: np.ndarray
    energy_density: np.ndarray

    def scalars(self) -> dict[str, np.ndarray]:
        return {"membrane_strain": self.membrane_strain, "bending_strain": self.bending_strain,
                "energy_density": self.energy_density}


def exports_on_template(model: ShellModel) -> bool:
    """Whether `model` is exported on its template mesh's own vertices (a mesh surface), so an
    export resolution does not apply."""
    return hasattr(model.surface, "uv") and hasattr(model.surface, "faces")


def export_grid(model: ShellModel, resolution: tuple[int, int], border=None):
    """Surface coordinates, faces and UVs to export a model on: the template mesh's own
    vertices for a mesh surface, else a regular grid: a panel's (an `OutlinePlane`) cut to its
    outline, curved edges included (`conforming_mesh`), another masked chart's faces with a
    vertex outside dropped. border: a panel's extra border points, fractions of arclength per
    edge number (`problem.outline_mesh.seam_fractions`)."""
    surface = model.surface
    if exports_on_template(model):
        uv = np.asarray(surface.uv, dtype=np.float64)
        return uv, np.asarray(surface.faces, dtype=np.int64), uv
    domain = surface.domain
    grid = grid_mesh(domain.bounds, resolution, periodic=domain.periodic)
    xi, faces, uv = grid.xi, grid.faces, grid.uv
    outline = getattr(surface, "outline", None)
    if outline is not None and not any(domain.periodic):
        return conforming_mesh(outline, grid, border)
    if domain.inside is not None:
        inside = domain.contains(torch.from_numpy(xi)).numpy()
        faces = faces[inside[faces].all(axis=1)]
        used = np.unique(faces)
        remap = -np.ones(len(xi), dtype=np.int64)
        remap[used] = np.arange(len(used))
        xi, uv, faces = xi[used], uv[used], remap[faces]
    return xi, faces, uv


def _strain_norm(strain: torch.Tensor, r_jets: torch.Tensor) -> torch.Tensor:
    """√(ε_αβ a^{αγ} a^{βδ} ε_γδ): the norm of a covariant surface tensor in the metric of r."""
    a1, a2 = r_jets[:, jets.D1], r_jets[:, jets.D2]
    metric = torch.stack((torch.stack(((a1 * a1).sum(-1), (a1 * a2).sum(-1)), -1),
                          torch.stack(((a1 * a2).sum(-1), (a2 * a2).sum(-1)), -1)), -2)
    mixed = torch.linalg.solve(metric, strain)  # a^{αγ} ε_γβ
    return torch.sqrt(torch.clamp((mixed * mixed.transpose(-1, -2)).sum((-1, -2)), min=0))


def deformed_mesh(model: ShellModel, field, resolution: tuple[int, int] = (64, 64), *,
                  load_factor: float = 1.0, pseudo_time: bool = False, border=None
                  ) -> DeformedMesh:
    """Evaluate the field (boundary conditions applied) on the export grid at a load factor
    (`export_grid`, with a panel's extra `border` points); with `pseudo_time` the field's
    pseudo-time input is that load factor too."""
    xi_np, faces, uv = export_grid(model, resolution, border)
    dtype = field.parameters[0].dtype
    energy = ShellEnergyTerm(model.material, model.loads)
    parts = {k: [] for k in ("r", "u", "eps", "kappa", "psi")}
    for start in range(0, len(xi_np), CHUNK):
        xi = torch.from_numpy(xi_np[start:start + CHUNK]).to(dtype)
        r = model.surface.jets(xi)
        cond = conditioning(load_factor, len(xi), dtype=dtype) if pseudo_time else None
        u = model.displacement_jets(field, xi, t=load_factor, conditioning=cond)
        samples = SurfaceSamples(xi=xi, r_jets=r, weight=torch.ones_like(xi[:, 0]),
                                 point_force=torch.zeros_like(r[:, 0]))
        eps, kappa, _ = strains(r, u)
        parts["r"].append(r[:, jets.VALUE])
        parts["u"].append(u[:, jets.VALUE])
        parts["eps"].append(_strain_norm(eps, r))
        parts["kappa"].append(_strain_norm(kappa, r))
        parts["psi"].append(energy.result(samples, u, load_factor, grad=False).density)
    cat = {k: torch.cat(v).double().numpy() for k, v in parts.items()}
    return DeformedMesh(xi=xi_np, reference=cat["r"], deformed=cat["r"] + cat["u"], faces=faces,
                        uv=uv, membrane_strain=cat["eps"], bending_strain=cat["kappa"],
                        energy_density=cat["psi"])


def surface_points(model: ShellModel, field, resolution: tuple[int, int], *,
                   load_factor: float = 1.0) -> np.ndarray:
    """Deformed positions (V, 3) [m] of the export grid's vertices (`export_grid`), without
    strains: e.g. the clearance to obstacles on a dense grid."""
    xi_np, _, _ = export_grid(model, resolution)
    dtype = field.parameters[0].dtype
    points = []
    for start in range(0, len(xi_np), CHUNK):
        xi = torch.from_numpy(xi_np[start:start + CHUNK]).to(dtype)
        points.append(model.surface.jets(xi)[:, jets.VALUE]
                      + model.displacement(field, xi, t=load_factor))
    return torch.cat(points).double().numpy()


def write_mesh_files(out: OutputDir, stem: str, mesh: DeformedMesh) -> None:
    """`stem`.obj (positions, UVs) and `stem`.ply (UVs, strains, energy density)."""
    write_obj(out.file(f"{stem}.obj"), mesh.deformed, mesh.faces, uvs=mesh.uv)
    write_ply(out.file(f"{stem}.ply"), mesh.deformed, mesh.faces, uvs=mesh.uv,
              vertex_scalars=mesh.scalars())


def write_reference_mesh(out: OutputDir, mesh: DeformedMesh) -> None:
    """reference.obj: the undeformed surface on the vertices and faces of mesh.obj."""
    write_obj(out.file("reference.obj"), mesh.reference, mesh.faces, uvs=mesh.uv)


def write_probe_points(out: OutputDir, model: ShellModel, displacements: dict) -> None:
    """probes.json: per probe its ξ, reference position [m] and displacement [m] (the viewer
    and the USD export label the probes with it)."""
    if not model.probes:
        return
    xi = torch.tensor([p.xi for p in model.probes], dtype=torch.float64)
    reference = model.surface.jets(xi)[:, jets.VALUE].double().numpy()
    out.write_json("probes.json", {
        p.name: {"xi": list(p.xi), "reference": [float(v) for v in reference[k]],
                 "displacement": [float(v) for v in displacements[p.name]]}
        for k, p in enumerate(model.probes)})


def write_render(out: OutputDir, name: str, mesh: DeformedMesh, *, up=(0.0, 0.0, 1.0),
                 views: tuple[str, ...] = ("iso",), obstacles=(), label: str | None = None
                 ) -> None:
    """The deformed surface coloured by bending strain from `views` side by side (default a
    three-quarter view from the side that shows it largest), with its ground shadow, the
    obstacles (vertices, faces) drawn in grey and a colour bar; 600 pixels high, each view as
    wide as its framed shape needs (300 to 800 pixels); `label` (e.g. a dynamic run's time
    "t = 3.00 s") written in the top left corner."""
    from taichi_ndf.render.trajectory import LABEL_ROWS, put_label

    image = render_figure(mesh.deformed, mesh.faces, scalars=mesh.bending_strain,
                          scalar_label=QUANTITIES["bending_strain"], up=up, views=views,
                          obstacles=tuple(Obstacle(v, f) for v, f in obstacles),
                          width=None, height=600, label_rows=0 if label is None else LABEL_ROWS)
    if label is not None:
        put_label(image, label, boxed=True)
    save_png(out.file(name), image)


def write_energy_plot(out: OutputDir, name: str, history, refinement: dict | None = None
                      ) -> None:
    """Π over iterations (load-step and grid-level boundaries marked), each solve's distance
    to its final Π on a log axis and, with `refinement` (a spline run on several grids:
    `SplineRun.refinement`), Π per grid level with its Richardson-extrapolated value and error
    bar (`taichi_ndf.render.energy_plot`)."""
    if not history:
        return
    from taichi_ndf.render.energy_plot import energy_figure

    save_png(out.file(name), energy_figure(history, refinement))


def trajectory_mesh_name(index: int) -> str:
    """File of trajectory frame `index` (a load step's index, or a pseudo-time frame's)."""
    return f"trajectory/step_{index:03d}.obj"


def write_trajectory_mesh(out: OutputDir, index: int, mesh: DeformedMesh) -> None:
    """Frame `index` of the trajectory as an OBJ with UVs; written as soon as the frame exists,
    so that a resumed run finds the frames of the load steps finished before the interruption."""
    write_obj(out.file(trajectory_mesh_name(index)), mesh.deformed, mesh.faces, uvs=mesh.uv)


def write_trajectory_video(out: OutputDir, states: list[np.ndarray], faces: np.ndarray,
                           load_factors: list[float], *, reference: np.ndarray, up,
                           obstacles=None, pseudo_time: bool = False,
                           physical_time: bool = False) -> bool:
    """trajectory.mp4 (H.264): the deformed `states` (positions (V, 3) [m] on `faces`) in
    order, coloured by displacement from `reference` on one colour range, with `obstacles`
    per state (meshes (vertices, faces) at that state) and a load-factor (or pseudo-time, or
    with `physical_time` the time "t = … s" of a dynamic run) label, all from one camera
    that frames every state (`render.trajectory`); a dynamic run's video plays in real time
    (`render.trajectory.real_time_fps`), the others at FPS. Where no H.264
    encoder is found the run keeps its other outputs: a warning names the cause and the
    video is left out (returns False)."""
    from taichi_ndf.render.trajectory import FPS, real_time_fps, trajectory_frames

    groups = None if obstacles is None else [tuple(Obstacle(v, f) for v, f in group)
                                             for group in obstacles]
    fps = real_time_fps(load_factors) if physical_time else FPS
    frames = trajectory_frames(states, faces, load_factors, reference=reference,
                               obstacles=groups, up=up, pseudo_time=pseudo_time,
                               physical_time=physical_time, fps=fps)
    try:
        write_video(out.file("trajectory.mp4"), frames, fps)
    except RuntimeError as err:
        log.warning("trajectory.mp4 not written: %s", err)
        return False
    return True


def write_field_outputs(out: OutputDir, model: ShellModel, field, probes: dict, *,
                        resolution: tuple[int, int], views: tuple[str, ...], history=(),
                        load_factor: float = 1.0, pseudo_time: bool = False,
                        refinement: dict | None = None, obstacles: tuple = (),
                        states: list[np.ndarray] | None = None,
                        state_parameters: list[float] | None = None,
                        state_obstacles: list | None = None, physical_time: bool = False,
                        label: str | None = None, pictures: bool = True) -> DeformedMesh:
    """The one writer of a run's outputs, static or dynamic: mesh.obj/.ply, reference.obj,
    probes.json, render.png (with `obstacles` (vertices, faces) and `label`) and energy.png
    (of a non-empty `history`) of the final field at `load_factor`, and trajectory.mp4 of
    `states` (positions (V, 3) [m]) at `state_parameters` (load factors, pseudo-times, or
    with `physical_time` times [s]) with `state_obstacles` per state (a progress stage of six
    steps); without `pictures` the meshes and probes only. ExportError for a non-finite mesh.
    Returns the final mesh."""
    name = "outputs: mesh, render, energy plot, video" if pictures else "outputs: mesh"
    with progress.stage(name, 6):
        mesh = deformed_mesh(model, field, resolution, load_factor=load_factor,
                             pseudo_time=pseudo_time)
        for quantity, values in mesh.scalars().items():
            if not all(math.isfinite(float(v)) for v in values):
                raise ExportError(f"non-finite {quantity} in the exported mesh")
        progress.report(1)
        write_mesh_files(out, "mesh", mesh)
        write_reference_mesh(out, mesh)
        write_probe_points(out, model, probes)
        progress.report(3)
        if not pictures:
            return mesh
        up = up_direction(model.loads.gravity)
        write_render(out, "render.png", mesh, up=up, views=views, obstacles=obstacles,
                     label=label)
        progress.report(4)
        write_energy_plot(out, "energy.png", history, refinement)
        progress.report(5)
        if states:
            write_trajectory_video(out, states, mesh.faces, state_parameters,
                                   reference=mesh.reference, up=up, pseudo_time=pseudo_time,
                                   physical_time=physical_time, obstacles=state_obstacles)
        progress.report(6)
    return mesh


def contact_outputs(config, out: OutputDir, surface: np.ndarray, points, *,
                    load_factor: float = 1.0, **counts) -> tuple[dict, tuple]:
    """The obstacles' meshes at `load_factor` (RUN/obstacles/*.obj, and (vertices, faces) for
    the render) and result.json's `contact`: the clearance of `surface` (points (N, 3) [m] of
    the final surface on CONTACT_GRID, `surface_points`) (`contact_summary`), the check points
    and κ of `points` (`ContactPoints`), and `counts`. config: the model's `ContactConfig`."""
    write_obstacles(config, out, load_factor)
    meshes = tuple(o.triangles(load_factor) for o in config.obstacles)
    contact = contact_summary(config, surface, load_factor)
    contact.update(evaluation_grid=list(CONTACT_GRID), check_points=points.count,
                   final_stiffness=points.term.stiffness, **counts)
    return contact, meshes

"""The outputs of a garment's run (several panels, `MultiPatchDiscretisation`): one mesh per
panel, one combined mesh with a `panel` vertex property and its undeformed twin, the probes, a
render showing all panels: the files `io.run_files.read_run` opens (ndf-view, ndf-export
--format usd). No checkpoint.pt: a garment's state is several fields."""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf import jets
from taichi_ndf.app.outputs import DeformedMesh, deformed_mesh, write_mesh_files
from taichi_ndf.io import OutputDir, write_obj, write_ply
from taichi_ndf.render.figure import Obstacle, render_figure
from taichi_ndf.render.image_file import save_png


def panel_meshes(plan, field, resolution: tuple[int, int], load_factor: float = 1.0
                 ) -> list[DeformedMesh]:
    """Each panel's deformed mesh on the export grid (`deformed_mesh` of its model)."""
    return [deformed_mesh(patch.model, f, resolution, load_factor=load_factor)
            for patch, f in zip(plan.patches, field.fields, strict=True)]


def combined(meshes: list[DeformedMesh]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The panels' meshes as one: vertices (V, 3) [m], faces (F, 3) and each vertex's panel
    index (V,) in the plan's order (the panels' vertices are not welded at the seams)."""
    offsets = np.cumsum([0] + [len(m.deformed) for m in meshes])
    vertices = np.concatenate([m.deformed for m in meshes])
    faces = np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=False)])
    panel = np.concatenate([np.full(len(m.deformed), i, dtype=np.float64)
                            for i, m in enumerate(meshes)])
    return vertices, faces, panel


def write_panel_outputs(out: OutputDir, plan, field, resolution: tuple[int, int], *,
                        probes: dict | None = None, views: tuple[str, ...] = ("iso",),
                        pictures: bool = True, obstacles: tuple = ()) -> None:
    """mesh_<panel>.obj/.ply per panel; mesh.obj (with UVs), mesh.ply (UVs, strains, energy
    density and a `panel` vertex property: the panel's index in the file's order) and
    reference.obj (undeformed, the same vertices and faces) of all panels; probes.json of
    `probes` (displacement (3,) [m] by "panel.probe", as `MultiPatchDiscretisation.probes`);
    render.png of all panels coloured by panel, with `obstacles` ((vertices, faces) each) in
    grey."""
    meshes = panel_meshes(plan, field, resolution)
    for patch, mesh in zip(plan.patches, meshes, strict=True):
        write_mesh_files(out, f"mesh_{patch.name}", mesh)
    vertices, faces, panel = combined(meshes)
    uv = np.concatenate([m.uv for m in meshes])
    scalars = {name: np.concatenate([m.scalars()[name] for m in meshes])
               for name in meshes[0].scalars()}
    write_obj(out.file("mesh.obj"), vertices, faces, uvs=uv)
    write_ply(out.file("mesh.ply"), vertices, faces, uvs=uv,
              vertex_scalars={**scalars, "panel": panel})
    write_obj(out.file("reference.obj"), np.concatenate([m.reference for m in meshes]), faces,
              uvs=uv)
    if probes:
        out.write_json("probes.json", _probe_points(plan, probes))
    if pictures:
        # the panels' indices on the whole map (not the 1st–99th percentiles of a field)
        image = render_figure(vertices, faces, scalars=panel,
                              scalar_label="panel (" + ", ".join(p.name for p in plan.patches)
                              + ")", scalar_range=(0.0, max(len(plan.patches) - 1, 1)),
                              obstacles=tuple(Obstacle(v, f) for v, f in obstacles),
                              views=views, width=None, height=600)
        save_png(out.file("render.png"), image)


def _probe_points(plan, probes: dict) -> dict:
    """probes.json's document: per probe "panel.probe" its ξ on its panel, reference
    position [m] and displacement [m]."""
    document = {}
    for patch in plan.patches:
        for p in patch.model.probes:
            xi = torch.tensor([p.xi], dtype=torch.float64)
            reference = patch.model.surface.jets(xi)[0, jets.VALUE].double().numpy()
            name = f"{patch.name}.{p.name}"
            document[name] = {"xi": list(p.xi), "reference": [float(v) for v in reference],
                              "displacement": [float(v) for v in probes[name]]}
    return document

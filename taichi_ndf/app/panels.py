"""The outputs of a run whose result has several named parts (a garment's panels:
`Discretisation.result_parts`, `MultiPatchDiscretisation`): one mesh per panel, one combined
mesh with a `panel` vertex property and its undeformed twin, the probes, a render showing all
panels in categorical colours with a legend naming them: the files `io.run_files.read_run`
opens (ndf-view, ndf-export --format usd)."""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf import jets
from taichi_ndf.app.outputs import DeformedMesh, deformed_mesh, write_mesh_files
from taichi_ndf.discretise.protocol import ResultPart
from taichi_ndf.io import OutputDir, grid_mesh, write_obj, write_ply
from taichi_ndf.problem.outline_mesh import seam_fractions
from taichi_ndf.render.figure import Obstacle, render_figure
from taichi_ndf.render.image_file import save_png
from taichi_ndf.render.legend import Legend


def part_meshes(parts, resolution: tuple[int, int], load_factor: float = 1.0
                ) -> list[DeformedMesh]:
    """Each part's (`ResultPart`: model and field) deformed mesh on the export grid, the two
    sides of each seam between outline edges sampled at the same fractions of their arclength
    (`seam_fractions`: its vertices coincide to the seam's gap)."""
    cuts = [grid_mesh(p.model.surface.domain.bounds, resolution).lines for p in parts]
    border = seam_fractions([getattr(p.model.surface, "outline", None) for p in parts], cuts,
                            parts[0].seams if parts else ())
    return [deformed_mesh(p.model, p.field, resolution, load_factor=load_factor, border=b)
            for p, b in zip(parts, border, strict=True)]


def panel_meshes(plan, field, resolution: tuple[int, int], load_factor: float = 1.0
                 ) -> list[DeformedMesh]:
    """Each panel's deformed mesh on the export grid (`part_meshes` of the plan's patches)."""
    seams = plan.outline_seams()
    return part_meshes([ResultPart(patch.name, patch.model, f, seams)
                        for patch, f in zip(plan.patches, field.fields, strict=True)],
                       resolution, load_factor)


def combined(meshes: list[DeformedMesh]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The panels' meshes as one: vertices (V, 3) [m], faces (F, 3) and each vertex's panel
    index (V,) in the plan's order (the panels' vertices are not welded at the seams)."""
    offsets = np.cumsum([0] + [len(m.deformed) for m in meshes])
    vertices = np.concatenate([m.deformed for m in meshes])
    faces = np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=False)])
    panel = np.concatenate([np.full(len(m.deformed), i, dtype=np.float64)
                            for i, m in enumerate(meshes)])
    return vertices, faces, panel


def write_panels_file(path, parts, meshes: list[DeformedMesh]) -> None:
    """The parts' deformed `meshes` (`part_meshes`) in one file: an OBJ with one object per
    part named by its panel (`o front`), with UVs; or a PLY (binary) with UVs, strains,
    energy density and the `panel` vertex property, a header comment naming each index
    ("panel 0 front")."""
    vertices, faces, panel = combined(meshes)
    uv = np.concatenate([m.uv for m in meshes])
    if str(path).lower().endswith(".obj"):
        write_obj(path, vertices, faces, uvs=uv,
                  objects=[(p.name, len(m.deformed)) for p, m in zip(parts, meshes, strict=True)])
        return
    scalars = {name: np.concatenate([m.scalars()[name] for m in meshes])
               for name in meshes[0].scalars()}
    write_ply(path, vertices, faces, uvs=uv, vertex_scalars={**scalars, "panel": panel},
              comments=[f"panel {i} {p.name}" for i, p in enumerate(parts)])


def write_panel_outputs(out: OutputDir, parts, resolution: tuple[int, int], *,
                        probes: dict | None = None, views: tuple[str, ...] = ("iso",),
                        pictures: bool = True, obstacles: tuple = ()) -> Legend | None:
    """mesh_<panel>.obj/.ply per part (`ResultPart`, named by its panel); mesh.obj (with
    UVs), mesh.ply (UVs, strains, energy density and a `panel` vertex property: the part's
    index in the file's order) and reference.obj (undeformed, the same vertices and faces) of
    all parts; probes.json of `probes` (displacement (3,) [m] by "panel.probe", as
    `MultiPatchDiscretisation.probes`); render.png of all panels, each in its colour of a
    categorical palette with a legend naming them, with `obstacles` ((vertices, faces) each)
    in grey. Returns that legend (None: no pictures)."""
    meshes = part_meshes(parts, resolution)
    for part, mesh in zip(parts, meshes, strict=True):
        write_mesh_files(out, f"mesh_{part.name}", mesh)
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
        out.write_json("probes.json", _probe_points(parts, probes))
    if not pictures:
        return None
    legend = Legend(tuple(p.name for p in parts))
    image = render_figure(vertices, faces, scalars=panel, scalar_label="panel", legend=legend,
                          obstacles=tuple(Obstacle(v, f) for v, f in obstacles), views=views,
                          width=None, height=600)
    save_png(out.file("render.png"), image)
    return legend


def _probe_points(parts, probes: dict) -> dict:
    """probes.json's document: per probe "panel.probe" its ξ on its panel, reference
    position [m] and displacement [m]."""
    document = {}
    for part in parts:
        for p in part.model.probes:
            xi = torch.tensor([p.xi], dtype=torch.float64)
            reference = part.model.surface.jets(xi)[0, jets.VALUE].double().numpy()
            name = f"{part.name}.{p.name}"
            document[name] = {"xi": list(p.xi), "reference": [float(v) for v in reference],
                              "displacement": [float(v) for v in probes[name]]}
    return document

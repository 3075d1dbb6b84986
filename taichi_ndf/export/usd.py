"""A run as one USD stage (`.usdc`) that Blender, Houdini and Omniverse open.

Layout (metres, up axis Z or Y after the run's gravity, stage metadata set so that importers
scale and orient it right):

    /World                      Xform, the default prim
    /World/deformed             Mesh: points (time-sampled over the trajectory frames when the
                                run has them; the default value is the final state), normals,
                                primvars:st (UVs), per-vertex primvars displacement,
                                membrane_strain, bending_strain, energy_density (final state),
                                and ndf:loadFactor (time-sampled); a garment run's
                                also primvars:panel (int, each vertex's panel index)
    /World/deformed/PANEL       GeomSubset (family "panel"): a garment panel's faces, one
                                per panel, named by it
    /World/reference            Mesh: the undeformed surface (purpose "guide")
    /World/probes               Points: the probes (time-sampled over the frames as
                                `RunFiles.probe_positions` places them; the default value
                                their final positions), names in customData
    /World/obstacles/NAME       Mesh: the scene's obstacles by their scene names, when it has any
    /World/Looks/surface        Material (UsdPreviewSurface, steel blue as render.png) bound to
                                the deformed and reference meshes; /World/Looks/obstacle (grey)
                                bound to the obstacles

Positions and UVs are stored as float32, the values of the run's OBJ files rounded to float32;
time code k is trajectory frame k (trajectory/step_k.obj), FRAMES_PER_SECOND time codes and
frames per second; a dynamic run's frame at time t [s] has the time code t × r with r its
output frames per second as time codes and frames per second (its codes are 0, 1, … at the
output rate; a last frame off that grid gets its fractional code), and `ndf:time` [s] instead
of `ndf:loadFactor`. Blender 5.0's importer maps time code k to its frame k and sets the frame
range, but keeps the scene's own frame rate (24 fps unless changed); it imports the reference
(a guide) only with its "Guide" option (tests/test_usd_blender.py).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from taichi_ndf.extras import require
from taichi_ndf.io.normals import vertex_normals
from taichi_ndf.io.output_dir import atomic_path
from taichi_ndf.io.run_files import QUANTITIES, RunFiles, garment_panels
from taichi_ndf.render.figure import OBSTACLE_BGR
from taichi_ndf.render.shaded import SURFACE_BGR

__all__ = ["require_usd", "write_run_usd", "FRAMES_PER_SECOND"]

FRAMES_PER_SECOND = 4.0  # as trajectory.mp4


def require_usd():
    """The pxr module of usd-core, or MissingExtra naming the [usd] extra."""
    return require("pxr.Usd", "usd", "USD export")


def _time_codes(run: RunFiles) -> list:
    """The frames' time codes: k for frame k, or for a dynamic run (`RunFiles.time_rate`)
    t × rate, so that with `rate` time codes per second a code is the physical time t [s]."""
    from pxr import Usd

    if run.time_rate is None:
        return [Usd.TimeCode(k) for k in range(len(run.frames))]
    return [Usd.TimeCode(frame.load_factor * run.time_rate) for frame in run.frames]


def write_run_usd(run: RunFiles, path: str | os.PathLike) -> Path:
    """Write `run` as a USD stage at `path` (.usdc binary, .usda text or .usd), atomically."""
    require_usd()
    from pxr import Sdf, Tf, Usd, UsdGeom, Vt

    path = Path(path)
    if path.suffix not in (".usd", ".usdc", ".usda"):
        raise ValueError(f"a USD file must end in .usdc, .usda or .usd, got {path}")
    with atomic_path(path) as temporary:
        stage = Usd.Stage.CreateNew(str(temporary))
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if abs(run.up[1]) > abs(run.up[2])
                               else UsdGeom.Tokens.z)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        stage.SetMetadata("comment", f"taichi-ndf run {run.name} ({run.path})")

        deformed = _mesh(stage, "/World/deformed", run.deformed, run.faces)
        points = deformed.GetPointsAttr()
        extent = deformed.GetExtentAttr()
        normals = deformed.CreateNormalsAttr(_vec3(vertex_normals(run.deformed, run.faces)))
        deformed.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        codes = _time_codes(run)
        if run.frames:
            dynamic = run.time_rate is not None
            load_factor = deformed.GetPrim().CreateAttribute(
                "ndf:time" if dynamic else "ndf:loadFactor", Sdf.ValueTypeNames.Double)
            load_factor.SetDocumentation("time [s] of each output frame" if dynamic else
                                         "load factor (or pseudo-time) of each trajectory frame")
            for code, frame in zip(codes, run.frames, strict=True):
                points.Set(_vec3(frame.vertices), code)
                extent.Set(_extent(frame.vertices), code)
                normals.Set(_vec3(vertex_normals(frame.vertices, run.faces)), code)
                load_factor.Set(frame.load_factor, code)
            stage.SetStartTimeCode(codes[0].GetValue())
            stage.SetEndTimeCode(codes[-1].GetValue())
            rate = run.time_rate or FRAMES_PER_SECOND
            stage.SetTimeCodesPerSecond(rate)
            stage.SetFramesPerSecond(rate)
        primvars = UsdGeom.PrimvarsAPI(deformed)
        if run.uv is not None:
            st = primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                        UsdGeom.Tokens.vertex)
            st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(run.uv, dtype=np.float32)))
        for name in run.available():
            primvar = primvars.CreatePrimvar(name, Sdf.ValueTypeNames.FloatArray,
                                             UsdGeom.Tokens.vertex)
            primvar.Set(Vt.FloatArray.FromNumpy(
                np.ascontiguousarray(run.quantity(name), dtype=np.float32)))
            primvar.GetAttr().SetDocumentation(f"{QUANTITIES[name]} at the final state")
        if "panel" in run.scalars:  # a garment run: each vertex's panel (mesh.ply's property)
            panel = primvars.CreatePrimvar("panel", Sdf.ValueTypeNames.IntArray,
                                           UsdGeom.Tokens.vertex)
            panel.Set(Vt.IntArray.FromNumpy(np.ascontiguousarray(run.scalars["panel"],
                                                                 dtype=np.int32)))
            panel.GetAttr().SetDocumentation("the vertex's panel: its index in the garment's "
                                             "[[panels]] order")
            _panel_subsets(deformed, run.faces, run.scalars["panel"],
                           garment_panels(run.path) or [])

        UsdGeom.Scope.Define(stage, "/World/Looks")
        surface = _display_material(stage, "/World/Looks/surface", SURFACE_BGR)
        _bind(deformed, surface)
        if run.reference is not None:
            reference = _mesh(stage, "/World/reference", run.reference, run.faces)
            reference.CreatePurposeAttr(UsdGeom.Tokens.guide)
            _bind(reference, surface)
        if run.probes:
            probes = UsdGeom.Points.Define(stage, "/World/probes")
            probe_points = probes.CreatePointsAttr(_vec3(run.probe_positions()[0]))
            for k in range(len(run.frames) if run.reference is not None else 0):
                probe_points.Set(_vec3(run.probe_positions(k)[0]), codes[k])
            probes.GetPrim().SetCustomDataByKey("names", Vt.StringArray([p.name
                                                                         for p in run.probes]))
        if run.obstacles:
            UsdGeom.Xform.Define(stage, "/World/obstacles")  # a group importers parent under
            grey = _display_material(stage, "/World/Looks/obstacle", OBSTACLE_BGR)
        names = run.obstacle_names or tuple(f"obstacle_{k}" for k in range(len(run.obstacles)))
        for name, obstacle in zip(names, run.obstacles, strict=True):
            mesh = _mesh(stage, f"/World/obstacles/{Tf.MakeValidIdentifier(name)}",
                         obstacle.vertices, obstacle.faces)
            _bind(mesh, grey)
        stage.GetRootLayer().Save()
        del stage
    return path


def _panel_subsets(mesh, faces: np.ndarray, panel: np.ndarray, names: list[str]) -> None:
    """One face subset of `mesh` per panel (family "panel"), named by it (`names` in the
    panels' order; a panel without a name: panel_<index>)."""
    from pxr import Tf, UsdGeom, Vt

    of_face = np.asarray(panel, dtype=np.int64)[faces[:, 0]]
    for index in np.unique(of_face):
        name = names[index] if index < len(names) else f"panel_{index}"
        UsdGeom.Subset.CreateGeomSubset(
            mesh, Tf.MakeValidIdentifier(name), UsdGeom.Tokens.face,
            Vt.IntArray.FromNumpy(np.nonzero(of_face == index)[0].astype(np.int32)), "panel")


def _display_material(stage, path: str, bgr):
    """A UsdPreviewSurface material of one diffuse colour (BGR in [0, 255], as the renders)."""
    from pxr import Gf, Sdf, UsdShade

    rgb = Gf.Vec3f(*(float(c) / 255.0 for c in reversed(np.asarray(bgr, dtype=np.float64))))
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/preview")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(rgb)
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def _bind(mesh, material) -> None:
    from pxr import UsdShade

    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def _vec3(array: np.ndarray):
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(array, dtype=np.float32))


def _extent(points: np.ndarray):
    from pxr import Vt

    p = np.asarray(points, dtype=np.float32)
    return Vt.Vec3fArray.FromNumpy(np.stack([p.min(axis=0), p.max(axis=0)]))


def _mesh(stage, prim_path: str, vertices: np.ndarray, faces: np.ndarray):
    """A triangle mesh prim (right-handed: faces counter-clockwise around their normal)."""
    from pxr import UsdGeom, Vt

    mesh = UsdGeom.Mesh.Define(stage, prim_path)
    mesh.CreatePointsAttr(_vec3(vertices))
    mesh.CreateExtentAttr(_extent(vertices))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(
        np.ascontiguousarray(faces, dtype=np.int32).ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # a polygon mesh, not a cage
    return mesh

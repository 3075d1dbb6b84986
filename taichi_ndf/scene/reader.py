"""Scene files (TOML): geometry, material, loads, boundary conditions, field, training, probes.

`docs/scenes.md` documents every key. Unknown keys and wrong types raise `SceneError` naming
the key; physical validation errors of the model (a point outside the domain, an invalid
material) are re-raised as `SceneError` with the section they come from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from taichi_ndf.boundary import (
    EDGES,
    PIN_ROTATIONS,
    BoundaryConditions,
    ClampedEdge,
    Handle,
    HingedEdge,
    InteriorLine,
    PinnedPoint,
    RimRotation,
    SymmetryPlane,
)
from taichi_ndf.field import FieldConfig
from taichi_ndf.geometry import Annulus, Cone, Cylinder, CylindricalRoof, Hemisphere, Plane
from taichi_ndf.problem.field_types import of_spec
from taichi_ndf.problem.line_loads import LineLoad, edge_path
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.model import Probe, ShellModel
from taichi_ndf.problem.pseudo_time import DEFAULT_FRAMES, TIME_RANGE
from taichi_ndf.problem.run_size import contact_check_points
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.render.figure import VIEWS
from taichi_ndf.scene.contact import parse_contact
from taichi_ndf.scene.dynamics import parse_dynamics
from taichi_ndf.scene.field import field_config, with_field_type
from taichi_ndf.scene.garment import is_garment, parse_garment
from taichi_ndf.scene.overrides import apply_overrides
from taichi_ndf.scene.schema import SceneError, Table, read_toml
from taichi_ndf.scene.schema import checked as _check
from taichi_ndf.scene.seams import parse_seams
from taichi_ndf.scene.self_contact import parse_self_contact
from taichi_ndf.scene.start import parse_start
from taichi_ndf.scene.terms import parse_terms
from taichi_ndf.scene.training import training
from taichi_ndf.shell.materials import (
    PRESETS,
    ClydeFabric,
    LinearIsotropic,
    OrthotropicStVK,
    preset,
)

GEOMETRIES = ("plane", "cylinder", "cone", "roof", "hemisphere", "annulus", "mesh")
CONSTRAINTS = ("clamped_edge", "hinged_edge", "pinned_point", "handle", "interior_line",
               "rim_rotation", "symmetry_plane")


@dataclass(frozen=True)
class OutputConfig:
    """resolution: grid cells per surface coordinate of the exported mesh (ignored for a
    mesh template, which is exported on its own vertices)."""

    resolution: tuple[int, int] = (64, 64)
    frames: int | None = None  # trajectory frames of a pseudo-time field (None: not one)
    usd: bool = False  # also write result.usdc (needs the [usd] extra)
    views: tuple[str, ...] = ("iso",)  # views side by side in render.png (render.figure.VIEWS)


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    model: ShellModel
    # The specification of its field type (`problem.field_types.FIELD_TYPES`): a SIREN's
    # `FieldConfig`, a spline field's `SplinePlan`.
    field: Any
    solver: SolverConfig
    quick_solver: SolverConfig
    output: OutputConfig
    path: Path
    document: dict  # the parsed TOML, for result.json
    # The output-scale estimate a SIREN's [field] names ("auto", "equilibrium", "linear",
    # "dimensional": `scaling.SCALE_ESTIMATES`), made when a run starts where it solves
    # (`output_scale.field_for_run`); None: a number given, or a spline field.
    output_scale_estimate: str | None = None
    # A run in physical time (`[dynamics]`, `problem.dynamics.DynamicsConfig`); None: quasistatic.
    dynamics: Any = None
    # Where the solve starts (`[start]`, `problem.start_shape.StartShape`); None: the rest shape.
    start: Any = None


def load_scene(path: str | Path, *, material: str | None = None,
               field: str | None = None, overrides: dict[str, object] | None = None) -> Scene:
    """Read and validate a scene file; relative paths inside it are relative to the file.

    material: a preset name that replaces the scene's [material] table.
    field: a field type's name ("siren", "spline": `FIELD_TYPES`) to solve the scene with
    that field (`with_field_type`).
    overrides: scene keys set after those two, {"loads.gravity": [0, 0, -5], ...}
    (`taichi_ndf.scene.overrides`; `ndf-sim --set`).
    """
    path = Path(path)
    document = read_toml(path, "scene file")
    if material is not None:
        document["material"] = {"preset": material}
    if field is not None:
        document = with_field_type(document, field)
    if overrides:
        document = apply_overrides(document, overrides)
    return parse_scene(document, base_dir=path.parent, path=path)


def parse_scene(document: dict, *, base_dir: Path, path: Path | None = None) -> Scene:
    if is_garment(document):
        return _garment(document, base_dir=base_dir, path=path)
    top = Table(document, "")
    name = top.string("name")
    description = top.string("description", "")
    surface = _section(top.table("geometry"), _geometry, base_dir)
    material = _section(top.table("material"), _material)
    loads = _section(top.table("loads", optional=True), _loads, surface.domain)
    _check(lambda: loads.check_domain(surface.domain), "loads")
    boundary = _section(top.table("boundary", optional=True), _boundary, surface)
    probes = tuple(Probe(t.string("name"), t.vector("xi", 2)) for t in top.tables("probes"))
    model = _check(lambda: ShellModel(surface, material, loads, boundary, probes), "probes")
    seams = parse_seams(top, surface, material)
    model = replace(model, contact=parse_contact(top, model, base_dir),
                    terms=parse_terms(top) + seams)
    field, estimate = _section(top.table("field", optional=True), field_config, model)
    kind = of_spec(field)
    if seams and kind.method != "newton":
        raise SceneError(f"seams: need [field] type = \"spline\" (a seam's points are Gauss "
                         f"points of the spline path's quadrature), not a {kind.label} field")
    model = parse_self_contact(top, model, field)
    solver, quick = _section(top.table("training", optional=True), training,
                             kind.method == "newton")
    output = _section(top.table("output", optional=True), _output, solver.pseudo_time)
    if solver.pseudo_time and not kind.pseudo_time:
        raise SceneError(f"training.pseudo_time: needs a SIREN field (a {kind.label} field has "
                         "no pseudo-time input)")
    if (isinstance(field, FieldConfig) and model.boundary.frame is not None
            and (solver.newton_iterations or quick.newton_iterations)):
        raise SceneError("training.newton_iterations: the last-layer Newton phases do not "
                         "support [boundary] frame (a tilted component depends on every output "
                         "weight); use Adam (newton_iterations = 0) or [field] type = \"spline\"")
    if solver.pseudo_time:
        if model.contact is not None:
            raise SceneError("training.pseudo_time: not available with [[obstacles]]")
        field = replace(field, conditioning=(TIME_RANGE,), pseudo_time=True)
    dynamics = parse_dynamics(top, field, model)
    start = parse_start(top, surface, field)
    if start is not None and dynamics is not None:
        raise SceneError("start: not available with [dynamics] (a run in physical time starts "
                         "from the rest shape)")
    top.close()
    scene = Scene(name=name, description=description, model=model, field=field, solver=solver,
                  quick_solver=quick, output=output, path=path or base_dir / "scene.toml",
                  document=document, output_scale_estimate=estimate, dynamics=dynamics,
                  start=start)
    try:  # its sizes fit the memory, before any work (at run start: `Discretisation.check_size`)
        kind.check_size(field, solver, 4, **contact_check_points(model.contact))
    except ValueError as err:
        raise SceneError(str(err)) from None
    return scene


def _garment(document: dict, *, base_dir: Path, path: Path | None) -> Scene:
    """A garment file (`[[panels]]`, `taichi_ndf.scene.garment`): its field is the panels'
    `MultiPatchPlan`, its model the first panel's with the garment's contact (`[[obstacles]]`,
    `[contact]`: the body the panels drape on)."""
    top = Table(document, "")
    name, description = top.string("name"), top.string("description", "")
    material = _section(top.table("material"), _material)
    plan, _ = parse_garment(top, material, top.table("field", optional=True),
                            read_material=_material)
    model = plan.patches[0].model
    model = replace(model, contact=parse_contact(top, model, base_dir))
    if model.contact is not None and model.contact.has_friction:
        raise SceneError("obstacles: friction is not supported on a garment's panels yet")
    model = parse_self_contact(top, model, plan)
    solver, quick = _section(top.table("training", optional=True), training, True)
    output = _section(top.table("output", optional=True), _output, False)
    top.close()
    return Scene(name=name, description=description, model=model, field=plan,
                 solver=solver, quick_solver=quick, output=output,
                 path=path or base_dir / "scene.toml", document=document)


def _section(table: Table, build, *args):
    result = _check(lambda: build(table, *args), table.path)
    table.close()
    return result


def _placement(t: Table) -> dict:
    out = {}
    if t.has("origin"):
        out["origin"] = t.vector("origin", 3)
    if t.has("frame"):
        frame = t._get("frame", None)
        if not _number_rows(frame, 3, 3):
            raise SceneError(f"{t.key('frame')}: expected three 3-vectors [e_x, e_y, e_z]")
        out["frame"] = tuple(tuple(float(v) for v in row) for row in frame)
    return out


def _number_rows(value, rows: int, columns: int) -> bool:
    """Whether `value` is a list of `rows` lists of `columns` finite numbers."""
    return (isinstance(value, list) and len(value) == rows
            and all(isinstance(row, list) and len(row) == columns for row in value)
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    for row in value for v in row))


def _geometry(t: Table, base_dir: Path):
    kind = t.string("type", choices=GEOMETRIES)
    if kind == "mesh":
        from taichi_ndf.geometry.mesh_surface import MeshSurface

        mesh_path = Path(t.string("path"))
        if not mesh_path.is_absolute():
            mesh_path = base_dir / mesh_path
        if not mesh_path.is_file():
            raise SceneError(f"{t.key('path')}: template mesh not found: {mesh_path}")
        options = {"cells": t.integer("fit_cells", minimum=1)} if t.has("fit_cells") else {}
        return MeshSurface.from_file(mesh_path, **options)
    placement = _placement(t)
    if kind == "plane":
        b = t._get("bounds", [[0.0, 1.0], [0.0, 1.0]])
        if not _number_rows(b, 2, 2):
            raise SceneError(f"{t.key('bounds')}: expected [[x_min, x_max], [y_min, y_max]] [m] "
                             f"(finite numbers), got {b!r}")
        return Plane(bounds=tuple(tuple(float(v) for v in p) for p in b), **placement)
    if kind == "cylinder":
        return Cylinder(radius=t.number("radius", positive=True), length=t.number(
            "length", positive=True), angle=math.radians(t.number("angle_deg", 360.0)), **placement)
    if kind == "cone":
        return Cone(bottom_radius=t.number("bottom_radius", positive=True),
                    top_radius=t.number("top_radius", positive=True),
                    height=t.number("height", positive=True), **placement)
    if kind == "roof":
        return CylindricalRoof(radius=t.number("radius", positive=True),
                               length=t.number("length", positive=True),
                               half_angle=math.radians(t.number("half_angle_deg", positive=True)),
                               **placement)
    if kind == "annulus":
        return Annulus(inner_radius=t.number("inner_radius", positive=True),
                       outer_radius=t.number("outer_radius", positive=True),
                       angle=math.radians(t.number("angle_deg", 360.0, positive=True)),
                       start_angle=math.radians(t.number("start_angle_deg", 0.0)),
                       slit=t.boolean("slit", False), **placement)
    return Hemisphere(radius=t.number("radius", positive=True),
                      hole_half_angle=math.radians(t.number("hole_half_angle_deg", 0.0)),
                      rim_angle=math.radians(t.number("rim_angle_deg", 90.0)),
                      azimuth=math.radians(t.number("azimuth_deg", 360.0)), **placement)


def _material(t: Table):
    if t.has("preset"):
        material = preset(t.string("preset", choices=PRESETS))
        if t.has("stiffness_scale"):
            material = material.scaled(t.number("stiffness_scale", positive=True))
        return material
    kind = t.string("type", choices=("linear", "orthotropic", "clyde"))
    density = t.number("areal_density", positive=True)
    if kind == "linear":
        nu = t.number("poisson_ratio")
        if t.has("young_modulus"):
            return LinearIsotropic.from_young(t.number("young_modulus", positive=True), nu,
                                              t.number("thickness", positive=True), density)
        return LinearIsotropic(membrane_stiffness=t.number("membrane_stiffness", positive=True),
                               bending_stiffness=t.number("bending_stiffness", positive=True),
                               poisson_ratio=nu, areal_density=density)
    stiffness = {k: t.number(k) for k in ("a11", "a12", "a22", "G12")}
    thickness = t.number("thickness", positive=True)
    if kind == "orthotropic":
        return OrthotropicStVK(**stiffness, thickness=thickness, areal_density=density,
                               weft_thickness=t.number("weft_thickness", thickness,
                                                       positive=True))
    eta = t._get("eta", None)
    limits = t.vector("strain_limits", 3)
    return ClydeFabric(**stiffness, eta=eta, strain_limits=limits, thickness=thickness,
                       areal_density=density)


def _loads(t: Table, domain) -> Loads:
    points = []
    for p in t.tables("point"):
        points.append(PointLoad(p.vector("xi", 2), p.vector("force", 3)))
        p.close()
    lines = []
    for line in t.tables("line"):
        lines.append(_check(lambda line=line: _line_load(line, domain), line.path))
        line.close()
    return Loads(gravity=t.vector("gravity", 3, (0.0, 0.0, 0.0)),
                 body_force=t.vector("body_force", 3, (0.0, 0.0, 0.0)),
                 pressure=t.number("pressure", 0.0), point_loads=tuple(points),
                 line_loads=tuple(lines))


def _line_load(t: Table, domain) -> LineLoad:
    """[[loads.line]]: `edge` (a name) or `path` (points in ξ), `force` [N/m], `nodes`."""
    if t.has("edge") == t.has("path"):
        raise SceneError(f"{t.path}: give exactly one of 'edge' or 'path'")
    if t.has("edge"):
        path = edge_path(t.string("edge", choices=EDGES), domain.bounds, domain.periodic)
    else:
        raw = t._get("path", None)
        if not (isinstance(raw, list) and len(raw) >= 2
                and all(isinstance(p, list) and len(p) == 2 for p in raw)):
            raise SceneError(f"{t.key('path')}: expected a list of two or more [ξ¹, ξ²] points")
        path = tuple(tuple(p) for p in raw)
    return LineLoad(path, t.vector("force", 3), t.integer("nodes", 8, minimum=1))


def _constraint(c: Table):
    kind = c.string("type", choices=CONSTRAINTS)
    if kind == "symmetry_plane":  # its components follow from the normal
        return SymmetryPlane(edge=c.string("edge"), normal=c.string("normal"),
                             antisymmetric=c.boolean("antisymmetric", False),
                             length=c.number("length", None, positive=True))
    common = {"components": c.string("components", "xyz")}
    if c.has("length"):
        common["length"] = c.number("length", positive=True)
    if kind in ("clamped_edge", "hinged_edge"):
        cls = ClampedEdge if kind == "clamped_edge" else HingedEdge
        return cls(edge=c.string("edge"), displacement=c.vector("displacement", 3, (0, 0, 0)),
                   **common)
    if kind == "pinned_point":
        return PinnedPoint(xi=c.vector("xi", 2),
                           rotation=c.string("rotation", "held", choices=PIN_ROTATIONS), **common)
    if kind == "handle":
        return Handle(xi=c.vector("xi", 2), displacement=c.vector("displacement", 3),
                      radius=c.number("radius", 0.0, nonnegative=True), **common)
    if kind == "interior_line":
        return InteriorLine(start=c.vector("start", 2), end=c.vector("end", 2),
                            extend=c.boolean("extend", False), hinged=c.boolean("hinged", False),
                            **common)
    return RimRotation(edge=c.string("edge"), axis_point=c.vector("axis_point", 3),
                       axis=c.vector("axis", 3), angle=math.radians(c.number("angle_deg")),
                       **common)


def _boundary(t: Table, surface) -> BoundaryConditions:
    constraints = []
    for c in t.tables("constraint"):
        constraints.append(_check(lambda c=c: _constraint(c), c.path))
        c.close()
    kwargs = {"length": t.number("length")} if t.has("length") else {}
    if t.has("frame"):
        frame = t._get("frame", None)
        if not _number_rows(frame, 3, 3):
            raise SceneError(f"{t.key('frame')}: expected three 3-vectors [e_x, e_y, e_z]")
        kwargs["frame"] = frame
    return BoundaryConditions(constraints, surface.domain, surface=surface, **kwargs)


def _output(t: Table, pseudo_time: bool) -> OutputConfig:
    res = t._get("resolution", [64, 64])
    if (not isinstance(res, list) or len(res) != 2
            or any(isinstance(v, bool) or not isinstance(v, int) or v < 2 for v in res)):
        raise SceneError(f"{t.key('resolution')}: expected two integers >= 2, got {res!r}")
    if t.has("frames") and not pseudo_time:
        raise SceneError(f"{t.key('frames')}: needs [training] pseudo_time = true (a "
                         f"load-step trajectory has one frame per load step)")
    frames = t.integer("frames", DEFAULT_FRAMES, minimum=2) if pseudo_time else None
    views = t._get("views", ["iso"])
    if (not isinstance(views, list) or not 1 <= len(views) <= 4
            or any(v not in VIEWS for v in views)):
        raise SceneError(f"{t.key('views')}: expected a list of one to four of "
                         f"{', '.join(VIEWS)}, got {views!r}")
    return OutputConfig(resolution=(res[0], res[1]), frames=frames, usd=t.boolean("usd", False),
                        views=tuple(views))

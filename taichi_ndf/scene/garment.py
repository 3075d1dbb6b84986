"""Garment files (TOML): panels sewn together (docs/scenes.md, "Garments").

A garment file is a scene file with `[[panels]]` instead of `[geometry]`: each panel a
rectangle width × height [m] placed where it starts (flat, or wrapped around a cylinder), or an
`outline` [[x, y], …] [m] (its edges e0, e1, …; a point [x, y, bulge] makes the edge from it a
circular arc, `taichi_ndf.problem.arcs`; integrated over the outline only:
`taichi_ndf.discretise.trimmed`) placed flat or cut flat and wrapped by its start, with its
own edges held and its own spline grid;
`[[seams]]` join `panel.edge` to `panel.edge`; `[field] grading = "seam_corners"` grades
every panel's knots towards the points where its seams turn.
Read into a `MultiPatchPlan` (`taichi_ndf.discretise.multipatch`). Errors are one line naming
the panel and the edge (an unknown panel or edge, an edge in two seams, seam lengths differing
by more than `LENGTH_TOLERANCE`; an outline's fewer than 3 points, zero-length edge, crossing
edges or clockwise order), raised before anything is solved.
"""

from __future__ import annotations

import math

from taichi_ndf.boundary import BoundaryConditions, ClampedEdge, HingedEdge
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.geometry import Cylinder, Plane
from taichi_ndf.objective.seam import SeamTerm
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import Probe, ShellModel
from taichi_ndf.problem.multipatch import (
    Gathered,
    MultiPatchPlan,
    Patch,
    PatchSeam,
    grain_turned,
)
from taichi_ndf.problem.outline import Outline, OutlinePlane
from taichi_ndf.problem.seams import (
    BENDING,
    DEFAULT_PENALTY,
    EDGES,
    LENGTH_TOLERANCE,
    ORIENTATIONS,
    EdgeSegment,
    SeamSpec,
)
from taichi_ndf.problem.start_shape import StartShape
from taichi_ndf.scene.schema import SceneError, Table, checked
from taichi_ndf.shell.materials import preset

__all__ = ["LENGTH_TOLERANCE", "RESTS", "is_garment", "parse_garment"]

# A panel's rest shape: its placement ("placed") or the flat pattern it is cut from ("flat").
RESTS = ("placed", "flat")
# [field] grading of a garment's panels: uniform knots, or the same spans graded towards the
# seam corners (`MultiPatchPlan.graded_at_seam_corners`).
GARMENT_GRADINGS = ("uniform", "seam_corners")


def is_garment(document: dict) -> bool:
    """Whether a parsed TOML document is a garment file (it has `[[panels]]`)."""
    return "panels" in document


def _outline(t: Table, name: str):
    """A polygon panel's outline, its flat surface (origin and frame as a rectangle's) and
    start shape and held target (`_surface`'s, the outline's plane for the rectangle's: with
    `rest = "flat"` and `wrap_radius` its pattern is wrapped from its ξ¹ = 0 line)."""
    for key in ("width", "height"):
        if t.has(key):
            raise SceneError(f"{t.key(key)}: panel {name!r} has an outline: give its points, "
                             f"not {key}")
    if t.has("wrap_radius") and t.string("rest", "placed", choices=RESTS) != "flat":
        raise SceneError(f"{t.key('wrap_radius')}: panel {name!r}: an outline panel is flat "
                         "at rest: wrap it as its start (rest = \"flat\")")
    points = t._get("outline", None)
    if not isinstance(points, list) or not all(isinstance(p, list) and len(p) in (2, 3)
                                               for p in points):
        raise SceneError(f"{t.key('outline')}: panel {name!r}: expected points [[x, y], …] or "
                         f"[x, y, bulge] (the edge from that point an arc), got {points!r}")
    outline = checked(lambda: Outline(tuple(tuple(p[:2]) for p in points),
                                      tuple(p[2] if len(p) == 3 else 0.0 for p in points)),
                      f"{t.key('outline')}: panel {name!r}")
    (x0, x1), (y0, y1) = outline.bounds
    return outline, *_surface(t, max(x1, 0.0) - min(x0, 0.0), y1 - y0,
                              lambda **placement: OutlinePlane(outline=outline, **placement))


def _box_sides(t: Table, name: str, outline: Outline, clamped: list, hinged: list):
    """An outline panel's clamped and hinged edges as the bounding-box sides they lie on (the
    clamp holds the whole side: every edge on it must be held the same way)."""
    sides = []
    for edges in (clamped, hinged):
        found = []
        for edge in edges:
            side = checked(lambda edge=edge: outline.box_side(edge),
                           f"{t.path}: panel {name!r}")
            others = [e for e in outline.on_side(side) if e not in edges]
            if others:
                raise SceneError(f"{t.path}: panel {name!r}: edge {edge!r} is held along the "
                                 f"whole bounding-box side {side}, which also holds edge "
                                 f"{others[0]!r}: hold both the same way")
            found.append(side)
        sides.append(sorted(set(found)))
    return sides


def _rectangle(t: Table):
    """A rectangle panel's rest surface, start shape and held target (`_surface`)."""
    width, height = t.number("width", positive=True), t.number("height", positive=True)
    return _surface(t, width, height,
                    lambda **placement: Plane(bounds=((0.0, width), (0.0, height)),
                                              **placement))


def _surface(t: Table, width: float, height: float, flat):
    """The panel's rest surface and start shape: width along ξ¹, height along ξ²; flat
    (`flat(origin=, frame=)`: the pattern placed), or a cylinder sector of `wrap_radius` (ξ¹
    its angle [rad], ξ² along its axis) — or, with `rest = "flat"`, the flat pattern tangent
    to that cylinder along its ξ¹ = 0 line (ξ¹ [m] round it) wrapped onto it by its start
    shape (`_flat_cut`)."""
    rest = t.string("rest", "placed", choices=RESTS)
    placement = {"origin": t.vector("origin", 3, (0.0, 0.0, 0.0))}
    if t.has("frame"):
        frame = t._get("frame", None)
        placement["frame"] = checked(lambda: tuple(tuple(float(v) for v in row)
                                                   for row in frame), t.key("frame"))
    if t.has("wrap_radius"):
        radius = t.number("wrap_radius", positive=True)
        if width / radius > 2 * math.pi * (1 - 1e-9):
            raise SceneError(f"{t.key('wrap_radius')}: a {width} m wide panel wraps more than "
                             f"a whole turn around radius {radius} m")
        if rest == "flat":
            return _flat_cut(t, width, height, radius, placement, flat)
    if t.has("held_radius"):
        raise SceneError(f"{t.key('held_radius')}: only a panel cut flat and wrapped (rest = "
                         f"\"flat\" with a wrap_radius) is held on a circle")
    if t.has("wrap_radius"):
        return checked(lambda: Cylinder(radius=radius, length=height, angle=width / radius,
                                        **placement), t.path), None, None
    return checked(lambda: flat(**placement), t.path), None, None


def _flat_cut(t: Table, width: float, height: float, radius: float, placement: dict, flat):
    """A flat-cut panel wrapped by its start: the pattern (`flat(origin=, frame=)`: the
    rectangle, or a polygon panel's outline plane) tangent to the cylinder
    origin + F (R cos θ, R sin θ, z) at θ = 0 (origin + R e_x, ξ¹ along e_y, ξ² along e_z,
    normal e_x outward) and the `wrap` start shape onto it (tangent along ξ¹ = 0, towards the
    axis), which puts ξ¹ = R θ where the placed sector has θ; with `held_radius`, the target
    of its held (clamped) edges: the wrap moved radially onto that radius (`Gathered`)."""
    surface = checked(lambda: Cylinder(radius=radius, length=height, angle=width / radius,
                                       **placement), t.path)
    ex, ey, ez = surface.frame
    origin = tuple(o + radius * e for o, e in zip(surface.origin, ex, strict=True))
    pattern = checked(lambda: flat(origin=origin, frame=(ey, ez, ex)), t.path)
    start = StartShape("wrap", axis=0, at=0.0, radius=radius)
    target = None
    if t.has("held_radius"):
        held = t.number("held_radius", positive=True)
        target = checked(lambda: Gathered(start, surface.origin, ez, held / radius),
                         t.key("held_radius"))
    return pattern, start, target


def _edges(t: Table, key: str) -> list[str]:
    """A list of edge names (none: [])."""
    value = t._get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise SceneError(f"{t.key(key)}: expected a list of edges like [\"xi2_max\"]")
    return value


def _material(t: Table, default, read_material):
    """The panel's material: the garment's, a preset named by `material`, or an inline
    `material` table (read as `[material]`, by `read_material`); then cut along `grain`
    [deg] (`grain_turned`)."""
    material = default
    if t.has("material"):
        value = t._get("material", None)
        if isinstance(value, str):
            material = checked(lambda: preset(value), t.key("material"))
        elif isinstance(value, dict):
            table = t.table("material")
            material = checked(lambda: read_material(table), table.path)
            table.close()
        else:
            raise SceneError(f"{t.key('material')}: expected a preset name or a table like "
                             f"{{preset = \"denim\"}}, got {value!r}")
    grain = t.number("grain", 0.0)
    return checked(lambda: grain_turned(material, grain), t.key("grain"))


def _panel(t: Table, index: int, material, gravity, default_spans, read_material) -> Patch:
    name = t.string("name", f"panels[{index}]")
    material = _material(t, material, read_material)
    outline = None
    if t.has("outline"):
        outline, surface, start, target = _outline(t, name)
    else:
        surface, start, target = _rectangle(t)
    clamped, hinged = _edges(t, "clamped"), _edges(t, "hinged")
    names = EDGES if outline is None else outline.edges
    for edge in clamped + hinged:
        if edge not in names:
            raise SceneError(f"{t.path}: panel {name!r}: no edge {edge!r} (edges: "
                             f"{', '.join(names)})")
    if outline is not None:
        clamped, hinged = _box_sides(t, name, outline, clamped, hinged)
    if start is not None and hinged:
        raise SceneError(f"{t.key('hinged')}: panel {name!r} is cut flat (rest = \"flat\"): "
                         f"its edges can be clamped where the placement puts them, not hinged")
    held = tuple(clamped) if start is not None else ()
    constraints = [] if start is not None else (
        [ClampedEdge(e) for e in clamped] + [HingedEdge(e) for e in hinged])
    band = {}  # the band width ℓ of the clamps' and hinges' vanishing factors
    if t.has("clamp_band"):
        if start is not None:
            raise SceneError(f"{t.key('clamp_band')}: panel {name!r} is cut flat (rest = "
                             "\"flat\"): its clamped edges are held by their coefficients, "
                             "with no band")
        band["length"] = t.number("clamp_band", positive=True)
    boundary = checked(lambda: BoundaryConditions(constraints, domain=surface.domain, **band),
                       t.path)
    probes = tuple(Probe(p.string("name"), p.vector("xi", 2)) for p in t.tables("probes"))
    model = checked(lambda: ShellModel(surface, material, Loads(gravity=gravity), boundary,
                                       probes), t.path)
    spans = tuple(int(v) for v in t.vector("spans", 2, default_spans))
    config = checked(lambda: SplineConfig(spans=spans, domain=surface.domain.bounds),
                     t.key("spans"))
    t.close()
    if target is not None and not held:
        raise SceneError(f"{t.key('held_radius')}: panel {name!r} has no clamped edge to hold "
                         f"on that circle")
    return checked(lambda: Patch(name, model, config, start=start, held=held,
                                 held_target=target, outline=outline), t.path)


def _side(t: Table, key: str, names: dict[str, int], patches: list[Patch]):
    """The panel (index) and the seam side (`EdgeSegment`, or a `PolygonEdge` named
    "panel.e<i>") that `key` names."""
    value = t.string(key)
    panel, _, edge = value.rpartition(".")
    if panel not in names:
        raise SceneError(f"{t.key(key)}: no panel {panel!r} (panels: {', '.join(names)})")
    outline = patches[names[panel]].outline
    edges = EDGES if outline is None else outline.edges
    if edge not in edges:
        raise SceneError(f"{t.key(key)}: panel {panel!r} has no edge {edge!r} (edges: "
                         f"{', '.join(edges)})")
    side = EdgeSegment(edge) if outline is None else outline.edge(edge, value)
    return names[panel], side


def _seam(t: Table, index: int, names: dict[str, int], patches: list[Patch]) -> PatchSeam:
    name = t.string("name", f"seams[{index}]")
    (a, side_a), (b, side_b) = _side(t, "a", names, patches), _side(t, "b", names, patches)
    spec = checked(lambda: SeamSpec(
        name, side_a, side_b,
        orientation=t.string("orientation", "same", choices=ORIENTATIONS),
        bending=t.string("bending", "transmitted", choices=BENDING),
        penalty=t.number("stiffness", DEFAULT_PENALTY, positive=True),
        segments=t.integer("segments", 64, minimum=1), nodes=t.integer("nodes", 4, minimum=1)),
        t.path)
    t.close()
    return PatchSeam(spec, a, b)


def parse_garment(top: Table, material, field: Table | None, *, read_material
                  ) -> tuple[MultiPatchPlan, tuple]:
    """The garment's plan (panels and seams) from the document's `[[panels]]`, `[[seams]]`,
    `[loads]` (gravity only) and `[field]` (`spans`: each panel's default grid), the
    garment's material already read (each panel's default) and `read_material` (Table ->
    material: how `[material]` is read, for a panel's inline table); returns the plan and
    the panels' probes (named "panel.probe")."""
    loads = top.table("loads", optional=True)
    gravity = loads.vector("gravity", 3, (0.0, 0.0, 0.0)) if loads is not None else (0, 0, 0)
    if loads is not None:
        loads.close()
    spans, grading = (16, 8), "uniform"
    if field is not None:
        field.string("type", "spline", choices=("spline",))
        spans = tuple(int(v) for v in field.vector("spans", 2, spans))
        grading = field.string("grading", grading, choices=GARMENT_GRADINGS)
        field.close()
    tables = top.tables("panels")
    patches = [_panel(t, i, material, gravity, spans, read_material)
               for i, t in enumerate(tables)]
    names: dict[str, int] = {}
    for t, patch in zip(tables, patches, strict=True):
        if patch.name in names:
            raise SceneError(f"{t.path}: a second panel named {patch.name!r}")
        names[patch.name] = len(names)
    seams, used = [], {}
    for index, t in enumerate(top.tables("seams")):
        seam = _seam(t, index, names, patches)
        for side, panel in ((seam.spec.a, seam.a), (seam.spec.b, seam.b)):
            key = side.edge if patches[panel].outline else f"{patches[panel].name}.{side.edge}"
            if key in used:
                raise SceneError(f"{t.path}: edge {key!r} is already in seam {used[key]!r}")
            used[key] = seam.spec.name
        seams.append(seam)
    plan = checked(lambda: MultiPatchPlan(tuple(patches), tuple(seams), tuple(gravity)),
                   "panels")
    if grading == "seam_corners":  # the same spans, graded towards where seams turn
        plan = checked(plan.graded_at_seam_corners, "field.grading")
    for t, seam in zip(top.tables("seams"), seams, strict=True):
        checked(lambda seam=seam: SeamTerm(seam.spec, patches[seam.a].model.surface,
                                           plan.seam_material(seam),
                                           surface_b=patches[seam.b].model.surface), t.path)
    probes = tuple(Probe(f"{p.name}.{q.name}", q.xi) for p in patches for q in p.model.probes)
    return plan, probes

"""Polygon panels (issue 30; docs/scenes.md "Garments", `outline`): the outline's checks, the
trimmed quadrature over it (`taichi_ndf.discretise.trimmed`), the coefficients it holds, and
garments of polygon panels against the same garments of rectangles."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.boundary import BoundaryConditions, ClampedEdge
from taichi_ndf.discretise import of_scene
from taichi_ndf.discretise.trimmed import TrimmedGrid, trimmed_points, unsupported
from taichi_ndf.field import SplineField
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.problem.outline import Outline, OutlinePlane
from taichi_ndf.problem.polygon import ear_clip
from taichi_ndf.problem.quadrature import span_points
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

L_SHAPE = ((0.0, 0.0), (0.2, 0.0), (0.2, 0.2), (0.13, 0.2), (0.13, 0.07), (0.0, 0.07))
STAR = ((0.0, 0.0), (1.3, 0.2), (0.9, 0.7), (1.5, 1.4), (0.6, 1.1), (0.1, 1.6), (0.3, 0.8))
MATERIAL = {"type": "linear", "membrane_stiffness": 6400.0, "bending_stiffness": 0.1,
            "poisson_ratio": 0.25, "areal_density": 0.144}


def _boundary_integral(points, a: int, b: int) -> float:
    """∫ x^a y^b over the polygon by Green: ∮ x^(a+1) y^b / (a + 1) dy, each edge by
    Gauss–Legendre exact for its degree (an independent rule: no triangles, no spans)."""
    nodes, weights = np.polynomial.legendre.leggauss(a + b + 2)
    t, w = (nodes + 1) / 2, weights / 2
    total = 0.0
    for i, (x0, y0) in enumerate(points):
        x1, y1 = points[(i + 1) % len(points)]
        x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
        total += float((w * x ** (a + 1) * y ** b).sum()) * (y1 - y0) / (a + 1)
    return total


@pytest.mark.parametrize(("points", "message"), [
    (((0, 0), (1, 0)), "at least 3 points"),
    (((0, 0), (1, 0), (1, 0), (0, 1)), "edge e1 has zero length"),
    (((0, 0), (1, 1), (1, 0), (0, 1)), "edges e0 and e2 cross or touch"),
    (((0, 0), (0, 1), (1, 1), (1, 0)), "clockwise"),
    (((0, 0), (2, 0), (1, 0), (1, 1)), "edges e0 and e1 overlap"),
    (((0, 0), (2, 0), (2, 2), (1, 0), (0, 2)), "cross or touch"),
])
def test_an_outline_that_is_not_a_simple_counter_clockwise_polygon_is_refused(points, message):
    with pytest.raises(ValueError, match=message):
        Outline(points)


@pytest.mark.parametrize("margin", [0.0, 0.013])
@pytest.mark.parametrize("points", [L_SHAPE, STAR])
def test_the_trimmed_quadrature_integrates_polynomials_over_the_outline(points, margin):
    """On the outline's bounding box, and on a wider chart (every edge trimmed)."""
    outline = Outline(points)
    chart = tuple((lo - margin, hi + margin) for lo, hi in outline.bounds)
    config = SplineConfig(spans=(7, 5), domain=chart)
    xi, weight = trimmed_points(outline, config)
    x, y = xi[:, 0].numpy(), xi[:, 1].numpy()
    w = weight.numpy()
    assert (w > 0).all() and outline.contains(xi.numpy()).all()
    assert abs(w.sum() - outline.area) <= 1e-14 * outline.area
    for a, b in ((1, 0), (2, 3), (3, 5), (4, 4)):  # total degree ≤ 2p + 2 = 8
        exact = _boundary_integral(outline.points, a, b)
        assert abs(float((w * x ** a * y ** b).sum()) - exact) <= 1e-13 * abs(exact), (a, b)


def test_an_outline_plane_is_masked_to_its_outline_on_a_chart_that_holds_it():
    outline = Outline(L_SHAPE)
    plane = OutlinePlane(outline=outline, chart=((-0.1, 0.2), (0.0, 0.3)))
    assert plane.domain.bounds == ((-0.1, 0.2), (0.0, 0.3))
    assert plane.domain.area == pytest.approx(outline.area, rel=1e-15)
    xi = torch.tensor([[0.05, 0.03], [0.05, 0.1], [-0.05, 0.03], [0.16, 0.19]],
                      dtype=torch.float64)
    assert plane.domain.contains(xi).tolist() == [True, False, False, True]
    with pytest.raises(ValueError, match="does not hold the outline's bounding box"):
        OutlinePlane(outline=outline, chart=((0.0, 0.2), (0.0, 0.1)))


def test_an_outline_that_is_the_rectangle_gets_the_rectangles_gauss_points():
    outline = Outline(((0.0, 0.0), (0.3, 0.0), (0.3, 0.2), (0.0, 0.2)))
    config = SplineConfig(spans=(5, 3), domain=outline.bounds)
    xi, weight = trimmed_points(outline, config)
    expected_xi, expected_weight = span_points(config)
    assert torch.equal(xi, expected_xi) and torch.equal(weight, expected_weight)


def test_ear_clipping_covers_a_non_convex_polygon_with_n_minus_2_triangles():
    triangles = ear_clip(STAR)
    assert len(triangles) == len(STAR) - 2
    p = np.asarray(STAR)
    areas = [0.5 * float((p[j] - p[i])[0] * (p[k] - p[i])[1] - (p[j] - p[i])[1] * (p[k] - p[i])[0])
             for i, j, k in triangles]
    assert min(areas) > 0 and abs(sum(areas) - Outline(STAR).area) < 1e-15


def test_coefficients_without_support_in_the_outline_are_held_and_k_is_regular():
    outline = Outline(L_SHAPE)
    config = SplineConfig(spans=(10, 10), domain=outline.bounds)
    field = SplineField(config, dtype=torch.float64)
    xi, _ = trimmed_points(outline, config)
    grid = TrimmedGrid(field, None, xi)
    outside = unsupported(grid, xi)
    # a cubic's coefficient (i, j) is supported on spans i − 3 … i, j − 3 … j; the notch
    # [0, 0.13] × [0.07, 0.2] holds spans 0 … 5 × 4 … 9 whole (0.02 m spans; 6 and 3 cut)
    m1, m2 = config.coefficient_counts
    expected = [i * m2 + j for i in range(m1) for j in range(m2) if i <= 5 and j - 3 >= 4]
    assert outside.tolist() == expected
    assert grid.unsupported.tolist() == sorted(3 * c + k for c in expected for k in range(3))


def garment_document(panels, seams=(), spans=(6, 4)) -> dict:
    return {"name": "t", "material": dict(MATERIAL), "loads": {"gravity": [0.0, 0.0, -9.81]},
            "field": {"type": "spline", "spans": list(spans)},
            "training": {"method": "newton", "load_steps": [1.0]},
            "panels": copy.deepcopy(list(panels)), "seams": copy.deepcopy(list(seams))}


def parse_garment(document):
    return parse_scene(document, base_dir=Path("."), path=Path("garment.toml"))


def solved_garment(document, change=lambda scene: scene):
    scene = change(parse_garment(document))
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    solution = panels.solve(scene.solver)
    assert all(panels.converged)
    return panels, solution


def test_a_polygon_that_is_the_rectangle_solves_as_the_rectangle_panel():
    rectangle = {"name": "a", "width": 0.3, "height": 0.2, "clamped": ["xi2_max"]}
    polygon = {"name": "a", "outline": [[0, 0], [0.3, 0], [0.3, 0.2], [0, 0.2]],
               "clamped": ["e2"]}
    (one, first), (two, second) = (solved_garment(garment_document([p]))
                                   for p in (rectangle, polygon))
    assert abs(second.energy - first.energy) <= 1e-12 * abs(first.energy)
    assert first.energy < 0
    assert two._linear.size == one._linear.size and two._linear.fixed is None


def test_a_seam_on_polygon_edges_is_the_seam_on_the_rectangles_edges():
    left = {"name": "a", "width": 0.15, "height": 0.2, "clamped": ["xi2_max"]}
    right = {"name": "b", "width": 0.15, "height": 0.2, "origin": [0.15, 0, 0],
             "clamped": ["xi2_max"]}
    rectangles = garment_document([left, right], [{"a": "a.xi1_max", "b": "b.xi1_min"}], (3, 4))
    left = {"name": "a", "outline": [[0, 0], [0.15, 0], [0.15, 0.2], [0, 0.2]],
            "clamped": ["e2"]}
    right = {"name": "b", "outline": [[0.15, 0], [0.3, 0], [0.3, 0.2], [0.15, 0.2]],
             "clamped": ["e2"]}
    polygons = garment_document([left, right], [{"a": "a.e1", "b": "b.e3",
                                          "orientation": "reversed"}], (3, 4))
    (_, first), (_, second) = solved_garment(rectangles), solved_garment(polygons)
    assert abs(second.energy - first.energy) <= 1e-12 * abs(first.energy)


TRAPEZOIDS = ({"name": "a", "outline": [[0, 0], [0.15, 0], [0.12, 0.2], [0, 0.2]],
               "clamped": ["e2"]},
              {"name": "b", "outline": [[0.15, 0], [0.3, 0], [0.3, 0.2], [0.12, 0.2]],
               "clamped": ["e2"]})


def test_two_trapezoids_seamed_along_their_slanted_edges_are_the_rectangle_they_make():
    """The cantilever (0.3 × 0.2 m, clamped along its top, gravity across it) as two
    trapezoids (8 × 8 spans each) sewn along the slanted edge from (0.15, 0) to (0.12, 0.2)
    and as one rectangle (16 × 8 spans). Measured (benchmarks/RESULTS.md "Garments: polygon
    panels"): Π 1.0e-5 relative apart, 4.8e-5 on half these grids, 1.7e-6 on twice."""
    seam = [{"name": "slant", "a": "a.e1", "b": "b.e3", "orientation": "reversed"}]
    smooth = [{**p, "clamp_band": 1.0} for p in TRAPEZOIDS]  # the clamps' φ one polynomial
    _, pair = solved_garment(garment_document(smooth, seam, (8, 8)))
    _, whole = solved_garment(garment_document([{"name": "w", "width": 0.3, "height": 0.2,
                                   "clamped": ["xi2_max"], "clamp_band": 1.0}], spans=(16, 8)))
    assert abs(pair.energy - whole.energy) <= 3e-5 * abs(whole.energy)
    assert pair.document["seam_gaps"]["slant"] < 1e-5


def test_clamp_band_is_the_band_of_a_panels_clamps():
    """`clamp_band` sets the band width ℓ of a panel's clamped (and hinged) edges: ℓ = 1
    solves as the panel whose boundary is built with ClampedEdge(edge, length=1) (to the
    last bit), and differently from the default band; a flat-cut panel has none to set."""
    def with_band(scene):
        (patch,) = scene.field.patches
        model = patch.model
        boundary = BoundaryConditions([ClampedEdge(c.edge, length=1.0)
                                       for c in model.boundary.constraints],
                                      domain=model.surface.domain)
        patch = dataclasses.replace(patch, model=dataclasses.replace(model, boundary=boundary))
        return dataclasses.replace(scene, field=dataclasses.replace(scene.field,
                                                                    patches=(patch,)))
    panel = {"name": "w", "width": 0.3, "height": 0.2, "clamped": ["xi2_max"]}
    _, built = solved_garment(garment_document([panel]), with_band)
    _, default = solved_garment(garment_document([panel]))
    _, banded = solved_garment(garment_document([{**panel, "clamp_band": 1.0}]))
    assert banded.energy == built.energy
    assert abs(banded.energy - default.energy) > 1e-3 * abs(default.energy)
    flat = {**panel, "rest": "flat", "wrap_radius": 0.15, "clamp_band": 1.0}
    _refused([flat], [], "panels[0].clamp_band: panel 'w' is cut flat")


def _refused(panels, seams, message):
    with pytest.raises(SceneError) as err:
        parse_garment(garment_document(panels, seams))
    assert message in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(("change", "seams", "message"), [
    ({"outline": [[0, 0], [0.15, 0.2], [0.15, 0], [0, 0.2]]}, [],
     "panel 'a': outline: edges e0 and e2 cross or touch"),
    ({"width": 0.1}, [], "panel 'a' has an outline: give its points, not width"),
    ({"clamped": ["e1"]}, [], "panel 'a': edge 'e1'"),
    ({"clamped": ["xi2_max"]}, [], "panel 'a': no edge 'xi2_max' (edges: e0, e1, e2, e3)"),
    ({}, [{"a": "a.e1", "b": "b.e9"}], "panel 'b' has no edge 'e9'"),
    ({}, [{"a": "a.e0", "b": "b.e1"}], "edge 'a.e0' is 0.15 m long and edge 'b.e1' 0.2 m"),
    ({}, [{"a": "a.e1", "b": "b.e3"}, {"a": "a.e1", "b": "b.e1"}],
     "edge 'a.e1' is already in seam"),
])
def test_a_wrong_polygon_panel_or_seam_is_refused_in_one_line_naming_panel_and_edge(
        change, seams, message):
    panels = copy.deepcopy(TRAPEZOIDS)
    panels[0].update(change)
    _refused(panels, seams, message)


def test_held_outline_edges_are_the_bounding_box_sides_they_lie_on():
    u_shape = {"name": "u", "outline": [[0, 0], [0.3, 0], [0.3, 0.2], [0.2, 0.2], [0.2, 0.1],
                                        [0.1, 0.1], [0.1, 0.2], [0, 0.2]],
               "clamped": ["e0"], "hinged": ["e2", "e6"]}
    (patch,) = parse_garment(garment_document([u_shape])).field.patches
    assert [(type(c).__name__, c.edge) for c in patch.model.boundary.constraints] == [
        ("ClampedEdge", "xi2_min"), ("HingedEdge", "xi2_max")]
    u_shape["hinged"] = ["e2"]  # e6 lies on the same side: the hinge would hold it too
    _refused([u_shape], [], "panel 'u': edge 'e2' is held along the whole bounding-box side "
             "xi2_max, which also holds edge 'e6': hold both the same way")


def test_a_polygon_panels_output_grid_keeps_the_faces_inside_its_outline():
    from taichi_ndf.app.outputs import export_grid

    (patch,) = parse_garment(garment_document([TRAPEZOIDS[1]])).field.patches
    xi, faces, _ = export_grid(patch.model, (16, 16))
    outline = patch.outline
    corners = xi[faces]  # (F, 3, 2)
    assert outline.contains(corners.mean(axis=1)).all()
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    # the staircase: faces with a vertex outside dropped (measured 0.835 of the area here)
    assert 0.8 * outline.area < area <= outline.area * (1 + 1e-12)


def test_a_polygon_panels_output_grid_reaches_its_border():
    """The outline is closed: the output grid keeps the faces whose vertices lie on its
    border, so a rectangle outline exports the rectangle's whole grid (every vertex, the
    edges' included) and two panels sewn along a shared edge both have vertices on it (the
    welded output; before, border vertices fell either way and the sides' rows were lost)."""
    from taichi_ndf.app.outputs import export_grid

    rectangle = {"name": "a", "outline": [[0, 0], [0.3, 0], [0.3, 0.2], [0, 0.2]]}
    (patch,) = parse_garment(garment_document([rectangle])).field.patches
    xi, faces, _ = export_grid(patch.model, (12, 8))
    assert len(xi) == 13 * 9 and len(faces) == 2 * 12 * 8
    for panel, x in ((TRAPEZOIDS[0], 0.0), (TRAPEZOIDS[1], 0.3)):
        (patch,) = parse_garment(garment_document([panel])).field.patches
        xi, _, _ = export_grid(patch.model, (16, 16))
        assert np.isclose(xi[:, 0], x).sum() == 17  # the straight side, every row


@pytest.mark.parametrize("points", [L_SHAPE, STAR])
def test_the_trimmed_quadrature_on_graded_knots_integrates_over_the_outline(points):
    """Graded knots (`[field] grading = "seam_corners"`): the outline's pieces are cut at the
    graded spans, the whole spans get their graded Gauss points (`span_points`), so the
    polynomials are integrated as on uniform knots, up to the mapped rule's 1e-9."""
    from taichi_ndf.problem.spline_grid import graded_towards

    outline = Outline(points)
    (lo1, hi1), (lo2, hi2) = outline.bounds
    config = graded_towards(SplineConfig(spans=(7, 5), domain=outline.bounds),
                            ((lo1 + 0.3 * (hi1 - lo1),), (hi2,)))
    assert config.graded
    xi, weight = trimmed_points(outline, config)
    x, y, w = xi[:, 0].numpy(), xi[:, 1].numpy(), weight.numpy()
    assert (w > 0).all() and outline.contains(xi.numpy()).all()
    assert abs(w.sum() - outline.area) <= 1e-8 * outline.area
    for a, b in ((1, 0), (2, 3), (3, 5), (4, 4)):
        exact = _boundary_integral(outline.points, a, b)
        assert abs(float((w * x ** a * y ** b).sum()) - exact) <= 1e-8 * abs(exact), (a, b)
    square = Outline(((lo1, lo2), (hi1, lo2), (hi1, hi2), (lo1, hi2)))
    expected_xi, expected_weight = span_points(config)
    xi, weight = trimmed_points(square, config)
    assert torch.equal(xi, expected_xi) and torch.equal(weight, expected_weight)


TSHIRT = Path(__file__).resolve().parents[1] / "benchmarks" / "garment_tshirt_sleeves.toml"


def test_a_tshirts_seam_corners_are_its_armholes_corners_and_the_sleeve_points_sewn_to_them():
    """`[field] grading = "seam_corners"`: the front's notch corners and the strap and side
    seams' ends at the armhole (where the sewn path turns), on the sleeve the points sewn to
    them (its straight inner end at 0.07 … 0.49) and its underarm corners; same spans."""
    import tomllib

    document = tomllib.loads(TSHIRT.read_text())
    document["field"]["grading"] = "seam_corners"
    plan = parse_scene(document, base_dir=TSHIRT.parent, path=TSHIRT).field
    corners = dict(zip((p.name for p in plan.patches), plan.seam_corners(), strict=True))
    assert corners["front"] == corners["back"] == ((0.0, 0.07, 0.401238898, 0.471238898),
                                                   (0.26, 0.4))
    assert corners["sleeve_right"] == ((0.0, 0.07, 0.21, 0.28, 0.35, 0.49, 0.56), (0.0,))
    for patch in plan.patches:
        assert patch.config.spans == (8, 6) and all(g is not None for g in patch.config.grading)
    document["field"]["grading"] = "seams"
    with pytest.raises(SceneError, match="grading"):
        parse_scene(document, base_dir=TSHIRT.parent, path=TSHIRT)

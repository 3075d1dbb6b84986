"""Curved outline edges (issue 30): arcs given by a bulge, integrated as arcs, sewn by arclength."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.discretise import of_scene
from taichi_ndf.discretise.trimmed import trimmed_points
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.geometry import Plane
from taichi_ndf.objective.seam import SeamTerm
from taichi_ndf.problem.arcs import Arc
from taichi_ndf.problem.outline import Outline
from taichi_ndf.problem.seams import SeamSpec
from taichi_ndf.scene.reader import load_scene, parse_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.shell.materials import LinearIsotropic
from tests.test_garment_outline import garment_document, parse_garment, solved_garment

ROOT = Path(__file__).resolve().parents[1]
R = 0.1
QUARTER = math.tan(math.pi / 8)  # the bulge of a quarter circle
DISC = Outline(((R, 0.0), (0.0, R), (-R, 0.0), (0.0, -R)), (QUARTER,) * 4)
HALF_DISC = Outline(((-R, 0.0), (0.0, 0.0), (R, 0.0)), (0.0, 0.0, 1.0))  # y ≥ 0

def _moment(a: int, b: int, upper: float) -> float:
    """∫ x^a y^b over the disc of radius R (upper = 2π) or its half y ≥ 0 (upper = π): the
    radial integral R^(a+b+2)/(a+b+2) times ∫₀^upper cos^a sin^b (a 200-point Gauss rule,
    exact for these trigonometric polynomials)."""
    nodes, weights = np.polynomial.legendre.leggauss(200)
    theta = 0.5 * upper * (nodes + 1)
    angular = 0.5 * upper * float(np.sum(weights * np.cos(theta) ** a * np.sin(theta) ** b))
    return R ** (a + b + 2) / (a + b + 2) * angular


@pytest.mark.parametrize("spans", [4, 7])
@pytest.mark.parametrize(("outline", "upper"), [(DISC, 2 * math.pi), (HALF_DISC, math.pi)])
def test_the_trimmed_quadrature_integrates_polynomials_over_a_disc_and_a_half_disc(
        outline, upper, spans):
    """Every monomial of degree ≤ 7 (the whole spans' tensor rule is exact to degree 7 in
    each coordinate), on knot spans that cut the arcs anywhere, to 1e-13 of R^(a+b+2); the
    weights positive and adding up to the area."""
    xi, w = (t.numpy() for t in trimmed_points(outline, SplineConfig(spans=(spans, spans),
                                                                     domain=outline.bounds)))
    assert (w > 0).all()
    assert abs(w.sum() - 0.5 * upper * R * R) < 1e-15
    for a in range(8):
        for b in range(8 - a):
            value = float(np.sum(w * xi[:, 0] ** a * xi[:, 1] ** b))
            assert abs(value - _moment(a, b, upper)) < 1e-13 * R ** (a + b + 2), (a, b)


def test_an_outline_with_arcs_has_the_arcs_area_bounds_inside_and_border():
    notch = Outline(((0, 0), (1, 0), (1, 0.3), (1, 0.5), (1, 1), (0, 1)),
                    (0, 0, -1.0, 0, 0, 0))  # a half circle of radius 0.1 cut into the side
    assert abs(notch.area - (1 - 0.5 * math.pi * 0.01)) < 1e-15
    assert abs(DISC.area - math.pi * R * R) < 1e-17 and HALF_DISC.bounds == ((-R, R), (0, R))
    assert notch.contains(np.array([[0.95, 0.4], [0.89, 0.4], [0.95, 0.29]])).tolist() == [
        False, True, True]
    border = notch.nearest_on_border(np.array([[0.95, 0.4], [0.6, 0.4]]))
    assert np.allclose(border, [[0.9, 0.4], [0.9, 0.4]])
    edge = notch.edge("e2")
    points, run, normal = edge.path(np.array([0.0, 0.5, 1.0]))
    assert np.allclose(points, [[1, 0.3], [0.9, 0.4], [1, 0.5]])
    assert np.allclose(np.linalg.norm(run, axis=1), 0.1 * math.pi)  # constant speed: arclength
    assert np.allclose(normal[1], [1, 0])  # outward: into the notch


@pytest.mark.parametrize(("points", "bulges", "message"), [
    (((0, 0), (1, 0), (1, 0.3), (1, 0.5), (1, 1), (0, 1)), (0, 0, -20.0, 0, 0, 0),
     "edges e0 and e2 cross or touch"),
    (((0, 0), (1, 0), (1, 1)), (0, float("inf"), 0), "edge e1: the bulge must be a finite"),
    (((0, 0), (1, 0), (1, 1)), (0, 0), "2 bulges for 3 edges"),
])
def test_a_wrong_curved_outline_is_refused_naming_the_edge(points, bulges, message):
    with pytest.raises(ValueError, match=message):
        Outline(points, bulges)


def test_a_seam_between_two_arcs_of_equal_length_ties_them_at_rest_by_arclength():
    """A panel's convex arc and another's concave one on the same circle, and a straight edge
    as long as the arc: the seam's length is the arc's, its points coincide at rest on the
    arc (gap 0) and on the straight edge are placed by arclength; unequal lengths refused."""
    bulge = 0.4
    a = Outline(((0, 0), (0.2, 0), (0.2, 0.3), (0, 0.3)), (0, bulge, 0, 0))
    b = Outline(((0.2, 0), (0.5, 0), (0.5, 0.3), (0.2, 0.3)), (0, 0, 0, -bulge))
    arc = Arc((0.2, 0.0), (0.2, 0.3), 4 * math.atan(bulge))
    plane = Plane(bounds=((0.0, 0.5), (0.0, 0.3)))
    material = LinearIsotropic(membrane_stiffness=6400.0, bending_stiffness=0.1,
                               poisson_ratio=0.25, areal_density=0.144)
    spec = SeamSpec("s", a.edge("e1", "a.e1"), b.edge("e3", "b.e3"), orientation="reversed")
    term = SeamTerm(spec, plane, material)
    assert abs(term.length - arc.length) < 1e-12
    count = term.xi.shape[0] // 2
    assert torch.allclose(term.xi[:count], term.xi[count:], atol=1e-15)
    straight = Outline(((0, 0), (arc.length, 0), (arc.length, 0.3), (0, 0.3)))
    spec = SeamSpec("t", a.edge("e1", "a.e1"), straight.edge("e0", "c.e0"))
    term = SeamTerm(spec, plane, material)
    s = term.xi[count:, 0] / arc.length  # the fraction along the straight edge
    assert torch.allclose(term.xi[:count], torch.from_numpy(arc.at(s.numpy())), atol=1e-15)
    short = Outline(((0, 0), (0.9 * arc.length, 0), (0.9 * arc.length, 0.3), (0, 0.3)))
    with pytest.raises(ValueError, match="edge 'a.e1' is 0.3.* m long and edge 'c.e0'"):
        SeamTerm(SeamSpec("u", a.edge("e1", "a.e1"), short.edge("e0", "c.e0")), plane,
                 material)


def test_two_panels_sewn_along_an_arc_are_the_rectangle_they_make():
    """The cantilever (0.3 × 0.2 m, clamped along its top, gravity across it) cut along an arc
    from (0.15, 0) to (0.15, 0.2) bulging 2 cm into the right half (bulge 0.2), the halves on
    8 × 8 spans sewn with the bending transmitted, against the rectangle on 16 × 8: Π within
    2e-5 relative (measured 3.1e-5, 6.1e-6, 9.5e-7 on 4, 8, 16 spans per half: converging; the
    trapezoids' straight cut 1.0e-5 on 8 × 8), the seam closed to 10 µm (measured 0.05 nm)."""
    halves = [{"name": "a", "outline": [[0, 0], [0.15, 0, 0.2], [0.15, 0.2], [0, 0.2]],
               "clamped": ["e2"], "clamp_band": 1.0},
              {"name": "b", "outline": [[0.15, 0], [0.3, 0], [0.3, 0.2], [0.15, 0.2, -0.2]],
               "clamped": ["e2"], "clamp_band": 1.0}]
    seam = [{"name": "curve", "a": "a.e1", "b": "b.e3", "orientation": "reversed"}]
    _, pair = solved_garment(garment_document(halves, seam, (8, 8)))
    _, whole = solved_garment(garment_document([{"name": "w", "width": 0.3, "height": 0.2,
                                "clamped": ["xi2_max"], "clamp_band": 1.0}], spans=(16, 8)))
    assert abs(pair.energy - whole.energy) <= 2e-5 * abs(whole.energy)
    assert pair.document["seam_gaps"]["curve"] < 1e-5


@pytest.mark.parametrize(("change", "message"), [
    ({"outline": [[0, 0], [0.3, 0], [0.3, 0.2, 0.5, 1], [0, 0.2]]},
     "panels[0].outline: panel 'a': expected points [[x, y], …] or [x, y, bulge]"),
    ({"outline": [[0, 0], [0.3, 0, -2.0], [0.3, 0.2], [0, 0.2]]},
     "panel 'a': outline: edges e0 and e1 cross or touch"),
    ({"outline": [[0, 0], [0.3, 0], [0.3, 0.2, 0.3], [0, 0.2]], "clamped": ["e2"]},
     "panel 'a': edge 'e2' is curved: it lies on no side of the outline's bounding box"),
])
def test_a_wrong_curved_panel_is_refused_in_one_line_naming_panel_and_edge(change, message):
    panel = {"name": "a", "outline": [[0, 0], [0.3, 0], [0.3, 0.2], [0, 0.2]]}
    panel.update(change)
    with pytest.raises(SceneError) as err:
        parse_garment(garment_document([panel]))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_curved_tshirts_armholes_are_half_circles_sewn_to_the_sleeves_halves():
    scene = load_scene(ROOT / "scenes" / "tshirt_body.toml")
    plan = scene.field
    front = next(p for p in plan.patches if p.name == "front")
    assert abs(front.outline.area - (0.471238898 * 0.45 - math.pi * 0.07 ** 2)) < 1e-12
    names = {s.spec.name: s for s in plan.seams}
    assert len(names) == 10
    for name in ("armhole_right_front", "armhole_right_back", "armhole_left_front",
                 "armhole_left_back"):
        seam = names[name]
        assert seam.spec.bending == "hinge" and seam.spec.b.bulge == -1.0
        assert abs(Arc(seam.spec.b.start, seam.spec.b.end, -math.pi).length
                   - math.dist(seam.spec.a.start, seam.spec.a.end)) < 1e-8


def test_the_curved_tshirt_converges_with_its_armholes_closed_on_a_coarse_grid():
    """scenes/tshirt_body.toml on 6 × 4 spans per panel, load steps 0.5 and 1 (29 s CPU; the
    band's move cuts them to 0.5, 0.75, 0.875, 1): every step converged by Newton's own
    criterion, the armhole seams closed to 0.1 mm (measured 63 µm; 33 µm on the scene's 8 × 6)
    and Π as measured at wip-garment10 (0.0757077795443395 J)."""
    document = tomllib.loads((ROOT / "scenes" / "tshirt_body.toml").read_text())
    document["field"]["spans"] = [6, 4]
    document["training"]["load_steps"] = [0.5, 1.0]
    scene = parse_scene(document, base_dir=ROOT / "scenes", path=ROOT / "scenes" / "x.toml")
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    solution = panels.solve(scene.solver)
    panels.check_solution(solution)
    assert all(panels.converged)
    gaps = solution.document["seam_gaps"]
    assert max(v for k, v in gaps.items() if k.startswith("armhole")) < 1e-4
    assert solution.energy == pytest.approx(0.0757077795443395, rel=1e-9)

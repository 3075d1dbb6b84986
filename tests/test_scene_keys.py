"""Scene keys of issue 17: line loads, the annulus geometry, symmetry planes; errors name the
key."""

import copy
import math
from pathlib import Path

import pytest

from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

BASE = {
    "name": "t",
    "geometry": {"type": "plane", "bounds": [[0.0, 2.0], [0.0, 1.0]]},
    "material": {"preset": "cloth"},
    "field": {"output_scale": 0.1},
}


def parse(**sections):
    document = copy.deepcopy(BASE)
    document.update(sections)
    return parse_scene(document, base_dir=Path("."))


def test_line_loads_along_an_edge_and_a_path():
    scene = parse(loads={"line": [{"edge": "xi1_max", "force": [0, 0, -2.0]},
                                  {"path": [[0, 0], [1, 1]], "force": [1, 0, 0], "nodes": 3}]})
    first, second = scene.model.loads.line_loads
    assert first.path == ((2.0, 0.0), (2.0, 1.0)) and first.nodes == 8
    assert second.path == ((0.0, 0.0), (1.0, 1.0)) and second.nodes == 3


@pytest.mark.parametrize("line, key", [
    ({"force": [0, 0, 1]}, "loads.line[0]: give exactly one of 'edge' or 'path'"),
    ({"edge": "xi1_max", "path": [[0, 0], [1, 0]], "force": [0, 0, 1]}, "exactly one"),
    ({"edge": "left", "force": [0, 0, 1]}, "loads.line[0].edge"),
    ({"path": [[0, 0]], "force": [0, 0, 1]}, "loads.line[0].path"),
    ({"path": [[0, 0], [3, 0]], "force": [0, 0, 1]}, "line load path point"),
    ({"edge": "xi1_max", "force": [0, 1]}, "loads.line[0].force"),
    ({"edge": "xi1_max", "force": [0, 0, 1], "nodes": 0}, "loads.line[0].nodes"),
    ({"edge": "xi1_max", "force": [0, 0, 1], "follower": True}, "'follower'"),
])
def test_line_load_errors_name_the_key(line, key):
    with pytest.raises(SceneError, match=key.replace("[", r"\[").replace("]", r"\]")):
        parse(loads={"line": [line]})


def test_annulus_geometry():
    scene = parse(geometry={"type": "annulus", "inner_radius": 6.0, "outer_radius": 10.0,
                            "slit": True},
                  boundary={"constraint": [{"type": "clamped_edge", "edge": "xi2_min"}]})
    surface = scene.model.surface
    assert surface.domain.bounds[1] == pytest.approx((0.0, 2 * math.pi))
    assert surface.domain.periodic == (False, False)
    full = parse(geometry={"type": "annulus", "inner_radius": 1.0, "outer_radius": 2.0})
    assert full.model.surface.domain.periodic == (False, True)
    assert full.field.periodic == (False, True)
    sector = parse(geometry={"type": "annulus", "inner_radius": 1.0, "outer_radius": 2.0,
                             "angle_deg": 90.0, "start_angle_deg": -45.0})
    assert sector.model.surface.domain.bounds[1] == pytest.approx((-math.pi / 4, math.pi / 4))


@pytest.mark.parametrize("geometry, key", [
    ({"inner_radius": 0.0, "outer_radius": 1.0}, "geometry.inner_radius"),
    ({"inner_radius": 2.0, "outer_radius": 1.0}, "geometry: outer_radius"),
    ({"inner_radius": 1.0, "outer_radius": 2.0, "angle_deg": 400.0}, "geometry: angle"),
    ({"inner_radius": 1.0, "outer_radius": 2.0, "angle_deg": 90.0, "slit": True},
     "geometry: slit"),
    ({"inner_radius": 1.0, "outer_radius": 2.0, "slit": 1}, "geometry.slit"),
])
def test_annulus_errors_name_the_key(geometry, key):
    with pytest.raises(SceneError, match=key):
        parse(geometry={"type": "annulus", **geometry})


def test_a_periodic_annulus_has_no_radial_edges():
    with pytest.raises(SceneError, match="periodic"):
        parse(geometry={"type": "annulus", "inner_radius": 1.0, "outer_radius": 2.0},
              boundary={"constraint": [{"type": "clamped_edge", "edge": "xi2_min"}]})


def test_mesh_fit_cells():
    root = Path(__file__).resolve().parents[1]
    geometry = {"type": "mesh", "path": str(root / "data" / "napkin.obj"), "fit_cells": 6}
    surface = parse(geometry=geometry).model.surface
    assert max(surface.cells) == 6
    with pytest.raises(SceneError, match="geometry.fit_cells"):
        parse(geometry={**geometry, "fit_cells": 0})


def test_symmetry_plane_constraints():
    scene = parse(boundary={"constraint": [
        {"type": "symmetry_plane", "edge": "xi1_min", "normal": "x"},
        {"type": "symmetry_plane", "edge": "xi2_max", "normal": "y", "antisymmetric": True,
         "length": 0.3}]})
    first, second = scene.model.boundary.constraints
    assert first.components == "x" and second.components == "xz" and second.length == 0.3
    assert scene.model.boundary.fold.active


@pytest.mark.parametrize("constraint, key", [
    ({"edge": "xi1_min", "normal": "x", "components": "x"}, "'components'"),
    ({"edge": "xi1_min"}, "boundary.constraint[0].normal: required"),
    ({"edge": "xi1_min", "normal": "q"}, "boundary.constraint[0]: SymmetryPlane: normal"),
    ({"edge": "xi1_min", "normal": "y"}, "plane normal to y"),
])
def test_symmetry_plane_errors_name_the_key(constraint, key):
    with pytest.raises(SceneError, match=key.replace("[", r"\[").replace("]", r"\]")):
        parse(boundary={"constraint": [{"type": "symmetry_plane", **constraint}]})


def test_slit_annular_plate_with_a_line_load_solves_end_to_end():
    """The slit annular plate in the linear regime (line force 1e-4 on the free face, the
    other face clamped): Newton on the output layer lowers Π below zero, the free face lifts
    along the force, and the outer corner more than the inner one (measured Π −1.5e-6 J,
    u_z 0.0065 at A and 0.0088 at B with width 64)."""
    from taichi_ndf.field import NeuralField
    from taichi_ndf.solve.solver import Solver

    two_pi = 2 * math.pi
    scene = parse(
        geometry={"type": "annulus", "inner_radius": 6.0, "outer_radius": 10.0, "slit": True},
        material={"type": "linear", "young_modulus": 21.0e6, "poisson_ratio": 0.0,
                  "thickness": 0.03, "areal_density": 1.0},
        boundary={"constraint": [{"type": "clamped_edge", "edge": "xi2_min"}]},
        loads={"line": [{"edge": "xi2_max", "force": [0.0, 0.0, 1e-4]}]},
        field={"width": 32, "hidden_layers": 2, "omega0": 3, "output_scale": 0.01},
        training={"iterations": 0, "newton_iterations": 4, "newton_samples": 1024},
        probes=[{"name": "A", "xi": [6.0, two_pi]}, {"name": "B", "xi": [10.0, two_pi]}])
    result = Solver(scene.model, NeuralField(scene.field, seed=0), scene.solver).run()
    assert result.energy < 0
    assert 0 < result.probes["A"][2] < result.probes["B"][2]

"""The grid rule along a periodic direction respects the concentrated loads' symmetry
(taichi_ndf.problem.spline_grid.load_symmetry): symmetric loads meet a symmetric grid."""

from __future__ import annotations

from pathlib import Path

import pytest

from taichi_ndf.geometry import Cylinder, Plane
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.spline_grid import load_symmetry, spans_for
from taichi_ndf.scene.reader import load_scene

VALIDATION = Path(__file__).resolve().parents[1] / "validation" / "scenes"


@pytest.mark.parametrize("case, spans, order", [
    ("pinched_cylinder", (64, 20), (2, 1)),     # on main 63 around: the loads 2.8 % apart
    ("pinched_hemisphere", (76, 20), (4, 1)),   # four loads 90° apart (main: 75)
])
def test_validation_grids_map_their_loads_onto_themselves(case, spans, order):
    scene = load_scene(VALIDATION / f"{case}.toml", field="spline")
    assert load_symmetry(scene.model.surface, scene.model.loads) == order
    assert scene.field.config.spans == spans


def test_the_order_is_that_of_positions_and_forces():
    cylinder = Cylinder(radius=1.0, length=2.0)
    (lo, hi), _ = cylinder.domain.bounds
    period = hi - lo

    def order(*points):
        return load_symmetry(cylinder, Loads(point_loads=[PointLoad(xi, f) for xi, f in points]))

    inward = ((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert order(((lo, 1.0), inward[0]), ((lo + period / 2, 1.0), inward[1])) == (2, 1)
    assert order(*[((lo + k * period / 3, 1.0), (0.0, 0.0, 1.0)) for k in range(3)]) == (3, 1)
    # a different force, or another height: no shift maps them onto each other
    assert order(((lo, 1.0), (1.0, 0, 0)), ((lo + period / 2, 1.0), (2.0, 0, 0))) == (1, 1)
    assert order(((lo, 1.0), (1.0, 0, 0)), ((lo + period / 2, 1.5), (1.0, 0, 0))) == (1, 1)
    assert order() == (1, 1)
    # rounded up to a multiple of the order, only along the periodic direction
    two = Loads(point_loads=[PointLoad((lo, 1.0), inward[0]),
                             PointLoad((lo + period / 2, 1.0), inward[1])])
    free = spans_for(cylinder, 2 * 3.14159 / 63 + 1e-6)
    assert free[0] % 2 == 1
    assert spans_for(cylinder, 2 * 3.14159 / 63 + 1e-6, two) == (free[0] + 1, free[1])
    plane = Plane(bounds=((0.0, 1.0), (0.0, 1.0)))
    assert spans_for(plane, 1 / 7, two) == spans_for(plane, 1 / 7) == (7, 7)


def test_the_pinched_cylinders_two_loads_move_alike_on_the_coarsest_grid(tmp_path):
    """`ndf-sim pinched_cylinder --field spline` (the grid rule's grid, f64). Measured: on main's
    63 spans around the radial displacements under the loads were 1.7650e-5 and 1.7167e-5 m
    (2.8 % apart); on 64 spans 1.7676e-5 m both (10.8 s CPU)."""
    import json

    from taichi_ndf.cli import sim

    out = tmp_path / "run"
    assert sim.main([str(VALIDATION / "pinched_cylinder.toml"), "--field", "spline",
                     "--precision", "f64", "--out", str(out)]) == 0
    probes = json.loads((out / "result.json").read_text())["probes"]
    radial = (-probes["load_0"][0], probes["load_pi"][0])
    assert radial[0] > 1e-5
    assert radial[0] == pytest.approx(radial[1], rel=1e-6)

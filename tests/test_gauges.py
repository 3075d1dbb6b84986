"""Gauge points (`taichi_ndf.boundary.gauges`, issue 33): a pinned point that only removes the
rigid motions under self-equilibrated loads carries no reaction and is no singular feature;
a pin that shares the load with another support, or holds a load, is one. The graded grids
(`[field] grading = "features"` and the adaptive path's `features_grid`) leave gauges out."""

from __future__ import annotations

from pathlib import Path

import pytest

from taichi_ndf.boundary.gauges import gauge_points
from taichi_ndf.problem.spline_grid import singular_features
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.adaptive import features_grid

ROOT = Path(__file__).resolve().parents[1]

# A free unit plate held at one interior point, with two point loads along x.
PLATE = """
name = "plate"
[geometry]
type = "plane"
bounds = [[0.0, 1.0], [0.0, 1.0]]
[material]
type = "linear"
young_modulus = 1.0e6
poisson_ratio = 0.3
thickness = 0.01
areal_density = 1.0
[loads]
{gravity}
[[loads.point]]
xi = [0.2, 0.5]
force = [-1.0, 0.0, 0.0]
[[loads.point]]
xi = [0.8, {second}]
force = [1.0, 0.0, 0.0]
[boundary]
[[boundary.constraint]]
type = "pinned_point"
xi = [0.3, 0.7]
{more}
[field]
type = "spline"
spans = [8, 8]
"""


def plate(tmp_path, gravity="", second=0.5, more=""):
    path = tmp_path / "plate.toml"
    path.write_text(PLATE.format(gravity=gravity, second=second, more=more))
    return load_scene(path, field="spline").model


def test_a_pin_under_self_equilibrated_loads_is_a_gauge(tmp_path):
    model = plate(tmp_path)
    assert gauge_points(model) == model.boundary.constraints
    assert singular_features(model.boundary, model.loads, model.surface.domain,
                             gauge_points(model)) == ((0.2, 0.8), (0.5,))


@pytest.mark.parametrize("case", [
    {"second": 0.6},  # the two forces are not on one line: a couple the pin holds
    {"gravity": "gravity = [0.0, 0.0, -9.81]"},  # the weight hangs on the pin
    {"more": '[[boundary.constraint]]\ntype = "clamped_edge"\nedge = "xi1_min"'},  # shared
])
def test_a_pin_that_holds_a_load_or_shares_it_is_a_feature(tmp_path, case):
    model = plate(tmp_path, **case)
    assert gauge_points(model) == ()
    f1, f2 = singular_features(model.boundary, model.loads, model.surface.domain,
                               gauge_points(model))
    assert 0.3 in f1 and 0.7 in f2


def test_the_pinched_hemispheres_pin_is_not_graded_towards():
    """Its pin on the hole's rim (λ = the domain's end) only removes the rigid motions of the
    four self-equilibrated loads: the grading of both paths follows the loads alone."""
    scene = load_scene(ROOT / "validation" / "scenes" / "pinched_hemisphere.toml",
                       field="spline", overrides={"field.grading": "features"})
    model = scene.model
    assert len(gauge_points(model)) == 1
    for config in (scene.field.config, features_grid(scene.field.config, model)):
        phi, lam = (g.features for g in config.grading)
        assert len(phi) == 4 and lam == (0.0,)


def test_the_napkins_pin_holds_its_weight():
    scene = load_scene(ROOT / "scenes" / "napkin.toml", field="spline")
    assert gauge_points(scene.model) == ()
    assert features_grid(scene.field.config, scene.model).graded

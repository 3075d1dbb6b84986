"""Contact in a solve: a plate resting on a plane ends at the barrier's offset height without
bending; the filter refuses steps that could cross an obstacle; bad obstacle definitions are
refused with errors that name them. (The quick runs of the contact scenes, with their
clearance on a 256² grid, are in tests/test_scenes.py.)"""

from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.app.outputs import deformed_mesh
from taichi_ndf.boundary import BoundaryConditions, PinnedPoint
from taichi_ndf.cli import sim
from taichi_ndf.contact import (
    ContactConfig,
    ContactHook,
    ContactPoints,
    ContactTerm,
    GroundPlane,
    Sphere,
)
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.geometry import Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import Probe, ShellModel
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.shell.materials import preset
from taichi_ndf.solve.solver import Solver, SolverConfig

F64 = torch.float64
SCENES = Path(__file__).resolve().parents[1] / "scenes"


def test_plate_resting_on_a_plane_ends_at_the_offset_height_without_bending():
    surface = Plane(bounds=((0.0, 0.2), (0.0, 0.2)))
    material = preset("cloth")
    probes = (Probe("centre", (0.1, 0.1)), Probe("corner", (0.0, 0.0)),
              Probe("edge", (0.2, 0.1)))
    model = ShellModel(surface, material, Loads(gravity=(0.0, 0.0, -9.81)),
                       BoundaryConditions([], surface.domain, surface=surface), probes)
    activation, margin = 1e-3, 1e-4
    plane_z = -(0.5 * material.thickness + margin + 0.9 * activation)  # starts at gap 0.9 ĝ
    contact = ContactConfig.resolve([GroundPlane(point=(0.0, 0.0, plane_z))], model,
                                    margin=margin, activation=activation)
    model = ShellModel(surface, material, model.loads, model.boundary, probes, contact=contact)
    field = NeuralField(FieldConfig(width=32, hidden_layers=2, omega0=5,
                                    domain=surface.domain.bounds, output_scale=1e-3))
    config = SolverConfig(iterations=0, samples=256, newton_iterations=10, newton_samples=1024,
                          monitor_samples=1024, progress=False)
    solver = Solver(model, field, config)
    result = solver.run()
    # κ carries the plate's weight at gap ĝ/2 (docs/contact.md): the plate sinks by 0.4 ĝ
    for name in ("centre", "corner", "edge"):
        assert result.probes[name][2] == pytest.approx(-0.4 * activation, abs=0.02 * activation)
    # flat: the height varies by less than 4 % of ĝ over the plate (17² grid; measured 2.3 %)
    mesh = deformed_mesh(model, field, (16, 16))
    heights = mesh.deformed[:, 2]
    assert float(heights.max() - heights.min()) < 0.04 * activation, np.ptp(heights)
    points = solver.contact.points
    assert points.count == len(points.grid_xi)  # the whole plate is in contact


def test_filter_refuses_a_step_that_could_cross_an_obstacle():
    surface = Plane(bounds=((-0.1, 0.1), (-0.1, 0.1)))
    term = ContactTerm([Sphere(centre=(0.0, 0.0, -0.5), radius=0.5)], offset=0.0,
                       activation=1e-3, stiffness=1.0)
    points = ContactPoints(term, surface, 5)
    start = torch.tensor([[0.0, 0.0, 0.002], [0.05, 0.0, 0.01]], dtype=F64)
    gaps = points.point_gaps(start, 1.0)
    down = torch.tensor([0.0, 0.0, -1.0], dtype=F64)
    assert points.step_allowed(start, gaps, start + 0.0015 * down, 1.0)
    assert not points.step_allowed(start, gaps, start + 0.0025 * down, 1.0)
    # a jump clean through the sphere ends outside, but moved more than its gap: refused
    assert not points.step_allowed(start, gaps, start + 1.2 * down, 1.0)
    # a stray point already inside may move, but not deeper than it was
    inside = torch.tensor([[0.0, 0.0, -0.001]], dtype=F64)
    stray = points.point_gaps(inside, 1.0)
    assert points.step_allowed(inside, stray, inside - 0.0005 * down, 1.0)
    assert not points.step_allowed(inside, stray, inside + 0.001 * down, 1.0)


def test_filter_with_both_ends_lets_a_point_at_a_tiny_gap_move_away_but_not_cross():
    surface = Plane(bounds=((-0.1, 0.1), (-0.1, 0.1)))
    term = ContactTerm([Sphere(centre=(0.0, 0.0, -0.5), radius=0.5)], offset=0.0,
                       activation=1e-3, stiffness=1.0)
    points = ContactPoints(term, surface, 5)
    start = torch.tensor([[0.0, 0.0, 2.5e-6]], dtype=F64)  # the stalled napkin_sphere point
    gaps = points.point_gaps(start, 1.0)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    side = torch.tensor([1.0, 0.0, 0.0], dtype=F64)
    away = start + 2e-5 * up
    assert not points.step_allowed(start, gaps, away, 1.0)  # one-sided: moved > its gap
    assert points.step_allowed(start, gaps, away, 1.0, both_ends=True)
    # sliding along the sphere by much more than the two gaps, or into it: refused
    assert not points.step_allowed(start, gaps, start + 1e-4 * side, 1.0, both_ends=True)
    assert not points.step_allowed(start, gaps, start - 1e-5 * up, 1.0, both_ends=True)
    # a jump clean through the sphere ends outside with a large end gap, but the path
    # crosses it: |end - start| = 1.2 m against gaps 0.002 + 0.198
    high = torch.tensor([[0.05, 0.0, 0.002]], dtype=F64)
    through = high - 1.2 * up
    assert float(points.point_gaps(through, 1.0)[0]) > 0
    assert not points.step_allowed(high, points.point_gaps(high, 1.0), through, 1.0,
                                   both_ends=True)


def test_the_siren_path_asks_the_contact_hook(monkeypatch):
    """Adam's steps go through the hook's policy (`accept`) and the last-layer Newton's
    line search through its `feasible` (the test projected Newton takes, each trial from the
    current iterate), from one hook made at the solver's start."""
    surface = Plane(bounds=((0.0, 0.2), (0.0, 0.2)))
    material = preset("cloth")
    bare = ShellModel(surface, material, Loads(gravity=(0.0, 0.0, -9.81)),
                      BoundaryConditions([], surface.domain, surface=surface), ())
    contact = ContactConfig.resolve([GroundPlane(point=(0.0, 0.0, -2e-3))], bare,
                                    margin=1e-4, activation=1e-3)
    model = ShellModel(surface, material, bare.loads, bare.boundary, (), contact=contact)
    field = NeuralField(FieldConfig(width=16, hidden_layers=1, omega0=5,
                                    domain=surface.domain.bounds, output_scale=1e-2))
    config = SolverConfig(iterations=2, samples=64, newton_iterations=1, newton_samples=64,
                          monitor_samples=64, progress=False)
    calls = []
    for name in ("accept", "check", "feasible", "feasible_start"):
        original = getattr(ContactHook, name)

        def spy(self, *args, _name=name, _original=original, **kwargs):
            calls.append((_name, id(self)))
            return _original(self, *args, **kwargs)
        monkeypatch.setattr(ContactHook, name, spy)
    solver = Solver(model, field, config)
    solver.run()
    names = [n for n, _ in calls]
    assert names.count("feasible_start") == 1 and names.count("accept") == 2, names
    # a Newton phase at the start and at the end of the load step; a check per Adam step (2)
    # and per Newton iterate a line search started from (at least one a phase)
    assert names.count("feasible") == 2, names
    assert names.count("check") >= 4, names
    assert {h for _, h in calls} == {id(solver.contact)}
    # the two-sided rule on this path (the one-sided one froze napkin_sphere at output_scale
    # 0.452: docs/scenes.md, "Field output scale")
    assert solver.contact.both_ends


NAPKIN = SCENES / "napkin_sphere.toml"


def edited(tmp_path, old, new):
    text = NAPKIN.read_text()
    assert old in text
    path = tmp_path / "scene.toml"
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize("old, new, message", [
    ("radius = 0.15", "radius = 0.0", r"obstacles\[0\].radius: must be > 0"),
    ('type = "sphere"', 'type = "cone"', r"obstacles\[0\].type: must be one of"),
    ("radius = 0.15", "radius = 0.15\nrounding = 0.1", r"obstacles\[0\]: unknown key"),
    ('stiffness = "auto"', "stiffness = -1.0", r"contact.stiffness: must be > 0"),
])
def test_bad_obstacle_tables_name_the_key(tmp_path, old, new, message):
    with pytest.raises(SceneError, match=message):
        load_scene(edited(tmp_path, old, new))


def test_open_mesh_obstacle_is_refused(tmp_path):
    torus = (SCENES.parent / "data" / "torus.obj").read_text().splitlines()
    (tmp_path / "open.obj").write_text("\n".join(torus[:-1]) + "\n")  # one triangle less
    text = (SCENES / "sheet_torus.toml").read_text().replace('"../data/torus.obj"',
                                                              '"open.obj"')
    (tmp_path / "scene.toml").write_text(text)
    with pytest.raises(SceneError, match="obstacles.*torus.*not closed"):
        load_scene(tmp_path / "scene.toml")


def test_obstacle_at_a_pinned_point_or_through_the_sheet_is_refused(tmp_path, capsys):
    pinned = edited(tmp_path, "[[obstacles]]",
                    '[[boundary.constraint]]\ntype = "pinned_point"\nxi = [0.0, 0.0]\n\n'
                    "[[obstacles]]")
    scene = load_scene(pinned)
    moved = scene.model.contact.obstacles[0].__class__(name="sphere", centre=(0.0, 0.0, 0.01),
                                                       radius=0.15)
    config = ContactConfig.resolve([moved], scene.model)
    with pytest.raises(ValueError, match="'sphere' intersects the PinnedPoint at ξ=.0.0, 0.0."):
        config.check(scene.model)
    through = edited(tmp_path, "centre = [0.0, 0.0, 0.0]", "centre = [0.2, 0.2, 0.1]")
    code = sim.main([str(through), "--out", str(tmp_path / "run"), "--quick",
                     "--precision", "f64"])
    assert code == 2
    assert "obstacle 'sphere' intersects the reference surface" in capsys.readouterr().err


def test_contact_without_obstacles_and_pseudo_time_with_them_are_refused(tmp_path):
    text = NAPKIN.read_text()
    start, end = text.index("[[obstacles]]"), text.index("[contact]")
    (tmp_path / "a.toml").write_text(text[:start] + text[end:])
    with pytest.raises(SceneError, match="contact: the scene has no"):
        load_scene(tmp_path / "a.toml")
    text = text.replace("newton_iterations = 10\nnewton_samples = 2048\n", "pseudo_time = true\n")
    (tmp_path / "p.toml").write_text(text.replace("newton_iterations = 3\n", ""))
    with pytest.raises(SceneError, match="pseudo_time: not available with"):
        load_scene(tmp_path / "p.toml")


def test_pinned_sheet_model_accepts_contact():
    """A model with contact and a pin far from the obstacle builds its solver."""
    surface = Plane(bounds=((-0.1, 0.1), (-0.1, 0.1)), origin=(0.0, 0.0, 0.2))
    model = ShellModel(surface, preset("cloth"), Loads(gravity=(0.0, 0.0, -9.81)),
                       BoundaryConditions([PinnedPoint((0.1, 0.1))], surface.domain,
                                          surface=surface))
    config = ContactConfig.resolve([Sphere(radius=0.1)], model)
    config.check(model)
    assert config.margin == pytest.approx(0.1 * config.activation)

"""Contact on the spline + projected-Newton path and friction: the friction term's gradient and
Hessian blocks against central differences, the stick/slip threshold of a plate on a tilted
plane at atan μ, quick spline runs of every contact scene (clearance on a 256² grid; the
napkin on a sphere keeps its 4-fold symmetry), the line search's feasibility test, and the
friction key of a scene."""

import dataclasses
import math
from pathlib import Path

import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.app.simulation import simulate
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.cli import sim
from taichi_ndf.contact import ContactConfig, ContactTerm, GroundPlane, Sphere
from taichi_ndf.contact.friction import FrictionTerm, smoothed_friction
from taichi_ndf.field import SplineConfig
from taichi_ndf.geometry import Plane
from taichi_ndf.io import OutputDir
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import Probe, ShellModel
from taichi_ndf.problem.sampling import sample_surface
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.problem.training import SolverConfig
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.scene.schema import SceneError
from taichi_ndf.shell.materials import preset
from taichi_ndf.solve.spline_solver import solve_spline

F64 = torch.float64
SCENES = Path(__file__).resolve().parents[1] / "scenes"
ACTIVATION = 0.01


def test_smoothed_friction_is_c1_and_its_derivatives_match_central_differences():
    eps = 1e-3
    y = torch.linspace(0.0, 3 * eps, 301, dtype=F64)[1:]
    f0, f1_over_y, df1 = smoothed_friction(y, eps)
    h = 1e-9
    f0p, f1p, _ = smoothed_friction(y + h, eps)
    f0m, f1m, _ = smoothed_friction(y - h, eps)
    assert torch.allclose((f0p - f0m) / (2 * h), f1_over_y * y, rtol=1e-6, atol=1e-9)
    # f₁′ is continuous (0 at ε from both sides); the differences' truncation there is h/(2ε²)
    assert torch.allclose(((y + h) * f1p - (y - h) * f1m) / (2 * h), df1, rtol=1e-5,
                          atol=1e-5 * 2 / eps)
    at = torch.tensor([eps - 1e-12, eps + 1e-12], dtype=F64)
    f0, f1_over_y, _ = smoothed_friction(at, eps)
    assert float(f0[0]) == pytest.approx(float(f0[1]), abs=3e-12)  # slope 1 over 2e-12
    assert float(f0[1]) == pytest.approx(2 * eps / 3)  # f₀(ε) = ε − ε/3
    zero = smoothed_friction(torch.zeros(1, dtype=F64), eps)
    assert float(zero[0]) == 0 and float(zero[1]) == float(zero[2]) == pytest.approx(2 / eps)


def friction_setup(moving=False):
    surface = Plane(bounds=((-0.3, 0.3), (-0.3, 0.3)))
    samples = sample_surface(surface, 40, None, torch.Generator().manual_seed(3), dtype=F64)
    motion = (0.01, -0.02, 0.005) if moving else (0.0, 0.0, 0.0)
    obstacles = [GroundPlane(point=(0.0, 0.0, -0.05), normal=(0.2, 0.1, 1.0), motion=motion),
                 Sphere(centre=(0.0, 0.0, -0.3), radius=0.25, motion=motion)]
    contact = ContactTerm(obstacles, offset=0.002, activation=ACTIVATION, stiffness=300.0)
    friction = FrictionTerm(contact, (0.3, 0.5), smoothing=1e-4)
    g = torch.Generator().manual_seed(7)
    # points a little above the plane (gaps 0.2–0.8 ĝ), then moved tangentially by 0–3 ε
    u = 1e-3 * torch.randn(len(samples), 6, 3, generator=g, dtype=F64)
    gap, normal = contact.gaps(samples.r_jets[:, jets.VALUE])
    target = ACTIVATION * (0.2 + 0.6 * torch.rand(len(samples), generator=g, dtype=F64))
    u[:, jets.VALUE] = (target - gap[:, 0])[:, None] * normal[:, 0]
    start = samples.r_jets[:, jets.VALUE] + u[:, jets.VALUE]
    friction.lag(samples, u, 0.5, start, 0.5)
    slip = 3e-4 * torch.randn(len(samples), 3, generator=g, dtype=F64)
    u[:, jets.VALUE] += slip
    return friction, samples, u


@pytest.mark.parametrize("moving", [False, True])
def test_friction_gradient_and_hessian_against_central_differences(moving):
    friction, samples, u = friction_setup(moving)
    value, grad = friction.evaluate(samples, u, 0.5)
    assert value > 0 and torch.all(grad[:, 1:] == 0)
    blocks = friction.hessian_blocks(samples, u, 0.5)
    step = 1e-9
    for k in range(3):
        up, down = u.clone(), u.clone()
        up[:, jets.VALUE, k] += step
        down[:, jets.VALUE, k] -= step
        # the term is a sum over samples: perturbing all at once gives each sample's column
        fd_value = (friction.evaluate(samples, up, 0.5, grad=False)[0]
                    - friction.evaluate(samples, down, 0.5, grad=False)[0]) / (2 * step)
        assert fd_value == pytest.approx(float(grad[:, jets.VALUE, k].sum()), rel=1e-5)
        fd = (friction.evaluate(samples, up, 0.5)[1] - friction.evaluate(
            samples, down, 0.5)[1])[:, jets.VALUE] / (2 * step)
        exact = blocks[:, jets.VALUE, :, jets.VALUE, k]
        assert torch.allclose(fd, exact, rtol=1e-5, atol=1e-6 * float(exact.abs().max()))
    eigen = torch.linalg.eigvalsh(blocks[:, jets.VALUE, :, jets.VALUE, :])
    assert float(eigen.min()) >= -1e-9 * float(eigen.max())  # positive semi-definite


def plate_on_tilted_plane(angle_deg: float, mu: float):
    """A free 0.1 m cloth plate resting on a plane with gravity tilted by `angle_deg` (the
    plane's slope), solved by projected Newton; returns the centre's displacement down the
    slope [m] and the friction's smoothing ε [m]."""
    surface = Plane(bounds=((0.0, 0.1), (0.0, 0.1)))
    material = preset("cloth")
    theta = math.radians(angle_deg)
    loads = Loads(gravity=(9.81 * math.sin(theta), 0.0, -9.81 * math.cos(theta)))
    probes = (Probe("centre", (0.05, 0.05)),)
    boundary = BoundaryConditions([], surface.domain, surface=surface)
    model = ShellModel(surface, material, loads, boundary, probes)
    activation, margin = 1e-3, 1e-4
    plane_z = -(0.5 * material.thickness + margin + 0.5 * activation)  # at gap ĝ/2
    contact = ContactConfig.resolve([GroundPlane(point=(0.0, 0.0, plane_z))], model,
                                    margin=margin, activation=activation, friction=(mu,),
                                    check_resolution=8)
    model = ShellModel(surface, material, loads, boundary, probes, contact=contact)
    plan = SplinePlan(SplineConfig(spans=(2, 2), degree=3, domain=surface.domain.bounds))
    run = solve_spline(model, plan, SolverConfig(method="newton", load_steps=(1.0,),
                                                 newton_max_iterations=30))
    return run.probes["centre"][0], run.contact.friction.smoothing


def test_plate_on_a_tilted_plane_sticks_below_the_friction_angle_and_slides_above():
    mu = 0.4
    angle = math.degrees(math.atan(mu))  # 21.8°; measured: sticks at 21.7°, slides at 21.9°
    stuck, eps = plate_on_tilted_plane(angle - 0.5, mu)
    assert 0 < stuck < eps  # creeps less than the smoothing distance
    slid, _ = plate_on_tilted_plane(angle + 0.5, mu)
    assert slid > 100 * eps  # slides (limited by the Newton iterations only)


CONTACT_SCENES = ("napkin_sphere", "tablecloth_box", "sleeve_capsule", "sheet_torus")


@pytest.mark.parametrize("name", CONTACT_SCENES)
def test_contact_scene_quick_on_the_newton_path_stays_outside(name, tmp_path):
    """`ndf-sim SCENE --field spline --quick` (the napkin as the scene; the others on at most
    8 × 8 spans in one load step with at most 10 Newton steps per round, so not necessarily
    converged: the line search keeps every state outside whether or not Newton converged):
    the sheet reaches the obstacle (check points) and its faces stay outside the
    obstacles (smallest signed distance over 256² points ≥ −1e-4 m); the napkin centred on the
    sphere keeps the 4-fold symmetry of its setup (corner displacements equal to 1e-3
    relative) and converges."""
    scene = load_scene(SCENES / f"{name}.toml", field="spline")
    solver = dataclasses.replace(scene.quick_solver, progress=False)
    if name != "napkin_sphere":  # quick: one load step, at most 8 × 8 spans
        config = scene.field.config
        spans = tuple(min(8, n) for n in config.spans)
        scene = dataclasses.replace(scene, field=dataclasses.replace(
            scene.field, config=dataclasses.replace(config, spans=spans)))
        solver = dataclasses.replace(solver, load_steps=(1.0,), newton_max_iterations=10)
    out = tmp_path / "run"
    written = simulate(scene, OutputDir(out), solver=solver)
    contact = written["contact"]
    assert contact["evaluation_grid"] == [255, 255]
    assert contact["min_signed_distance"] >= -1e-4, contact
    assert contact["check_points"] > 0 and contact["newton_rounds"] > 0
    for obstacle in scene.model.contact.obstacles:
        assert (out / "obstacles" / f"{obstacle.name}.obj").stat().st_size > 0
    assert all(math.isfinite(v) for p in written["probes"].values() for v in p)
    if name == "napkin_sphere":
        corners = torch.tensor([written["probes"][f"corner_{s}"] for s in ("pp", "mp", "mm",
                                                                            "pm")], dtype=F64)
        assert float(corners[0, 2]) < -0.2  # it drapes
        mirrored = corners.abs()
        assert float((mirrored - mirrored[0]).abs().max()) <= 1e-3 * float(mirrored.max())
        assert written["levels"][-1]["converged"]


def test_line_search_never_steps_into_an_obstacle():
    """A plate falling onto a plane under a load far above the barrier's rule (κ set 1e5×
    too low): the barrier alone would let it sink through, the feasibility test keeps every
    point of the dense grid outside."""
    surface = Plane(bounds=((0.0, 0.1), (0.0, 0.1)))
    material = preset("cloth")
    loads = Loads(gravity=(0.0, 0.0, -9.81))
    boundary = BoundaryConditions([], surface.domain, surface=surface)
    model = ShellModel(surface, material, loads, boundary, (Probe("centre", (0.05, 0.05)),))
    config = ContactConfig.resolve([GroundPlane(point=(0.0, 0.0, -0.002))], model,
                                   activation=1e-3, check_resolution=12)
    config = ContactConfig(config.obstacles, config.thickness, config.activation,
                           config.stiffness * 1e-5, config.margin, 12)
    model = ShellModel(surface, material, loads, boundary, model.probes, contact=config)
    plan = SplinePlan(SplineConfig(spans=(2, 2), degree=3, domain=surface.domain.bounds))
    run = solve_spline(model, plan, SolverConfig(method="newton", load_steps=(1.0,),
                                                 newton_max_iterations=15))
    points = run.contact.points
    u = model.displacement(run.field, points.grid_xi)
    assert float(points.point_gaps(points.grid_r + u, 1.0).min()) > 0


NAPKIN = SCENES / "napkin_sphere.toml"


@pytest.mark.parametrize("value, message", [
    ("-0.2", r"obstacles\[0\].friction: must be >= 0"),
    ("inf", r"obstacles\[0\].friction: must be finite"),
    ('"high"', r"obstacles\[0\].friction: expected a number"),
])
def test_bad_friction_is_refused_with_exit_code_2(tmp_path, capsys, value, message):
    path = tmp_path / "scene.toml"
    path.write_text(NAPKIN.read_text().replace("radius = 0.15", f"radius = 0.15\nfriction = "
                                               f"{value}"))
    with pytest.raises(SceneError, match=message):
        load_scene(path)
    assert sim.main([str(path), "--out", str(tmp_path / "run"), "--quick", "--precision",
                     "f64"]) == 2
    assert "friction" in capsys.readouterr().err


def test_friction_is_refused_on_the_siren_path(tmp_path, capsys):
    path = tmp_path / "scene.toml"
    path.write_text(NAPKIN.read_text().replace("radius = 0.15", "radius = 0.15\nfriction = 0.3"))
    assert load_scene(path).model.contact.friction == (0.3,)
    assert sim.main([str(path), "--out", str(tmp_path / "run"), "--quick", "--precision",
                     "f64"]) == 2
    assert "friction is solved on the spline" in capsys.readouterr().err


def test_the_strain_treatment_reaches_the_contact_potential():
    """`ContactPotential.psd_hessian_blocks`: projected Newton's "strain" treatment in a
    contact round (before, Newton found no such method there and fell back to the clamped
    projection): the shell's blocks through the strains plus the barrier's, every block
    positive semi-definite at a state whose exact blocks are not."""
    from taichi_ndf.contact.newton_contact import ContactPotential
    from taichi_ndf.objective import Objective, ShellEnergyTerm
    from taichi_ndf.shell.hessian import jet_steps
    from tests.test_contact_barrier import displacement_near, surface_samples

    samples = surface_samples()
    term = ContactTerm([Sphere(centre=(0.0, 0.0, -0.3), radius=0.25)], offset=0.002,
                       activation=0.01, stiffness=300.0)
    u = displacement_near(term, samples)
    u[:, 1:] += 0.05 * torch.randn(len(samples), 5, 3, dtype=F64,
                                   generator=torch.Generator().manual_seed(6))
    objective = Objective(ShellEnergyTerm(preset("cotton_polyester"), Loads()))
    potential = ContactPotential(objective, (term,), 1.0)
    steps = jet_steps(samples.r_jets, u, 0.6, 1e-5)
    exact = potential.hessian_blocks(samples, u, steps=steps).reshape(-1, 18, 18)
    psd = potential.psd_hessian_blocks(samples, u, steps=steps).reshape(-1, 18, 18)
    barrier = term.hessian_blocks(samples, u, 1.0).reshape(-1, 18, 18)
    assert float(barrier.abs().max()) > 0
    shell = objective.hessian_blocks(samples, u, 1.0, steps=steps, psd=True)
    scale = float(psd.abs().max())
    assert torch.allclose(psd, barrier + shell.reshape(-1, 18, 18), rtol=0, atol=1e-12 * scale)
    assert float(torch.linalg.eigvalsh(exact).min()) < -1e-6 * scale
    assert float(torch.linalg.eigvalsh(psd).min()) >= -1e-12 * scale

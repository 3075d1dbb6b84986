"""Total potential energy: closed-form values of analytic fields, gradients against central
finite differences, point-load samples, per-sample stiffness and the public function."""

import math

import pytest
import torch

from taichi_ndf.geometry import Cone, Cylinder, Hemisphere, Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import SurfaceSamples, sample_surface
from taichi_ndf.shell import (
    LinearIsotropic,
    OrthotropicStVK,
    ShellEnergy,
    function_jets,
    potential_energy,
    preset,
    strains,
)

CLOTH = LinearIsotropic.from_young(5000.0, 0.3, 1e-3, 0.144)


def _samples(surface, n, seed=0, loads=None):
    return sample_surface(surface, n, loads, torch.Generator().manual_seed(seed))


def _energy_of_deformation(material, surface, deformed, n):
    samples = _samples(surface, n)
    u = function_jets(deformed, samples.xi) - samples.r_jets
    return ShellEnergy(material, Loads()).evaluate(samples, u, grad=False)


def test_pure_stretch_energy():
    stretch = 1.2
    plane = Plane(bounds=((0.0, 2.0), (0.0, 1.0)))
    result = _energy_of_deformation(
        CLOTH, plane, lambda xi: torch.stack((stretch * xi[:, 0], xi[:, 1], 0 * xi[:, 0]), 1),
        n=256)
    e11 = 0.5 * (stretch**2 - 1)
    assert result.internal == pytest.approx(0.5 * CLOTH.membrane_stiffness * e11**2 * 2.0,
                                            rel=1e-6)
    assert result.external == 0.0 and result.total == result.internal


def test_pure_bending_of_a_plate_into_a_cylinder():
    rho, length, width = 0.3, 1.5, 0.4  # rolled through 5 rad
    plane = Plane(bounds=((0.0, length), (0.0, width)))

    def rolled(xi):
        t = xi[:, 0] / rho
        return torch.stack((rho * torch.sin(t), xi[:, 1], rho * (1 - torch.cos(t))), dim=1)

    result = _energy_of_deformation(CLOTH, plane, rolled, n=256)
    expected = 0.5 * CLOTH.bending_stiffness / rho**2 * length * width
    assert result.internal == pytest.approx(expected, rel=1e-6)


def test_inflated_cylinder_energy():
    radius, length, factor = 2.0, 3.0, 1.01
    cylinder = Cylinder(radius=radius, length=length)

    def inflated(xi):
        r = cylinder.positions(xi)
        return torch.stack((factor * r[:, 0], factor * r[:, 1], r[:, 2]), dim=1)

    result = _energy_of_deformation(CLOTH, cylinder, inflated, n=512)
    hoop, curvature_change = 0.5 * (factor**2 - 1), (factor - 1) / radius
    psi = (0.5 * CLOTH.membrane_stiffness * hoop**2
           + 0.5 * CLOTH.bending_stiffness * curvature_change**2)
    assert result.internal == pytest.approx(psi * 2 * math.pi * radius * length, rel=1e-6)


@pytest.mark.parametrize("hole", [0.0, 0.3], ids=["disk_chart", "polar_chart"])
def test_inflated_hemisphere_energy(hole):
    radius, factor = 1.5, 1.02
    sphere = Hemisphere(radius=radius, hole_half_angle=hole)
    result = _energy_of_deformation(CLOTH, sphere, lambda xi: factor * sphere.positions(xi),
                                    n=4096)
    e, k, nu = 0.5 * (factor**2 - 1), (factor - 1) / radius, CLOTH.poisson_ratio
    psi = (1 + nu) * (CLOTH.membrane_stiffness * e**2 + CLOTH.bending_stiffness * k**2)
    assert torch.allclose(result.density, torch.full_like(result.density, psi), rtol=1e-10)
    area = 2 * math.pi * radius**2 * math.cos(hole)
    assert result.internal == pytest.approx(psi * area, rel=2e-3)  # Monte-Carlo area


def test_nonuniform_field_converges_to_the_closed_form():
    a = 0.2
    plane = Plane()
    result = _energy_of_deformation(
        CLOTH, plane, lambda xi: torch.stack((xi[:, 0] + a * xi[:, 0] ** 2, xi[:, 1],
                                              0 * xi[:, 0]), 1), n=16384)
    # ε₁₁ = 2aξ + 2a²ξ², Ψ = ½ D ε₁₁²
    expected = 0.5 * CLOTH.membrane_stiffness * 4 * a * a * (1 / 3 + a / 2 + a * a / 5)
    assert result.internal == pytest.approx(expected, rel=1e-4)


def test_clyde_pure_stretch_energy():
    canvas = preset("canvas")
    e11 = 0.05
    result = _energy_of_deformation(
        canvas, Plane(), lambda xi: torch.stack((math.sqrt(1 + 2 * e11) * xi[:, 0], xi[:, 1],
                                                 0 * xi[:, 0]), 1), n=64)
    (mu, alpha) = canvas.eta[0]
    eta = sum(m / al * ((e11**2 + 1) ** al - 1) for m, al in zip(mu, alpha, strict=True))
    assert result.internal == pytest.approx(0.5 * canvas.a11 * eta, rel=1e-6)


LOADS = Loads(gravity=(0.0, -3.0, -9.81), body_force=(0.4, 0.0, 0.1), pressure=2.0,
              point_loads=[((1.0, 0.5), (1.0, -2.0, 3.0))])
MATERIALS = {
    "linear": CLOTH,
    "orthotropic": OrthotropicStVK(3.0, 1.0, 2.0, 1.5, 1e-2, 0.1),
    "clyde": preset("canvas").scaled(50.0),
}


@pytest.mark.parametrize("name", MATERIALS)
def test_gradient_matches_central_differences(name):
    material = MATERIALS[name]
    cone = Cone(bottom_radius=1.0, top_radius=0.6, height=1.5)
    generator = torch.Generator().manual_seed(7)
    samples = _samples(cone, 48, loads=LOADS)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=generator, dtype=torch.float64)
    energy = ShellEnergy(material, LOADS)
    grad = energy.evaluate(samples, u).grad_u_jets
    h = 1e-6
    for _ in range(3):
        direction = torch.randn(u.shape, generator=generator, dtype=torch.float64)
        plus = energy.evaluate(samples, u + h * direction, grad=False).total
        minus = energy.evaluate(samples, u - h * direction, grad=False).total
        fd = (plus - minus) / (2 * h)
        assert float((grad * direction).sum()) == pytest.approx(fd, rel=1e-6, abs=1e-9)


def test_point_samples_never_evaluate_the_strain_energy():
    plane = Plane()
    samples = _samples(plane, 16, loads=Loads(point_loads=[((0.5, 0.5), (0.0, 0.0, -1.0))]))
    samples.r_jets[-1, 1:] = 0.0  # a degenerate point (√a = 0) carrying a point load
    u = torch.zeros(len(samples), 6, 3, dtype=torch.float64)
    u[:, 0, 2] = 0.1
    result = ShellEnergy(CLOTH, Loads()).evaluate(samples, u)
    assert result.total == pytest.approx(0.1)  # −P·u = 0.1 J
    assert torch.isfinite(result.grad_u_jets).all()
    assert result.grad_u_jets[-1, 0].tolist() == [0.0, 0.0, 1.0]
    assert result.density[-1] == 0.0 and result.sqrt_a[-1] == 0.0


def test_stiffness_terms_and_per_sample_stiffness():
    cone = Cone()
    samples = _samples(cone, 64)
    u = 0.05 * torch.randn(64, 6, 3, generator=torch.Generator().manual_seed(3),
                           dtype=torch.float64)
    for material in MATERIALS.values():
        energy = ShellEnergy(material, Loads())
        result = energy.evaluate(samples, u)
        recombined = sum(s * t for s, t in zip(material.stiffness, result.stiffness_terms,
                                               strict=True))
        assert recombined == pytest.approx(result.internal, rel=1e-12)
        assert energy.evaluate(samples, u, grad=False).total == result.total
        doubled = torch.tensor(material.stiffness, dtype=torch.float64).repeat(64, 1) * 2
        twice = energy.evaluate(samples, u, stiffness=doubled)
        assert twice.internal == pytest.approx(2 * result.internal, rel=1e-12)
        assert torch.allclose(twice.grad_u_jets, 2 * result.grad_u_jets)
        assert ShellEnergy(material.scaled(2.0), Loads()).evaluate(
            samples, u, grad=False).internal == pytest.approx(2 * result.internal, rel=1e-12)
    with pytest.raises(ValueError, match="stiffness must have shape"):
        ShellEnergy(CLOTH, Loads()).evaluate(samples, u, stiffness=torch.ones(64, 3))


def test_invalid_arguments_raise():
    samples = _samples(Plane(), 8)
    with pytest.raises(ValueError, match="u_jets"):
        ShellEnergy(CLOTH, Loads()).evaluate(samples, torch.zeros(8, 3))
    with pytest.raises(TypeError, match="material"):
        ShellEnergy("cloth", Loads())
    with pytest.raises(TypeError, match="loads"):
        ShellEnergy(CLOTH, {"gravity": (0, 0, -9.81)})
    with pytest.raises(ValueError, match="samples"):
        potential_energy(Plane(), CLOTH, Loads(), torch.zeros(8, 6, 3))


def test_potential_energy_of_an_explicit_displacement():
    plane = Plane()
    loads = Loads(gravity=(0.0, 0.0, -9.81))
    sag = 0.01

    def displacement(xi):  # (N, 2) -> (N, 3): derivatives by autograd
        bump = sag * torch.sin(math.pi * xi[:, 0]) * torch.sin(math.pi * xi[:, 1])
        return torch.stack((0 * bump, 0 * bump, -bump), dim=1)

    report = potential_energy(plane, CLOTH, loads, displacement, n=4096,
                              generator=torch.Generator().manual_seed(0))
    samples = report.samples
    u_jets = function_jets(displacement, samples.xi)
    direct = ShellEnergy(CLOTH, loads).evaluate(samples, u_jets, grad=False)
    assert report.total == pytest.approx(direct.total, rel=1e-12)
    assert report.internal > 0 > report.external
    # ∫ sin sin = 4/π²: external work −ρ_A g sag 4/π² (Monte Carlo)
    assert report.external == pytest.approx(-0.144 * 9.81 * sag * 4 / math.pi**2, rel=1e-3)
    eps, kappa, _ = strains(samples.r_jets, u_jets)
    assert torch.equal(report.membrane_strain, eps) and torch.equal(report.bending_strain, kappa)
    assert torch.equal(report.displacement, u_jets[:, 0])
    again = potential_energy(plane, CLOTH, loads, u_jets, samples=samples)
    assert again.total == report.total


def test_empty_sample_set():
    empty = SurfaceSamples(torch.zeros(0, 2, dtype=torch.float64),
                           torch.zeros(0, 6, 3, dtype=torch.float64),
                           torch.zeros(0, dtype=torch.float64),
                           torch.zeros(0, 3, dtype=torch.float64))
    result = ShellEnergy(CLOTH, Loads()).evaluate(empty, torch.zeros(0, 6, 3,
                                                                     dtype=torch.float64))
    assert result.total == 0.0 and result.grad_u_jets.shape == (0, 6, 3)


def test_per_sample_load_factor_scales_the_external_work_of_each_sample():
    cone = Cone(bottom_radius=1.0, top_radius=0.6, height=1.5)
    samples = _samples(cone, 48, loads=LOADS)
    generator = torch.Generator().manual_seed(11)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=generator, dtype=torch.float64)
    energy = ShellEnergy(MATERIALS["linear"], LOADS)
    plain = energy.evaluate(samples, u)
    ones = energy.evaluate(samples, u, load_factor=torch.ones(len(samples), dtype=torch.float64))
    assert ones.total == plain.total
    assert torch.equal(ones.grad_u_jets, plain.grad_u_jets)
    # A uniform factor is the scaled loads (point forces travel with the samples).
    scaled_samples = _samples(cone, 48, loads=LOADS.scaled(0.3))
    scaled = ShellEnergy(MATERIALS["linear"], LOADS.scaled(0.3)).evaluate(scaled_samples, u)
    uniform = energy.evaluate(samples, u, load_factor=torch.full((len(samples),), 0.3,
                                                                 dtype=torch.float64))
    assert uniform.external == pytest.approx(scaled.external, rel=1e-12)
    assert uniform.internal == plain.internal
    torch.testing.assert_close(uniform.grad_u_jets, scaled.grad_u_jets, rtol=1e-12, atol=1e-15)
    # Per sample: each sample's external work is its own factor times its work at factor 1.
    lam = torch.rand(len(samples), generator=generator, dtype=torch.float64)
    mixed = energy.evaluate(samples, u, load_factor=lam)
    per_sample = torch.tensor([energy.evaluate(_one(samples, i), u[i:i + 1], grad=False).external
                               for i in range(len(samples))], dtype=torch.float64)
    assert mixed.external == pytest.approx(float((lam * per_sample).sum()), rel=1e-12)
    with pytest.raises(ValueError, match="load_factor must have shape"):
        energy.evaluate(samples, u, load_factor=torch.ones(3, dtype=torch.float64))


def _one(samples, i):
    return SurfaceSamples(xi=samples.xi[i:i + 1], r_jets=samples.r_jets[i:i + 1],
                          weight=samples.weight[i:i + 1], point_force=samples.point_force[i:i + 1])


@pytest.mark.parametrize("name", MATERIALS)
def test_gradient_with_per_sample_load_factor_matches_central_differences(name):
    cone = Cone(bottom_radius=1.0, top_radius=0.6, height=1.5)
    generator = torch.Generator().manual_seed(13)
    samples = _samples(cone, 48, loads=LOADS)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=generator, dtype=torch.float64)
    lam = torch.rand(len(samples), generator=generator, dtype=torch.float64)
    energy = ShellEnergy(MATERIALS[name], LOADS)
    grad = energy.evaluate(samples, u, load_factor=lam).grad_u_jets
    h = 1e-6
    for _ in range(3):
        direction = torch.randn(u.shape, generator=generator, dtype=torch.float64)
        plus = energy.evaluate(samples, u + h * direction, grad=False, load_factor=lam).total
        minus = energy.evaluate(samples, u - h * direction, grad=False, load_factor=lam).total
        fd = (plus - minus) / (2 * h)
        assert float((grad * direction).sum()) == pytest.approx(fd, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("surface", [Hemisphere(radius=10.0), Cylinder(radius=0.3, length=1.0),
                                     Cone(bottom_radius=1.0, top_radius=0.6, height=1.5)],
                         ids=["hemisphere", "cylinder", "cone"])
def test_the_undeformed_curved_shell_stores_no_energy_to_the_last_bit(surface):
    # IEEE arithmetic (taichi_ndf.init's fast_math off): the strains a - A of u = 0 are exactly
    # zero; with the compiler's fast math the hemisphere stored 3.6e-30 J.
    samples = _samples(surface, 4096)
    result = ShellEnergy(CLOTH, Loads()).evaluate(samples, torch.zeros_like(samples.r_jets),
                                                 grad=False)
    assert result.internal == 0.0

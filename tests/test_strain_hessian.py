"""The shell energy's per-point Hessian blocks through its strains (`strain_energy_hessians`,
`ShellEnergyTerm.hessian_blocks`) against central differences of the Taichi-autodiff gradient
(`sample_hessians`), float64, for every material law, on a flat and a curved surface, with
per-sample stiffness and with zero-weight point-load samples."""

import pytest
import torch

from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.geometry import Cylinder, Plane
from taichi_ndf.objective import Objective, ShellEnergyTerm
from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.quadrature import span_quadrature
from taichi_ndf.shell.hessian import jet_steps, sample_hessians
from taichi_ndf.shell.materials import LinearIsotropic, OrthotropicStVK, preset

DT = torch.float64
MATERIALS = {
    "linear_isotropic": LinearIsotropic.from_young(1e6, 0.3, 0.01, 1.0),
    "orthotropic": OrthotropicStVK(a11=2e4, a12=3e3, a22=1e4, G12=4e3, thickness=0.01,
                                   areal_density=1.0),
    "clyde": preset("canvas"),
}
SURFACES = {"plane": Plane(bounds=((0.0, 1.0), (0.0, 1.0))),
            "cylinder": Cylinder(radius=0.5, length=1.0)}


def _samples(surface_name):
    surface = SURFACES[surface_name]
    loads = Loads(gravity=(0.0, 0.0, -9.81),
                  point_loads=(PointLoad((0.5, 0.5), (0.0, 0.0, -1.0)),))
    config = SplineConfig(spans=(2, 2), domain=surface.domain.bounds,
                          periodic=surface.domain.periodic)
    return span_quadrature(surface, config, loads, points=3, dtype=DT), loads


@pytest.mark.parametrize("surface_name", ["plane", "cylinder"])
@pytest.mark.parametrize("law", ["linear_isotropic", "orthotropic", "clyde"])
def test_strain_hessian_matches_central_differences_of_the_gradient(law, surface_name):
    samples, loads = _samples(surface_name)
    material = MATERIALS[law]
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=torch.Generator().manual_seed(1),
                           dtype=DT)
    stiffness = torch.tensor(material.stiffness, dtype=DT) * torch.linspace(
        0.5, 1.5, len(samples), dtype=DT)[:, None]
    objective = Objective(ShellEnergyTerm(material, loads, stiffness=stiffness))
    potential = objective.potential(0.7)
    steps = jet_steps(samples.r_jets, u, 1.0, 1e-5)
    got = potential.hessian_blocks(samples, u, steps=steps)
    expected = sample_hessians(potential, samples, u, steps=steps)
    assert float((got - expected).abs().max() / expected.abs().max()) <= 1e-6
    point_load = samples.weight == 0
    assert point_load.sum() == 1 and float(got[point_load].abs().max()) == 0.0

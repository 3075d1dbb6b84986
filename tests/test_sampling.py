"""Stratified jittered area samples and point-load samples."""

import math

import pytest
import torch

from taichi_ndf.geometry import Cylinder, Hemisphere, Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.sampling import SurfaceSamples, sample_surface


def test_area_samples():
    cylinder = Cylinder(radius=2.0, length=3.0)
    samples = sample_surface(cylinder, 1000, generator=torch.Generator().manual_seed(0))
    assert isinstance(samples, SurfaceSamples) and len(samples) == 1000
    assert samples.xi.dtype == torch.float64 and samples.r_jets.shape == (1000, 6, 3)
    assert torch.allclose(samples.weight, torch.full((1000,), 6 * math.pi / 1000,
                                                     dtype=torch.float64))
    assert samples.weight.sum().item() == pytest.approx(cylinder.domain.area, rel=1e-12)
    assert (samples.point_force == 0).all()
    assert cylinder.domain.contains(samples.xi).all()
    assert torch.equal(samples.r_jets, cylinder.jets(samples.xi))


def test_samples_are_reproducible_and_resampled():
    plane = Plane()
    a = sample_surface(plane, 64, generator=torch.Generator().manual_seed(1))
    b = sample_surface(plane, 64, generator=torch.Generator().manual_seed(1))
    c = sample_surface(plane, 64, generator=torch.Generator().manual_seed(2))
    assert torch.equal(a.xi, b.xi) and not torch.equal(a.xi, c.xi)


def test_point_load_samples_have_zero_weight_and_carry_the_force():
    plane = Plane(bounds=((0, 2), (0, 1)))
    loads = Loads(point_loads=[((0.5, 0.5), (0, 0, -2.0)), ((2.0, 1.0), (1.0, 0, 0))])
    samples = sample_surface(plane, 100, loads, torch.Generator().manual_seed(0))
    assert len(samples) == 102
    assert (samples.weight[100:] == 0).all() and (samples.weight[:100] > 0).all()
    assert samples.xi[100:].tolist() == [[0.5, 0.5], [2.0, 1.0]]
    assert samples.point_force[100:].tolist() == [[0, 0, -2.0], [1.0, 0, 0]]
    assert (samples.point_force[:100] == 0).all()
    with pytest.raises(ValueError, match="outside"):
        sample_surface(plane, 10, Loads(point_loads=[((3.0, 0.5), (0, 0, 1))]))


def test_masked_domain_keeps_the_samples_inside_and_weights_them_by_its_area():
    disk = Hemisphere(radius=1.0)
    samples = sample_surface(disk, 20000, generator=torch.Generator().manual_seed(0))
    kept = len(samples)
    assert kept / 20000 == pytest.approx(math.pi / 4, rel=5e-3)  # disk / square
    assert disk.domain.contains(samples.xi).all()
    assert torch.allclose(samples.weight, torch.full_like(samples.weight,
                                                          disk.domain.area / kept))


def test_conversion():
    samples = sample_surface(Plane(), 16, dtype=torch.float32)
    assert samples.xi.dtype == torch.float32 and samples.r_jets.dtype == torch.float32
    back = samples.to(dtype=torch.float64)
    assert back.weight.dtype == torch.float64 and back.point_force.dtype == torch.float64

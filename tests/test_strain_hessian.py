"""The shell energy's per-point Hessian blocks through its strains (`strain_energy_hessians`,
`ShellEnergyTerm.hessian_blocks`) against central differences of the Taichi-autodiff gradient
(`sample_hessians`), float64, for every material law, on a flat and a curved surface, with
per-sample stiffness and with zero-weight point-load samples."""

import dataclasses

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


@pytest.mark.parametrize("surface_name", ["plane", "cylinder"])
@pytest.mark.parametrize("law", ["linear_isotropic", "orthotropic", "clyde"])
def test_strain_hessian_is_exact_to_1e_8_against_extrapolated_differences(law, surface_name):
    """Against central differences of the full gradient at steps 2e-4 and 1e-4 of each
    channel's scale, Richardson-extrapolated (truncation ~step⁴: the reference itself is good
    to ~1e-10): the blocks agree to ≤ 1e-8 relative in float64 (the quadratic laws' law
    Hessian, differences at rest with unit steps, is exact to rounding; the Clyde law's central
    differences extrapolated: before, 2.9e-8 on the cylinder)."""
    samples, loads = _samples(surface_name)
    material = MATERIALS[law]
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=torch.Generator().manual_seed(1),
                           dtype=DT)
    potential = Objective(ShellEnergyTerm(material, loads)).potential(0.7)
    got = potential.hessian_blocks(samples, u, steps=jet_steps(samples.r_jets, u, 1.0, 1e-5))
    coarse, fine = (sample_hessians(potential, samples, u,
                                    steps=jet_steps(samples.r_jets, u, 1.0, relative))
                    for relative in (2e-4, 1e-4))
    reference = (4 * fine - coarse) / 3
    assert float((got - reference).abs().max() / reference.abs().max()) <= 1e-8


@pytest.mark.parametrize("law", ["orthotropic", "clyde"])
def test_psd_blocks_are_positive_semi_definite_and_exact_without_stress(law):
    """The "strain" treatment (`psd`): every block positive semi-definite at a deformed state
    with compressed and stretched points; at the undeformed state (no stress) the exact
    blocks."""
    samples, loads = _samples("cylinder")
    material = MATERIALS[law]
    potential = Objective(ShellEnergyTerm(material, loads)).potential(1.0)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=torch.Generator().manual_seed(2),
                           dtype=DT)
    steps = jet_steps(samples.r_jets, u, 1.0, 1e-5)
    exact = potential.hessian_blocks(samples, u, steps=steps).reshape(-1, 18, 18)
    psd = potential.psd_hessian_blocks(samples, u, steps=steps).reshape(-1, 18, 18)
    active = samples.weight != 0  # a point-load sample's blocks are zero
    exact, psd = exact[active], psd[active]
    scale = exact.abs().amax(dim=(1, 2))
    assert float(torch.linalg.eigvalsh(exact).min(dim=1).values.div(scale).min()) < -1e-3
    assert float(torch.linalg.eigvalsh(psd).min(dim=1).values.div(scale).min()) >= -1e-12
    zero = torch.zeros_like(u)
    steps = jet_steps(samples.r_jets, zero, 1.0, 1e-5)
    rest = potential.hessian_blocks(samples, zero, steps=steps)
    assert torch.allclose(potential.psd_hessian_blocks(samples, zero, steps=steps), rest,
                          rtol=0, atol=1e-12 * float(rest.abs().max()))


def test_point_blocks_compute_the_tangent_length_once_per_state_for_every_chunk(monkeypatch):
    """Blocks asked chunk by chunk of rows (as Newton's assembly asks, `PointBlocks`) take
    their strain steps from one RMS tangent length of all samples, computed once per state
    (`PointBlocks`, or by its caller for several at one state: `state_tangent`) and passed
    down to every chunk (`tangent=`): every chunk's blocks are those rows of all points'
    blocks, bit for bit, exact and psd; a new state computes it anew; a tangent length passed
    is the one used."""
    from taichi_ndf.minimise.point_blocks import PointBlocks, state_tangent
    from taichi_ndf.objective import terms
    from taichi_ndf.shell.hessian import flat_blocks

    samples, loads = _samples("cylinder")
    potential = Objective(ShellEnergyTerm(MATERIALS["clyde"], loads)).potential(1.0)
    u = 0.05 * torch.randn(len(samples), 6, 3, generator=torch.Generator().manual_seed(4),
                           dtype=DT)
    steps = jet_steps(samples.r_jets, u, 1.0, 1e-5)
    calls = []
    original = terms.tangent_length
    monkeypatch.setattr(terms, "tangent_length",
                        lambda *args: calls.append(1) or original(*args))

    class Linearisation:  # what PointBlocks reads of one
        def __init__(self):
            self.samples = samples

        def fd_steps(self, u_jets, parameters, relative):
            return steps

    for state in (u, 1.5 * u):
        for psd in (False, True):
            whole = flat_blocks(potential.hessian_blocks(samples, state, steps=steps) if not psd
                                else potential.psd_hessian_blocks(samples, state, steps=steps))
            calls.clear()
            blocks = PointBlocks(Linearisation(), potential, None, state, 1e-5, psd=psd)
            chunked = torch.cat([blocks(slice(s, s + 5)) for s in range(0, len(samples), 5)])
            assert len(samples) > 10 and len(calls) == 1
            assert torch.equal(chunked, whole)
            # a second PointBlocks at this state (Newton's projected K after its exact one)
            # given the scale computes none
            again = PointBlocks(Linearisation(), potential, None, state, 1e-5, psd=psd,
                                tangent=state_tangent(potential, samples, state))
            assert len(calls) == 2
            assert torch.equal(again(slice(5, 10)), whole[5:10]) and len(calls) == 2
    length = potential.tangent_length(samples, u)
    first = slice(0, 5)
    assert torch.equal(potential.hessian_blocks(samples, u, steps=steps, rows=first,
                                                tangent=length),
                       potential.hessian_blocks(samples, u, steps=steps)[first])
    assert not torch.equal(potential.hessian_blocks(samples, u, steps=steps, rows=first,
                                                    tangent=2 * length),
                           potential.hessian_blocks(samples, u, steps=steps)[first])


@pytest.mark.parametrize("law", ["linear_isotropic", "orthotropic"])
def test_a_quadratic_laws_hessian_is_computed_once_per_sample_set_and_rows(law, monkeypatch):
    """A quadratic law's d²E/ds² does not depend on the strains: it is computed on the first
    ask for a sample set, chunk of rows, weights and material (differences at rest, 7 law
    gradients besides dE/ds) and kept, so a later state's blocks take one law gradient (dE/ds).
    Every chunk's blocks at every state are the exact blocks of its own points, point by
    point: the one-sided law differences at that state (each point's 6 × 6 written out, a
    moderate step: exact for an affine gradient up to ~1e-9), through J = ds/dU and the stress
    part as before; new
    weights (the same r_jets) or another material are not served the kept ones."""
    from taichi_ndf.shell import strain_hessian
    from taichi_ndf.shell.energy import law_inputs

    samples, loads = _samples("cylinder")
    material = MATERIALS[law]
    term = ShellEnergyTerm(material, loads)
    calls = []
    original = strain_hessian._strain_gradient
    monkeypatch.setattr(strain_hessian, "_strain_gradient",
                        lambda *a, **k: calls.append(1) or original(*a, **k))

    def per_point(samples, u, rows):
        """The blocks of `rows` with each point's law Hessian by one-sided differences at its
        own strains (step 1e-3), point by point."""
        r, w = samples.r_jets[rows], samples.weight[rows]
        stiffness, params = law_inputs(material, len(w), None, DT, "cpu")
        strain = strain_hessian._strain_vector(r, u[rows])
        out = torch.zeros(len(w), 6, 3, 6, 3, dtype=DT)
        for q in range(len(w)):
            if w[q] == 0:
                continue
            def grad(s, q=q):
                return original(strain_hessian._law_kernel(material.law), r[q:q + 1].contiguous(),
                                s[None], weight=w[q:q + 1].contiguous(),
                                stiffness=stiffness[q:q + 1].contiguous(), params=params)[0]
            stress = grad(strain[q])
            hessian = torch.stack([(grad(strain[q] + 1e-3 * e) - stress) / 1e-3
                                   for e in torch.eye(6, dtype=DT)], dim=1)
            hessian = 0.5 * (hessian + hessian.T)
            x = (r[q] + u[rows][q])[None].contiguous()
            jac = x.new_zeros(1, 6, 6, 3)
            strain_hessian._strain_derivatives(x, stress[None].contiguous(), jac, jac, False)
            flat = jac.reshape(6, 18)
            block = (flat.T @ hessian @ flat).reshape(1, 6, 3, 6, 3)
            strain_hessian._strain_derivatives(x, stress[None].contiguous(), jac, block, True)
            out[q] = block[0]
        return out

    n = len(samples)
    chunks = (slice(0, n // 2), slice(n // 2, n))
    for k, scale in enumerate((0.05, 0.08)):
        u = scale * torch.randn(n, 6, 3, generator=torch.Generator().manual_seed(5), dtype=DT)
        steps = jet_steps(samples.r_jets, u, 1.0, 1e-5)
        for rows in chunks:
            calls.clear()
            got = term.hessian_blocks(samples, u, steps=steps, rows=rows)
            assert len(calls) == (8 if k == 0 else 1)  # dE/ds, and 7 at rest on the first ask
            expected = per_point(samples, u, rows)
            assert float((got - expected).abs().max() / expected.abs().max()) <= 1e-9
    heavier = type(samples)(samples.xi, samples.r_jets, 2 * samples.weight,
                            samples.point_force, samples.barrier_weight)
    calls.clear()
    got = term.hessian_blocks(heavier, u, steps=steps, rows=chunks[1])
    assert len(calls) == 8
    expected = per_point(heavier, u, chunks[1])
    assert float((got - expected).abs().max() / expected.abs().max()) <= 1e-9
    field = material.stiffness_names[-1]  # the bending stiffness (linear) or G12 (orthotropic)
    stiffer = ShellEnergyTerm(dataclasses.replace(
        material, **{field: 2 * getattr(material, field)}), loads)
    calls.clear()
    stiffer.hessian_blocks(heavier, u, steps=steps, rows=chunks[1])
    assert len(calls) == 8


def test_one_kept_law_hessian_per_sample_set_and_rows_whatever_the_materials_asked():
    """A material fit asks the blocks of one sample set at many materials: the kept law
    Hessians of that sample set stay one per chunk of rows (the last material's), not one per
    material seen; the blocks at each material are the ones computed afresh for it."""
    from taichi_ndf.shell import strain_hessian

    samples, loads = _samples("plane")
    material = MATERIALS["orthotropic"]
    n = len(samples)
    u = 0.05 * torch.randn(n, 6, 3, generator=torch.Generator().manual_seed(3), dtype=DT)
    steps = jet_steps(samples.r_jets, u, 1.0, 1e-5)
    rows = slice(0, n // 2)
    materials = [dataclasses.replace(material, a11=(1 + 0.1 * k) * material.a11)
                 for k in range(5)]
    for m in materials:
        got = ShellEnergyTerm(m, loads).hessian_blocks(samples, u, steps=steps, rows=rows)
    kept = strain_hessian._QUADRATIC_LAW_HESSIANS[samples.r_jets]
    assert len(kept) == 1
    strain_hessian._QUADRATIC_LAW_HESSIANS.pop(samples.r_jets)
    assert torch.equal(got, ShellEnergyTerm(materials[-1], loads).hessian_blocks(
        samples, u, steps=steps, rows=rows))

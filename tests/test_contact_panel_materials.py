"""A material per panel against obstacles (issue 30): the contact rounds build the shell term
per round on the round's points (`ContactMinimiser(..., base_at=)`, a `PanelEnergy` over each
panel's rows of the round's linearisation) and take its Hessian blocks on the rows with shell
weight (`PanelEnergy.restricted`). The two panels of test_contact_panels.py over the sphere
(2 load steps, 3 contact rounds, about 2 s CPU a solve)."""

from __future__ import annotations

import pytest
import torch
from test_contact_panels import _scene, _sheet

import taichi_ndf.discretise.multipatch as multipatch
from taichi_ndf.contact.newton_contact import _subset
from taichi_ndf.discretise import of_scene
from taichi_ndf.discretise.panel_energy import PanelEnergy

STIFF = {"preset": "cotton_polyester", "stiffness_scale": 10}  # the same density


def _solved(document: dict, *, panel_energy: bool = False):
    """The panels solved; panel_energy: the shell term a `PanelEnergy` even where the panels
    share one material (the one-material `ShellEnergyTerm` switched off in the module)."""
    scene = _scene(document)
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    with pytest.MonkeyPatch.context() as patch:
        if panel_energy:
            patch.setattr(multipatch, "ShellEnergyTerm", lambda material, loads: None)
        solution = panels.solve(scene.solver)
    panels.check_solution(solution)
    return scene, panels, solution


def _grid(n: int = 41) -> torch.Tensor:
    s = torch.linspace(0.0, 1.0, n, dtype=torch.float64)
    return torch.stack(torch.meshgrid(0.2 * s, 0.2 * s, indexing="ij"), dim=-1).reshape(-1, 2)


def _mean_sag(panels, patch: int) -> float:
    """The mean downward displacement [m] of a panel over a 41² grid."""
    return -float(panels.displacement_of(patch, _grid())[:, 0, 2].mean())


def test_panel_energy_restricted_to_rows_is_those_rows_of_the_whole():
    """The blocks of `restricted(keep)` on the kept samples are the kept rows of all
    samples' blocks (each panel's kept rows again one slice), two materials 10× apart."""
    document = _sheet(obstacle=False)
    document["panels"][1]["material"] = STIFF
    scene = _scene(document)
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    linear = panels._joined(panels._grids()[0], 1.0)
    samples = linear.samples
    energy = PanelEnergy(scene.field.materials, scene.model.loads,
                         [linear.rows(i) for i in range(2)])
    c = 0.01 * torch.randn(linear.coefficient_offsets[-1], 3, dtype=torch.float64,
                           generator=torch.Generator().manual_seed(0))
    u = linear.displacement(c)
    steps = torch.full((6,), 1e-6, dtype=torch.float64)
    keep = torch.zeros(len(samples), dtype=torch.bool)
    keep[::3] = True
    keep[linear.rows(1).start:linear.rows(1).start + 5] = True  # panel 1's first rows
    whole = energy.hessian_blocks(samples, u, 1.0, steps=steps)
    part = energy.restricted(keep).hessian_blocks(_subset(samples, keep), u[keep], 1.0,
                                                  steps=steps)
    # the shell's blocks are not bit-for-bit the same in batches of other sizes (~1e-11)
    assert float((part - whole[keep]).abs().max()) <= 1e-9 * float(whole.abs().max())
    assert not torch.equal(whole[linear.rows(0)][:5], whole[linear.rows(1)][:5])


def test_two_materials_drape_onto_a_sphere_without_entering_it():
    """The right panel 10 × as stiff (same density): every load step converges, contact
    acts (check points, rounds), every point of a 41² grid per panel stays outside the
    sphere, the seam stays closed; the stiff panel sags less than the soft one beside it and
    both less than with one material (the seam ties them)."""
    document = _sheet()
    document["panels"][1]["material"] = STIFF
    scene, panels, solution = _solved(document)
    _, same, _ = _solved(_sheet())
    assert all(panels.converged)
    assert solution.contact.count > 0 and solution.contact_counts["newton_rounds"] >= 2
    term = scene.model.contact.term()
    for i, patch in enumerate(scene.field.patches):
        x = patch.model.surface.jets(_grid())[:, 0] + panels.displacement_of(i, _grid())[:, 0]
        assert float(term.gaps(x, 1.0)[0].min()) > 0
    assert max(solution.document["seam_gaps"].values()) < 1e-6
    soft, stiff = _mean_sag(panels, 0), _mean_sag(panels, 1)
    assert 0 < stiff < 0.97 * soft  # 3.82 mm, 4.08 mm (4.84 mm with one material)
    assert soft < _mean_sag(same, 0) and stiff < 0.9 * _mean_sag(same, 1)


def test_the_panel_energy_path_with_one_material_is_the_one_material_path():
    """Both panels' shell a `PanelEnergy` of the same material (built per contact round)
    gives the one-material `ShellEnergyTerm` run's Π and coefficients to 1e-10."""
    _, one, a = _solved(_sheet())
    _, each, b = _solved(_sheet(), panel_energy=True)
    assert abs(b.energy - a.energy) <= 1e-10 * abs(a.energy)
    ca = torch.cat([f.coefficients.detach() for f in one.fields])
    cb = torch.cat([f.coefficients.detach() for f in each.fields])
    assert float((cb - ca).abs().max()) <= 1e-10 * float(ca.abs().max())
    assert b.iterations == a.iterations
    assert b.contact_counts == a.contact_counts

"""Contact for multi-patch (garment) runs (issue 30): a garment file with `[[obstacles]]` is
read (it was refused), and its panels are solved by the contact rounds over the patches' joint
chart (`minimise.multipatch.MultiPatchGrid`, the `ContactGrid` protocol of
`contact.newton_contact`): no point of the dense check grid inside the obstacle, Π decreasing,
converged, the seam closed."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from taichi_ndf.discretise import of_scene
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.multipatch import MultiPatchGrid
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

ROOT = Path(__file__).resolve().parents[1]


def _sheet(obstacle: bool = True, friction: float = 0.0) -> dict:
    """Two 0.2 m square panels side by side (seamed along x = 0.2 m), their outer edges
    clamped, sagging under gravity (8.5 mm at the seam without it) onto a sphere under the
    seam (its top 5 mm below)."""
    panel = {"width": 0.2, "height": 0.2, "spans": [4, 4]}
    document = {
        "name": "two_panels_on_a_sphere", "material": {"preset": "cotton_polyester"},
        "loads": {"gravity": [0.0, 0.0, -9.81]}, "training": {"method": "newton",
                                                               "load_steps": [0.5, 1.0]},
        "panels": [{"name": "left", **panel, "origin": [0.0, 0.0, 0.0],
                    "clamped": ["xi1_min"]},
                   {"name": "right", **panel, "origin": [0.2, 0.0, 0.0],
                    "clamped": ["xi1_max"]}],
        "seams": [{"name": "middle", "a": "left.xi1_max", "b": "right.xi1_min"}]}
    if obstacle:
        document["obstacles"] = [{"type": "sphere", "name": "ball", "centre": [0.2, 0.1, -0.055],
                                  "radius": 0.05, "friction": friction}]
        document["contact"] = {"check_resolution": 24}
    return document


def _scene(document: dict):
    return parse_scene(document, base_dir=ROOT / "scenes", path=ROOT / "scenes" / "x.toml")


def test_a_garment_with_obstacles_is_read_with_its_contact():
    scene = _scene(_sheet())
    assert scene.model.contact is not None
    assert [o.name for o in scene.model.contact.obstacles] == ["ball"]
    with pytest.raises(SceneError, match="contact: the scene has no"):
        _scene({**_sheet(obstacle=False), "contact": {"check_resolution": 24}})


def test_friction_on_panels_is_refused_in_one_line_by_the_reader():
    with pytest.raises(SceneError, match="friction is not supported on a garment"):
        _scene(_sheet(friction=0.3))


def test_panels_of_other_materials_are_read_with_obstacles():
    """A material per panel is read with obstacles (test_contact_panel_materials.py solves
    it; flat-cut panels with obstacles: test_contact_flat_panels.py)."""
    document = _sheet()
    document["panels"][1]["material"] = "denim"
    assert len(set(_scene(document).field.materials)) == 2


def test_the_joint_chart_maps_each_patch_to_its_own_grid():
    """`MultiPatchGrid.at_points` at joint ξ is each patch's `GridLinearisation.at_points` at
    its own ξ, the indices offset to the joint coefficient block; the joint surface's jets
    are the patch surfaces'."""
    scene = _scene(_sheet())
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    grids = [GridLinearisation(f, p.model.boundary) for p, f in
             zip(scene.field.patches, panels.fields, strict=True)]
    chart = MultiPatchGrid(grids, [p.model.surface for p in scene.field.patches])
    own = torch.tensor([[0.03, 0.11], [0.17, 0.01], [0.11, 0.19]], dtype=torch.float64)
    shift = torch.tensor([chart.shifts[1], 0.0], dtype=torch.float64)
    joint = torch.cat((own + shift, own))
    assert chart.patch_of(joint).tolist() == [1, 1, 1, 0, 0, 0]
    assert bool(chart.contains(joint).all())
    at = chart.at_points(joint, 1.0)
    for patch, rows in ((1, slice(0, 3)), (0, slice(3, 6))):
        alone = grids[patch].at_points(own, 1.0)
        offset = chart.coefficient_offsets[patch]
        assert torch.equal(at.index[rows], alone.index + offset)
        assert torch.allclose(at.offset[rows], alone.offset, rtol=1e-12, atol=1e-15)
        assert torch.allclose(at.jacobian.dense()[:, rows], alone.jacobian.dense(),
                              rtol=1e-12, atol=1e-12)
        assert torch.allclose(chart.surface.jets(joint[rows]),
                              scene.field.patches[patch].model.surface.jets(own))
    edge = torch.tensor([[0.0, 0.05], [0.2, 0.2]], dtype=torch.float64)
    assert torch.equal(chart.local(edge + shift, 1), edge)  # a seam's points stay on the edge
    gap = torch.tensor([[0.2 + 0.5 * chart.GAP * 0.2, 0.1]], dtype=torch.float64)
    assert not bool(chart.contains(gap).any())


def test_two_seamed_panels_sag_onto_a_sphere_without_entering_it():
    """The sheet sags 8.5 mm under gravity without the sphere, whose top is 5 mm below it;
    with it, every point of a dense grid over both panels (their edges, the seam's, included)
    stays outside (gap > 0 beyond h/2 + margin), some come within the activation distance
    (contact acted), each load step's Π decreases and converges, the seam stays closed."""
    scene = _scene(_sheet())
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    solution = panels.solve(scene.solver)
    panels.check_solution(solution)
    assert all(panels.converged)
    for t in scene.solver.load_steps:
        energies = [h.energy for h in solution.history if h.load_factor == t]
        assert energies[-1] < energies[0]
        pairs = zip(energies[:-1], energies[1:], strict=True)
        assert all(b <= a + 1e-12 * abs(a) for a, b in pairs)
    assert solution.contact.count > 0 and solution.contact_counts["newton_rounds"] >= 2
    config = scene.model.contact
    s = torch.linspace(0.0, 1.0, 41, dtype=torch.float64)
    xi = torch.stack(torch.meshgrid(0.2 * s, 0.2 * s, indexing="ij"), dim=-1).reshape(-1, 2)
    smallest = []
    for i, patch in enumerate(scene.field.patches):
        x = patch.model.surface.jets(xi)[:, 0] + panels.displacement_of(i, xi)[:, 0]
        smallest.append(float(config.term().gaps(x, 1.0)[0].min()))
    assert min(smallest) > 0
    assert min(smallest) < config.activation
    assert max(solution.document["seam_gaps"].values()) < 1e-4


def test_the_shipped_skirt_on_a_body_rests_on_it_without_entering():
    """scenes/skirt_body.toml at 4 × 2 spans per panel (3.7 s CPU): every load step converges,
    both panels come within the activation distance of the capsule and stay outside it on a
    61² grid per panel, the seams closed."""
    import tomllib

    path = ROOT / "scenes" / "skirt_body.toml"
    document = tomllib.loads(path.read_text())
    document["field"]["spans"] = [4, 2]
    scene = parse_scene(document, base_dir=path.parent, path=path)
    assert [o.name for o in scene.model.contact.obstacles] == ["body"]
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    solution = panels.solve(scene.solver)
    panels.check_solution(solution)
    assert all(panels.converged)
    config = scene.model.contact
    s = torch.linspace(0.0, 1.0, 61, dtype=torch.float64)
    for i, patch in enumerate(scene.field.patches):
        (lo1, hi1), (lo2, hi2) = patch.model.surface.domain.bounds
        xi = torch.stack(torch.meshgrid(lo1 + (hi1 - lo1) * s, lo2 + (hi2 - lo2) * s,
                                        indexing="ij"), dim=-1).reshape(-1, 2)
        x = patch.model.surface.jets(xi)[:, 0] + panels.displacement_of(i, xi)[:, 0]
        gap = float(config.term().gaps(x, 1.0)[0].min())
        assert 0 < gap < config.activation
    assert max(solution.document["seam_gaps"].values()) < 1e-6


def test_simulate_writes_a_garments_contact_summary_and_its_obstacles(tmp_path):
    """The app's one path on the two panels over the sphere: result.json's `contact` (the
    clearance of every panel's output surface, the rounds), the obstacle's mesh, a render."""
    import json

    import cv2

    from taichi_ndf.app.simulation import simulate
    from taichi_ndf.io import OutputDir

    document = _sheet()
    document["output"] = {"resolution": [8, 8]}
    out = tmp_path / "run"
    simulate(_scene(document), OutputDir(out))
    contact = json.loads((out / "result.json").read_text())["contact"]
    assert 0 < contact["min_gap"] < contact["activation_distance"]
    assert contact["newton_rounds"] >= 2 and contact["check_points"] > 0
    assert (out / "obstacles" / "ball.obj").is_file()
    pixels = cv2.imread(str(out / "render.png"))
    assert pixels is not None and pixels.std() > 0

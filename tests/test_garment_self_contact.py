"""Self-contact in a garment file (issue 30; docs/scenes.md "Self-contact"): the barrier
between the Gauss points of all panels, within a panel and across panels, neighbours measured
where the panels start (`discretise.panel_contact.StartPositions`): a cloth panel drooping
under gravity onto a held panel below crosses it without `[self_contact]` and rests on it
with it (no crossing in the output meshes, `io.mesh_check.self_intersections`); a flat-cut
skirt whose panels never come near equals the run without it; what remains refused says so
in one line."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
import torch

from taichi_ndf.app.panels import combined, part_meshes
from taichi_ndf.io.mesh_check import self_intersections
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError
from tests.test_contact_flat_panels import solve_garment

ROOT = Path(__file__).resolve().parents[1]
DROP = 0.05  # [m]: the upper panel's held edge above the lower panel


def _stack(self_contact: dict | None) -> dict:
    """Two 0.2 m square cotton panels, 6 × 6 spans: the lower clamped on its four edges at
    z = 0, the upper DROP above it clamped on one edge (a cantilever: it droops about 4 cm
    under gravity, through the lower one where nothing stops it)."""
    document = {
        "name": "stack", "material": {"preset": "cotton_polyester"},
        "loads": {"gravity": [0.0, 0.0, -9.81]},
        "field": {"type": "spline", "spans": [6, 6]},
        "training": {"method": "newton", "load_steps": [0.25, 0.5, 0.75, 1.0]},
        "panels": [
            {"name": "lower", "width": 0.2, "height": 0.2, "origin": [0.0, 0.0, 0.0],
             "clamped": ["xi1_min", "xi1_max", "xi2_min", "xi2_max"]},
            {"name": "upper", "width": 0.2, "height": 0.2, "origin": [0.0, 0.0, DROP],
             "clamped": ["xi1_min"]}]}
    if self_contact is not None:
        document["self_contact"] = self_contact
    return document


def _crossings(panels, resolution=(24, 24)) -> int:
    """Intersecting triangle pairs of the panels' output meshes joined into one mesh."""
    vertices, faces, _ = combined(part_meshes(panels.result_parts(panels.field), resolution))
    return len(self_intersections(vertices, faces))


def _middle_z(scene, panels) -> list[float]:
    xi = torch.tensor([[0.1, 0.1]], dtype=torch.float64)
    return [float(p.model.surface.jets(xi)[0, 0, 2] + panels.displacement_of(i, xi)[0, 0, 2])
            for i, p in enumerate(scene.field.patches)]


def test_a_drooping_panel_crosses_the_held_one_without_self_contact_and_rests_on_it_with():
    """Without [self_contact] the upper panel's middle ends below the lower one's and the
    meshes cross; with it (ĝ = 5 mm, the rest by default) every load step converges, the
    upper panel rests above the lower one, their middles about o + ĝ/2 apart (within a
    factor 1.5: the cantilever's bending carries part of its weight), and no triangle of the
    joined output meshes crosses another."""
    plain, free, _ = solve_garment(_stack(None))
    lower, upper = _middle_z(plain, free)
    assert upper < lower
    assert _crossings(free) > 0
    scene, panels, solution = solve_garment(_stack({"distance": 0.005}))
    config = scene.model.contact.self_contact
    assert all(panels.converged)
    lower, upper = _middle_z(scene, panels)
    rest = config.offset + 0.5 * config.activation
    assert rest / 1.5 < upper - lower < 1.5 * rest
    assert _crossings(panels) == 0


def _skirt(spans=(6, 4)) -> dict:
    """scenes/skirt_panels.toml on `spans`, its panels cut flat (their flat patterns lie on
    top of each other; their seams' sides start at the same place, the wrap)."""
    document = tomllib.loads((ROOT / "scenes" / "skirt_panels.toml").read_text())
    document["field"]["spans"] = list(spans)
    for p in document["panels"]:
        p.pop("probes", None)
        p.update(rest="flat")
    return document


def test_a_skirt_whose_panels_never_come_near_equals_the_run_without_self_contact():
    """The flat-cut two-panel skirt with [self_contact]: its panels meet only at the seams
    (neighbours where they start), so every load step's Π equals the run without it to
    1e-10 relative, the seams as closed (with neighbours by rest distance the two flat
    patterns' seam edges are 0.47 m apart and the sewn points would repel)."""
    document = _skirt()
    _, _, alone = solve_garment(document)
    document["self_contact"] = {"distance": 0.005}
    scene, panels, with_self = solve_garment(document)
    assert scene.model.contact.self_contact is not None
    assert not scene.model.contact.obstacles
    assert all(panels.converged)
    for a, b in zip(alone.document["load_steps"], with_self.document["load_steps"],
                    strict=True):
        assert b["energy"] == pytest.approx(a["energy"], rel=1e-10)
    for name, gap in alone.document["seam_gaps"].items():
        assert with_self.document["seam_gaps"][name] == pytest.approx(gap, rel=1e-6)


def test_a_seam_that_starts_wider_open_than_the_exclusion_allows_is_refused():
    document = _skirt((4, 2))
    document["self_contact"] = {"distance": 0.005}
    document["panels"][1]["wrap_radius"] = 0.2  # the back's sides start 0.1 m off the front's
    with pytest.raises(ValueError, match="self_contact: seam '(left|right)' starts"):
        solve_garment(document)


@pytest.mark.parametrize("change, message", [
    (lambda d: d["field"].update(type="siren"), "field.type"),
    (lambda d: d["self_contact"].update(offset=0.001), "self_contact.offset: 0.001 m is below"),
])
def test_what_a_garment_still_refuses_is_said_in_one_line(change, message):
    document = _stack({"distance": 0.005})
    change(document)
    path = ROOT / "scenes" / "x.toml"
    with pytest.raises(SceneError) as error:
        parse_scene(document, base_dir=path.parent, path=path)
    assert message in str(error.value)
    assert "\n" not in str(error.value)

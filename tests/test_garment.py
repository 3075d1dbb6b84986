"""Garment files and the multi-patch discretisation (issue 30; docs/scenes.md "Garments"):
panels read into a `MultiPatchPlan`, one-line errors naming the panel and the edge, and the
two-panel skirt solved in one Newton equal to the periodic one-patch skirt."""

from __future__ import annotations

import copy
import math
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch
from sim_process import sim_refusal

from taichi_ndf.app.panels import combined, panel_meshes
from taichi_ndf.discretise import MultiPatchDiscretisation, of_scene
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "skirt_panels.toml"
sys.path.insert(0, str(ROOT / "benchmarks"))


def _document() -> dict:
    return tomllib.loads(SCENE.read_text())


def _parse(document):
    return parse_scene(copy.deepcopy(document), base_dir=SCENE.parent, path=SCENE)


def test_the_skirt_reads_into_two_panels_and_two_seams():
    scene = _parse(_document())
    plan = scene.field
    assert [p.name for p in plan.patches] == ["front", "back"]
    assert [(s.spec.name, s.a, s.b, s.spec.a.edge, s.spec.b.edge) for s in plan.seams] == [
        ("left", 0, 1, "xi1_max", "xi1_min"), ("right", 1, 0, "xi1_max", "xi1_min")]
    assert plan.patches[0].config.spans == (16, 8)
    assert plan.patches[1].model.surface.domain.bounds[0][1] == pytest.approx(math.pi)
    assert isinstance(of_scene(scene), MultiPatchDiscretisation)


def _seam(document, index, **change):
    document["seams"][index].update(change)
    return document


def _panel(document, index, **change):
    document["panels"][index].update(change)
    return document


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: _seam(d, 0, a="frnt.xi1_max"), "seams[0].a: no panel 'frnt' (panels: front, "
                                               "back)"),
    (lambda d: _seam(d, 1, b="front.xi3_min"), "seams[1].b: panel 'front' has no edge "
                                                "'xi3_min'"),
    (lambda d: _seam(d, 1, a="front.xi1_max"), "seams[1]: edge 'front.xi1_max' is already in "
                                                "seam 'left'"),
    (lambda d: _panel(d, 1, height=0.5), "seams[0]: seam 'left': edge 'xi1_max' is 0.4 m long "
                                          "and edge 'xi1_min' 0.5 m"),
    (lambda d: _panel(d, 0, clamped=["waist"]), "panels[0]: panel 'front': no edge 'waist'"),
    (lambda d: _panel(d, 0, wrap_radius=0.05), "panels[0].wrap_radius: a 0.471238898 m wide"),
    (lambda d: _panel(d, 1, name="front"), "panels[1]: a second panel named 'front'"),
])
def test_bad_garments_are_refused_in_one_line_naming_the_panel_and_the_edge(change, message):
    with pytest.raises(SceneError) as err:
        _parse(change(_document()))
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_ndf_sim_refuses_a_bad_garment_with_exit_code_2(tmp_path):
    scene = tmp_path / "bad.toml"
    scene.write_text(SCENE.read_text().replace('a = "back.xi1_max"', 'a = "back.hem"'))
    assert "panel 'back' has no edge 'hem'" in sim_refusal(scene, tmp_path / "out")


def test_the_two_panel_skirt_is_the_periodic_skirt():
    """4 × 2 spans per panel in one Newton against the periodic cylinder on 8 × 2 (the same
    space: the seams transmit bending): Π within 1e-6 relative, u within 1e-9 m (measured at
    16 × 8: 5e-9 and 5e-11 m, benchmarks/RESULTS.md "Garments"); the seams closed; both
    panels in the combined mesh."""
    from garment_skirt import periodic_document

    document = _document()
    document["field"]["spans"] = [4, 2]
    scene = _parse(document)
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    solution = panels.solve(scene.solver)
    panels.check_solution(solution)
    assert all(panels.converged)
    periodic = of_scene(parse_scene(periodic_document(document, (4, 2)),
                                    base_dir=SCENE.parent))
    periodic.start(scene.solver, seed=0)
    reference = periodic.solve(scene.solver)
    assert solution.energy < 0
    assert abs(solution.energy - reference.energy) <= 1e-6 * abs(reference.energy)
    xi = torch.tensor([[0.3, 0.0], [1.5, 0.1], [3.0, 0.2]], dtype=torch.float64)
    for i in range(2):
        u = panels.displacement_of(i, xi)[:, 0]
        at = xi + torch.tensor([math.pi * i, 0.0], dtype=torch.float64)
        assert float((u - periodic.displacement(at, 1.0)[:, 0]).norm(dim=1).max()) < 1e-9
    assert float(panels.displacement_of(0, xi)[:, 0].norm(dim=1).max()) > 1e-5
    assert max(solution.document["seam_gaps"].values()) < 1e-9
    meshes = panel_meshes(scene.field, solution.field, (8, 4))
    vertices, faces, panel = combined(meshes)
    assert np.array_equal(np.unique(panel), [0.0, 1.0])
    assert faces.max() == len(vertices) - 1


def test_the_multi_patch_discretisation_implements_the_whole_protocol():
    import inspect

    from taichi_ndf.discretise import Discretisation

    for name, member in vars(Discretisation).items():
        if inspect.isfunction(member) and not name.startswith("_"):
            assert (inspect.signature(getattr(MultiPatchDiscretisation, name)).parameters.keys()
                    == inspect.signature(member).parameters.keys()), name


def test_simulate_writes_a_mesh_per_panel_and_the_combined_mesh(tmp_path):
    """The app's one path (`simulate`) on the skirt at 4 × 2 spans per panel."""
    import cv2

    from taichi_ndf.app.simulation import simulate
    from taichi_ndf.io import OutputDir, read_mesh

    document = _document()
    document["field"]["spans"] = [4, 2]
    document["output"]["resolution"] = [16, 8]
    scene = _parse(document)
    out = tmp_path / "run"
    result = simulate(scene, OutputDir(out))
    assert result["energy"] < 0 and set(result["probes"]) == {"front.hem"}
    assert [step["converged"] for step in result["load_steps"]] == [True, True]
    front, back = read_mesh(out / "mesh_front.obj"), read_mesh(out / "mesh_back.obj")
    both = read_mesh(out / "mesh.obj")
    assert len(both.vertices) == len(front.vertices) + len(back.vertices)
    assert b"property float panel" in (out / "mesh.ply").read_bytes()[:2000]
    pixels = cv2.imread(str(out / "render.png"))
    assert pixels is not None and pixels.std() > 0


class _Recorder:
    """The hooks a garment solve calls, in order, with the load factor of each record."""

    def __init__(self):
        self.calls = []

    def on_start(self, solver):
        self.calls.append(("start", solver.state.iteration))

    def on_record(self, solver, energy, grad_norm, load_factor):
        self.calls.append(("record", load_factor))

    def on_load_step(self, solver, load_factor):
        self.calls.append(("load_step", load_factor))

    def on_end(self, solver):
        self.calls.append(("end", solver.state.iteration))


def test_the_garment_solve_calls_the_callbacks_and_the_divergence_guard_stops_it():
    """The callbacks see every Newton iteration and each load step; the divergence guard
    (a Π of NaN at the second record) stops the solve with `DivergenceError` and resets
    every panel's coefficients to the last good state (here the first load step's start, zero:
    the panels' coefficients take Newton's iterate when a load step ends)."""
    from taichi_ndf.minimise.callbacks import DivergenceError, DivergenceGuard

    document = _document()
    document["field"]["spans"] = [4, 2]
    scene = _parse(document)
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    recorder = _Recorder()
    solution = panels.solve(scene.solver, callbacks=[DivergenceGuard(), recorder])
    records = [c for c in recorder.calls if c[0] == "record"]
    assert len(records) == solution.iterations > 2
    assert recorder.calls[0] == ("start", 0) and recorder.calls[-1] == ("end", len(records))
    assert [c for c in recorder.calls if c[0] == "load_step"] == [("load_step", 0.5),
                                                                 ("load_step", 1.0)]

    class Poison:  # Π turns NaN at the second iteration, after the first good state
        def on_record(self, solver, energy, grad_norm, load_factor):
            if solver.state.iteration == 1:
                for f in solver.field.fields:
                    f.coefficients.data.fill_(1.0)
                guard.on_record(solver, math.nan, grad_norm, load_factor)

    guard = DivergenceGuard()
    panels.start(scene.solver, seed=0)
    with pytest.raises(DivergenceError, match="diverged at iteration 1"):
        panels.solve(scene.solver, callbacks=[guard, Poison()])
    assert all(float(f.coefficients.abs().max()) == 0.0 for f in panels.fields)


def test_a_garment_run_opens_in_ndf_view_and_ndf_export_usd_and_refuses_obj(tmp_path, capsys):
    """A garment run's directory (skirt at 4 × 2 spans per panel) reads back as a run: the
    combined mesh with its reference and the panel property, the probes; ndf-export --format
    usd writes a stage with a panel primvar; ndf-export to OBJ (which evaluates a checkpoint)
    refuses it in one line naming the panels, exit 2; ndf-view's viewer opens it."""
    from taichi_ndf.app.simulation import simulate
    from taichi_ndf.cli import export
    from taichi_ndf.io import OutputDir
    from taichi_ndf.io.run_files import garment_panels, read_run

    document = _document()
    document["field"]["spans"] = [4, 2]
    document["output"]["resolution"] = [8, 4]
    out = tmp_path / "run"
    result = simulate(_parse(document), OutputDir(out), pictures=False)
    assert garment_panels(out) == ["front", "back"]
    run = read_run(out)
    assert run.reference.shape == run.deformed.shape == (2 * 9 * 5, 3)
    assert np.array_equal(np.unique(run.scalars["panel"]), [0.0, 1.0])
    assert run.available() == ["displacement", "membrane_strain", "bending_strain",
                               "energy_density"]
    assert float(run.quantity("displacement").max()) > 1e-5
    (probe,) = run.probes
    assert probe.name == "front.hem"
    np.testing.assert_array_equal(probe.displacement, result["probes"]["front.hem"])
    np.testing.assert_allclose(probe.reference, [0.0, 0.15, 0.0], atol=1e-7)

    (out / "checkpoint.pt").unlink()  # a run written before garments were checkpointed
    assert export.main([str(out), "--out", str(tmp_path / "skirt.obj")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "garment run (2 panels: front, back)" in err
    pxr = pytest.importorskip("pxr", reason="usd-core (taichi-ndf[usd]) is missing")
    stage_path = tmp_path / "skirt.usda"
    assert export.main([str(out), "--format", "usd", "--out", str(stage_path)]) == 0
    stage = pxr.Usd.Stage.Open(str(stage_path))
    mesh = stage.GetPrimAtPath("/World/deformed")
    panel = pxr.UsdGeom.PrimvarsAPI(mesh).GetPrimvar("panel").Get()
    np.testing.assert_array_equal(np.array(panel), run.scalars["panel"].astype(int))
    assert stage.GetPrimAtPath("/World/reference").IsValid()

    pytest.importorskip("viser", reason="viser (taichi-ndf[viewer]) is missing")
    from taichi_ndf.viewer.app import RunViewer

    viewer = RunViewer(run, port=0)
    try:
        vertices, values, _ = viewer.frame_state()
        np.testing.assert_array_equal(vertices, run.deformed)
        assert values is not None and len(values) == len(vertices)
    finally:
        viewer.stop()

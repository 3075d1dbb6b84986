"""A garment's run is a full run (issues 30, 26): its outputs come from the discretisation's
result parts (no branch on the field type in the app), it writes checkpoint.pt and resumes
from it bit for bit, ndf-export writes it to OBJ/PLY with one object per panel, and its
render has a legend naming the panels."""

from __future__ import annotations

import ast
import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf.discretise import of_scene
from taichi_ndf.minimise.callbacks import CheckpointWriter
from taichi_ndf.minimise.checkpoint import CheckpointError
from taichi_ndf.scene.reader import parse_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "skirt_panels.toml"
# Classes whose isinstance would tell field types apart.
FIELD_CLASSES = {"MultiPatchPlan", "SplinePlan", "FieldConfig", "SplineField", "NeuralField",
                 "MultiPatchDiscretisation", "SplineDiscretisation", "SirenDiscretisation",
                 "MultiPatchField", "PanelFields"}


def _scene(spans=(4, 2), resolution=(8, 4)):
    """The two-panel skirt on `spans` per panel (tiny: seconds), two load steps."""
    document = tomllib.loads(SCENE.read_text())
    document["field"]["spans"] = list(spans)
    document["output"]["resolution"] = list(resolution)
    return parse_scene(copy.deepcopy(document), base_dir=SCENE.parent, path=SCENE)


def test_the_app_tells_no_field_types_apart():
    """No isinstance on a field, plan or discretisation class anywhere in app/ (the result
    parts say what a run writes)."""
    for path in (ROOT / "taichi_ndf" / "app").glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance":
                names = {n.id for n in ast.walk(node.args[1]) if isinstance(n, ast.Name)}
                assert not names & FIELD_CLASSES, f"{path.name}:{node.lineno}"
            if isinstance(node, ast.ImportFrom):
                assert not {a.name for a in node.names} & FIELD_CLASSES, path.name


def test_result_parts_name_the_panels_or_none():
    scene = _scene()
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    parts = panels.result_parts(panels.field)
    assert [p.name for p in parts] == ["front", "back"]
    assert [p.model for p in parts] == [p.model for p in scene.field.patches]
    assert parts[1].field is panels.fields[1]
    napkin = parse_scene(tomllib.loads((ROOT / "scenes" / "napkin.toml").read_text()),
                         base_dir=ROOT / "scenes")
    single = of_scene(napkin)
    (part,) = single.result_parts("the field")
    assert part.name == "" and part.model is napkin.model and part.field == "the field"


def _untimed(record) -> dict:
    """A Newton record without its seconds (which differ between any two runs)."""
    return {k: v for k, v in vars(record).items() if not k.startswith("time_")}


class _StopAfterFirstLoadStep:
    """Ctrl-C after the first load step (as a user's, inside the solve)."""

    def on_load_step(self, solver, load_factor):
        raise KeyboardInterrupt


def _interrupted(scene, checkpoint) -> None:
    """The garment `scene` solved until Ctrl-C after its first load step (writing
    `checkpoint`)."""
    first = of_scene(scene)
    first.start(scene.solver, seed=0)
    with pytest.raises(KeyboardInterrupt):
        first.solve(scene.solver, callbacks=[CheckpointWriter(checkpoint),
                                             _StopAfterFirstLoadStep()])


def _whole_and_resumed(scene, tmp_path):
    """The garment `scene` solved through (its solution), and a second run interrupted after
    its first load step (Ctrl-C inside the solve: the checkpoint is written) started again
    from its checkpoint.pt (the discretisation, ready to solve), and that checkpoint."""
    whole = of_scene(scene)
    whole.start(scene.solver, seed=0)
    reference = whole.solve(scene.solver, callbacks=[CheckpointWriter(tmp_path / "whole.pt")])
    checkpoint = tmp_path / "checkpoint.pt"
    _interrupted(scene, checkpoint)
    resumed = of_scene(scene)
    resumed.start(scene.solver, seed=0, resume_from=checkpoint)
    return reference, resumed, checkpoint


def test_a_resumed_garment_run_equals_the_uninterrupted_one_bit_for_bit(tmp_path):
    """Interrupted after load step 1 (KeyboardInterrupt in a callback: the Ctrl-C path writes
    the checkpoint), resumed from checkpoint.pt: the same coefficients, Π, history, probes
    and load steps as the run that went through, bit for bit."""
    scene = _scene()
    reference, resumed, checkpoint = _whole_and_resumed(scene, tmp_path)
    assert resumed.state.load_step == 1 and len(resumed.state.steps) == 1
    assert [h.load_factor for h in resumed.state.history] == [0.5] * len(
        resumed.state.history)
    solution = resumed.solve(scene.solver, callbacks=[CheckpointWriter(checkpoint)])
    for a, b in zip(reference.field.fields, solution.field.fields, strict=True):
        assert torch.equal(a.coefficients, b.coefficients)
    assert solution.energy == reference.energy
    assert solution.probes == reference.probes
    assert solution.document == reference.document
    assert [_untimed(h) for h in solution.history] == [_untimed(h) for h in reference.history]
    # the end's checkpoint holds the final state: a resume of the finished run solves nothing
    done = of_scene(scene)
    done.start(scene.solver, seed=0, resume_from=checkpoint)
    again = done.solve(scene.solver)
    assert again.energy == reference.energy and again.iterations == reference.iterations


def test_a_checkpoint_of_other_panels_or_load_steps_is_refused_in_one_line(tmp_path):
    scene = _scene()
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    checkpoint = tmp_path / "checkpoint.pt"
    panels.state.save(checkpoint)
    coarser = _scene(spans=(2, 2))
    with pytest.raises(CheckpointError, match="not this garment's panels") as err:
        of_scene(coarser).start(coarser.solver, seed=0, resume_from=checkpoint)
    assert "\n" not in str(err.value)

    from taichi_ndf.field import SplineField
    from taichi_ndf.minimise.state import State

    spline = tmp_path / "spline.pt"  # one spline field's (a single-grid run's) state
    State.newton(SplineField(scene.field.patches[0].config)).save(spline)
    with pytest.raises(CheckpointError, match="holds a SplineField, not this garment's panels"):
        panels.start(scene.solver, seed=0, resume_from=spline)


def test_ndf_sim_resumes_a_garment_and_refuses_another_scenes_checkpoint(tmp_path):
    """simulate writes checkpoint.pt for a garment; resumed (a finished run: nothing left to
    solve) it writes the same meshes; a checkpoint of another garment is refused in one line
    naming the sections that differ."""
    from taichi_ndf.app.simulation import SimulationError, simulate
    from taichi_ndf.io import OutputDir

    scene = _scene()
    out = tmp_path / "run"
    result = simulate(scene, OutputDir(out), pictures=False)
    assert (out / "checkpoint.pt").is_file()
    meshes = {name: (out / name).read_bytes() for name in ("mesh.obj", "mesh_front.obj",
                                                          "mesh_back.ply", "probes.json")}
    again = simulate(scene, OutputDir(out, overwrite=True), resume=True, pictures=False)
    assert again["energy"] == result["energy"] and again["probes"] == result["probes"]
    assert meshes == {name: (out / name).read_bytes() for name in meshes}
    other = _scene(spans=(2, 2))
    with pytest.raises(SimulationError, match=r"--resume: the scene changed .*\[field\] "
                                              "differ") as err:
        simulate(other, OutputDir(out, overwrite=True), resume=True, pictures=False)
    assert "\n" not in str(err.value)


def test_resume_with_other_load_steps_is_refused(tmp_path):
    scene = _scene()
    checkpoint = tmp_path / "checkpoint.pt"
    _interrupted(scene, checkpoint)
    import dataclasses

    other = dataclasses.replace(scene.solver, load_steps=(0.25, 1.0))
    with pytest.raises(CheckpointError, match=r"finished the load steps \[0.5\]"):
        of_scene(scene).start(other, seed=0, resume_from=checkpoint)
    assert np.isfinite(float(torch.load(checkpoint, weights_only=True)["extra"]["steps"][0][
        "energy"]))


def test_ndf_export_writes_a_garment_with_one_object_per_panel(tmp_path, capsys):
    """From the run's checkpoint.pt at the run's own resolution: the OBJ read back by trimesh
    has an object per panel, named by it, with the vertices of the run's mesh_<panel>.obj
    (same count, same positions); the PLY has the run's combined vertices and its `panel`
    property, and names the panels in its header; the USD stage (from the run's files) has a
    face subset per panel, named by it."""
    import trimesh

    from taichi_ndf.app.simulation import simulate
    from taichi_ndf.cli import export
    from taichi_ndf.io import OutputDir, read_mesh

    out = tmp_path / "run"
    simulate(_scene(), OutputDir(out), pictures=False)
    obj, ply = tmp_path / "skirt.obj", tmp_path / "skirt.ply"
    assert export.main([str(out), "--out", str(obj), "--resolution", "8", "4"]) == 0
    assert "2 panels (front 45 vertices, back 45 vertices)" in capsys.readouterr().out
    scene = trimesh.load_scene(obj, process=False, maintain_order=True, split_objects=True)
    assert sorted(scene.geometry) == ["back", "front"]
    for name, mesh in scene.geometry.items():
        run = read_mesh(out / f"mesh_{name}.obj")
        used = np.unique(mesh.faces)
        assert len(used) == len(run.vertices) == 45
        np.testing.assert_array_equal(mesh.vertices[used], run.vertices)
        assert len(mesh.faces) == len(run.faces)
    assert export.main([str(out), "--out", str(ply), "--resolution", "8", "4"]) == 0
    combined = trimesh.load(ply, process=False)
    run = read_mesh(out / "mesh.ply")
    np.testing.assert_array_equal(combined.vertices, run.vertices)
    panel = combined.metadata["_ply_raw"]["vertex"]["data"]["panel"]
    assert np.array_equal(np.bincount(panel.astype(int)), [45, 45])
    assert b"comment panel 0 front\ncomment panel 1 back\n" in ply.read_bytes()[:400]

    pxr = pytest.importorskip("pxr", reason="usd-core (taichi-ndf[usd]) is missing")
    stage_path = tmp_path / "skirt.usda"
    assert export.main([str(out), "--format", "usd", "--out", str(stage_path)]) == 0
    stage = pxr.Usd.Stage.Open(str(stage_path))
    mesh = pxr.UsdGeom.Mesh(stage.GetPrimAtPath("/World/deformed"))
    subsets = pxr.UsdGeom.Subset.GetGeomSubsets(mesh, pxr.UsdGeom.Tokens.face, "panel")
    assert [s.GetPrim().GetName() for s in subsets] == ["front", "back"]
    faces = [np.array(s.GetIndicesAttr().Get()) for s in subsets]
    assert [len(f) for f in faces] == [64, 64]
    np.testing.assert_array_equal(np.concatenate(faces), np.arange(128))


def _swatch_found(image: np.ndarray, bgr) -> bool:
    """Whether a 5 × 5 block of pixels of exactly this colour is in the image (a swatch)."""
    same = (image == np.asarray(bgr, dtype=np.uint8)).all(axis=2).astype(np.int32)
    blocks = same.cumsum(0).cumsum(1)
    b = np.pad(blocks, ((1, 0), (1, 0)))
    counts = b[5:, 5:] - b[:-5, 5:] - b[5:, :-5] + b[:-5, :-5]
    return bool((counts == 25).any())


def test_a_garment_render_has_a_categorical_legend_naming_the_panels(tmp_path):
    """render.png of the skirt's panels (at the placement: no solve): write_panel_outputs
    returns the legend it drew, naming the panels in order, each with its own palette colour;
    the picture holds each colour's swatch and no colour bar (none of viridis's colours)."""
    import cv2

    from taichi_ndf.app.panels import write_panel_outputs
    from taichi_ndf.io import OutputDir
    from taichi_ndf.render.mpl import VIRIDIS_BGR

    scene = _scene()
    panels = of_scene(scene)
    panels.start(scene.solver, seed=0)
    out = OutputDir(tmp_path / "run")
    legend = write_panel_outputs(out, panels.result_parts(panels.field), (8, 4))
    assert [name for name, _ in legend.entries()] == ["front", "back"]
    (front, a), (back, b) = legend.entries()
    assert a != b
    image = cv2.imread(str(tmp_path / "run" / "render.png"))
    assert _swatch_found(image, a) and _swatch_found(image, b)
    # a colour bar shows nearly all of viridis's colours (the old render: 238 of 240)
    viridis = {tuple(c) for c in VIRIDIS_BGR[8:-8].tolist()}
    assert len(viridis & {tuple(p) for p in image.reshape(-1, 3).tolist()}) < 10
    assert write_panel_outputs(out, panels.result_parts(panels.field), (8, 4),
                               pictures=False) is None


def test_a_resumed_flat_cut_gathered_skirt_equals_the_uninterrupted_one(tmp_path):
    """Flat-cut panels with a gathered waist (`held_radius`): after a resume the seams are
    still sewn from the placement and the held rows still move from it (not from the
    resumed coefficients), so the resumed run ends bit for bit where the whole one does."""
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from garment_skirt import flat_document

    document = flat_document("flat", 7.68e-7, (4, 2))
    document["training"]["load_steps"] = [0.5, 1.0]
    for panel in document["panels"]:
        panel["held_radius"] = 0.12
    scene = parse_scene(document, base_dir=SCENE.parent, path=SCENE)
    reference, resumed, _ = _whole_and_resumed(scene, tmp_path)
    solution = resumed.solve(scene.solver)
    for a, b in zip(reference.field.fields, solution.field.fields, strict=True):
        assert torch.equal(a.coefficients, b.coefficients)
    assert solution.energy == reference.energy

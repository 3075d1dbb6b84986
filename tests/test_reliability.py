"""Issue 15: each numbered defect of the reliability audit, reproduced in-process.

Every test here failed before its fix; the defect number is in the test's name.
"""

from __future__ import annotations

import ast
import json
import logging
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from test_cli import (
    RUNTIME,
    SMALL_NAPKIN,
    interrupt_after_saving,
    run_sim,
    small_napkin,
    write_scene,
)

from taichi_ndf.cli import export
from taichi_ndf.io import read_mesh, write_obj
from taichi_ndf.minimise.checkpoint import CheckpointError, load_checkpoint

ROOT = Path(__file__).resolve().parents[1]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` by relative path, with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


# -- 1: a run directory never mixes two runs ------------------------------------------------

@pytest.mark.parametrize(("failure", "code"), [(MemoryError, 2), (KeyboardInterrupt, 130)],
                         ids=["out-of-memory", "ctrl-c"])
def test_1_failed_output_writing_keeps_the_previous_complete_run(tmp_path, monkeypatch, capsys,
                                                                 failure, code):
    import taichi_ndf.app.outputs as outputs  # the one output writer (`write_field_outputs`)

    scene = small_napkin(tmp_path)
    out = tmp_path / "run"
    assert run_sim(scene, "--out", out) == 0
    before = snapshot(out)
    capsys.readouterr()

    def fail(*args, **kwargs):
        raise failure()

    monkeypatch.setattr(outputs, "write_render", fail)
    assert run_sim(scene, "--out", out, "--overwrite", "--iters", "15") == code
    line = one_line(capsys.readouterr().err)
    staging = tmp_path / "run.incomplete"
    assert str(staging) in line
    assert snapshot(out) == before  # the previous run, byte for byte
    assert load_checkpoint(staging / "checkpoint.pt").extra["iteration"] == 15

    monkeypatch.undo()
    assert run_sim(scene, "--out", out, "--resume", "--iters", "15") == 0
    result = json.loads((out / "result.json").read_text())
    assert result["iterations"] == 15
    assert load_checkpoint(out / "checkpoint.pt").extra["iteration"] == 15
    assert not staging.exists()


def test_1_an_interrupted_first_run_leaves_only_a_named_incomplete_attempt(tmp_path,
                                                                           monkeypatch, capsys):
    interrupt_after_saving(monkeypatch)
    out = tmp_path / "run"
    assert run_sim(small_napkin(tmp_path), "--out", out) == 130
    line = one_line(capsys.readouterr().err)
    assert "interrupted" in line and "--resume" in line
    assert not out.exists()
    assert load_checkpoint(tmp_path / "run.incomplete" / "checkpoint.pt").extra["iteration"] == 5


# -- 2: unreadable checkpoints ---------------------------------------------------------------

@pytest.fixture(scope="module")
def good_checkpoint(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("good")
    assert run_sim(small_napkin(folder), "--out", folder / "run", "--iters", "2") == 0
    return folder / "run" / "checkpoint.pt"


def _damaged(kind: str, good: Path, tmp_path: Path) -> Path:
    data = good.read_bytes()
    path = tmp_path / "checkpoint.pt"
    if kind == "directory":
        path.mkdir()
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif kind == "bit-flipped":
        flipped = bytearray(data)
        for i in range(0, len(flipped), 97):
            flipped[i] ^= 0x10
        path.write_bytes(bytes(flipped))
    elif kind == "random":
        path.write_bytes(np.random.default_rng(0).bytes(4096))
    elif kind == "text":
        path.write_text("this is not a checkpoint\n")
    elif kind == "foreign":
        import torch

        torch.save({"kind": "taichi_ndf.minimise.checkpoint", "format_version": 1,
                    "architecture": {"width": "wide"}}, path)
    return path


@pytest.mark.parametrize("kind", ["directory", "empty", "truncated", "bit-flipped", "random",
                                  "text", "foreign"])
def test_2_export_of_an_unreadable_checkpoint_is_one_line(tmp_path, capsys, good_checkpoint,
                                                          kind):
    path = _damaged(kind, good_checkpoint, tmp_path)
    with pytest.raises(CheckpointError, match=str(path)):
        load_checkpoint(path)
    code = export.main([str(path), "--out", str(tmp_path / "m.obj"), *RUNTIME])
    line = one_line(capsys.readouterr().err)
    assert code == 2 and str(path) in line, line
    assert not (tmp_path / "m.obj").exists()


# -- 3: scene paths in checkpoints ------------------------------------------------------------

# The small napkin of test_cli on a template mesh (sheet.obj next to the scene), 2 iterations.
TEMPLATE_SCENE = SMALL_NAPKIN.format(lr=1e-3).replace(
    'type = "plane"\nbounds = [[0.0, 1.0], [0.0, 1.0]]', 'type = "mesh"\npath = "sheet.obj"'
).replace("iterations = 10", "iterations = 2")
assert 'path = "sheet.obj"' in TEMPLATE_SCENE


def write_sheet(path: Path, n: int = 4, *, mirrored: bool = False) -> None:
    u, v = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="xy")
    uv = np.column_stack([u.ravel(), v.ravel()])
    vertices = np.column_stack([uv, np.zeros(len(uv))]) * 0.5
    if mirrored:
        uv = uv * [-1.0, 1.0] + [1.0, 0.0]
    faces = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    write_obj(path, vertices, np.array(faces), uvs=uv)


def test_3_export_of_a_template_run_works_from_another_directory(tmp_path, monkeypatch):
    scene_dir = tmp_path / "scenes"
    scene_dir.mkdir()
    write_sheet(scene_dir / "sheet.obj")
    write_scene(scene_dir, TEMPLATE_SCENE)
    monkeypatch.chdir(tmp_path)
    assert run_sim("scenes/scene.toml", "--out", "run") == 0
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert export.main(["../run/checkpoint.pt", "--out", "m.obj", *RUNTIME]) == 0
    assert len(read_mesh("m.obj").vertices) == 25


# -- 4: the scene's seed ---------------------------------------------------------------------

def test_4_the_scenes_seed_is_used_unless_seed_is_given(tmp_path):
    scene = write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3).replace(
        "iterations = 10", "iterations = 2\nseed = 7"))
    assert run_sim(scene, "--out", tmp_path / "a") == 0
    result = json.loads((tmp_path / "a" / "result.json").read_text())
    assert result["seed"] == 7 and result["resolved"]["solver"]["seed"] == 7
    assert run_sim(scene, "--out", tmp_path / "b", "--seed", "0") == 0
    assert json.loads((tmp_path / "b" / "result.json").read_text())["seed"] == 0


# -- 5: the divergence message ---------------------------------------------------------------

def test_5_divergence_before_the_first_checkpoint_names_no_checkpoint(tmp_path, capsys):
    assert run_sim(small_napkin(tmp_path, lr=1e30), "--out", tmp_path / "run") == 2
    line = one_line(capsys.readouterr().err)
    assert "diverged at iteration 1" in line
    assert "checkpoint.pt" not in line, line


# -- 6: tracebacks ---------------------------------------------------------------------------

def test_6_nan_observation_is_refused(tmp_path, capsys):
    from inverse.cli.fit_material import main as fit_material

    observed = tmp_path / "o.obj"
    observed.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    code = fit_material(["--scene", str(ROOT / "scenes" / "inverse" / "cantilever_strip.toml"),
                         "--observed", str(observed), "--point-cloud", "--estimate", "bending",
                         "--out", str(tmp_path / "out")])
    line = one_line(capsys.readouterr().err)
    assert code == 2 and str(observed) in line and "finite" in line
    assert not (tmp_path / "out").exists()


def test_6_a_picture_named_obj_as_template_is_one_line(tmp_path, capsys, monkeypatch):
    import cv2

    # As in a plain install: trimesh's optional text-encoding guesser is missing.
    monkeypatch.setitem(sys.modules, "charset_normalizer", None)

    noise = np.random.default_rng(0).integers(0, 255, (16, 16, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "picture.png"), noise)
    (tmp_path / "sheet.obj").write_bytes((tmp_path / "picture.png").read_bytes())
    scene = write_scene(tmp_path, TEMPLATE_SCENE)
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    line = one_line(capsys.readouterr().err)
    assert "geometry" in line and "sheet.obj" in line


def test_6_a_resolution_beyond_memory_is_refused_before_work(tmp_path, capsys, good_checkpoint):
    code = export.main([str(good_checkpoint), "--resolution", "100000",
                        "--out", str(tmp_path / "m.obj"), *RUNTIME])
    line = one_line(capsys.readouterr().err)
    assert code == 2 and "--resolution" in line and "memory" in line
    scene = write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3).replace(
        "resolution = [16, 16]", "resolution = [100000, 100000]"))
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    line = one_line(capsys.readouterr().err)
    assert "output.resolution" in line and "memory" in line
    assert not (tmp_path / "run").exists() and not (tmp_path / "run.incomplete").exists()


# -- 7: misleading or late messages ----------------------------------------------------------

@pytest.mark.parametrize("text", [
    "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "f 1/1 2/2 3/3 4/4\n",
    "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\nv 3 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "vt 1.5 1\nf 1/1 2/2 3/3 4/4\nf 2/2 5/5 3/3\n",
], ids=["one-quad", "quad-and-triangle"])
def test_7_quads_with_uvs_keep_their_uvs(tmp_path, text):
    path = tmp_path / "quad.obj"
    path.write_text(text)
    mesh = read_mesh(path)
    count = len(mesh.vertices)
    np.testing.assert_array_equal(mesh.vertices[:4, 0], [0, 2, 2, 0])
    np.testing.assert_allclose(mesh.uvs, [[0, 0], [1, 0], [1, 1], [0, 1], [1.5, 1]][:count])
    assert len(mesh.faces) == count - 2
    # Triangles of the quad keep its orientation (counter-clockwise in UV).
    corners = mesh.uvs[mesh.faces]
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0)


@pytest.mark.parametrize(("edit", "message"), [
    (("bounds = [[0.0, 1.0], [0.0, 1.0]]", "bounds = [0.0, 1.0]"), "geometry.bounds"),
    (("bounds = [[0.0, 1.0], [0.0, 1.0]]", "bounds = [[0.0, 1.0], [0.0, \"x\"]]"),
     "geometry.bounds"),
], ids=["flat-bounds", "string-bound"])
def test_7_bad_bounds_name_the_key(tmp_path, capsys, edit, message):
    scene = write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3).replace(*edit))
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    assert message in one_line(capsys.readouterr().err)


def test_7_binary_scene_names_the_file(tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    assert str(scene) in one_line(capsys.readouterr().err)


def test_7_sft_refuses_a_nan_physics_weight_before_work(tmp_path, capsys):
    from inverse.cli.sft import main as sft

    with pytest.raises(SystemExit) as stop:
        sft(["--frames", str(tmp_path / "f"), "--camera", str(tmp_path / "c.json"),
             "--template", str(tmp_path / "t.obj"), "--texture", str(tmp_path / "x.png"),
             "--out", str(tmp_path / "out"), "--physics-weight", "nan"])
    line = one_line(capsys.readouterr().err)
    assert stop.value.code == 2 and "--physics-weight" in line and "finite" in line
    # The configuration refuses it too (for callers that do not parse a command line).
    from inverse.sft.settings import ReconstructionConfig

    with pytest.raises(ValueError, match="physics_weight"):
        ReconstructionConfig(physics_weight=float("nan"))


def test_7_resume_with_a_changed_scene_says_so(tmp_path, capsys):
    scene = small_napkin(tmp_path)
    out = tmp_path / "run"
    assert run_sim(scene, "--out", out, "--iters", "2") == 0
    capsys.readouterr()
    scene.write_text(scene.read_text().replace("-9.81", "-3.0"))
    assert run_sim(scene, "--out", out, "--resume", "--iters", "4") == 2
    line = one_line(capsys.readouterr().err)
    assert "scene changed" in line and "loads" in line


# -- 8: accepted silently --------------------------------------------------------------------

def test_8_zero_iterations_is_refused(tmp_path, capsys):
    scene = write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3).replace(
        "iterations = 10", "iterations = 0"))
    assert run_sim(scene, "--out", tmp_path / "run") == 2
    assert "training.iterations" in one_line(capsys.readouterr().err)
    assert run_sim(small_napkin(tmp_path), "--out", tmp_path / "run", "--iters", "0") == 2
    assert "--iterations 0" in one_line(capsys.readouterr().err)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("edit", [{"fx": "600"}, {"width": 640.5}, {"cy": True},
                                  {"t": [0, 0, "1"]}, {"fy": None}])
def test_8_camera_values_must_be_numbers(edit):
    from inverse.sft.camera import camera_from_json
    from inverse.sft.inputs import InputError

    camera = {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480,
              "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 1]}
    camera_from_json(camera)
    with pytest.raises(InputError, match=next(iter(edit))):
        camera_from_json({**camera, **edit})


def test_8_a_mirrored_uv_chart_is_reported(tmp_path, caplog):
    from taichi_ndf.geometry.mesh_surface import MeshSurface

    write_sheet(tmp_path / "mirrored.obj", mirrored=True)
    with caplog.at_level(logging.WARNING):
        MeshSurface.from_file(tmp_path / "mirrored.obj")
    assert "mirrored" in caplog.text and "normal" in caplog.text
    caplog.clear()
    write_sheet(tmp_path / "plain.obj")
    with caplog.at_level(logging.WARNING):
        MeshSurface.from_file(tmp_path / "plain.obj")
    assert "mirrored" not in caplog.text


# -- 9: plain install ------------------------------------------------------------------------

def _third_party_imports() -> tuple[set[str], set[str]]:
    """Third-party top-level module names imported by the packages: (at module level, only
    inside functions, i.e. lazily)."""
    eager, lazy = set(), set()
    for package in ("taichi_ndf", "inverse"):
        for path in (ROOT / package).rglob("*.py"):
            tree = ast.parse(path.read_text())
            module_level = {id(n) for n in tree.body}
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    found = {a.name.split(".")[0] for a in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0:
                    found = {node.module.split(".")[0]}
                else:
                    continue
                (eager if id(node) in module_level else lazy).update(found)
    local = set(sys.stdlib_module_names) | {"taichi_ndf", "inverse"}
    return eager - local, lazy - local - eager


def _requirement_names(requirements: list[str]) -> set[str]:
    return {d.split(">")[0].split("=")[0].split("<")[0].strip() for d in requirements}


def test_9_every_imported_package_is_a_base_dependency():
    """Module-level imports need a base dependency; an import inside a function (an optional
    feature, imported lazily with a message naming its extra) a base dependency or an extra."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    distributions = {"cv2": "opencv-python-headless", "pxr": "usd-core",
                     "imageio_ffmpeg": "imageio-ffmpeg"}
    base = _requirement_names(project["dependencies"])
    extras = set().union(*(_requirement_names(v) for k, v in
                           project["optional-dependencies"].items() if k != "dev"))
    eager, lazy = _third_party_imports()
    missing = {n for n in eager if distributions.get(n, n) not in base}
    assert not missing, f"imported but not in [project] dependencies: {sorted(missing)}"
    missing = {n for n in lazy if distributions.get(n, n) not in base | extras}
    assert not missing, f"imported lazily but in no dependency or extra: {sorted(missing)}"


def test_9_importing_the_command_line_tools_prints_no_taichi_banner():
    modules = ("taichi_ndf.cli.sim", "taichi_ndf.cli.export", "taichi_ndf.cli.validate",
               "inverse.cli.fit_material", "inverse.cli.sft", "inverse.cli.sft_eval")
    done = subprocess.run([sys.executable, "-c", "; ".join(f"import {m}" for m in modules)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "[Taichi]" not in done.stdout + done.stderr

"""The long-running tools besides ndf-sim (`test_progress.py`) on a pseudo-terminal: each shows a
progress bar within 5 s of the start of its solve, and ndf-sft one for each of its two long
stages (tracking, then the reconstruction, which was silent before: 15 s on the 30-frame roll,
about a minute on a 50-frame capture)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from test_progress import WRAPPER, _first_progress, _progress_times

ROOT = Path(__file__).resolve().parents[1]
ROLL = ROOT / "data" / "sft" / "roll"


def _tool(module: str, *args) -> list[str]:
    return [sys.executable, "-c", WRAPPER.format(module=module), *map(str, args)]


def test_ndf_validate_spline_shows_progress_within_5_s(tmp_path):
    command = _tool("taichi_ndf.cli.validate", "square_plate", "--field", "spline", "--quick",
                    "--out", tmp_path / "v")
    seconds, text = _first_progress(command, r"Newton level 0", timeout=60)
    assert seconds < 5, f"first progress after {seconds:.1f} s:\n{text}"


def test_ndf_validate_siren_shows_progress_within_5_s(tmp_path):
    """The SIREN path (Adam, with its Newton scale estimate first) of ndf-validate."""
    command = _tool("taichi_ndf.cli.validate", "square_plate", "--field", "siren", "--quick",
                    "--out", tmp_path / "v")
    seconds, text = _first_progress(command, r"Newton level 0|Adam, load 1", timeout=90)
    assert seconds < 5, f"first progress after {seconds:.1f} s:\n{text}"


def test_ndf_sft_shows_tracking_then_reconstruction_progress(tmp_path):
    inputs = ["--frames", ROLL / "frames", "--camera", ROLL / "camera.json", "--template",
              ROLL / "template.obj", "--texture", ROLL / "texture.png", "--masks", ROLL / "masks"]
    command = _tool("inverse.cli.sft", *inputs, "--out", tmp_path / "s")
    # the reconstruction's bar with frames counted (its stage follows the tracking's)
    (tracking, reconstruction), text = _progress_times(
        command, [r"SfT tracking, frames", r"SfT reconstruction, frames: +\d+%.*\| *[1-9]\d*/29"],
        timeout=120)
    assert tracking < 5, f"first progress after {tracking:.1f} s:\n{text}"
    assert reconstruction > tracking


def test_ndf_fit_material_shows_progress_within_5_s(tmp_path):
    from taichi_ndf.io import write_obj
    from taichi_ndf.io.grid import grid_mesh
    from taichi_ndf.scene.reader import load_scene

    scene_file = ROOT / "scenes" / "inverse" / "cantilever_strip.toml"
    scene = load_scene(scene_file)
    grid = grid_mesh(scene.model.surface.domain.bounds, scene.output.resolution)
    observed = tmp_path / "flat.obj"  # the undeformed strip: a fit's start, any shape will do
    write_obj(observed, np.column_stack([grid.xi, np.zeros(len(grid.xi))]), grid.faces)
    command = _tool("inverse.cli.fit_material", scene_file, "--observed", observed,
                    "--estimate", "bending", "--quick", "--out", tmp_path / "f")
    seconds, text = _first_progress(command, r"equilibrium|outer fit", timeout=60)
    assert seconds < 5, f"first progress after {seconds:.1f} s:\n{text}"


def test_ndf_sweep_says_its_plan_within_5_s(tmp_path):
    study = tmp_path / "study.toml"
    study.write_text(f'job = "scene"\nbase = "{ROOT / "scenes" / "napkin.toml"}"\n'
                     '[options]\nquick = true\n[axes]\n"material.stiffness_scale" = [0.5, 1.0]\n')
    command = _tool("taichi_ndf.cli.sweep", study, "--out", tmp_path / "out")
    seconds, text = _first_progress(command, r"study: 2 runs", timeout=60)
    assert seconds < 5, f"first progress after {seconds:.1f} s:\n{text}"


def test_ndf_sft_eval_shows_its_frames_within_5_s(tmp_path):
    """ndf-sft-eval against point clouds (a capture's 50 Kinect clouds take about a minute):
    a bar for reading the frames, then one for their chamfer, each counting frames."""
    from inverse.sft.metrics import surface_samples
    from taichi_ndf.io import write_obj

    t = np.linspace(0.0, 1.0, 9)
    x, y = np.meshgrid(t, t, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.ones(x.size)])
    a = (np.arange(8)[:, None] * 9 + np.arange(8)[None, :]).ravel()
    faces = np.concatenate([np.column_stack([a, a + 9, a + 10]),
                            np.column_stack([a, a + 10, a + 1])])
    (tmp_path / "gt").mkdir()
    for i in range(12):
        write_obj(tmp_path / "pred" / f"{i:06d}.obj", vertices, faces)
        np.save(tmp_path / "gt" / f"point_cloud_{i:03d}.npy",
                surface_samples(vertices, faces, count=20000, seed=i))
    command = _tool("inverse.cli.sft_eval", "--pred", tmp_path / "pred", "--gt",
                    tmp_path / "gt")
    (first, counted), text = _progress_times(
        command, [r"read 12 meshes and clouds", r"chamfer of 12 frames.*\| *1[0-2]/12"],
        timeout=90)
    assert first < 5, f"first progress after {first:.1f} s:\n{text}"
    assert counted >= first


def test_ndf_export_shows_its_stage_within_5_s(tmp_path):
    """ndf-export of a run at a fine resolution (seconds for a million-vertex mesh)."""
    import subprocess

    from test_progress import SCENE

    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE.format(field='type = "spline"\nspans = [4, 4]',
                                  training="newton_max_iterations = 300"))
    subprocess.run([sys.executable, "-m", "taichi_ndf.cli.sim", str(scene), "--out",
                    str(tmp_path / "run"), "--no-pictures"], check=True, cwd=ROOT,
                   capture_output=True)
    command = _tool("taichi_ndf.cli.export", tmp_path / "run", "--resolution", 600,
                    "--out", tmp_path / "fine.ply")
    (first, done), text = _progress_times(
        command, [r"export 600 × 600 mesh to fine\.ply", r"wrote|2/2"], timeout=90)
    assert first < 5, f"first progress after {first:.1f} s:\n{text}"
    assert done >= first

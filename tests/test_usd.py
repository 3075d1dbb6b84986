"""USD export of a run: read back with pxr, points, UVs and time samples equal the run's OBJ
files (rounded to float32, USD's point type) exactly; a missing [usd] extra is named."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from test_cli import SMALL_NAPKIN, run_sim, write_scene

from taichi_ndf.cli import export

pxr = pytest.importorskip("pxr", reason="usd-core (pip install 'taichi-ndf[usd]') is missing")
from pxr import Usd, UsdGeom  # noqa: E402

# The small napkin in two load steps (a trajectory of two frames), writing result.usdc and a
# render.png of two views.
SCENE = (SMALL_NAPKIN.format(lr=1e-3)
         .replace("checkpoint_every = 5", "checkpoint_every = 5\nload_steps = [0.5, 1.0]")
         .replace("resolution = [16, 16]",
                  'resolution = [16, 16]\nusd = true\nviews = ["iso", "top"]'))


def obj_rows(path: Path, tag: str, columns) -> np.ndarray:
    lines = [ln for ln in path.read_text().splitlines() if ln.startswith(tag + " ")]
    return np.loadtxt(lines, usecols=columns, ndmin=2)


def obj_faces(path: Path) -> np.ndarray:
    lines = [ln.replace("/", " ") for ln in path.read_text().splitlines() if ln.startswith("f ")]
    return np.loadtxt(lines, usecols=(1, 3, 5), dtype=np.int64) - 1


def as_f32(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float32)


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("usd")
    assert run_sim(write_scene(tmp, SCENE), "--out", tmp / "run") == 0
    return tmp / "run"


def test_stage_holds_the_run_obj_files_exactly(run):
    stage = Usd.Stage.Open(str(run / "result.usdc"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z  # gravity along -z
    assert stage.GetDefaultPrim().GetPath() == "/World"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/deformed"))
    points = mesh.GetPointsAttr()

    final = run / "mesh.obj"
    np.testing.assert_array_equal(np.array(points.Get(Usd.TimeCode.Default())),
                                  as_f32(obj_rows(final, "v", (1, 2, 3))))
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3),
                                  obj_faces(final))
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.vertex
    np.testing.assert_array_equal(np.array(st.Get()), as_f32(obj_rows(final, "vt", (1, 2))))

    frames = sorted((run / "trajectory").glob("step_*.obj"))
    assert len(frames) == 2 and points.GetTimeSamples() == [0.0, 1.0]
    for k, frame in enumerate(frames):
        np.testing.assert_array_equal(np.array(points.Get(Usd.TimeCode(k))),
                                      as_f32(obj_rows(frame, "v", (1, 2, 3))))
    load_factor = mesh.GetPrim().GetAttribute("ndf:loadFactor")
    assert [load_factor.Get(Usd.TimeCode(k)) for k in range(2)] == [0.5, 1.0]
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0.0, 1.0)

    reference = UsdGeom.Mesh(stage.GetPrimAtPath("/World/reference"))
    np.testing.assert_array_equal(np.array(reference.GetPointsAttr().Get()),
                                  as_f32(obj_rows(run / "reference.obj", "v", (1, 2, 3))))
    assert reference.GetPurposeAttr().Get() == UsdGeom.Tokens.guide
    normals = np.array(mesh.GetNormalsAttr().Get(Usd.TimeCode(1)))
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-6)


def bound_colour(mesh) -> list[float]:
    """The diffuse colour of the UsdPreviewSurface bound to a mesh."""
    from pxr import UsdShade

    material, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
    shader = material.ComputeSurfaceSource()[0]
    assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
    return list(shader.GetInput("diffuseColor").Get())


def test_display_material_and_frame_rate(run):
    stage = Usd.Stage.Open(str(run / "result.usdc"))
    deformed = UsdGeom.Mesh(stage.GetPrimAtPath("/World/deformed"))
    assert bound_colour(deformed) == pytest.approx([95 / 255, 150 / 255, 205 / 255])
    assert stage.GetFramesPerSecond() == stage.GetTimeCodesPerSecond() == 4.0


def test_render_png_has_the_scene_views(run):
    import cv2

    # 600 pixels high; each view 300-800 wide (fitted to the framed shape), then the colour bar.
    height, width, _ = cv2.imread(str(run / "render.png")).shape
    assert height == 600 and 2 * 300 < width < 2 * 800 + 200


def test_strain_primvars_equal_the_ply_values(run):
    from taichi_ndf.io import read_mesh
    from taichi_ndf.io.run_files import read_run

    stage = Usd.Stage.Open(str(run / "result.usdc"))
    primvars = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/deformed"))
    ply = read_mesh(run / "mesh.ply").vertex_scalars
    for name in ("membrane_strain", "bending_strain", "energy_density"):
        np.testing.assert_array_equal(np.array(primvars.GetPrimvar(name).Get()),
                                      as_f32(ply[name]), err_msg=name)
    displacement = np.array(primvars.GetPrimvar("displacement").Get())
    expected = np.linalg.norm(obj_rows(run / "mesh.obj", "v", (1, 2, 3))
                              - obj_rows(run / "reference.obj", "v", (1, 2, 3)), axis=1)
    np.testing.assert_array_equal(displacement, as_f32(expected))
    probes = stage.GetPrimAtPath("/World/probes")
    assert list(probes.GetCustomDataByKey("names")) == ["free_corner"]
    points = UsdGeom.Points(probes).GetPointsAttr()
    run_files = read_run(run)
    assert points.GetTimeSamples() == [0.0, 1.0]  # the probes move with the frames
    for k in range(2):
        np.testing.assert_array_equal(np.array(points.Get(Usd.TimeCode(k))),
                                      as_f32(run_files.probe_positions(k)[0]))


def test_export_cli_writes_obstacles_and_refuses_to_overwrite(run, tmp_path, capsys):
    obstacle = run / "obstacles" / "post.obj"
    obstacle.parent.mkdir(exist_ok=True)
    obstacle.write_text("v 0 0 -2\nv 1 0 -2\nv 0 1 -2\nf 1 2 3\n")
    try:
        out = tmp_path / "run.usda"
        assert export.main([str(run), "--format", "usd", "--out", str(out)]) == 0
        stage = Usd.Stage.Open(str(out))
        post = UsdGeom.Mesh(stage.GetPrimAtPath("/World/obstacles/post"))  # its scene name
        np.testing.assert_array_equal(np.array(post.GetPointsAttr().Get()),
                                      as_f32([[0, 0, -2], [1, 0, -2], [0, 1, -2]]))
        assert bound_colour(post) == pytest.approx([160 / 255] * 3)  # the renders' grey
        assert export.main([str(run / "checkpoint.pt"), "--format", "usd", "--out",
                            str(out)]) == 2
        assert "exists; pass --overwrite" in capsys.readouterr().err
    finally:
        obstacle.unlink()
    assert export.main([str(tmp_path), "--format", "usd"]) == 2
    assert "holds no result.json" in capsys.readouterr().err


def test_missing_usd_extra_is_named(run, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pxr.Usd", None)  # import pxr.Usd now fails
    assert export.main([str(run), "--format", "usd", "--out", str(tmp_path / "x.usdc")]) == 2
    assert "pip install 'taichi-ndf[usd]'" in capsys.readouterr().err
    scene = write_scene(tmp_path, SCENE)
    assert run_sim(scene, "--out", tmp_path / "never") == 2
    err = capsys.readouterr().err
    assert "[output] usd = true" in err and "taichi-ndf[usd]" in err
    assert not (tmp_path / "never" / "checkpoint.pt").exists()  # refused before the solve

"""A USD export imported into Blender (bpy, Blender as a Python module): the objects under
their names (the obstacle under its scene name, in the /World group), the display material
bound, time code k at Blender's frame k over the stage's frame range, and the trajectory as
animated points. (Blender 5.0.1 keeps its scene's 24 fps: its importer does not read the
stage's frames per second, which the USD test checks equal to the time codes per second.)

Needs bpy (`pip install bpy`: Blender's own wheel, ~350 MB, CPython 3.11 for Blender 5.0) and
usd-core; skips, saying which is missing, without them.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_render_figure import fake_run

pytest.importorskip("pxr", reason="usd-core (pip install 'taichi-ndf[usd]') is missing")
bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module: pip install bpy, "
                          "~350 MB, a wheel for CPython 3.11) is not installed")

from taichi_ndf.export.usd import write_run_usd  # noqa: E402
from taichi_ndf.io.run_files import read_run  # noqa: E402


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """The run of `fake_run` (three frames, an obstacle "block", a probe "tip") written as USD
    and imported into an empty Blender scene."""
    tmp = tmp_path_factory.mktemp("blender")
    run = read_run(fake_run(tmp / "run", frames=3, obstacle=True))
    stage = write_run_usd(run, tmp / "run.usdc")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    # import_guide: the reference surface is a guide (purpose "guide"), left out by default
    assert bpy.ops.wm.usd_import(filepath=str(stage), import_guide=True) == {"FINISHED"}
    return run, bpy.context.scene


def mesh_object(name: str):
    """The imported mesh object called `name` (Blender may suffix a duplicate name)."""
    found = [o for o in bpy.data.objects if o.type == "MESH" and o.name.split(".")[0] == name]
    assert len(found) == 1, sorted(o.name for o in bpy.data.objects)
    return found[0]


def evaluated_vertices(obj, frame: int) -> np.ndarray:
    """World positions (V, 3) of a mesh object's vertices at `frame`, after its modifiers
    (the importer animates time-sampled points with a Mesh Sequence Cache modifier)."""
    bpy.context.scene.frame_set(frame)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    try:
        local = np.array([v.co[:] for v in mesh.vertices])
    finally:
        evaluated.to_mesh_clear()
    matrix = np.array(obj.matrix_world)
    return local @ matrix[:3, :3].T + matrix[:3, 3]


def test_objects_keep_their_names(imported):
    run, _ = imported
    names = {o.name.split(".")[0] for o in bpy.data.objects}
    assert {"deformed", "reference", "block"} <= names, sorted(names)
    assert "obstacle_0" not in names
    assert mesh_object("block").parent.name == "World"
    np.testing.assert_allclose(evaluated_vertices(mesh_object("block"), 0),
                               run.obstacles[0].vertices, atol=1e-6)


def test_display_material_is_bound(imported):
    deformed = mesh_object("deformed")
    materials = [slot.material for slot in deformed.material_slots if slot.material]
    assert [m.name.split(".")[0] for m in materials] == ["surface"]
    shader = next(n for n in materials[0].node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    colour = list(shader.inputs["Base Color"].default_value)[:3]
    assert colour == pytest.approx([95 / 255, 150 / 255, 205 / 255], abs=1e-6)  # render.png's


def test_frame_range_and_trajectory(imported):
    run, scene = imported
    assert (scene.frame_start, scene.frame_end) == (0, len(run.frames) - 1)
    deformed = mesh_object("deformed")
    for k, frame in enumerate(run.frames):
        np.testing.assert_allclose(evaluated_vertices(deformed, k), frame.vertices, atol=1e-6,
                                   err_msg=f"frame {k}")

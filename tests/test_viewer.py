"""`ndf-view` without a browser: its help and the missing-extra message work without viser, and
the viewer's frame/colour state (what the browser test then sees drawn)."""

from __future__ import annotations

import json
import socket
import sys

import numpy as np
import pytest
from test_render_figure import fake_run

from taichi_ndf.cli import view
from taichi_ndf.io.run_files import read_run


def test_help_and_missing_extra_without_viser(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser now fails
    with pytest.raises(SystemExit) as stop:
        view.main(["--help"])
    assert stop.value.code == 0 and "--port" in capsys.readouterr().out
    assert view.main([str(fake_run(tmp_path))]) == 2
    assert "pip install 'taichi-ndf[viewer]'" in capsys.readouterr().err


def test_bad_input_exits_2(tmp_path, capsys):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    assert view.main([str(tmp_path / "nothing")]) == 2
    assert "run directory not found" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        view.main([str(tmp_path), "--port", "70000"])
    assert stop.value.code == 2


def test_frames_and_colours(tmp_path):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    from taichi_ndf.viewer.app import RunViewer

    run = read_run(fake_run(tmp_path, frames=3, obstacle=True))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    viewer = RunViewer(run, port=port)
    try:
        assert viewer.url == f"http://127.0.0.1:{port}"
        vertices, values, note = viewer.frame_state()  # the last frame, bending strain
        np.testing.assert_array_equal(vertices, run.frames[-1].vertices)
        np.testing.assert_array_equal(values, run.quantity("bending_strain"))
        viewer.frame.value = 0
        vertices, values, note = viewer.frame_state()
        np.testing.assert_array_equal(vertices, run.frames[0].vertices)
        assert values is None and "final frame only" in note and "load factor 0.3333" in note
        assert "probes interpolated" in viewer.note.content
        # fake_run's frame k is the reference + (k + 1)/3 of the displacement: the tip at 0.1 m
        for handle in viewer.probes[0]:
            assert handle.visible
            np.testing.assert_allclose(handle.position, [1.0, 1.0, 0.1], atol=1e-6)
        viewer.colour.value = "displacement"
        _, values, _ = viewer.frame_state()
        np.testing.assert_allclose(values, np.linalg.norm(run.frames[0].vertices - run.reference,
                                                          axis=1))
    finally:
        viewer.stop()


def test_a_taken_port_prints_the_port_actually_bound(tmp_path, capsys, monkeypatch):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    run = fake_run(tmp_path)

    def interrupt(_seconds):
        raise KeyboardInterrupt

    monkeypatch.setattr(view.time, "sleep", interrupt)  # served, then Ctrl-C at once
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert view.main([str(run), "--port", str(port)]) == 0
    out = capsys.readouterr().out
    bound = int(out.split("http://127.0.0.1:")[1].split()[0])
    assert bound != port and f"port {port} was taken" in out, out
    assert f"ssh -L {bound}:127.0.0.1:{bound} HOST" in out and f"{port}:127" not in out, out


def test_probes_on_every_frame(tmp_path):
    """Inside a triangle the interpolation is linear; a load step that result.json records
    gives the solver's own value."""
    path = fake_run(tmp_path, frames=2)
    probes = json.loads((path / "probes.json").read_text())
    probes["middle"] = {"xi": [0.5, 0.5], "reference": [0.37, 0.61, 0.0],
                        "displacement": [0.0, 0.0, 0.0]}
    (path / "probes.json").write_text(json.dumps(probes))
    run = read_run(path)
    positions, exact = run.probe_positions(0)
    assert not exact
    np.testing.assert_allclose(positions[0], [1.0, 1.0, 0.15], atol=1e-9)  # a mesh vertex
    # fake_run's sheet rises as 0.3 x² and moves in z only; frame 0 is half loaded. On the
    # triangles about x = 0.37 (nodes x0 < x < x1) the mesh interpolates x² linearly.
    nodes = np.unique(run.reference[:, 0])
    x0, x1 = nodes[nodes <= 0.37].max(), nodes[nodes > 0.37].min()
    expected = 0.5 * 0.3 * (x0 ** 2 + (0.37 - x0) * (x0 + x1))
    np.testing.assert_allclose(positions[1], [0.37, 0.61, expected], atol=1e-12)
    final, exact = run.probe_positions(1)
    assert exact and np.allclose(final[0], [1.0, 1.0, 0.3])

    result = json.loads((path / "result.json").read_text())
    result["load_steps"] = [{"load_factor": 0.5, "energy": -0.5,
                             "probes": {"tip": [0.0, 0.01, 0.2], "middle": [0, 0, 0.02]}}]
    (path / "result.json").write_text(json.dumps(result))
    positions, exact = read_run(path).probe_positions(0)
    assert exact
    np.testing.assert_allclose(positions, [[1.0, 1.01, 0.2], [0.37, 0.61, 0.02]])


def test_camera_frames_the_mesh_and_plot_has_the_decrement(tmp_path):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    from taichi_ndf.viewer.app import FOV_DEG, RunViewer

    path = fake_run(tmp_path, frames=3)
    result = json.loads((path / "result.json").read_text())
    for k, row in enumerate(result["history"]):
        row["decrement"] = 0.0 if k == 4 else 10.0 ** -k
    (path / "result.json").write_text(json.dumps(result))
    run = read_run(path)
    viewer = RunViewer(run, port=0, frame=0)
    try:
        assert int(viewer.frame.value) == 0
        assert viewer.server.initial_camera.fov == pytest.approx(np.radians(FOV_DEG))
        width, height = 1600, 900
        camera = viewer.framing(run.deformed, width / height)
        assert camera.fov_y_deg == FOV_DEG
        points = camera.to_camera(run.deformed)
        pixels = points[:, :2] / points[:, 2:] @ np.diag(camera.intrinsics(width, height)
                                                          [[0, 1], [0, 1]])
        spread = np.ptp(pixels, axis=0) / [width, height]
        assert 0.8 < spread.max() <= 1.0, spread  # fills the canvas on its tighter side
        x, pi, log_decrement = viewer.plot.data
        np.testing.assert_array_equal(x, np.arange(5))
        np.testing.assert_array_equal(pi, run.history[1])
        np.testing.assert_allclose(log_decrement[:4], [0, -1, -2, -3])
        assert np.isnan(log_decrement[4])  # λ² = 0: a gap on the log axis
        assert [s["label"] for s in viewer.plot.series] == ["iteration", "Π [J]",
                                                            "log₁₀ λ² [J]"]
    finally:
        viewer.stop()
    adam = read_run(fake_run(tmp_path / "adam"))
    viewer = RunViewer(adam, port=0)
    try:
        assert len(viewer.plot.data) == 2  # Π only: an Adam run has no decrement
    finally:
        viewer.stop()


def test_frame_out_of_range_exits_2(tmp_path, capsys):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    assert view.main([str(fake_run(tmp_path, frames=2)), "--frame", "2", "--port", "0"]) == 2
    assert "frame 2 is not one of the run's 2 trajectory frames" in capsys.readouterr().err


def test_run_without_reference_shows_probes_at_the_final_frame_only(tmp_path):
    pytest.importorskip("viser", reason="viser (pip install 'taichi-ndf[viewer]') is missing")
    from taichi_ndf.viewer.app import RunViewer

    path = fake_run(tmp_path, frames=2)
    (path / "reference.obj").unlink()  # a run written before reference.obj existed
    viewer = RunViewer(read_run(path), port=0, frame=0)
    try:
        assert "final frame only" in viewer.note.content and not viewer.probes
        viewer.frame.value = 1
        (sphere, label), = viewer.probes
        assert sphere.visible and label.visible
        np.testing.assert_allclose(sphere.position, [1.0, 1.0, 0.3])
        viewer.frame.value = 0
        assert not sphere.visible and not label.visible
    finally:
        viewer.stop()

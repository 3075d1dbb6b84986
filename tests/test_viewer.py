"""`ndf-view` without a browser: its help and the missing-extra message work without viser, and
the viewer's frame/colour state (what the browser test then sees drawn)."""

from __future__ import annotations

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
        assert not any(handle.visible for handle in viewer.probes)  # final positions only
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

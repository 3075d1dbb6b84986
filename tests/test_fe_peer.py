"""benchmarks/fe_peer.py (issue 28) without running a solve: its --help, the one-line skip where
Kratos is not importable (a stand-in package hides it; Kratos is never needed here), bad
levels refused with exit code 2, and the per-level scene it writes being the scene
`--field spline` makes, with the spans given."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

from tests.scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "fe_peer.py"


def _module():
    return load_script("benchmarks/fe_peer.py")


def _run(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True,
                          timeout=120, env={**os.environ, **(env or {})})


def test_help_lists_the_options():
    proc = _run("--help")
    assert proc.returncode == 0, proc.stderr
    for option in ("--cases", "--levels", "--json", "--codes"):
        assert option in proc.stdout


def test_bad_level_is_refused_in_one_line():
    proc = _run("--levels", "0")
    assert proc.returncode == 2
    assert "--levels" in proc.stderr.strip().splitlines()[-1]


def test_kratos_absent_is_skipped_with_one_line(tmp_path):
    hidden = tmp_path / "KratosMultiphysics"
    hidden.mkdir()
    (hidden / "__init__.py").write_text("raise ImportError('hidden by the test')\n")
    out = tmp_path / "peer.json"
    proc = _run("--codes", "kratos", "--cases", "roof", "--levels", "1", "--json", str(out),
                env={"PYTHONPATH": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr
    skip = [line for line in proc.stdout.splitlines() if "Kratos skipped" in line]
    assert skip == ["fe_peer: Kratos skipped (not importable: ImportError: hidden by the test)"]
    report = json.loads(out.read_text())
    assert report["kratos_skipped"] == "ImportError: hidden by the test"
    assert report["cases"]["roof"]["rows"] == []


def test_level_scene_is_the_spline_scene_on_the_given_spans(tmp_path):
    from taichi_ndf.scene.field import with_field_type

    scene = ROOT / "validation" / "scenes" / "cantilever_shear.toml"
    written = _module().spline_scene(scene, (16, 2), tmp_path / "s.toml")
    with open(scene, "rb") as f:
        expected = with_field_type(tomllib.load(f), "spline")
    expected["field"]["spans"] = [16, 2]
    with open(written, "rb") as f:
        assert tomllib.load(f) == expected

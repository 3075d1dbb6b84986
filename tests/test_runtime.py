import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import taichi_ndf
from taichi_ndf import runtime
from taichi_ndf.runtime import Runtime

ROOT = Path(__file__).resolve().parents[1]


def test_init_is_idempotent_with_same_settings(taichi_runtime):
    assert taichi_ndf.init(arch="cpu", precision="f64", seed=0) == taichi_runtime


def test_second_init_with_other_settings_raises(taichi_runtime):
    with pytest.raises(RuntimeError, match="already initialised"):
        taichi_ndf.init(arch="cpu", precision="f32", seed=0)


def test_runtime_validates_settings():
    with pytest.raises(ValueError, match="unknown arch"):
        Runtime(arch="tpu")
    with pytest.raises(ValueError, match="unknown precision"):
        Runtime(precision="f16")


def test_dtype_follows_precision(taichi_runtime):
    assert taichi_runtime.dtype == torch.float64
    assert taichi_ndf.current().device.type == "cpu"


def test_runtime_arches_follow_the_backend():
    assert "opengl" in runtime.arches("taichi")
    assert "opengl" not in runtime.arches("quadrants")
    assert Runtime(arch="opengl", backend="taichi").arch == "opengl"
    with pytest.raises(ValueError, match="unknown arch 'opengl' for the quadrants backend"):
        Runtime(arch="opengl", backend="quadrants")
    with pytest.raises(ValueError, match="unknown Taichi backend 'jax'"):
        Runtime(backend="jax")


def test_the_session_runs_on_the_selected_backend(taichi_runtime):
    from taichi_ndf.runtime import ti

    wanted = os.environ.get(runtime.BACKEND_VARIABLE) or runtime.installed_backends()[0]
    assert taichi_runtime.backend == wanted == ti.__name__ == runtime.selected_backend()
    assert runtime.machine_description(taichi_runtime)["backend"].startswith(wanted + " ")


def test_the_bound_backend_cannot_change(taichi_runtime):
    other = next(name for name in runtime.BACKENDS if name != taichi_runtime.backend)
    with pytest.raises(RuntimeError, match=f"cannot switch to {other}"):
        runtime.language(other)


@pytest.mark.parametrize("value, message", [
    ("jax", "TAICHI_NDF_BACKEND=jax: unknown Taichi backend 'jax'"),
    ("quadrants", "TAICHI_NDF_BACKEND=quadrants: the quadrants backend is not installed: "
     r"pip install taichi-ndf\[quadrants\]"),
])
def test_backend_variable_is_checked_before_anything_is_imported(monkeypatch, value, message):
    monkeypatch.setattr(runtime, "_language", None)  # as before the first kernel module
    monkeypatch.setattr(runtime.importlib.util, "find_spec",
                        lambda name: None if name == "quadrants" else object())
    monkeypatch.setenv(runtime.BACKEND_VARIABLE, value)
    with pytest.raises((ValueError, RuntimeError), match=message):
        runtime.selected_backend()


def test_without_the_variable_taichi_comes_first(monkeypatch):
    monkeypatch.setattr(runtime, "_language", None)
    monkeypatch.delenv(runtime.BACKEND_VARIABLE, raising=False)
    monkeypatch.setattr(runtime.importlib.util, "find_spec", lambda name: object())
    assert runtime.selected_backend() == "taichi"
    monkeypatch.setattr(runtime.importlib.util, "find_spec",
                        lambda name: None if name == "taichi" else object())
    assert runtime.selected_backend() == "quadrants"
    assert runtime.arches() == runtime.BACKEND_ARCHES["quadrants"]
    monkeypatch.setattr(runtime.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(RuntimeError, match="neither taichi nor quadrants is installed"):
        runtime.selected_backend()


def test_a_bad_backend_variable_is_one_line_and_exit_2_for_the_tools(tmp_path):
    env = {**os.environ, runtime.BACKEND_VARIABLE: "jax",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run([sys.executable, "-m", "taichi_ndf.cli.sim", "--help"], env=env,
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "TAICHI_NDF_BACKEND=jax" in done.stderr

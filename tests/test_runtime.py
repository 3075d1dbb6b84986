import pytest
import torch

import taichi_ndf
from taichi_ndf.runtime import Runtime


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

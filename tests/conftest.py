"""One Taichi runtime for the whole test session: CPU, float64."""

import pytest
import torch

import taichi_ndf


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    # Torch's OpenMP threads spin between small ops and starve Taichi's own thread pool on
    # 2 cores (measured: a field step 5x slower with 2 torch threads than with 1).
    torch.set_num_threads(1)
    return taichi_ndf.init(arch="cpu", precision="f64", seed=0)

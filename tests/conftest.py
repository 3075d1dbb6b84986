"""One Taichi runtime for the whole test session: CPU, float64."""

import pytest

import taichi_ndf


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    return taichi_ndf.init(arch="cpu", precision="f64", seed=0)

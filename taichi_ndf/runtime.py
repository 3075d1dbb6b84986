"""The one place that initialises Taichi.

Nothing Taichi happens at import time. ``init`` is called once per process (tests use a
session fixture); a second call with the same settings is a no-op, a second call with other
settings raises, because re-initialising Taichi invalidates every field and kernel that exists.
"""

from __future__ import annotations

import logging
import os
import platform
import random
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

log = logging.getLogger(__name__)

ARCHES = ("cpu", "x64", "cuda", "vulkan", "metal", "opengl", "gpu")
PRECISIONS = ("f32", "f64")


@dataclass(frozen=True)
class Runtime:
    """Settings of the initialised Taichi runtime."""

    arch: str = "cpu"
    precision: str = "f64"
    seed: int = 0
    debug: bool = False

    def __post_init__(self):
        if self.arch not in ARCHES:
            raise ValueError(f"unknown arch {self.arch!r}; choose one of {ARCHES}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"unknown precision {self.precision!r}; choose one of {PRECISIONS}")

    @property
    def dtype(self) -> torch.dtype:
        """Torch dtype of all real-valued tensors of this runtime."""
        return torch.float64 if self.precision == "f64" else torch.float32

    @property
    def device(self) -> torch.device:
        """Torch device that holds tensors shared with Taichi kernels."""
        if self.arch in ("cuda", "gpu") and torch.cuda.is_available():
            return torch.device("cuda")
        return torch.device("cpu")


_current: Runtime | None = None


def cache_dir() -> Path:
    """Directory of Taichi's offline kernel cache (``TAICHI_NDF_CACHE`` overrides it)."""
    default = Path.home() / ".cache" / "taichi_ndf" / "ti_cache"
    return Path(os.environ.get("TAICHI_NDF_CACHE", default))


def init(arch: str = "cpu", precision: str = "f64", seed: int = 0, *,
         debug: bool = False) -> Runtime:
    """Initialise Taichi for this process and seed torch, numpy and Python's RNG.

    arch: "cpu" (Taichi's x64 backend), "cuda", "vulkan", "metal", "opengl" or "gpu".
    precision: "f32" or "f64"; the default real type of kernels and of all tensors.
    debug: Taichi debug mode (bounds checks, autodiff validation); slow.
    """
    global _current
    wanted = Runtime(arch=arch, precision=precision, seed=seed, debug=debug)
    if _current is not None:
        if _current == wanted:
            return _current
        raise RuntimeError(
            f"taichi_ndf is already initialised with {_current}; cannot re-initialise with "
            f"{wanted} in the same process (call taichi_ndf.reset() first, which invalidates "
            "every existing field and network)"
        )
    import taichi as ti

    ti_arch = {
        "cpu": ti.x64, "x64": ti.x64, "cuda": ti.cuda, "vulkan": ti.vulkan,
        "metal": ti.metal, "opengl": ti.opengl, "gpu": ti.gpu,
    }[arch]
    fp = ti.f64 if precision == "f64" else ti.f32
    path = cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    ti.init(
        arch=ti_arch,
        default_fp=fp,
        random_seed=seed,
        debug=debug,
        offline_cache=True,
        offline_cache_file_path=str(path),
        ad_stack_size=512,
        log_level=ti.WARN,
    )
    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)
    _current = wanted
    log.info("taichi_ndf initialised: %s (cache %s)", wanted, path)
    return wanted


def reset() -> None:
    """Tear Taichi down so ``init`` may be called again (tests only)."""
    global _current
    if _current is None:
        return
    import taichi as ti

    ti.reset()
    _current = None


def current() -> Runtime:
    """The active runtime; raises if ``init`` has not been called."""
    if _current is None:
        raise RuntimeError(
            "taichi_ndf is not initialised: call taichi_ndf.init(arch=..., precision=...) first")
    return _current


def is_initialised() -> bool:
    return _current is not None


def machine_description(runtime: Runtime) -> dict:
    """Python, platform, processor, CPU count and the runtime's arch and precision (for the
    machine record of result files)."""
    return {"python": platform.python_version(), "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "arch": runtime.arch, "precision": runtime.precision}

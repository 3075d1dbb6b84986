"""taichi-ndf: neural deformation fields on Kirchhoff-Love thin shells, on Taichi."""

import os

# Taichi (and its fork quadrants) prints a version banner when imported; the library (and every
# tool's --help) stays quiet. ENABLE_TAICHI_HEADER_PRINT=1 (ENABLE_QUADRANTS_HEADER_PRINT=1) in
# the environment brings the banner back.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
os.environ.setdefault("ENABLE_QUADRANTS_HEADER_PRINT", "False")

__all__ = ["init", "reset", "current", "is_initialised"]
__version__ = "0.1.0"


def __getattr__(name: str):
    """`init`, `reset`, `current`, `is_initialised` from `taichi_ndf.runtime`, imported on
    first use: importing the package (every tool's --help) does not import torch or Taichi."""
    if name in __all__:
        from taichi_ndf import runtime

        return getattr(runtime, name)
    raise AttributeError(f"module 'taichi_ndf' has no attribute {name!r}")

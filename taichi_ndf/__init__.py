"""taichi-ndf: neural deformation fields on Kirchhoff-Love thin shells, on Taichi."""

import os

# Taichi (and its fork quadrants) prints a version banner when imported; the library (and every
# tool's --help) stays quiet. ENABLE_TAICHI_HEADER_PRINT=1 (ENABLE_QUADRANTS_HEADER_PRINT=1) in
# the environment brings the banner back.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
os.environ.setdefault("ENABLE_QUADRANTS_HEADER_PRINT", "False")

from taichi_ndf.runtime import current, init, is_initialised, reset

__all__ = ["init", "reset", "current", "is_initialised"]
__version__ = "0.1.0"

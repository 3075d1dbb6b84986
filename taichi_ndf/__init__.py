"""taichi-ndf: neural deformation fields on Kirchhoff-Love thin shells, on Taichi."""

from taichi_ndf.runtime import current, init, is_initialised, reset

__all__ = ["init", "reset", "current", "is_initialised"]
__version__ = "0.1.0"

"""Optional dependencies (pip extras), imported only by the features that need them."""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["MissingExtra", "require"]


class MissingExtra(ImportError):
    """An optional package is not installed; the message names the extra that brings it."""


def require(module: str, extra: str, purpose: str) -> ModuleType:
    """Import `module`, or raise MissingExtra naming `pip install 'taichi-ndf[extra]'`."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise MissingExtra(f"{purpose} needs the optional extra [{extra}] (module {module} is "
                           f"missing): pip install 'taichi-ndf[{extra}]'") from err
